"""Chain campaigns drawn from the independent forward model (:mod:`cell.truth.chain`),
written in the exchange format (Extension v1.1): for the blind validation, the speed bench
and the tests. Nothing here imports the fitter (:mod:`cell.diagnosis.chain`).

The default arm is a UR5 in standard DH (Universal Robots' published parameters: d1 89.159,
a2 −425, a3 −392.25, d4 109.15, d5 94.65, d6 82.3 mm, α = 90, 0, 0, 90, −90, 0°), measured
by a tracker whose pose is unknown. :func:`arm` gives 1–8 joints: the UR5's six, then two
more wrist rows (:data:`EXTRA`) for a 7- or 8-joint chain.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cell.truth import chain as truth
from cell.truth import files

UR5 = [
    {"name": "j1", "type": "revolute", "a_mm": 0.0, "alpha_deg": 90.0, "d_mm": 89.159, "theta_deg": 0.0},
    {"name": "j2", "type": "revolute", "a_mm": -425.0, "alpha_deg": 0.0, "d_mm": 0.0, "theta_deg": 0.0},
    {"name": "j3", "type": "revolute", "a_mm": -392.25, "alpha_deg": 0.0, "d_mm": 0.0, "theta_deg": 0.0},
    {"name": "j4", "type": "revolute", "a_mm": 0.0, "alpha_deg": 90.0, "d_mm": 109.15, "theta_deg": 0.0},
    {"name": "j5", "type": "revolute", "a_mm": 0.0, "alpha_deg": -90.0, "d_mm": 94.65, "theta_deg": 0.0},
    {"name": "j6", "type": "revolute", "a_mm": 0.0, "alpha_deg": 0.0, "d_mm": 82.3, "theta_deg": 0.0},
]
MARKERS = [[40.0, 0.0, 30.0], [-20.0, 35.0, 30.0], [-20.0, -35.0, 50.0]]
EXTRA = [
    {"name": "j7", "type": "revolute", "a_mm": 0.0, "alpha_deg": 90.0, "d_mm": 60.0, "theta_deg": 0.0},
    {"name": "j8", "type": "revolute", "a_mm": 0.0, "alpha_deg": -90.0, "d_mm": 45.0, "theta_deg": 0.0},
]
MARKER4 = [10.0, 50.0, 20.0]


def arm(joints: int) -> list[dict]:
    """The first ``joints`` DH rows of the UR5 followed by :data:`EXTRA` (1 to 8)."""
    rows = UR5 + EXTRA
    if not 1 <= joints <= len(rows):
        raise ValueError(f"joints {joints}: 1 to {len(rows)}")
    return [dict(r) for r in rows[:joints]]


def warm_up(rng: np.random.Generator, poses: int) -> np.ndarray:
    """(poses,) temperatures °C of an arm warming up from a cold start while it is
    measured: from 18–24 °C it rises by 8–15 °C towards its working temperature (time
    constant a third of the campaign), read by a sensor to ±0.05 °C."""
    t0, rise = rng.uniform(18.0, 24.0), rng.uniform(8.0, 15.0)
    x = np.arange(poses) / max(poses - 1, 1)
    return t0 + rise * (1.0 - np.exp(-3.0 * x)) + rng.normal(0.0, 0.05, poses)


def make(directory: Path, effects: dict | None = None, *, poses: int = 60, noise_mm: float = 0.05,
         seed: int = 0, sensor: bool = True, markers=MARKERS, rows=UR5, modified: bool = False,
         split: bool = False, model_extra: dict | None = None, lens: float = 0.0,
         repeats: int = 0, places: int = 0, jitter_deg: float = 3.0, outliers: int = 0,
         outlier_mm: tuple[float, float] = (1.0, 5.0), dirs: bool = False,
         temps: bool = False) -> Path:
    """Write a campaign with ``effects`` (see :mod:`cell.truth.chain`) to ``directory``:
    ``poses`` poses with readings uniform over ±150° (joint 2 in −160…−20°, the arm above
    its base), the last ``repeats`` of them revisiting earlier ones (same readings, new
    noise: what lets a diagnosis estimate the noise); the sensor at a random pose.

    ``places`` > 0 gives a production-like layout instead: that many stations drawn as
    above, each pose one of them at random plus a jitter uniform in ±``jitter_deg`` per
    joint (revisits as before). ``outliers`` marker readings (a tracker's glitch) are moved
    by ``outlier_mm`` (uniform) in a random direction, after the noise. With ``dirs`` every
    pose is approached from a random side per joint (±1, from a stream of its own) and
    the ``jK_dir`` columns are written; without, the arm has no backlash to show (the
    truth's backlash acts only where a direction is known). With ``temps`` the arm warms up
    over the campaign (:func:`warm_up`) and the ``temp_c`` column is written; without, it
    stays at the reference temperature and has no thermal growth to show."""
    rng = np.random.default_rng(seed)
    if places:
        c = rng.uniform(-150, 150, (places, len(rows)))
        c[:, 1] = rng.uniform(-160 + jitter_deg, -20 - jitter_deg, places)
        q = c[rng.integers(places, size=poses)] + rng.uniform(-jitter_deg, jitter_deg,
                                                              (poses, len(rows)))
    else:
        q = rng.uniform(-150, 150, (poses, len(rows)))
        q[:, 1] = rng.uniform(-160, -20, poses)          # keep the arm above its base
    if repeats:
        if not 0 < repeats < poses:
            raise ValueError(f"repeats {repeats}: 1 to poses − 1")
        q[poses - repeats:] = q[rng.choice(poses - repeats, repeats, replace=False)]
    R = truth.random_rotation(rng) if sensor else np.eye(3)
    t = rng.uniform(-800, 800, 3) if sensor else np.zeros(3)
    approach = np.random.default_rng([seed, 1]).choice((-1, 1), q.shape) if dirs else None
    temp = np.round(warm_up(np.random.default_rng([seed, 2]), poses), 2) if temps else None
    data = truth.campaign_rows(rows, modified, q, markers, effects or {}, R, t, noise_mm, rng,
                               lens=lens, dirs=approach, temps=temp)
    if outliers:
        k = len(rows) + 2                              # x_mm's index in a data row
        for i in rng.choice(len(data), min(outliers, len(data)), replace=False):
            u = rng.normal(size=3)
            data[i][k:k + 3] = list(np.asarray(data[i][k:k + 3], float)
                                    + rng.uniform(*outlier_mm) * u / np.linalg.norm(u))
    directory = Path(directory)
    model = {"format": "cell-measurements/1", "kinematics": "dh",
             "dh_convention": "modified" if modified else "standard", "joints": rows,
             "measurement_frame": "sensor" if sensor else "base", "markers": "unknown",
             "source": "cell.truth.chain_campaign: DH arm drawn by cell.truth.chain"} | (model_extra or {})
    head = ["sample"] + [f"j{k + 1}" for k in range(len(rows))] + ["marker", "x_mm", "y_mm", "z_mm"]
    head += ["split"] if split else []
    head += [f"j{k + 1}_dir" for k in range(len(rows))] if dirs else []
    head += ["temp_c"] if temps else []
    table = []
    for r in data:
        cells = [int(r[0])] + [float(v) for v in r[1:1 + len(rows)]] + [int(r[1 + len(rows)])]
        cells += [float(v) for v in r[2 + len(rows):]]
        cells += (["holdout" if r[0] % 3 == 0 else "fit"] if split else [])
        cells += [int(v) for v in approach[int(r[0])]] if dirs else []
        cells += [float(temp[int(r[0])])] if temps else []
        table.append(cells)
    return files.write(directory, {"model.yaml": files.yaml_text(model),
                                   "points.csv": files.csv_text(head, table)})
