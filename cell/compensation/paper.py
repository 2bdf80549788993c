"""Seed 000's grid model, as published ("Plane positioning compensation method for assembly
robot with visual guiding", 2017), method section steps (1)–(5) and its special cases.

The grid lives in joint space: four grain points P1 (the current command), P2 = P1 + kΔ1 on
θ1, P3 = P1 + kΔ2 on θ2, P4 = both. In Cartesian space it is the near-parallelogram with
edges S1 = J(P0)·[kΔ1, 0]ᵀ and S2 = J(P0)·[0, kΔ2]ᵀ (eqs. 7, 8) laid on the *measured*
current point, so the model error is absorbed by the measurement and never identified.

Reading of the paper this implementation takes (each choice reproduces Table 1):

* The grid is built on the side where P0 lies: the sign of each joint's edge is the sign of
  that joint's component of J(P0)⁻¹·(P0 − P_measured) (zero counts as +).
* Step (1) scores each grain point with ε_i = d(P0, P_i) + repeatability radius (eq. 9);
  the radius is the same for all four, so it changes the score, not the choice.
* Step (2) moves to the best grain point along the grid edge, or stays if P1 is best.
* Step (3) halves k (k → k // 2). Special case "P0 at the parallelogram's centre" (within
  ``tie_mm`` of the point where the predicted grid's diagonals cross): stay and take
  k → 3k // 4 instead.
* Special case "P0 at a circumcentre" (scores of three grain points equal within ``tie_mm``),
  applied to any tie of two or more: the tied grain point with the shortest travel from
  the current point wins. (On the skewed grids of the paper's own set-up every such
  circumcentre lies outside the grid; a two-way tie is what happens in practice.)
* Step (4): with k = 16 the grids are k = 16, 8, 4, 2, then step (1) "once more" at k = 1
  and the robot moves there; that is the last step.
* Step (5): :func:`learn_offset` repeats the run for one target and averages the accumulated
  joint offsets (last command − first command) into a compensation the next cycles start
  from (``start_offset_units``).

Table 1 prints the picks at k = 16, 8, 4 as "1st/2nd/3rd step" and the final pick as "last
step". Its min-error for group c (0.0275 mm) is not the distance between its own last-step
point (249.8255, 933.0127) and the target (249.85, 933.03), which is 0.0300 mm; we report the
distance we compute.
"""
from __future__ import annotations

import numpy as np

from cell.compensation.base import Arm, CompensationResult, Recorder
from cell.errors import KinematicsError
from cell.kinematics import Scara

_CORNERS = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])


def run_paper(robot: Scara, arm: Arm, target_mm, *, k: int = 16, start_units=None,
              start_offset_units=(0, 0), repeatability_mm: float = 0.02,
              tie_mm: float = 1e-6) -> CompensationResult:
    """Run seed 000's grid compensation towards ``target_mm`` = (x, y).

    ``start_units``: first command (θ1, θ2 in command units); default the nominal inverse
    kinematics of the target rounded to whole units, plus ``start_offset_units`` (step 5's
    learned compensation). ``k``: first grid spacing in command units (paper: 16).
    Raises KinematicsError for an unreachable target or a non-positive k.
    """
    if not isinstance(k, (int, np.integer)) or k < 1:
        raise KinematicsError(f"grid spacing k = {k!r} must be a whole number of command units ≥ 1")
    target = np.asarray(target_mm, dtype=float)
    q_ref = robot.ik_planar(*target)            # P0 in joint space; raises if unreachable
    J = robot.jacobian(*q_ref)                  # J(P0), mm per degree
    unit = robot.from_units([1, 1])
    Ju = J * unit                               # mm per command unit
    if start_units is None:
        start_units = robot.to_units(q_ref) + np.asarray(start_offset_units, dtype=np.int64)
    rec = Recorder("paper", arm, target, unit)
    point = rec.move(start_units, note="first arrival")

    while True:
        side = np.where(np.linalg.solve(Ju, target - point) >= 0, 1, -1)
        offsets = _CORNERS * side * k                         # grain points P1..P4
        predicted = point + offsets @ Ju.T
        score = np.hypot(*(predicted - target).T) + repeatability_mm   # eq. 9
        tied = np.flatnonzero(score <= score.min() + tie_mm)
        # special case 2: P0 at the parallelogram's centre (where its diagonals cross)
        centre = bool(np.hypot(*((predicted[0] + predicted[3]) / 2 - target)) <= tie_mm)
        if centre:
            best = 0                                          # stay; spacing 3/4
        else:                                                 # shortest travel among ties
            travel = np.hypot(*(offsets[tied] @ Ju.T).T)
            best = int(tied[np.argmin(travel)])
        note = "centre: spacing x3/4" if centre else ("tie: shortest travel" if len(tied) > 1 else "")
        if best == 0:
            rec.stay(spacing=k, note=note or "P1 nearest: stay")
        else:
            point = rec.move(rec.command + offsets[best], spacing=k, note=note)
        if k == 1:
            break
        k = max(1, (3 * k) // 4 if centre else k // 2)
    return rec.result


def learn_offset(robot: Scara, arm: Arm, target_mm, repeats: int = 5, **kw) -> np.ndarray:
    """Step (5): run ``repeats`` times for one target from the same start and return the mean
    accumulated joint offset (last − first command), rounded to whole command units."""
    if repeats < 1:
        raise KinematicsError(f"repeats = {repeats} must be ≥ 1")
    offsets = []
    for _ in range(repeats):
        res = run_paper(robot, arm, target_mm, **kw)
        offsets.append(np.subtract(res.final.command_units, res.steps[0].command_units))
    return np.rint(np.mean(offsets, axis=0)).astype(np.int64)
