"""Time laws through joint way-points (seed 003): quintic polynomial, quintic and septic
B-spline. Pure numerics, no I/O.

All three laws interpolate the way-points ``q_0..q_{m-1}`` (shape (m, J), one column per
joint, deg or mm) at knot times ``t_0 = 0 < t_1 < ... < t_{m-1} = duration``, start and
stop at rest, and are returned as one :class:`scipy.interpolate.PPoly` so they are
evaluated, differentiated and checked the same way.

Laws (names as used by ``cellctl plan timelaw --law``):

``quintic-poly``
    Piecewise quintic polynomial between consecutive way-points — the comparison law of
    seed 003. Each piece is the quintic Hermite polynomial matching position, velocity and
    acceleration at both of its ends (``BPoly.from_derivatives``). Via-point velocities and
    accelerations come from finite differences: those of the parabola through the
    way-point and its two neighbours (``v_i = np.gradient`` second-order central
    difference; ``a_i = 2 (s_i − s_{i−1}) / (t_{i+1} − t_{i−1})`` with ``s_i`` the slope of
    chord i). End points: v = a = 0. Continuous to the 2nd derivative (C2) by
    construction; jerk jumps at the via points.
``quintic-bspline``
    Degree-5 interpolating B-spline (``make_interp_spline(k=5)``) with knots at the
    way-point times, v = a = 0 at both ends (the 4 extra conditions a quintic needs).
    C4 between knots' pieces, so certainly C2 as seed 003 requires.
``septic-bspline``
    Degree-7 interpolating B-spline, v = a = jerk = 0 at both ends (6 extra conditions).

Time parametrisation (``timing``): ``"uniform"`` (default) spaces the knots equally over
``duration_s``, as seed 003's per-segment parameter 0 ≤ t ≤ 1 does; ``"chord"`` spaces them
in proportion to the Euclidean distance between consecutive joint vectors (units as given).

Every bad input raises :class:`~cell.errors.TrajectoryError` naming the value.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BPoly, BSpline, PPoly, make_interp_spline

from cell.errors import TrajectoryError
from cell.motion.names import LAWS, TIMINGS

__all__ = ["LAWS", "TIMINGS", "JointTrajectory", "Peaks", "knot_times", "plan_timelaw",
           "continuity_jumps"]


def _waypoints(value) -> np.ndarray:
    try:
        q = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TrajectoryError(f"waypoints = {value!r} is not a table of numbers "
                              "(rows of equal length)") from None
    if q.ndim == 1:
        q = q[:, None]  # a single joint given as a flat list
    if q.ndim != 2 or q.shape[1] < 1:
        raise TrajectoryError(f"waypoints must have shape (m, J), got {q.shape}")
    if q.shape[0] < 2:
        raise TrajectoryError(f"need at least 2 way-points, got {q.shape[0]}")
    bad = np.argwhere(~np.isfinite(q))
    if bad.size:
        i, j = (int(v) for v in bad[0])
        raise TrajectoryError(f"way-point {i}, joint {j}: {q[i, j]!r} is not a finite number")
    return q


def knot_times(waypoints, duration_s: float, timing: str = "uniform") -> np.ndarray:
    """Knot times (m,) in seconds from 0 to ``duration_s`` for the way-points (m, J).

    :raises TrajectoryError: duration not finite and > 0, unknown timing, fewer than two
        way-points, or (chord timing) two consecutive way-points that coincide.
    """
    q = _waypoints(waypoints)
    try:
        T = float(duration_s)
    except (TypeError, ValueError):
        raise TrajectoryError(f"duration_s = {duration_s!r} is not a number") from None
    if not (math.isfinite(T) and T > 0):
        raise TrajectoryError(f"duration_s = {duration_s!r} must be a finite number > 0")
    if timing == "uniform":
        return np.linspace(0.0, T, q.shape[0])
    if timing == "chord":
        chord = np.linalg.norm(np.diff(q, axis=0), axis=1)
        if (chord == 0).any():
            i = int(np.argmax(chord == 0))
            raise TrajectoryError(
                f"way-points {i} and {i + 1} coincide; chord timing needs distinct "
                "consecutive way-points (use timing 'uniform' for a dwell)")
        t = np.concatenate([[0.0], np.cumsum(chord)])
        t = T * t / t[-1]
        t[-1] = T
        return t
    raise TrajectoryError(f"timing = {timing!r}; choose one of {TIMINGS}")


@dataclass(frozen=True)
class Peaks:
    """Peak magnitudes per joint (J,): deg/s, deg/s², deg/s³ (mm/s... for a prismatic joint)."""

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    @property
    def overall(self) -> dict[str, float]:
        """Largest peak over all joints for velocity, acceleration and jerk."""
        return {"velocity": float(self.velocity.max()),
                "acceleration": float(self.acceleration.max()),
                "jerk": float(self.jerk.max())}


@dataclass(frozen=True)
class JointTrajectory:
    """A time law through way-points: ``law``, ``timing``, ``knots_s`` (m,),
    ``waypoints`` (m, J) and ``pp``, a :class:`~scipy.interpolate.PPoly` whose breakpoints
    are the knots (value shape (J,))."""

    law: str
    timing: str
    knots_s: np.ndarray
    waypoints: np.ndarray
    pp: PPoly

    @property
    def duration_s(self) -> float:
        return float(self.knots_s[-1])

    def __call__(self, t_s, nu: int = 0) -> np.ndarray:
        """Value (nu = 0) or ``nu``-th time derivative at times ``t_s``; shape (..., J).

        :raises TrajectoryError: a time outside [0, duration] or not finite.
        """
        t = np.asarray(t_s, dtype=float)
        if not np.isfinite(t).all() or (t < 0).any() or (t > self.duration_s).any():
            raise TrajectoryError(
                f"times must lie in [0, {self.duration_s}] s, got range "
                f"[{np.nanmin(t)}, {np.nanmax(t)}]")
        return self.pp(t, nu)

    def sample_times(self, per_piece: int = 200) -> np.ndarray:
        """Dense time grid: ``per_piece`` equal steps in every knot interval, knots included."""
        k = self.knots_s
        steps = np.linspace(0.0, 1.0, per_piece + 1)[:-1]
        t = (k[:-1, None] + np.diff(k)[:, None] * steps).ravel()
        return np.append(t, k[-1])

    def peaks(self, per_piece: int = 200) -> Peaks:
        """Peak |velocity|, |acceleration|, |jerk| per joint, sampled on :meth:`sample_times`."""
        t = self.sample_times(per_piece)
        return Peaks(*(np.abs(self.pp(t, nu)).max(axis=0) for nu in (1, 2, 3)))


def _fd_via(q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Via-point velocity and acceleration from the parabola through each point's neighbours."""
    v = np.zeros_like(q)
    a = np.zeros_like(q)
    if q.shape[0] > 2:
        v[1:-1] = np.gradient(q, t, axis=0, edge_order=2)[1:-1]
        s = np.diff(q, axis=0) / np.diff(t)[:, None]
        a[1:-1] = 2.0 * np.diff(s, axis=0) / (t[2:] - t[:-2])[:, None]
    return v, a


def _bspline_pp(spl: BSpline, n_joints: int) -> PPoly:
    """PPoly of a vector-valued BSpline, without the zero-length end intervals."""
    parts = [PPoly.from_spline(BSpline(spl.t, spl.c[:, j], spl.k)) for j in range(n_joints)]
    x = parts[0].x
    keep = np.diff(x) > 0
    c = np.stack([p.c[:, keep] for p in parts], axis=-1)
    return PPoly(c, np.append(x[:-1][keep], x[-1]))


def plan_timelaw(waypoints, duration_s: float, law: str = "quintic-bspline",
                 timing: str = "uniform") -> JointTrajectory:
    """Fit one of :data:`LAWS` through joint way-points (m, J) over ``duration_s`` seconds.

    The result passes through every way-point at its knot time, starts and stops at rest
    (v = a = 0; the septic also jerk = 0). See the module docstring for each law.
    :raises TrajectoryError: unknown law or timing, fewer than 2 way-points, non-finite
        values, duration not > 0, coincident way-points under chord timing.
    """
    if law not in LAWS:
        raise TrajectoryError(f"law = {law!r}; choose one of {LAWS}")
    q = _waypoints(waypoints)
    t = knot_times(q, duration_s, timing)
    J = q.shape[1]
    if law == "quintic-poly":
        v, a = _fd_via(q, t)
        pp = PPoly.from_bernstein_basis(BPoly.from_derivatives(t, np.stack([q, v, a], axis=1)))
    else:
        k = 5 if law == "quintic-bspline" else 7
        zero = np.zeros(J)
        ends = [(d, zero) for d in range(1, (k - 1) // 2 + 1)]
        pp = _bspline_pp(make_interp_spline(t, q, k=k, bc_type=(ends, ends)), J)
    return JointTrajectory(law=law, timing=timing, knots_s=t, waypoints=q, pp=pp)


def continuity_jumps(traj: JointTrajectory, max_order: int = 2) -> np.ndarray:
    """Jumps at the interior knots: right limit − left limit of each derivative.

    Each side is evaluated exactly from its own piece polynomial (no finite step).
    :returns: array (m−2, max_order+1, J): knot, derivative order 0..max_order, joint.
    """
    pp = traj.pp
    x = pp.x
    out = np.zeros((len(x) - 2, max_order + 1, pp.c.shape[-1]))
    for i in range(1, len(x) - 1):
        left = PPoly(pp.c[:, i - 1:i], x[i - 1:i + 1])  # one piece, evaluated at its end
        right = PPoly(pp.c[:, i:i + 1], x[i:i + 2])
        for nu in range(max_order + 1):
            out[i - 1, nu] = right(x[i], nu) - left(x[i], nu)
    return out
