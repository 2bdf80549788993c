"""Validation campaigns measured on the independent forward model (:mod:`cell.truth.model`).
Pure numerics.

The design is :class:`cell.diagnosis.synth.Design`'s (seed 000 robot, poses over an hour of
warm-up, straight moves sampled every 2 ms, 70/30 fit/holdout; see that module): the same
poses, moves, temperatures, split and noise levels the plant-based campaigns use, drawn here
by :func:`draw_rows` once per seed. Only the measured x/y come from the truth, so
:func:`measured` can put several truths on the same rows (the validation's combinations
size their second effect that way) and :func:`make_campaign` is the same rows with the
noise added.

Noise, as the plant: repeatability (σ ``repeatability_mm`` per axis) once per pose, on the
true point before the camera; measurement noise (σ ``measurement_noise_mm``) on every
measured value, poses and path samples. Temperature: ``ambient + rise·(1 − e^(−t/τ))``
from a cold start at t = 0; the campaign records it with a sensor noise. An
``offset_bump`` happens at :func:`bump_time`, halfway through the poses in time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cell.diagnosis.replay import first_step_dirs
from cell.diagnosis.synth import Design, straight_move
from cell.kinematics import PRESETS
from cell.measurements import FORMAT, Campaign, CameraSpec, ModelSpec
from cell.truth import model
from cell.truth.parts import Part, compose


@dataclass
class Move:
    """One straight move: command times ``t`` (M,) s since its first frame, commands ``q``
    (M,2) deg, directions ``dirs0`` (2,) before it, start ``start_s`` on the campaign clock,
    its measurement noise ``noise`` (M,2) mm and its split."""

    t: np.ndarray
    q: np.ndarray
    dirs0: np.ndarray
    start_s: float
    noise: np.ndarray
    split: str


@dataclass
class Rows:
    """One campaign without its truth. Poses: commands ``q`` (n,2) deg (whole command
    units), approach directions ``dirs``, times ``t`` s, true and recorded temperatures °C,
    payload kg, split, repeatability ``repeat`` and measurement ``noise`` (n,2) mm."""

    q: np.ndarray
    dirs: np.ndarray
    t: np.ndarray
    temp_true: np.ndarray
    temp_read: np.ndarray
    payload: np.ndarray
    split: np.ndarray
    repeat: np.ndarray
    noise: np.ndarray
    moves: list[Move]


def _warmup(design: Design, t) -> np.ndarray:
    t = np.maximum(np.asarray(t, dtype=float), 0.0)
    return design.ambient_c + design.rise_c * (1.0 - np.exp(-t / design.tau_s))


def draw_rows(seed: int, design: Design = Design()) -> Rows:
    """The poses, moves and noise of campaign ``seed`` (module docstring)."""
    rng = np.random.default_rng(seed)
    g = PRESETS[design.robot]
    n = design.n_points
    q = np.column_stack([rng.uniform(*design.theta1_deg, n),
                         rng.choice((-1.0, 1.0), n) * rng.uniform(*design.theta2_abs_deg, n)])
    q = np.round(q / g.unit[0]) * g.unit[0]
    dirs = rng.choice((-1.0, 1.0), (n, 2))
    t = np.arange(n) * design.pose_period_s + rng.uniform(0, 2.0, n)
    temp = _warmup(design, t)
    rows = Rows(q=q, dirs=dirs, t=t, temp_true=temp,
                temp_read=temp + rng.normal(0, design.temp_sensor_sigma_c, n),
                payload=rng.choice((0.0, 0.5, 1.0), n),
                split=np.where(rng.random(n) < design.holdout_share, "holdout",
                               "fit").astype(object),
                repeat=rng.normal(0, design.repeatability_mm, (n, 2)),
                noise=rng.normal(0, design.measurement_noise_mm, (n, 2)), moves=[])
    if design.n_moves:
        k_hold = max(1, int(round(design.holdout_share * design.n_moves)))
        hold = set(rng.permutation(design.n_moves)[:k_hold].tolist())
        start = (float(t[-1]) if n else 0.0) + 60.0
        for m in range(design.n_moves):
            tm, qm = straight_move(rng, design, g.l1_mm, g.l2_mm, g.limits)
            rows.moves.append(Move(tm, qm, first_step_dirs(qm), start + 10.0 * m,
                                   rng.normal(0, design.measurement_noise_mm, qm.shape),
                                   "holdout" if m in hold else "fit"))
    return rows


def bump_time(rows: Rows) -> float:
    """When an ``offset_bump`` happens: halfway between the first and the last pose (s)."""
    return float(rows.t[0] + rows.t[-1]) / 2.0 if len(rows.t) else 0.0


def nominal_cell(design: Design) -> model.Cell:
    """The nominal cell of ``design`` (what model.yaml states)."""
    g = PRESETS[design.robot]
    return model.Cell(g.l1_mm, g.l2_mm, tuple(design.camera_center_mm), tuple(design.stations))


def measured(parts: Sequence[Part], rows: Rows, design: Design = Design(), noise: bool = True
             ) -> tuple[np.ndarray, list[np.ndarray]]:
    """What the camera reports on ``rows`` for a truth made of ``parts``: poses (n,2) mm
    and one (M,2) array per move; without ``noise`` neither repeatability nor measurement
    noise is added."""
    cell = nominal_cell(design)
    truth = compose(parts, bump_at_s=bump_time(rows))
    pts = model.measure_points(cell, truth, rows.q, rows.dirs, rows.t, rows.temp_true,
                               rows.repeat if noise else None)
    if noise:
        pts = pts + rows.noise
    paths = []
    for mv in rows.moves:
        clock = mv.start_s + mv.t
        xy = model.measure_path(cell, truth, mv.q, mv.t, clock, _warmup(design, clock), mv.dirs0)
        paths.append(xy + mv.noise if noise else xy)
    return pts, paths


def make_campaign(parts: Sequence[Part], seed: int, design: Design = Design(),
                  rows: Rows | None = None) -> Campaign:
    """Campaign ``seed`` measured on the truth made of ``parts`` (``rows`` if already
    drawn for this seed and design). Returns an in-memory
    :class:`~cell.measurements.Campaign` in the exchange format's columns."""
    rows = draw_rows(seed, design) if rows is None else rows
    g = PRESETS[design.robot]
    xy, paths_xy = measured(parts, rows, design)
    n = len(rows.t)
    points = {"sample": np.arange(n, dtype=np.int64), "time_s": rows.t, "j1_deg": rows.q[:, 0],
              "j2_deg": rows.q[:, 1], "x_mm": xy[:, 0], "y_mm": xy[:, 1],
              "j1_dir": rows.dirs[:, 0], "j2_dir": rows.dirs[:, 1], "temp_c": rows.temp_read,
              "payload_kg": rows.payload, "split": rows.split}
    paths = None
    if rows.moves:
        def cat(f):
            return np.concatenate([f(m, i) for i, m in enumerate(rows.moves)])
        paths = {"move": cat(lambda m, i: np.full(len(m.t), i, dtype=np.int64)),
                 "time_s": cat(lambda m, i: m.t),
                 "j1_cmd_deg": cat(lambda m, i: m.q[:, 0]),
                 "j2_cmd_deg": cat(lambda m, i: m.q[:, 1]),
                 "x_mm": np.concatenate([p[:, 0] for p in paths_xy]),
                 "y_mm": np.concatenate([p[:, 1] for p in paths_xy]),
                 "split": cat(lambda m, i: np.full(len(m.t), m.split, dtype=object))}
    spec = ModelSpec(format=FORMAT, l1_mm=g.l1_mm, l2_mm=g.l2_mm, command_unit_deg=g.unit[0],
                     joint_limits_deg=[list(g.limits[0]), list(g.limits[1])],
                     camera=CameraSpec(center_mm=design.camera_center_mm),
                     stations=list(design.stations))
    return Campaign(model=spec, points=points, paths=paths, source=f"truth model seed {seed}")


def rms_displacement(parts: Sequence[Part], rows: Rows, design: Design = Design()) -> float:
    """Noise-free rms displacement (mm, both axes, poses and path samples together) that a
    truth made of ``parts`` makes against the nominal cell on ``rows``."""
    p0, q0 = measured([], rows, design, noise=False)
    p1, q1 = measured(parts, rows, design, noise=False)
    d = np.concatenate([(p1 - p0).ravel()] + [(b - a).ravel() for a, b in zip(q0, q1)])
    return float(math.sqrt(np.mean(d ** 2) * 2)) if d.size else 0.0
