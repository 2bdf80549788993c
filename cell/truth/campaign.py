"""Planar validation campaigns measured on the independent forward model
(:mod:`cell.truth.model`) and written as files in the exchange format by the truth's own
writer (:mod:`cell.truth.files`). Pure numerics apart from :func:`write_campaign`.

Nothing here comes from the fitter's side: the robot's numbers, the poses, the moves, the
approach directions and the noise are this module's own, taken from the seeds and from
``cell/measurements.md`` ("Conventions of the effects", the section the truth follows).

**Robot** (:data:`ROBOTS`): seed 000's SCARA, l1 = l2 = 500 mm, command unit Δ = 0.01°;
joint limits ±170° and ±150° (the seeds give none: the design's own, wider than every pose
it draws). The camera's optical axis meets the work plane at (250, 930) mm, beside seed
000's Table 1 targets (≈ 248, 933 mm). CAN stations j1, j2, j3, j4 in that order (seed 002:
station i gets its frames σ·i late).

**Poses** (:class:`Design`): ``n_points`` static poses, one every ``pose_period_s`` (12 s:
move, settle, measure) while the arm warms up, T = ambient + rise·(1 − e^(−t/τ)), recorded
by a sensor with σ 0.05 K. Two layouts:

* ``places = 0`` (uniform): every pose drawn anew, θ1 uniform in ``theta1_deg``, |θ2| in
  ``theta2_abs_deg`` with both elbows, each joint approached from a random direction;
* ``places = k`` (production-like): the robot serves k stations (3–12 in the validation),
  drawn like the uniform poses; each pose is a station, chosen at random, plus a jitter
  uniform in ±``place_jitter_deg`` per joint. A joint's approach direction is the sign of
  its commanded motion from the previous pose (kept when it did not move), as it happens
  on a cell that goes from station to station.

Every pose is in whole command units. payload_kg is 0, 0.5 or 1 kg at random (nothing
depends on it). split: 70/30 at random.

**Moves** (paths.csv): ``n_moves`` straight Cartesian moves after the poses, 100–250 mm
long (between two stations of one elbow where the layout has them), quintic time law over
``move_s``, sampled every ``path_dt_s``; the recording starts ``pre_s`` before the first
motion (the arm standing at the start) and ends ``hold_s`` after it. A move's approach
directions follow the format's convention for paths without directions: each joint
approached the start in the direction of its own first commanded motion. Whole moves split
70/30.

**Noise**: repeatability σ ``repeatability_mm`` per axis once per arrival (seed 000: about
20 µm), on the true point before the camera; measurement σ ``measurement_noise_mm`` on
every measured value; ``outliers`` poses (a camera misdetection) moved by 0.5–3 mm in a
random direction.

**Columns**: ``directions``, ``temperature`` and ``split_column`` say whether points.csv
(and paths.csv, for the split) carry those optional columns; the truth is the same either
way (without directions the diagnosis must take them as unknown, without a temperature it
cannot see one).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from cell.truth import files, model
from cell.truth.parts import Part, compose

FORMAT = "cell-measurements/1"        # cell/measurements.md, model.yaml's first key


@dataclass(frozen=True)
class Robot:
    """A planar SCARA as the truth knows it: link lengths (mm), one command unit (deg),
    joint limits (deg) and where the numbers come from."""

    name: str
    source: str
    l1_mm: float
    l2_mm: float
    unit_deg: float
    limits_deg: tuple[tuple[float, float], tuple[float, float]]


ROBOTS = {"seed000": Robot("seed000", "seed 000: l1 = l2 = 500 mm, command unit 0.01°; "
                                      "limits the design's own", 500.0, 500.0, 0.01,
                           ((-170.0, 170.0), (-150.0, 150.0)))}


@dataclass(frozen=True)
class Design:
    """A campaign design (module docstring); units mm, deg, s, °C."""

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
    pre_s: float = 0.04
    camera_center_mm: tuple[float, float] = (250.0, 930.0)
    stations: tuple[str, ...] = ("j1", "j2", "j3", "j4")
    repeatability_mm: float = 0.01
    measurement_noise_mm: float = 0.005
    holdout_share: float = 0.3
    theta1_deg: tuple[float, float] = (-150.0, 150.0)
    theta2_abs_deg: tuple[float, float] = (15.0, 140.0)
    places: int = 0
    place_jitter_deg: float = 1.0
    outliers: int = 0
    outlier_mm: tuple[float, float] = (0.5, 3.0)
    directions: bool = True
    temperature: bool = True
    split_column: bool = True


def as_design(d) -> Design:
    """``d`` as a :class:`Design`: any object with some of its fields (another module's
    design of the same names) gives those, the rest keep their defaults."""
    if isinstance(d, Design):
        return d
    return Design(**{f.name: getattr(d, f.name) for f in dataclasses.fields(Design)
                     if hasattr(d, f.name)})


@dataclass
class Move:
    """One straight move: times ``t`` (M,) s since its first frame, commands ``q`` (M,2)
    deg, approach directions ``dirs0`` (2,), start ``start_s`` on the campaign clock, its
    measurement noise ``noise`` (M,2) mm and its split."""

    t: np.ndarray
    q: np.ndarray
    dirs0: np.ndarray
    start_s: float
    noise: np.ndarray
    split: str


@dataclass
class Rows:
    """One campaign without its truth. Poses: commands ``q`` (n,2) deg (whole command
    units), true approach directions ``dirs``, times ``t`` s, true and recorded
    temperatures °C, payload kg, split, repeatability ``repeat``, measurement ``noise``
    and gross ``outlier`` offsets (n,2) mm; ``place`` (n,) the station of each pose (−1 in
    the uniform layout)."""

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
    outlier: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    place: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


# ------------------------------------------------------------------ geometry of the design
def tool_xy(robot: Robot, q_deg: np.ndarray) -> np.ndarray:
    """Nominal tool centre (N,2) mm of commands (N,2) deg (seed 000's forward kinematics)."""
    return np.array([model.tool_xy(robot.l1_mm, robot.l2_mm, a, b) for a, b in q_deg])


def joints_of(robot: Robot, xy: np.ndarray, elbow: float) -> np.ndarray | None:
    """Joint commands (N,2) deg reaching points ``xy`` (N,2) mm on the ``elbow`` (±1)
    branch, θ1 unwrapped along the points; None if one is out of reach."""
    l1, l2 = robot.l1_mm, robot.l2_mm
    r2 = xy[:, 0] ** 2 + xy[:, 1] ** 2
    c2 = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    if np.any(np.abs(c2) > 1.0):
        return None
    t2 = elbow * np.arccos(c2)
    t1 = np.arctan2(xy[:, 1], xy[:, 0]) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))
    return np.degrees(np.column_stack([np.unwrap(t1), t2]))


def approach_dirs(q: np.ndarray) -> np.ndarray:
    """The format's convention for a move without directions: each joint approached the
    start in the direction of its own first commanded motion (0 if it never moves)."""
    out = np.zeros(2)
    for j in range(2):
        steps = np.diff(q[:, j])
        moving = steps[steps != 0]
        out[j] = math.copysign(1.0, moving[0]) if moving.size else 0.0
    return out


def _sequence_dirs(rng: np.random.Generator, q: np.ndarray) -> np.ndarray:
    """Each pose's approach direction per joint: the sign of its commanded motion from the
    previous pose, kept where the joint did not move; the first pose's at random."""
    dirs = np.empty_like(q)
    last = rng.choice((-1.0, 1.0), 2)
    for i in range(len(q)):
        for j in range(2):
            if i and q[i, j] != q[i - 1, j]:
                last[j] = 1.0 if q[i, j] > q[i - 1, j] else -1.0
            dirs[i, j] = last[j]
    return dirs


def _draw_q(rng: np.random.Generator, d: Design, n: int, margin: float = 0.0) -> np.ndarray:
    lo2, hi2 = d.theta2_abs_deg
    return np.column_stack([rng.uniform(d.theta1_deg[0] + margin, d.theta1_deg[1] - margin, n),
                            rng.choice((-1.0, 1.0), n) * rng.uniform(lo2 + margin, hi2 - margin, n)])


def _profile(d: Design) -> tuple[np.ndarray, np.ndarray]:
    """(times (M,), path share 0 → 1 (M,)) of a move: pre-roll, quintic, hold."""
    n = int(round(d.move_s / d.path_dt_s))
    u = np.linspace(0.0, 1.0, n + 1)
    s = np.concatenate([np.zeros(int(round(d.pre_s / d.path_dt_s))),
                        10 * u ** 3 - 15 * u ** 4 + 6 * u ** 5,
                        np.ones(int(round(d.hold_s / d.path_dt_s)))])
    return np.arange(len(s)) * d.path_dt_s, s


def straight_move(rng: np.random.Generator, d: Design, robot: Robot,
                  centres: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(times (M,), commands (M,2) deg) of one straight Cartesian move that keeps |θ2| in
    15°–150° and θ1 inside its limits: from a station toward another of the same elbow 100–250
    mm away when ``centres`` (k,2) has such a pair, else from a station (or a random pose)
    in a random direction."""
    t, s = _profile(d)
    lim1 = robot.limits_deg[0]
    for attempt in range(2000):
        if centres is not None and len(centres):
            q0 = centres[rng.integers(len(centres))].copy()
            elbow = 1.0 if q0[1] >= 0 else -1.0
        else:
            elbow = float(rng.choice((-1.0, 1.0)))
            q0 = np.array([rng.uniform(-120, 120), elbow * rng.uniform(30, 120)])
        p0 = tool_xy(robot, q0[None, :])[0]
        p1 = None
        if centres is not None and attempt < 200:
            ends = tool_xy(robot, centres)
            dist = np.hypot(*(ends - p0).T)
            same = (np.sign(centres[:, 1]) == elbow) & (dist >= 100) & (dist <= 250)
            if same.any():
                p1 = ends[rng.choice(np.flatnonzero(same))]
        if p1 is None:
            ang = rng.uniform(0, 2 * math.pi)
            p1 = p0 + rng.uniform(100, 250) * np.array([math.cos(ang), math.sin(ang)])
        q = joints_of(robot, p0 + s[:, None] * (p1 - p0), elbow)
        if q is None:
            continue
        q[:, 0] += q0[0] - q[0, 0]                   # θ1 on the start pose's branch
        ok = (np.abs(q[:, 1]) > 15).all() and (np.abs(q[:, 1]) < 150).all() \
            and (q[:, 0] > lim1[0]).all() and (q[:, 0] < lim1[1]).all()
        if ok:
            return t, q
    raise RuntimeError("no feasible straight move found")  # pragma: no cover


def _warmup(d: Design, t) -> np.ndarray:
    t = np.maximum(np.asarray(t, dtype=float), 0.0)
    return d.ambient_c + d.rise_c * (1.0 - np.exp(-t / d.tau_s))


def draw_rows(seed: int, design=Design()) -> Rows:
    """The poses, moves and noise of campaign ``seed`` (module docstring)."""
    d = as_design(design)
    rng = np.random.default_rng(seed)
    robot = ROBOTS[d.robot]
    n = d.n_points
    centres = None
    if d.places:
        centres = _draw_q(rng, d, d.places, margin=d.place_jitter_deg)
        centres = np.round(centres / robot.unit_deg) * robot.unit_deg
        place = rng.integers(d.places, size=n)
        q = centres[place] + rng.uniform(-d.place_jitter_deg, d.place_jitter_deg, (n, 2))
    else:
        place = np.full(n, -1)
        q = _draw_q(rng, d, n)
    q = np.round(q / robot.unit_deg) * robot.unit_deg
    dirs = _sequence_dirs(rng, q) if d.places else rng.choice((-1.0, 1.0), (n, 2))
    t = np.arange(n) * d.pose_period_s + rng.uniform(0, 2.0, n)
    temp = _warmup(d, t)
    outlier = np.zeros((n, 2))
    if d.outliers:
        idx = rng.choice(n, min(d.outliers, n), replace=False)
        ang = rng.uniform(0, 2 * math.pi, len(idx))
        size = rng.uniform(*d.outlier_mm, len(idx))
        outlier[idx] = size[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    rows = Rows(q=q, dirs=dirs, t=t, temp_true=temp,
                temp_read=temp + rng.normal(0, d.temp_sensor_sigma_c, n),
                payload=rng.choice((0.0, 0.5, 1.0), n),
                split=np.where(rng.random(n) < d.holdout_share, "holdout", "fit").astype(object),
                repeat=rng.normal(0, d.repeatability_mm, (n, 2)),
                noise=rng.normal(0, d.measurement_noise_mm, (n, 2)), moves=[],
                outlier=outlier, place=place)
    if d.n_moves:
        k_hold = max(1, int(round(d.holdout_share * d.n_moves)))
        hold = set(rng.permutation(d.n_moves)[:k_hold].tolist())
        start = (float(t[-1]) if n else 0.0) + 60.0
        for m in range(d.n_moves):
            tm, qm = straight_move(rng, d, robot, centres)
            rows.moves.append(Move(tm, qm, approach_dirs(qm), start + 10.0 * m,
                                   rng.normal(0, d.measurement_noise_mm, qm.shape),
                                   "holdout" if m in hold else "fit"))
    return rows


def bump_time(rows: Rows) -> float:
    """When an ``offset_bump`` happens: halfway between the first and the last pose (s)."""
    return float(rows.t[0] + rows.t[-1]) / 2.0 if len(rows.t) else 0.0


def nominal_cell(design=Design()) -> model.Cell:
    """The nominal cell of ``design`` (what model.yaml states)."""
    d = as_design(design)
    r = ROBOTS[d.robot]
    return model.Cell(r.l1_mm, r.l2_mm, tuple(d.camera_center_mm), tuple(d.stations))


def measured(parts: Sequence[Part], rows: Rows, design=Design(), noise: bool = True
             ) -> tuple[np.ndarray, list[np.ndarray]]:
    """What the camera reports on ``rows`` for a truth made of ``parts``: poses (n,2) mm
    and one (M,2) array per move; without ``noise`` neither repeatability, measurement
    noise nor outliers are added."""
    d = as_design(design)
    cell = nominal_cell(d)
    truth = compose(parts, bump_at_s=bump_time(rows))
    pts = model.measure_points(cell, truth, rows.q, rows.dirs, rows.t, rows.temp_true,
                               rows.repeat if noise else None)
    if noise:
        pts = pts + rows.noise + (rows.outlier if len(rows.outlier) else 0.0)
    paths = []
    for mv in rows.moves:
        clock = mv.start_s + mv.t
        xy = model.measure_path(cell, truth, mv.q, mv.t, clock, _warmup(d, clock), mv.dirs0)
        paths.append(xy + mv.noise if noise else xy)
    return pts, paths


def tables(parts: Sequence[Part], seed: int, design=Design(), rows: Rows | None = None
           ) -> tuple[dict, dict[str, tuple[list[str], list[list]]]]:
    """(model.yaml as a dict, {file name: (columns, rows)}) of campaign ``seed`` measured on
    the truth made of ``parts``, in the columns ``cell/measurements.md`` names."""
    d = as_design(design)
    rows = draw_rows(seed, d) if rows is None else rows
    robot = ROBOTS[d.robot]
    xy, paths_xy = measured(parts, rows, d)
    cols = ["sample", "time_s", "j1_deg", "j2_deg", "x_mm", "y_mm"]
    cols += ["j1_dir", "j2_dir"] if d.directions else []
    cols += ["temp_c"] if d.temperature else []
    cols += ["payload_kg"] + (["split"] if d.split_column else [])
    pts = []
    for i in range(len(rows.t)):
        r = [i, float(rows.t[i]), float(rows.q[i, 0]), float(rows.q[i, 1]),
             float(xy[i, 0]), float(xy[i, 1])]
        r += [int(rows.dirs[i, 0]), int(rows.dirs[i, 1])] if d.directions else []
        r += [float(rows.temp_read[i])] if d.temperature else []
        r += [float(rows.payload[i])] + ([str(rows.split[i])] if d.split_column else [])
        pts.append(r)
    out = {"points.csv": (cols, pts)}
    if rows.moves:
        pcols = ["move", "time_s", "j1_cmd_deg", "j2_cmd_deg", "x_mm", "y_mm"]
        pcols += ["split"] if d.split_column else []
        prow = []
        for m, (mv, p) in enumerate(zip(rows.moves, paths_xy)):
            for k in range(len(mv.t)):
                prow.append([m, float(mv.t[k]), float(mv.q[k, 0]), float(mv.q[k, 1]),
                             float(p[k, 0]), float(p[k, 1])] + ([mv.split] if d.split_column else []))
        out["paths.csv"] = (pcols, prow)
    spec = {"format": FORMAT, "kinematics": "scara", "l1_mm": robot.l1_mm, "l2_mm": robot.l2_mm,
            "command_unit_deg": robot.unit_deg,
            "joint_limits_deg": [list(robot.limits_deg[0]), list(robot.limits_deg[1])],
            "camera": {"center_mm": [float(v) for v in d.camera_center_mm]},
            "stations": list(d.stations)}
    return spec, out


def write_campaign(directory: Path | str, parts: Sequence[Part], seed: int, design=Design(),
                   rows: Rows | None = None) -> Path:
    """Campaign ``seed`` on the truth made of ``parts`` written to ``directory`` (model.yaml,
    points.csv, paths.csv when it has moves) by the truth's own writer. Returns the path."""
    spec, tabs = tables(parts, seed, design, rows)
    text = {"model.yaml": files.yaml_text(spec)}
    text |= {name: files.csv_text(c, r) for name, (c, r) in tabs.items()}
    return files.write(directory, text)


@dataclass
class _Camera:
    center_mm: tuple[float, float]


@dataclass
class _Model:
    format: str
    kinematics: str
    l1_mm: float
    l2_mm: float
    command_unit_deg: float
    joint_limits_deg: list
    camera: _Camera | None
    stations: list[str]


@dataclass
class Tables:
    """A campaign in memory, with the attributes of the reader's campaign object (``model``
    with model.yaml's keys, ``points`` / ``paths`` column → array, ``source``,
    ``station_order``) so a test can diagnose it without files. The validation does not
    use it: it writes files (:func:`write_campaign`) and reads them with the reader."""

    model: _Model
    points: dict | None
    paths: dict | None
    source: str
    extra: dict = field(default_factory=dict)

    @property
    def station_order(self) -> list[str]:
        return list(self.model.stations)


def _arrays(columns: list[str], rows: list[list]) -> dict:
    out = {}
    for k, c in enumerate(columns):
        col = [r[k] for r in rows]
        if c == "split":
            out[c] = np.array(col, dtype=object)
        elif c in ("sample", "move"):
            out[c] = np.array(col, dtype=np.int64)
        else:
            out[c] = np.array(col, dtype=float)
    return out


def make_campaign(parts: Sequence[Part], seed: int, design=Design(), rows: Rows | None = None
                  ) -> Tables:
    """Campaign ``seed`` on the truth made of ``parts``, in memory (:class:`Tables`)."""
    spec, tabs = tables(parts, seed, design, rows)
    m = _Model(spec["format"], spec["kinematics"], spec["l1_mm"], spec["l2_mm"],
               spec["command_unit_deg"], spec["joint_limits_deg"],
               _Camera(tuple(spec["camera"]["center_mm"])), spec["stations"])
    pts = _arrays(*tabs["points.csv"]) if "points.csv" in tabs else None
    pth = _arrays(*tabs["paths.csv"]) if "paths.csv" in tabs else None
    return Tables(m, pts, pth, f"truth model seed {seed}")


def rms_displacement(parts: Sequence[Part], rows: Rows, design=Design()) -> float:
    """Noise-free rms displacement (mm, both axes, poses and path samples together) that a
    truth made of ``parts`` makes against the nominal cell on ``rows``."""
    p0, q0 = measured([], rows, design, noise=False)
    p1, q1 = measured(parts, rows, design, noise=False)
    dd = np.concatenate([(p1 - p0).ravel()] + [(b - a).ravel() for a, b in zip(q0, q1)])
    return float(math.sqrt(np.mean(dd ** 2) * 2)) if dd.size else 0.0
