"""backlash: lost motion; the joint depends on the approach direction
(format: θ_true = θ_cmd − dir·b/2)."""
from __future__ import annotations

import numpy as np

from cell.effects.base import (CALIBRATE_JOINT, PLANAR_JOINTS, Effect, OnChain,
                               ParamSpec, Remedy, grid)


def backlash(x, jidx, cmd_deg, dirs):
    """Lost motion of total width b_j (deg): the output trails the drive by half the band,
    Δθ_j = −dir_j·b_j/2, so a reversal moves the joint by b_j. Depends on the direction of
    the last motion only (dir 0 = unknown, centre of the band); not on the angle. The
    traversal of the band at a reversal (≤ b/speed, ms) is not modelled."""
    out = np.zeros_like(cmd_deg, dtype=float)
    out[:, list(jidx)] = -0.5 * grid(x, jidx, 1)[:, 0] * dirs[:, list(jidx)]
    return out


def d_backlash(x, jidx, a, dirs):
    """∂Δθ_j/∂b_j = −dir_j/2; piecewise constant in the angle."""
    cols = []
    for j in jidx:
        c = np.zeros_like(a)
        c[:, j] = -0.5 * dirs[:, j]
        cols.append(c)
    return cols, None


WIDTH = ParamSpec("backlash_deg", "deg", "total lost-motion width", (0.0, 2.0), (0.01, 0.1), False)

EFFECT = Effect(
    "backlash", "transmission", "joint", PLANAR_JOINTS, True, (WIDTH,),
    "direction", "lost motion: the joint depends on the approach direction", backlash, d_backlash,
    mimics=("joint_offset", "gear_ratio", "cyclic_error"),
    remedy=CALIBRATE_JOINT,
    chain=OnChain("all", "backlash_{unit}",
                  remedy=Remedy("calibrate_joint", "Compensate the lost motion, or service the "
                                "drive: {what}{on}."),
                  term=lambda poses, k: -0.5 * poses.dirs[:, k],     # Δq_k = −dir_k·b/2
                  unseen="no jK_dir column: the direction of the joint's last motion is "
                         "not known", bounds=WIDTH.bounds))
