"""link_length: a link is longer or shorter than nominal (format: L_true = L_nominal + d)."""
from __future__ import annotations

import numpy as np

from cell.effects.base import (CALIBRATE_CHAIN, CALIBRATE_KINEMATICS, PLANAR_JOINTS, Effect,
                               OnChain, ParamSpec, grid, unit_columns)


def link_length(x, jidx, links_mm, temp_c):
    """Link length error: Δl_k = d_k (mm), constant (``j1``/``j2`` = link 1/2)."""
    out = np.zeros((len(temp_c), 2))
    out[:, list(jidx)] += grid(x, jidx, 1)[:, 0]
    return out


def d_link_length(x, jidx, links_mm, temp_c):
    """∂Δl_k/∂d_k = 1; no temperature dependence."""
    return unit_columns(jidx, len(temp_c)), None


EFFECT = Effect(
    "link_length", "kinematics", "link", PLANAR_JOINTS, True,
    (ParamSpec("link_delta_mm", "mm", "true − nominal link length", (-50.0, 50.0), (0.1, 1.0)),),
    "position", "a link is longer or shorter than nominal", link_length, d_link_length,
    remedy=CALIBRATE_KINEMATICS,
    chain=OnChain("geometric", remedy=CALIBRATE_CHAIN))
