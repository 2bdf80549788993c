"""Our own compensation: a Jacobian step from the measured error, then the nearest lattice point.

Seed 000 walks a shrinking grid (about five decisions, up to five moves) and can end on a
lattice point that is not the nearest one (Table 1 group a ends 0.0265 mm away while a
lattice point 0.0223 mm away exists). Here the arm's reachable positions near the target
are the lattice of whole command units, and each decision jumps straight to the lattice
point predicted closest to the target:

1. Move to the first command (nominal IK rounded to whole units, plus any learned offset)
   and measure point p at command q.
2. Predict where each candidate command c would land: p + FK(c) − FK(q). The model error
   is absorbed by the measurement p; what remains is the (tiny) change of the error over a
   few command units.
3. The candidates are every lattice point that can be closer than the best found so far: a
   box around q + J⁻¹(P0 − p), sized from the lattice's smallest singular value, so the
   search is exact for the predicted distances, not a fixed neighbourhood.
4. Stop when the best candidate is the current command, was visited already, or gains less
   than ``min_gain_mm`` (a measurement-noise guard); otherwise move and go to 2. With a
   backlash side, each arrival takes up the lost motion from it (see :func:`run_lattice`).

On the nominal model this reaches the nearest lattice point in at most two moves.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from cell.compensation.base import Arm, CompensationResult, Recorder
from cell.errors import KinematicsError
from cell.kinematics import Scara

_MAX_BOX = 12


def nearest_lattice(robot: Scara, q_units: np.ndarray, point: np.ndarray,
                    target: np.ndarray) -> tuple[np.ndarray, float]:
    """Command (whole units) whose predicted position p + FK(c) − FK(q) is nearest ``target``.

    Returns the command and its predicted distance in mm.
    """
    unit = robot.from_units([1, 1])
    q_deg = q_units * unit
    base = robot.fk_planar(*q_deg)
    Ju = robot.jacobian(*q_deg) * unit
    ideal = q_units + np.linalg.solve(Ju, target - point)
    centre = np.rint(ideal).astype(np.int64)
    d_centre = np.hypot(*(point + Ju @ (centre - q_units) - target))
    smin = np.linalg.svd(Ju, compute_uv=False)[-1]
    radius = min(_MAX_BOX, int(math.ceil((d_centre + 1e-9) / smin)) + 1)
    span = range(-radius, radius + 1)
    cands = centre + np.array(list(itertools.product(span, span)), dtype=np.int64)
    fk = robot.fk_planar_batch(cands * unit)
    dist = np.hypot(*(point + fk - base - target).T)
    # never cross the stretched/folded singularity or leave the joint limits on the way
    deg = cands * unit
    (lo1, hi1), (lo2, hi2) = robot.g.limits[0], robot.g.limits[1]
    margin = robot.g.singular_margin_deg
    same_elbow = np.sign(deg[:, 1]) == np.sign(q_deg[1])
    clear = (np.abs(deg[:, 1]) >= margin) & (np.abs(deg[:, 1]) <= 180.0 - margin)
    inside = (deg[:, 0] >= lo1) & (deg[:, 0] <= hi1) & (deg[:, 1] >= lo2) & (deg[:, 1] <= hi2)
    dist = np.where(same_elbow & clear & inside, dist, np.inf)
    i = int(np.argmin(dist))
    if not np.isfinite(dist[i]):
        return q_units, float(np.hypot(*(point - target)))
    return cands[i], float(dist[i])


def run_lattice(robot: Scara, arm: Arm, target_mm, *, start_units=None,
                start_offset_units=(0, 0), max_moves: int = 4, min_gain_mm: float = 0.002,
                approach_dirs=None, backlash_margin_units: int = 0,
                from_units=None) -> CompensationResult:
    """Compensate towards ``target_mm`` = (x, y) by nearest-lattice jumps (see module doc).

    ``max_moves`` bounds the arrivals including the first; ``min_gain_mm`` is the least
    predicted improvement worth a move (keep it near the measurement noise).

    Backlash: with ``approach_dirs`` (the side, +1 or −1 per joint, every arrival takes up
    the lost motion from) and ``backlash_margin_units`` > 0, every arrival comes from that
    side. A joint that would arrive the other way first passes through a via point the
    margin beyond the command (not measured; part of the arrival), so the lost motion is
    the same at every arrival and the measurement absorbs it. ``from_units`` is where the
    joints are before the first arrival (None: unknown, so it comes through a via point
    on both joints). Without a side, a reversal moves the tool by the backlash and
    predictions made across it are off by that much.

    Raises KinematicsError for an unreachable target or ``max_moves`` < 1.
    """
    if max_moves < 1:
        raise KinematicsError(f"max_moves = {max_moves} must be ≥ 1")
    target = np.asarray(target_mm, dtype=float)
    if start_units is None:
        start_units = robot.to_units(robot.ik_planar(*target)) + np.asarray(start_offset_units)
    start_units = np.asarray(start_units, dtype=np.int64)
    rec = Recorder("lattice", arm, target, robot.from_units([1, 1]))
    before = None if from_units is None else np.asarray(from_units, dtype=float)
    point = rec.move(start_units, note="first arrival",
                     via=via_point(approach_dirs, backlash_margin_units, before, start_units, robot))
    visited = {tuple(rec.command)}
    while rec.result.moves < max_moves:
        best, predicted = nearest_lattice(robot, rec.command, point, target)
        gain = np.hypot(*(point - target)) - predicted
        if tuple(best) in visited or gain < min_gain_mm:
            break
        point = rec.move(best, note=f"predicted {predicted:.4f} mm",
                         via=via_point(approach_dirs, backlash_margin_units, rec.command, best, robot))
        visited.add(tuple(best))
    return rec.result


def margin_units(robot: Scara, recipe_margin: int) -> int:
    """The via-point margin, command units, that clears the backlash seed 004 measured
    (``robot.backlash_deg``): the recipe's ``backlash_margin_units``, or 1.5 × the measured
    band rounded up when that is wider. A recipe margin of 0 (via points off) stays 0."""
    if recipe_margin <= 0:
        return recipe_margin
    need = [math.ceil(1.5 * b / u) for b, u in zip(robot.backlash_deg, robot.g.unit[:2]) if b > 0]
    return max([recipe_margin, *need])


def via_point(dirs, margin: int, before, command, robot: Scara | None = None) -> np.ndarray | None:
    """The via point an arrival at ``command`` from ``before`` passes through so that every
    joint arrives from its side ``dirs`` (the sign counts). None when no side is kept
    (``dirs`` None or ``margin`` ≤ 0) or every joint already arrives from it. ``before``
    None (unknown) sends every joint through the via point. With ``robot``, a via point
    outside its joint limits is left out (None): near a limit the arrival comes straight,
    and its measurement absorbs the backlash."""
    if dirs is None or margin <= 0:
        return None
    dirs = np.where(np.asarray(dirs) < 0, -1, 1)
    if before is None:
        wrong = np.ones(2, dtype=bool)
    else:
        step = np.sign(command - before)
        wrong = (step != 0) & (step != dirs)
    if not wrong.any():
        return None
    via = np.asarray(command, dtype=np.int64) - dirs * margin * wrong
    if robot is not None:
        try:
            robot.check_limits(robot.from_units(via), joints=(0, 1))
        except KinematicsError:
            return None
    return via
