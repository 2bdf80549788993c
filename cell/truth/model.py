"""The independent forward model of the planar cell: what the validation's campaigns are
measured on. Pure numerics, no I/O.

Written from the definitions in ``cell/measurements.md`` and the seeds (``../shared/seeds``),
on purpose **without** :mod:`cell.effects` or :mod:`cell.kinematics`: the diagnosis fits
with those, so a sign, unit or composition mistake in them would cancel out if the truth
came from them too. Everything here is a plain per-point loop over ``math``; its
parameters are its own (a gear as the ratio of true to nominal teeth, a cyclic error as
cosine and sine components, the camera as a gain and a turn in radians, the CAN delay in
seconds), so the conversion to the vocabulary's units (:mod:`cell.truth.parts`) is part of
what the agreement test (``tests/cell/test_truth.py``) checks.

How one measured point comes about (units: deg, mm, s, °C)::

    drive     each joint's drive has command θ_d; on a path the CAN station at bus position
              k (1-based, ``Cell.stations``) gets its frames σ·k late (seed 002), so at time
              t its drive has the command of t − σ·k (linear between command samples, the
              first one before the move)
    joint     θ = θ_d·N_nominal/N_true            the drive turns the motor by the nominal ratio
                + zero                            the joint's true zero lies off the nominal one
                − dir·play/2                      the output trails the drive by half the play in
                                                  the direction of the last motion (dir = ±1, 0)
                + Σ c·cos(nθ_d) + s·sin(nθ_d)     transmission error, n cycles per revolution
                + bump·[t ≥ t_bump]               (outside the vocabulary) a knock moves the zero
              and for joint 2 + κ·θ_d,1          (outside the vocabulary) coupling to joint 1
              every term of a joint is taken at its drive angle θ_d (the format's convention)
    links     L_k = L_k,nominal + e_k + a·L_k,nominal·(T − T_ref)   (thermal: ISO 1, 20 °C)
    tool      x = L1 cos θ1 + L2 cos(θ1 + θ2), y = L1 sin θ1 + L2 sin(θ1 + θ2)   (seed 000)
              − (0, g·(r / 1 m)²)                 (outside the vocabulary) reach-dependent sag
              + A·exp(−|p − p₀|²/(2w²))·(cos β, sin β)   (outside the vocabulary) a smooth
                                                  local bump of the work plane (a warped table)
              + repeatability of the arrival (points only)
    camera    m = c + gain·R(turn)·(p − c), c the camera centre on the work plane, then
              m = c + d·(1 + K·|d|²), d = m − c    (outside the vocabulary) radial lens
                                                  distortion

The direction of the last motion on a path is the sign of the last non-zero step of the
drive's command (``dirs0`` before the first step); for static points it is given.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class Cell:
    """The nominal cell, as a campaign's model.yaml states it: link lengths (mm), where the
    camera's optical axis meets the work plane (mm, base frame), the CAN station order."""

    l1_mm: float
    l2_mm: float
    camera_center_mm: tuple[float, float]
    stations: tuple[str, ...] = ("j1", "j2", "j3", "j4")

    def bus_position(self, joint: int) -> int:
        """1-based position of joint ``joint`` (1 or 2) on the bus."""
        return list(self.stations).index(f"j{joint}") + 1


@dataclass(frozen=True)
class Ripple:
    """A transmission error of ``cycles`` periods per joint revolution (1–4):
    Δθ = cos_deg·cos(cycles·θ) + sin_deg·sin(cycles·θ), θ the drive angle."""

    cycles: int
    cos_deg: float
    sin_deg: float


@dataclass(frozen=True)
class Bump:
    """From campaign time ``at_s`` on, joint ``joint`` (1 or 2) has its zero ``step_deg`` off."""

    joint: int
    step_deg: float
    at_s: float


@dataclass(frozen=True)
class PlaneBump:
    """A smooth local displacement of the tool centre: ``amp_mm`` at ``at_mm`` (base frame),
    Gaussian fall-off of width ``width_mm``, in direction ``dir_rad`` (from +x toward +y)."""

    amp_mm: float
    at_mm: tuple[float, float]
    width_mm: float
    dir_rad: float


@dataclass(frozen=True)
class Truth:
    """How the true cell differs from the nominal one; the defaults are a perfect cell.
    Per-joint tuples hold (joint 1, joint 2). See the module docstring for each term."""

    zero_deg: tuple[float, float] = (0.0, 0.0)
    link_error_mm: tuple[float, float] = (0.0, 0.0)
    teeth_ratio: tuple[float, float] = (1.0, 1.0)        # N_true / N_nominal
    play_deg: tuple[float, float] = (0.0, 0.0)
    ripples: tuple[tuple[Ripple, ...], tuple[Ripple, ...]] = ((), ())
    expansion_per_k: float = 0.0
    ref_temp_c: float = 20.0
    camera_gain: float = 1.0
    camera_turn_rad: float = 0.0
    frame_delay_s: float = 0.0
    # outside the vocabulary
    lens_k_per_mm2: float = 0.0
    sag_mm_at_1m: float = 0.0
    bump: Bump | None = None
    coupling_21: float = 0.0
    plane_bump: PlaneBump | None = None


# ------------------------------------------------------------------ one point
def joint_angle_deg(truth: Truth, joint: int, drive_deg: float, direction: float,
                    clock_s: float, drive1_deg: float) -> float:
    """True angle (deg) of joint ``joint`` (1 or 2) whose drive has command ``drive_deg``,
    last moved in ``direction`` (−1, 0, +1), at campaign time ``clock_s``; ``drive1_deg`` is
    joint 1's drive command (for the coupling of joint 2)."""
    k = joint - 1
    theta = drive_deg / truth.teeth_ratio[k]
    theta += truth.zero_deg[k]
    theta -= direction * truth.play_deg[k] / 2.0
    for rp in truth.ripples[k]:
        arg = rp.cycles * math.radians(drive_deg)
        theta += rp.cos_deg * math.cos(arg) + rp.sin_deg * math.sin(arg)
    b = truth.bump
    if b is not None and b.joint == joint and clock_s >= b.at_s:
        theta += b.step_deg
    if joint == 2:
        theta += truth.coupling_21 * drive1_deg
    return theta


def link_lengths_mm(cell: Cell, truth: Truth, temp_c: float) -> tuple[float, float]:
    """True link lengths (mm) at temperature ``temp_c``."""
    grow = truth.expansion_per_k * (temp_c - truth.ref_temp_c)
    return (cell.l1_mm + truth.link_error_mm[0] + cell.l1_mm * grow,
            cell.l2_mm + truth.link_error_mm[1] + cell.l2_mm * grow)


def tool_xy(l1: float, l2: float, theta1_deg: float, theta2_deg: float) -> tuple[float, float]:
    """Seed 000's planar forward kinematics: tool centre (mm); θ2 measured from link 1."""
    a = math.radians(theta1_deg)
    ab = math.radians(theta1_deg + theta2_deg)
    return l1 * math.cos(a) + l2 * math.cos(ab), l1 * math.sin(a) + l2 * math.sin(ab)


def camera_sees(cell: Cell, truth: Truth, x: float, y: float) -> tuple[float, float]:
    """What the fixed camera reports (mm) for a tool centre at (x, y) mm."""
    cx, cy = cell.camera_center_mm
    dx, dy = x - cx, y - cy
    co, si = math.cos(truth.camera_turn_rad), math.sin(truth.camera_turn_rad)
    u = truth.camera_gain * (co * dx - si * dy)
    v = truth.camera_gain * (si * dx + co * dy)
    if truth.lens_k_per_mm2:
        f = 1.0 + truth.lens_k_per_mm2 * (u * u + v * v)
        u, v = u * f, v * f
    return cx + u, cy + v


def true_xy(cell: Cell, truth: Truth, drive: tuple[float, float], dirs: tuple[float, float],
            clock_s: float, temp_c: float) -> tuple[float, float]:
    """True tool centre (mm, before the camera and without repeatability)."""
    d1, d2 = drive
    t1 = joint_angle_deg(truth, 1, d1, dirs[0], clock_s, d1)
    t2 = joint_angle_deg(truth, 2, d2, dirs[1], clock_s, d1)
    x, y = tool_xy(*link_lengths_mm(cell, truth, temp_c), t1, t2)
    if truth.sag_mm_at_1m:
        y -= truth.sag_mm_at_1m * (x * x + y * y) / 1e6
    pb = truth.plane_bump
    if pb is not None:
        r2 = (x - pb.at_mm[0]) ** 2 + (y - pb.at_mm[1]) ** 2
        a = pb.amp_mm * math.exp(-r2 / (2.0 * pb.width_mm ** 2))
        x, y = x + a * math.cos(pb.dir_rad), y + a * math.sin(pb.dir_rad)
    return x, y


# ------------------------------------------------------------------ tables
def _table(name: str, a, n: int | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 2 or (n is not None and len(a) != n) \
            or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite with shape ({n or 'N'}, 2), got {a.shape}")
    return a


def _series(name: str, a, n: int) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite with shape ({n},), got {a.shape}")
    return a


def measure_points(cell: Cell, truth: Truth, cmd_deg, dirs, clock_s, temp_c,
                   repeat_mm=None) -> np.ndarray:
    """What the camera reports (N,2) mm for N static poses: commands ``cmd_deg`` (N,2) deg,
    last-motion directions ``dirs`` (N,2) (−1, 0, +1), campaign times ``clock_s`` (N,) s,
    true temperatures ``temp_c`` (N,) °C, and each arrival's repeatability offset
    ``repeat_mm`` (N,2) mm (added to the true point before the camera; default none).
    Raises ValueError for arrays of the wrong shape or non-finite values."""
    cmd = _table("cmd_deg", cmd_deg)
    n = len(cmd)
    dirs = _table("dirs", dirs, n)
    clock = _series("clock_s", clock_s, n)
    temp = _series("temp_c", temp_c, n)
    rep = np.zeros((n, 2)) if repeat_mm is None else _table("repeat_mm", repeat_mm, n)
    out = np.empty((n, 2))
    for i in range(n):
        x, y = true_xy(cell, truth, (cmd[i, 0], cmd[i, 1]), (dirs[i, 0], dirs[i, 1]),
                       clock[i], temp[i])
        out[i] = camera_sees(cell, truth, x + rep[i, 0], y + rep[i, 1])
    return out


def drive_commands(cell: Cell, truth: Truth, cmd_deg, time_s) -> np.ndarray:
    """The command each drive has (N,2) deg at the move times ``time_s`` (N,) s when the
    controller sent ``cmd_deg`` (N,2): joint j's frames arrive σ·k_j late."""
    cmd = _table("cmd_deg", cmd_deg)
    t = _series("time_s", time_s, len(cmd)).tolist()
    out = cmd.copy()
    for j in (1, 2):
        lag = truth.frame_delay_s * cell.bus_position(j)
        if not lag:
            continue
        col = cmd[:, j - 1].tolist()
        for i, ti in enumerate(t):
            want = ti - lag
            if want <= t[0]:
                out[i, j - 1] = col[0]
                continue
            hi = bisect.bisect_left(t, want)          # t[hi-1] < want <= t[hi]
            lo = hi - 1
            share = (want - t[lo]) / (t[hi] - t[lo])
            out[i, j - 1] = col[lo] + share * (col[hi] - col[lo])
    return out


def last_directions(drive_deg: np.ndarray, dirs0: Sequence[float]) -> np.ndarray:
    """Direction of each joint's last motion (N,2) along drive commands (N,2): the sign of
    the last non-zero step, ``dirs0`` until the first one."""
    out = np.empty_like(drive_deg)
    last = [float(dirs0[0]), float(dirs0[1])]
    for i in range(len(drive_deg)):
        for j in range(2):
            if i:
                step = drive_deg[i, j] - drive_deg[i - 1, j]
                if step > 0:
                    last[j] = 1.0
                elif step < 0:
                    last[j] = -1.0
            out[i, j] = last[j]
    return out


def measure_path(cell: Cell, truth: Truth, cmd_deg, time_s, clock_s, temp_c,
                 dirs0=(0.0, 0.0)) -> np.ndarray:
    """What the camera reports (N,2) mm along one move: commands ``cmd_deg`` (N,2) deg at
    move times ``time_s`` (N,) s (strictly increasing), campaign times ``clock_s`` (N,) s,
    true temperatures ``temp_c`` (N,) °C, last-motion directions ``dirs0`` (2,) before the
    move. No repeatability along a path (it is a property of an arrival). Raises ValueError
    for bad shapes, non-finite values or time not increasing."""
    cmd = _table("cmd_deg", cmd_deg)
    n = len(cmd)
    t = _series("time_s", time_s, n)
    if n > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("time_s must increase strictly")
    clock = _series("clock_s", clock_s, n)
    temp = _series("temp_c", temp_c, n)
    drive = drive_commands(cell, truth, cmd, t)
    dirs = last_directions(drive, dirs0)
    out = np.empty((n, 2))
    for i in range(n):
        x, y = true_xy(cell, truth, (drive[i, 0], drive[i, 1]), (dirs[i, 0], dirs[i, 1]),
                       clock[i], temp[i])
        out[i] = camera_sees(cell, truth, x, y)
    return out
