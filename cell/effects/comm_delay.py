"""comm_delay: joints receive their commands one after another on the CAN bus (seed 002:
station k is σ·k late)."""
from __future__ import annotations

import numpy as np

from cell.effects.base import Effect, MovingCommands, ParamSpec, Remedy


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


EFFECT = Effect(
    "comm_delay", "comms", "comms", (), False,
    (ParamSpec("comm_delay_sigma_ms", "ms", "per-frame delay σ; station k is σ·k late",
               (0.0, 50.0), (0.5, 4.0), False),),
    "speed", "joints receive their commands one after another", comm_delay, d_comm_delay,
    needs=(MovingCommands(),),
    remedy=Remedy("comms", "Check the joint stations' delays on the bus and the recipe's "
                  "motion.sync (corrected or sync), then run a line to compare.",
                  ("cellctl recipe show NAME",)))
