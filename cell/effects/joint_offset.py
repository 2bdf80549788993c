"""joint_offset: the joint's zero differs from the nominal zero (format: θ_true = θ_cmd + o)."""
from __future__ import annotations

import numpy as np

from cell.effects.base import (CALIBRATE_CHAIN, CALIBRATE_KINEMATICS, PLANAR_JOINTS, Effect,
                               OnChain, ParamSpec, constant_term, grid, unit_columns)


def joint_offset(x, jidx, cmd_deg, dirs):
    """Zero-position error: Δθ_j = o_j (deg), the same at every angle and direction."""
    out = np.zeros_like(cmd_deg, dtype=float)
    out[:, list(jidx)] += grid(x, jidx, 1)[:, 0]
    return out


def d_joint_offset(x, jidx, a, dirs):
    """∂Δθ/∂o_j = 1 on joint j; nothing depends on the angle."""
    return unit_columns(jidx, len(a)), None


EFFECT = Effect(
    "joint_offset", "kinematics", "joint", PLANAR_JOINTS, True,
    (ParamSpec("offset_deg", "deg", "joint zero error", (-5.0, 5.0), (0.02, 0.2)),),
    "constant", "joint zero differs from the nominal zero", joint_offset, d_joint_offset,
    remedy=CALIBRATE_KINEMATICS,
    chain=OnChain("all", "offset_{unit}", remedy=CALIBRATE_CHAIN, term=constant_term))
