"""comm_delay: joints receive their commands one after another on the CAN bus (seed 002:
station k is σ·k late). On a chain, on the samples of a measured move: q_k(t) =
q_cmd,k(t − σ·b_k), b_k the joint's bus position (its first-order form −σ·b_k·q̇_cmd,k is
the screening's linearisation)."""
from __future__ import annotations

import numpy as np

from cell.effects.base import ChainPoses, Effect, OnChain, ParamSpec, Remedy
from cell.numerics.stats import distinct


def comm_delay(x, order, time_s, cmd_deg):
    """Per-frame CAN delay σ (ms, seed 002): joint j receives its command λ_j = σ·k_j late
    (k_j = 1-based station position), so at time t it has the command of t − λ_j. The
    commanded trajectory is interpolated linearly between its samples and held at its
    first value before the first one. σ = 0 is the identity."""
    lam = float(x[0]) * 1e-3 * np.asarray(order, dtype=float)
    out = np.array(cmd_deg, dtype=float)
    for j in range(2):
        if lam[j]:
            out[:, j] = np.interp(time_s - lam[j], time_s, cmd_deg[:, j])
    return out


def d_comm_delay(x, order):
    """λ_j = σ·k_j ms, ∂λ_j/∂σ = k_j."""
    k = np.asarray(order, dtype=float)
    return float(x[0]) * k, k


def chain_lag(poses: ChainPoses, k: int) -> np.ndarray:
    """Joint k's value change per ms of σ: −b_k·q̇_k/1000 (deg, at q̇ deg/s), the first-order
    time shift of its command by σ·b_k ms; 0 at static poses, and for a joint whose bus
    position is not known."""
    b = poses.bus[k] if k < len(poses.bus) else None
    if poses.rate is None or b is None:
        return np.zeros(len(poses.q))
    return -float(b) * poses.rate[:, k] * 1e-3


def chain_shift(poses: ChainPoses, k: int, sigma_ms: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint k's exact change at σ (ms), and its derivative: along each measured move the
    command of t − σ·b_k ms (interpolated linearly between the samples, held at the first
    one before it, as :func:`comm_delay`) minus that of t; the derivative −b_k/1000 times
    the slope of the command's segment at t − λ (0 while held). 0 at static poses and for a
    joint whose bus position is not known."""
    n = len(poses.q)
    b = poses.bus[k] if k < len(poses.bus) else None
    if poses.rate is None or poses.move is None or b is None:
        return np.zeros(n), np.zeros(n)
    lag = float(sigma_ms) * float(b) * 1e-3
    out, dv = np.zeros(n), np.zeros(n)
    for m in distinct(poses.move[poses.move >= 0]):
        idx = np.flatnonzero(poses.move == m)
        t, q = poses.move_t[idx], poses.q[idx, k]
        ts = t - lag
        out[idx] = np.interp(ts, t, q) - q
        if len(t) > 1:
            seg = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, len(t) - 2)
            slope = (q[seg + 1] - q[seg]) / (t[seg + 1] - t[seg])
            held = (ts < t[0]) | (ts > t[-1])
            dv[idx] = np.where(held, 0.0, -float(b) * slope * 1e-3)
    return out, dv


SIGMA = ParamSpec("comm_delay_sigma_ms", "ms", "per-frame delay σ; station k is σ·k late",
                  (0.0, 50.0), (0.5, 4.0), False)

EFFECT = Effect(
    "comm_delay", "comms", "comms", (), False,
    (SIGMA,),
    "speed", "joints receive their commands one after another", comm_delay, d_comm_delay,
    remedy=Remedy("comms", "Check the joint stations' delays on the bus and the recipe's "
                  "motion.sync (corrected or sync), then run a line to compare.",
                  ("cellctl recipe show NAME",)),
    chain=OnChain("bus", "comm_delay_sigma_ms", "ms", term=chain_lag, shift=chain_shift,
                  unseen="no measured moves (paths.csv): the joints' lag shows only in motion",
                  bounds=SIGMA.bounds))
