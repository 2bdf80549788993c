"""motor_cyclic_error: a periodic error of the motor-side gear, seen at the joint N times per
joint revolution (format: θ_true = θ_cmd + a·sin(2π·N·θ_cmd/360° + φ), N the known
motor-to-joint gear ratio; on a chain q_true = q + s·sin(N·q) + c·cos(N·q) on the joints
whose model states N, ``motor_gear_ratio``).

A ripple of the motor's own gear stage (pinion eccentricity, a worn tooth) turns once per
motor revolution, i.e. N times per joint revolution: at N = 50 its period at the joint is
7.2°. Its amplitude at the joint is the motor-side error divided by N, so it is small, but
its period is short: a campaign identifies it only when the joint's angles sample that
period densely (:func:`~cell.effects.base.phase_coverage`). Seed 004's stepped sweep
shows why that must be checked: a fixed step of a whole (or half) period photographs the
same phase (or two opposite ones) at every stop, and the ripple becomes a constant.

When it cannot be tested it mimics nothing in particular: at a few stations each sees its
own phase, a scatter no single vocabulary effect reproduces (a joint that never moves is
already covered: its offset has gear_ratio and cyclic_error as rivals).
"""
from __future__ import annotations

import math

import numpy as np

from cell.effects.base import (CALIBRATE_JOINT, INF, PLANAR_JOINTS, ChainPoses, Effect,
                               OnChain, ParamSpec, Remedy, grid, phase_coverage)

MOTOR_GEAR_RATIO = 50.0     # motor turns per joint turn, when the cell's model does not say


def motor_cyclic_error(x, jidx, cmd_deg, dirs):
    """Δθ_j = a_j·sin(2π·N_j·θ_cmd,j/360° + φ_j): amplitude a (deg at the joint), phase φ
    (deg, at command 0), N the motor-to-joint gear ratio (known constant)."""
    g = grid(x, jidx, 3)
    out = np.zeros_like(cmd_deg, dtype=float)
    arg = np.radians(g[:, 2] * cmd_deg[:, list(jidx)] + g[:, 1])
    out[:, list(jidx)] = g[:, 0] * np.sin(arg)
    return out


def d_motor_cyclic_error(x, jidx, a, dirs):
    """∂/∂a = sin(arg), ∂/∂φ = a·cos(arg)·π/180, ∂/∂θ_cmd = a·cos(arg)·N·π/180."""
    g = grid(x, jidx, 3)
    cols, dda = [], np.zeros_like(a)
    for i, j in enumerate(jidx):
        amp, ph, n = g[i]
        arg = np.radians(n * a[:, j] + ph)
        ca, cp = np.zeros_like(a), np.zeros_like(a)
        ca[:, j] = np.sin(arg)
        cp[:, j] = amp * np.cos(arg) * math.pi / 180.0
        cols += [ca, cp]
        dda[:, j] = amp * np.cos(arg) * n * math.pi / 180.0
    return cols, dda


def _motor_harmonic(cosine: bool):
    """The chain term of one coefficient: Δq_k per degree of it, sin or cos of N_k·q_k (q_k
    the joint's model value, deg; N_k its stated motor gear ratio)."""
    def term(poses: ChainPoses, k: int) -> np.ndarray:
        arg = np.radians(poses.motor_ratio[k] * poses.q[:, k])
        return np.cos(arg) if cosine else np.sin(arg)
    return term


def _chain_coverage(poses: ChainPoses, k: int, places: np.ndarray) -> str:
    """:func:`phase_coverage` of joint k's model values at its stated motor gear ratio."""
    return phase_coverage(poses.q[:, k], poses.motor_ratio[k], places, f"j{k + 1}")


# on a chain, linear in its coefficients as cyclic_error: a·sin(Nq + φ) = s·sin(Nq) + c·cos(Nq)
CHAIN_PARTS = (("motor_cyclic_sin_deg", _motor_harmonic(False)),
               ("motor_cyclic_cos_deg", _motor_harmonic(True)))
AMPLITUDE_MAX_DEG = 0.5

EFFECT = Effect(
    "motor_cyclic_error", "transmission", "joint", PLANAR_JOINTS, True,
    (ParamSpec("motor_cyclic_amp_deg", "deg", "amplitude at the joint", (0.0, AMPLITUDE_MAX_DEG),
               (0.01, 0.05), False, start=(0.01, 0.45)),
     ParamSpec("motor_cyclic_phase_deg", "deg", "phase at θ = 0", (-INF, INF), (0.0, 360.0),
               False),
     ParamSpec("motor_gear_ratio", "1", "motor turns per joint turn (known)", (1.0, 1000.0),
               (MOTOR_GEAR_RATIO, MOTOR_GEAR_RATIO), False, fitted=False,
               default=MOTOR_GEAR_RATIO)),
    "angle", "periodic error of the motor-side gear, N periods per joint turn",
    motor_cyclic_error, d_motor_cyclic_error,
    remedy=CALIBRATE_JOINT,
    chain=OnChain("geared", unit="deg", parts=CHAIN_PARTS, coverage=_chain_coverage,
                  remedy=Remedy("calibrate_joint", "Compensate the motor-side ripple over the "
                                "joint's angle, or service the motor's gear stage: {what}{on}."),
                  bounds=(-AMPLITUDE_MAX_DEG, AMPLITUDE_MAX_DEG)))
