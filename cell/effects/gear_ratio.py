"""gear_ratio: the drive converts joint to motor angle with a wrong ratio
(format: θ_true = θ_cmd·(1 + ε))."""
from __future__ import annotations

import numpy as np

from cell.effects.base import (CALIBRATE_CHAIN, CALIBRATE_JOINT, PLANAR_JOINTS, Effect, OnChain,
                               ParamSpec, grid)


def gear_ratio(x, jidx, cmd_deg, dirs):
    """Gear ratio error: θ_true = θ_cmd·(1 + ε_j), i.e. Δθ_j = ε_j·θ_cmd,j, where
    ε = N_nominal/N_true − 1 (the drive converts joint angle to motor angle with the
    nominal ratio). Zero at the joint's zero, growing with the angle."""
    out = np.zeros_like(cmd_deg, dtype=float)
    out[:, list(jidx)] = grid(x, jidx, 1)[:, 0] * cmd_deg[:, list(jidx)]
    return out


def d_gear_ratio(x, jidx, a, dirs):
    """∂Δθ_j/∂ε_j = θ_cmd,j; ∂Δθ_j/∂θ_cmd,j = ε_j."""
    cols, dda = [], np.zeros_like(a)
    for i, j in enumerate(jidx):
        c = np.zeros_like(a)
        c[:, j] = a[:, j]
        cols.append(c)
        dda[:, j] = x[i]
    return cols, dda


RATIO = ParamSpec("gear_ratio_rel", "1", "ε = N_nominal/N_true − 1", (-0.05, 0.05), (2e-4, 2e-3))

EFFECT = Effect(
    "gear_ratio", "transmission", "joint", PLANAR_JOINTS, True, (RATIO,),
    "angle", "joint angle scaled by a wrong gear ratio", gear_ratio, d_gear_ratio,
    mimics=("joint_offset",),     # on a joint that never moves: a constant angle error
    remedy=CALIBRATE_JOINT,
    chain=OnChain("all", "gear_ratio_rel", "1", remedy=CALIBRATE_CHAIN,
                  term=lambda poses, k: poses.q[:, k],     # Δq_k = ε·q_k
                  bounds=RATIO.bounds))
