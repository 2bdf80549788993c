"""Validation campaigns drawn from the plant (:class:`cell.sim.plant.Plant`). Pure numerics.

:func:`make_campaign` measures one campaign in the exchange format on a plant carrying the
given effects (the tests use it; ``cellctl diagnose validate`` measures the same design on
the independent forward model instead, :mod:`cell.truth.campaign`, since the plant computes
its truth with :mod:`cell.effects`, the functions the diagnosis fits with). The design (:class:`Design`, defaults below) is meant to be what a careful
engineer would record on the seed 000 robot (l1 = l2 = 500 mm, command unit 0.01°):

* **points**: ``n_points`` static poses, joints uniform over θ1 ∈ [−150°, 150°] and
  |θ2| ∈ [15°, 140°] with both elbows (15° keeps clear of the stretched-arm singularity),
  each approached from a random direction per joint (recorded in j1_dir / j2_dir). One
  pose every ``pose_period_s`` (12 s: move, settle, measure), so 300 poses take an hour
  while the arm warms up from 20 °C by ``rise_c`` = 6 K with τ = 30 min (the default plant
  file's warm-up); temp_c is the sensor reading (σ 0.05 K). payload_kg is 0, 0.5 or 1 kg
  at random (nothing in the vocabulary depends on it: a variable with no effect). split:
  70/30 at random.
* **paths**: ``n_moves`` straight Cartesian moves after the poses, 100–250 mm long, quintic
  time law over 0.4 s plus a 40 ms hold, commanded and measured every ``path_dt_s`` (2 ms);
  each joint approaches a move's start in the direction of its first motion (the
  convention :mod:`.replay` assumes). Whole moves split 70/30.
* **noise**: repeatability σ 0.01 mm per arrival, measurement σ 0.005 mm (plant defaults
  of deploy/plants/default.yaml); camera centre (250, 930) mm as there; CAN stations
  j1, j2, j3, j4 (comm_delay: j1 is σ late, j2 2σ).

``distortion`` (tests) is applied to every measured point: a way to inject an effect that
is not in the vocabulary.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from cell import effects as fx
from cell.kinematics import planar_xy
from cell.robots import PRESETS
from cell.measurements import FORMAT, Campaign, CameraSpec, ModelSpec
from cell.diagnosis.replay import first_step_dirs
from cell.sim.plant import Plant


@dataclass(frozen=True)
class Design:
    """Validation campaign design (see module docstring); units mm, deg, s, °C."""

    robot: str = "seed000"
    n_points: int = 300
    n_moves: int = 6
    pose_period_s: float = 12.0
    rise_c: float = 6.0
    tau_s: float = 1800.0
    ambient_c: float = 20.0
    temp_sensor_sigma_c: float = 0.05
    path_dt_s: float = 0.002
    move_s: float = 0.4
    hold_s: float = 0.04
    camera_center_mm: tuple[float, float] = (250.0, 930.0)
    stations: tuple[str, ...] = ("j1", "j2", "j3", "j4")
    repeatability_mm: float = 0.01
    measurement_noise_mm: float = 0.005
    holdout_share: float = 0.3
    theta1_deg: tuple[float, float] = (-150.0, 150.0)
    theta2_abs_deg: tuple[float, float] = (15.0, 140.0)


def effect_dicts(effects: Sequence[fx.EffectInstance]) -> list[dict]:
    """Effect instances as plant-config entries."""
    return [{"effect": e.effect, "joints": list(e.joints), "params": dict(e.params)} for e in effects]


def _ik(l1, l2, xy, elbow):
    r2 = (xy ** 2).sum(1)
    c2 = (r2 - l1 ** 2 - l2 ** 2) / (2 * l1 * l2)
    if np.any(np.abs(c2) > 1):
        return None
    t2 = elbow * np.arccos(c2)
    t1 = np.arctan2(xy[:, 1], xy[:, 0]) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))
    return np.degrees(np.column_stack([np.unwrap(t1), t2]))


def straight_move(rng, design: Design, l1, l2, limits) -> tuple[np.ndarray, np.ndarray]:
    """(time (M,), commanded joints (M,2)) of one straight move that stays clear of limits
    and of the stretched/folded arm."""
    n = int(round(design.move_s / design.path_dt_s))
    s_t = np.linspace(0.0, 1.0, n + 1)
    s = 10 * s_t ** 3 - 15 * s_t ** 4 + 6 * s_t ** 5
    hold = int(round(design.hold_s / design.path_dt_s))
    s = np.concatenate([s, np.ones(hold)])
    t = np.arange(len(s)) * design.path_dt_s
    for _ in range(1000):
        elbow = float(rng.choice((-1.0, 1.0)))
        q0 = np.array([rng.uniform(-120, 120), elbow * rng.uniform(30, 120)])
        p0 = planar_xy(l1, l2, q0[None, :])[0]
        ang = rng.uniform(0, 2 * np.pi)
        p1 = p0 + rng.uniform(100, 250) * np.array([np.cos(ang), np.sin(ang)])
        q = _ik(l1, l2, p0 + s[:, None] * (p1 - p0), elbow)
        if q is None:
            continue
        q[:, 0] += q0[0] - q[0, 0]   # same branch of θ1 as the start pose
        ok = (np.abs(q[:, 1]) > 15).all() and (np.abs(q[:, 1]) < 150).all() \
            and (q[:, 0] > limits[0][0]).all() and (q[:, 0] < limits[0][1]).all()
        if ok:
            return t, q
    raise RuntimeError("no feasible straight move found")  # pragma: no cover


def make_campaign(effects: Sequence[fx.EffectInstance], seed: int, design: Design = Design(),
                  distortion: Callable[[np.ndarray], np.ndarray] | None = None) -> Campaign:
    """One campaign measured on a plant carrying ``effects`` (see module docstring).

    ``seed`` drives the pose draw, the split and the plant's noise. Returns an in-memory
    :class:`~cell.measurements.Campaign` (write it with
    :func:`cell.measurements.write_campaign`).
    """
    rng = np.random.default_rng(seed)
    g = PRESETS[design.robot]
    plant = Plant.from_config({
        "robot": design.robot, "effects": effect_dicts(effects), "seed": int(seed),
        "repeatability_mm": design.repeatability_mm,
        "measurement_noise_mm": design.measurement_noise_mm,
        "temperature": {"ambient_c": design.ambient_c, "rise_c": design.rise_c,
                        "tau_s": design.tau_s},
        "camera_center_mm": list(design.camera_center_mm), "stations": list(design.stations)})
    n = design.n_points
    q = np.column_stack([rng.uniform(*design.theta1_deg, n),
                         rng.choice((-1.0, 1.0), n) * rng.uniform(*design.theta2_abs_deg, n)])
    q = np.round(q / g.unit[0]) * g.unit[0]                   # whole command units
    dirs = rng.choice((-1.0, 1.0), (n, 2))
    t = np.arange(n) * design.pose_period_s + rng.uniform(0, 2.0, n)
    xy = plant.campaign_points(q, dirs, t)
    if distortion is not None:
        xy = distortion(xy)
    temp = plant.temperature(t) + rng.normal(0, design.temp_sensor_sigma_c, n)
    split = np.where(rng.random(n) < design.holdout_share, "holdout", "fit").astype(object)
    points = {"sample": np.arange(n, dtype=np.int64), "time_s": t, "j1_deg": q[:, 0],
              "j2_deg": q[:, 1], "x_mm": xy[:, 0], "y_mm": xy[:, 1], "j1_dir": dirs[:, 0],
              "j2_dir": dirs[:, 1], "temp_c": temp,
              "payload_kg": rng.choice((0.0, 0.5, 1.0), n), "split": split}
    paths = None
    if design.n_moves:
        k_hold = max(1, int(round(design.holdout_share * design.n_moves)))
        hold = set(rng.permutation(design.n_moves)[:k_hold].tolist())
        cols: dict[str, list] = {c: [] for c in ("move", "time_s", "j1_cmd_deg", "j2_cmd_deg",
                                                 "x_mm", "y_mm", "split")}
        start = float(t[-1]) + 60.0
        for m in range(design.n_moves):
            tm, qm = straight_move(rng, design, g.l1_mm, g.l2_mm, g.limits)
            d0 = first_step_dirs(qm)
            xym = plant.campaign_path(qm, tm, start_s=start + 10.0 * m, dirs0=d0)
            if distortion is not None:
                xym = distortion(xym)
            cols["move"] += [m] * len(tm)
            cols["time_s"] += tm.tolist()
            cols["j1_cmd_deg"] += qm[:, 0].tolist()
            cols["j2_cmd_deg"] += qm[:, 1].tolist()
            cols["x_mm"] += xym[:, 0].tolist()
            cols["y_mm"] += xym[:, 1].tolist()
            cols["split"] += ["holdout" if m in hold else "fit"] * len(tm)
        paths = {k: np.array(v, dtype=np.int64 if k == "move" else (object if k == "split" else float))
                 for k, v in cols.items()}
    model = ModelSpec(format=FORMAT, l1_mm=g.l1_mm, l2_mm=g.l2_mm, command_unit_deg=g.unit[0],
                      joint_limits_deg=[list(g.limits[0]), list(g.limits[1])],
                      camera=CameraSpec(center_mm=design.camera_center_mm),
                      stations=list(design.stations))
    return Campaign(model=model, points=points, paths=paths, source=f"plant seed {seed}")
