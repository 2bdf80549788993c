"""cyclic_error: periodic transmission error of the drive, a few cycles per joint revolution
(format: θ_true = θ_cmd + a·sin(2π·θ_cmd/P + φ), P = 360°/n, n = 1–4; on a chain
q_true = q + Σₙ (sₙ·sin(n·q) + cₙ·cos(n·q)) over the joint's model value q)."""
from __future__ import annotations

import math

import numpy as np

from cell.effects.base import (CALIBRATE_JOINT, INF, PLANAR_JOINTS, ChainPoses, Effect,
                               OnChain, ParamSpec, Remedy, grid)

DEG = math.pi / 180.0
ORDERS = (1, 2, 3, 4)   # cycles per joint revolution the screening tries


def cyclic_error(x, jidx, cmd_deg, dirs):
    """Periodic transmission error: Δθ_j = a_j·sin(2π·θ_cmd,j/P_j + φ_j), amplitude a (deg),
    phase φ (deg), period P (joint deg). P is a known constant of the drive (default 360°:
    once per revolution of the output gear); a and φ are fitted."""
    g = grid(x, jidx, 3)
    out = np.zeros_like(cmd_deg, dtype=float)
    arg = 2 * np.pi * cmd_deg[:, list(jidx)] / g[:, 2] + np.radians(g[:, 1])
    out[:, list(jidx)] = g[:, 0] * np.sin(arg)
    return out


def d_cyclic_error(x, jidx, a, dirs):
    """∂/∂a = sin(arg), ∂/∂φ = a·cos(arg)·π/180, ∂/∂θ_cmd = a·cos(arg)·2π/P."""
    g = grid(x, jidx, 3)
    cols, dda = [], np.zeros_like(a)
    for i, j in enumerate(jidx):
        amp, ph, per = g[i]
        arg = 2 * np.pi * a[:, j] / per + math.radians(ph)
        s, c = np.sin(arg), np.cos(arg)
        ca, cp = np.zeros_like(a), np.zeros_like(a)
        ca[:, j] = s
        cp[:, j] = amp * c * DEG
        cols += [ca, cp]
        dda[:, j] = amp * c * 2 * np.pi / per
    return cols, dda


def _harmonic(order: int, cosine: bool):
    """The chain term of one coefficient: Δq_k per degree of it, sin or cos of order·q_k
    (q_k the joint's model value, deg)."""
    def term(poses: ChainPoses, k: int) -> np.ndarray:
        arg = np.radians(order * poses.q[:, k])
        return np.cos(arg) if cosine else np.sin(arg)
    return term


# on a chain the ripple is linear in its coefficients: a·sin(nq + φ) = s·sin(nq) + c·cos(nq),
# s = a·cos φ, c = a·sin φ, for each order n the screening may keep
CHAIN_PARTS = tuple((f"cyclic{n}_{f}_deg", _harmonic(n, f == "cos"))
                    for n in ORDERS for f in ("sin", "cos"))
AMPLITUDE = ParamSpec("cyclic_amp_deg", "deg", "amplitude", (0.0, 1.0), (0.01, 0.08), False,
                      start=(0.01, 0.9))

EFFECT = Effect(
    "cyclic_error", "transmission", "joint", PLANAR_JOINTS, True,
    (AMPLITUDE,
     ParamSpec("cyclic_phase_deg", "deg", "phase at θ = 0", (-INF, INF), (0.0, 360.0), False),
     ParamSpec("cyclic_period_deg", "deg", "period in joint deg (known)", (1e-3, 3600.0),
               (360.0, 360.0), False, fitted=False, default=360.0)),
    "angle", "periodic transmission error of the drive", cyclic_error, d_cyclic_error,
    mimics=("joint_offset",),     # on a joint that never moves: a constant angle error
    remedy=CALIBRATE_JOINT,
    chain=OnChain("revolute", unit="deg", parts=CHAIN_PARTS, choice=2,
                  remedy=Remedy("calibrate_joint", "Compensate the transmission ripple over the "
                                "joint's angle, or service the drive: {what}{on}."),
                  bounds=(-AMPLITUDE.bounds[1], AMPLITUDE.bounds[1])))
