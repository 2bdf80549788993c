"""Straight-line moves for CAN joint stations with the seed 002 delay correction. Pure numerics.

Seed 002 (CAN-station SCARA) splits a straight move from a start pose to a target pose
(x_mm, y_mm, z_mm, phi_deg) into ``n`` equal Cartesian steps. Every interpolation point is
converted to joints with :meth:`cell.kinematics.Scara.ik` (one explicit elbow for the whole
move). Segment ``k`` (k = 1..n) lasts ``T`` seconds and commands each joint to its target
``θ*_k`` at the velocity

    ω_i = (θ*_i − θ0_i) / T                                   (seed 002, uncorrected)

The stations receive their frames one after another, so station ``p`` on the bus
(p = 1 for the first) starts ``λ_p = σ·p`` late. Seed 002 folds the delay into the
velocity so every joint still arrives at the same instant::

    ω_i = Δθ_i / (T − λ_i)                                    (seed 002, corrected)

Units: joints are (θ1_deg, θ2_deg, d3_mm, θ4_deg); the ``*_deg`` names below hold mm
(and mm/s) for the prismatic joint j3. Times are seconds. Delays are always given per
*joint* (j1..j4); :func:`joint_delays` maps bus order to joints.

Time law. Seed 002 spaces the interpolation points equally (``time_law="linear"``): the
tool starts and stops at full speed. Its Fig. 8(c) adds a non-linear interpolation that
makes start and stop smooth; here (``time_law="smooth"``) point k sits at the path fraction
s(k/n) with s(u) = 10u³ − 15u⁴ + 6u⁵, whose velocity and acceleration are zero at both
ends, while every segment still lasts T: the steps are short at the ends and long in the
middle (peak speed 1.875× the mean).

Every bad input raises :class:`~cell.errors.TrajectoryError` naming the value;
T ≤ λ_i is an error, never a negative or infinite velocity.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from cell.errors import CellError, TrajectoryError
from cell.kinematics import JOINT_NAMES, Elbow, Scara

__all__ = [
    "TIME_LAWS", "LinePlan", "Segment", "SimulatedPath", "station_delays", "joint_delays",
    "delay_corrected_velocities", "line_joints", "plan_line", "joint_positions_at", "simulate_line",
    "max_line_deviation", "tool_positions",
]


# --------------------------------------------------------------------------- validation
def _finite_scalar(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TrajectoryError(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(v):
        raise TrajectoryError(f"{name} = {value!r} is not a finite number")
    return v


def _finite_array(name: str, value, shape: tuple[int, ...] | None = None) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TrajectoryError(f"{name} = {value!r} is not an array of numbers") from None
    if shape is not None and a.shape != shape:
        raise TrajectoryError(f"{name} must have shape {shape}, got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise TrajectoryError(f"{name}[{', '.join(map(str, idx))}] = {a[idx]!r} is not a finite number")
    return a


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TrajectoryError(f"{name} = {value!r} must be a whole number")
    if value < 1:
        raise TrajectoryError(f"{name} = {value} must be at least 1")
    return int(value)


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------- delays
def station_delays(sigma_s: float, n_stations: int) -> np.ndarray:
    """Command delays in bus order, ``λ_p = σ·p`` for p = 1..n (seed 002).

    :param sigma_s: per-frame delay σ in seconds, finite and ≥ 0.
    :param n_stations: number of stations on the bus, ≥ 1.
    :returns: array of shape (n_stations,), seconds; element 0 is the first station.
    :raises TrajectoryError: σ negative or not finite, n not a whole number ≥ 1.
    """
    s = _finite_scalar("sigma_s", sigma_s)
    if s < 0:
        raise TrajectoryError(f"sigma_s = {sigma_s!r} must be ≥ 0")
    n = _positive_int("n_stations", n_stations)
    return s * np.arange(1, n + 1, dtype=float)


def _check_station_order(station_order) -> tuple[str, ...]:
    order = tuple(station_order)
    if sorted(order) != sorted(JOINT_NAMES):
        raise TrajectoryError(
            f"station_order = {order!r} must name each of {JOINT_NAMES} exactly once")
    return order


def joint_delays(sigma_s: float, station_order=JOINT_NAMES) -> np.ndarray:
    """Per-joint delays (j1..j4) for stations wired in ``station_order`` (bus order).

    The joint on the first station gets σ, the second 2σ, ... e.g. order
    ``("j3", "j1", "j4", "j2")`` gives j1 = 2σ, j2 = 4σ, j3 = σ, j4 = 3σ.

    :returns: array of shape (4,), seconds, indexed by joint.
    :raises TrajectoryError: bad σ, or an order that is not a permutation of j1..j4.
    """
    order = _check_station_order(station_order)
    lam = station_delays(sigma_s, len(order))
    out = np.empty(len(JOINT_NAMES))
    for p, name in enumerate(order):
        out[JOINT_NAMES.index(name)] = lam[p]
    return out


def delay_corrected_velocities(delta_deg, segment_s: float, delays_s) -> np.ndarray:
    """Seed 002's corrected velocities ``ω_i = Δθ_i / (T − λ_i)``.

    :param delta_deg: joint increments Δθ, shape (J,) or (n, J) (deg, or mm for j3).
    :param segment_s: segment time T in seconds, > 0.
    :param delays_s: per-joint delays λ, shape (J,), seconds, each ≥ 0. All zeros gives
        the uncorrected ``Δθ/T``.
    :returns: velocities with the shape of ``delta_deg`` (deg/s, or mm/s for j3).
    :raises TrajectoryError: non-finite input, T ≤ 0, a negative delay, mismatched shapes,
        or T ≤ λ_i for any joint (the joint could never arrive in time).
    """
    T = _finite_scalar("segment_s", segment_s)
    if T <= 0:
        raise TrajectoryError(f"segment_s = {segment_s!r} must be > 0")
    d = _finite_array("delta_deg", delta_deg)
    lam = _finite_array("delays_s", delays_s)
    if lam.ndim != 1 or d.ndim not in (1, 2) or d.shape[-1] != lam.shape[0]:
        raise TrajectoryError(
            f"delta_deg shape {d.shape} does not match delays_s shape {lam.shape} "
            "(need (J,) or (n, J) against (J,))")
    for i, l in enumerate(lam):
        name = JOINT_NAMES[i] if lam.shape[0] == len(JOINT_NAMES) else f"joint {i}"
        if l < 0:
            raise TrajectoryError(f"delay of {name} = {l!r} s must be ≥ 0")
        if T <= l:
            raise TrajectoryError(
                f"segment time T = {T * 1e3:.6g} ms is not longer than the delay of {name} "
                f"λ = {l * 1e3:.6g} ms; lengthen the segment or shorten the bus delay")
    return d / (T - lam)


# --------------------------------------------------------------------------- planning
def _smooth(u: np.ndarray) -> np.ndarray:
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


#: path fraction s(u) at time fraction u, per law; s(0) = 0, s(1) = 1
TIME_LAWS = {"linear": lambda u: u, "smooth": _smooth}
#: peak speed of each law relative to the mean speed of the move
TIME_LAW_PEAK = {"linear": 1.0, "smooth": 1.875}


@dataclass(frozen=True)
class Segment:
    """One interpolation segment as sent to the stations.

    ``index`` k = 1..n is the way-point it ends at (``LinePlan.joints_deg[k]``);
    it starts at ``start_s`` = (k−1)·T and lasts ``duration_s`` = T seconds.
    ``target_deg`` (4,) and ``velocity_deg_s`` (4,) are per joint j1..j4 (j3 in mm, mm/s).
    """

    index: int
    start_s: float
    duration_s: float
    target_deg: np.ndarray
    velocity_deg_s: np.ndarray


@dataclass(frozen=True)
class LinePlan:
    """A straight move split into interpolation points (arrays are read-only).

    ``joints_deg`` (n+1, 4) joint way-points, index 0 = start; ``poses`` (n+1, 4)
    Cartesian way-points (x_mm, y_mm, z_mm, phi_deg); ``segments`` n entries;
    ``station_order`` bus order of the joints; ``delays_s`` (4,) per-joint delays the
    velocities were corrected for (zeros = uncorrected); ``segment_s`` T; ``elbow``.
    """

    joints_deg: np.ndarray
    segments: list[Segment]
    poses: np.ndarray
    station_order: tuple[str, ...] = JOINT_NAMES
    delays_s: np.ndarray = field(default_factory=lambda: _readonly(np.zeros(4)))
    segment_s: float = 0.0
    elbow: str = "right"

    @property
    def n_points(self) -> int:
        """Number of segments n (= interpolation points after the start)."""
        return len(self.segments)

    @property
    def velocities_deg_s(self) -> np.ndarray:
        """All segment velocities stacked, shape (n, 4)."""
        return np.array([s.velocity_deg_s for s in self.segments])


def _endpoint_ik(robot: Scara, pose: np.ndarray, elbow: Elbow) -> np.ndarray:
    """:meth:`Scara.ik`, except that a *stretched-arm* end point is accepted.

    ``Scara.ik`` refuses poses within ``singular_margin_deg`` of a singularity, which is
    right for moving *through* them, but seed 002's home pose (400, 0, −50, 0) — all joints
    zero, arm stretched — is where a move starts. For the first and last way-point only,
    a pose within the margin of the stretched arm is solved with θ2 = ±acos(c2) (clamped)
    and the usual limit check. Folded-arm and unreachable poses are still refused.
    """
    try:
        return robot.ik(pose, elbow=elbow)
    except CellError:
        g = robot.g
        r = math.hypot(pose[0], pose[1])
        c2 = (r * r - g.l1_mm ** 2 - g.l2_mm ** 2) / (2 * g.l1_mm * g.l2_mm)
        stretched = (math.cos(math.radians(g.singular_margin_deg)) <= c2
                     and r <= (g.l1_mm + g.l2_mm) * (1 + 1e-12))
        if not stretched or elbow not in ("right", "left"):
            raise
    t2 = math.acos(min(1.0, c2)) * (1.0 if elbow == "right" else -1.0)
    t1 = math.atan2(pose[1], pose[0]) - math.atan2(g.l2_mm * math.sin(t2), g.l1_mm + g.l2_mm * math.cos(t2))
    t1d, t2d = math.degrees(t1), math.degrees(t2)
    t1d = (t1d + 180.0) % 360.0 - 180.0
    q = np.array([t1d, t2d, pose[2] - g.base_z_mm - g.tool_z_mm,
                  (pose[3] - t1d - t2d + 180.0) % 360.0 - 180.0])
    robot.check_limits(q)
    return q


def line_joints(robot: Scara, start_pose, end_pose, n_points: int, segment_s: float,
                elbow: Elbow = "right", *, time_law: str = "linear") -> tuple[np.ndarray, np.ndarray]:
    """The way-points of :func:`plan_line`, without its segments: (poses (n+1, 4), joints
    (n+1, 4)), checked and unwrapped as :func:`plan_line` says, raising what it raises for
    these arguments (the mover builds its own segments from the joints)."""
    p0, p1, n, _ = _line_args(start_pose, end_pose, n_points, segment_s)
    _check_time_law(time_law)
    return _way_points(robot, p0, p1, n, elbow, time_law)


def _line_args(start_pose, end_pose, n_points, segment_s) -> tuple[np.ndarray, np.ndarray, int, float]:
    """(start pose, end pose, n, T) of a line, checked; raises TrajectoryError naming the
    first bad one."""
    p0 = _finite_array("start_pose", start_pose, (4,))
    p1 = _finite_array("end_pose", end_pose, (4,))
    n = _positive_int("n_points", n_points)
    T = _finite_scalar("segment_s", segment_s)
    if T <= 0:
        raise TrajectoryError(f"segment_s = {segment_s!r} must be > 0")
    return p0, p1, n, T


def _check_time_law(time_law: str) -> None:
    if time_law not in TIME_LAWS:
        raise TrajectoryError(f"time_law = {time_law!r}; choose one of {sorted(TIME_LAWS)}")


def _way_points(robot: Scara, p0: np.ndarray, p1: np.ndarray, n: int, elbow: Elbow,
                time_law: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`line_joints` of arguments already checked: the poses along the line, their
    joints by IK, unwrapped, and the first point off its limits named."""
    s = TIME_LAWS[time_law](np.linspace(0.0, 1.0, n + 1))[:, None]
    poses = p0 + s * (p1 - p0)
    poses[-1] = p1  # exact target, no rounding from the linspace
    joints = np.empty_like(poses)
    # the interior points in one call; where one of them fails, point by point to name it
    inner = robot.ik_rows(poses[1:n], elbow) if n > 1 else poses[1:n]
    for k in (0, n) if inner is not None else range(n + 1):
        pose = poses[k]
        try:
            joints[k] = _endpoint_ik(robot, pose, elbow) if k in (0, n) else robot.ik(pose, elbow=elbow)
        except CellError as exc:
            raise TrajectoryError(
                f"interpolation point {k} of {n} at pose ({', '.join(f'{v:.4f}' for v in pose)}) "
                f"cannot be reached: {exc}") from exc
    if inner is not None:
        joints[1:n] = inner
    for j in (0, 3):  # revolute joints returned wrapped to [-180, 180)
        joints[:, j] = np.unwrap(joints[:, j], period=360.0)
    lo, hi = np.array(robot.g.limits, dtype=float).T
    if not (np.isfinite(joints).all() and (joints >= lo).all() and (joints <= hi).all()):
        for k, q in enumerate(joints):      # name the first point off its limits
            try:
                robot.check_limits(q)
            except CellError as exc:
                raise TrajectoryError(f"interpolation point {k} of {n}: {exc}") from exc
    return poses, joints


def plan_line(robot: Scara, start_pose, end_pose, n_points: int, segment_s: float,
              delays_s=None, elbow: Elbow = "right", *,
              station_order=JOINT_NAMES, time_law: str = "linear") -> LinePlan:
    """Plan a straight move with ``n_points`` Cartesian steps of ``segment_s`` each (seed 002).

    :param robot: kinematics used for :meth:`Scara.ik` at every interpolation point.
    :param start_pose, end_pose: (x_mm, y_mm, z_mm, phi_deg); phi is interpolated linearly.
    :param n_points: number of segments n ≥ 1 (way-points 0..n).
    :param segment_s: segment time T in seconds, > 0.
    :param delays_s: per-joint delays (4,) in seconds (use :func:`joint_delays` to map a
        bus order), or ``None`` for the uncorrected velocities Δθ/T.
    :param elbow: ``"right"`` or ``"left"``, kept for the whole move.
    :param station_order: bus order of the joints, recorded in the plan.
    :param time_law: ``"linear"`` (equal steps, seed 002) or ``"smooth"`` (smooth start
        and stop, seed 002 Fig. 8c; see the module doc).
    :returns: :class:`LinePlan`. The first and last way-point may sit on the stretched-arm
        singularity (see :func:`_endpoint_ik`); interior points may not. θ1 and θ4 are unwrapped along the move (no 360° jumps)
        and re-checked against the joint limits.
    :raises TrajectoryError: bad numbers, n < 1, T ≤ λ_i, or an interpolation point the
        robot cannot reach (message names the point and the kinematic reason).
    """
    p0, p1, n, T = _line_args(start_pose, end_pose, n_points, segment_s)
    order = _check_station_order(station_order)
    _check_time_law(time_law)
    lam = np.zeros(4) if delays_s is None else _finite_array("delays_s", delays_s, (4,))
    delay_corrected_velocities(np.zeros(4), T, lam)  # validate delays before any IK work
    poses, joints = _way_points(robot, p0, p1, n, elbow, time_law)
    vel = delay_corrected_velocities(np.diff(joints, axis=0), T, lam)
    segments = [Segment(index=k, start_s=(k - 1) * T, duration_s=T,
                        target_deg=_readonly(joints[k]), velocity_deg_s=_readonly(vel[k - 1]))
                for k in range(1, n + 1)]
    return LinePlan(joints_deg=_readonly(joints), segments=segments, poses=_readonly(poses),
                    station_order=order, delays_s=_readonly(lam), segment_s=T, elbow=elbow)


# --------------------------------------------------------------------------- simulation
def _joint_breakpoints(plan: LinePlan, j: int, delay) -> tuple[np.ndarray, np.ndarray]:
    """(times, positions) of joint ``j``'s piecewise-linear motion under ``delay`` (s, one
    value, or one per segment).

    Model (seed 002 stations): segment k's command arrives at start_s + delay; the joint
    then moves from wherever it is toward the segment target at |ω| and holds on arrival.
    A late joint that has not arrived when the next command comes simply takes the new one.
    """
    delays = np.broadcast_to(np.asarray(delay, dtype=float), (len(plan.segments),))
    t_now, p_now = 0.0, float(plan.joints_deg[0, j])
    target, speed = p_now, 0.0
    ts, ps = [0.0], [p_now]

    def advance(t_to: float) -> None:
        nonlocal t_now, p_now
        gap = target - p_now
        if gap != 0.0 and speed > 0.0:
            t_arrive = t_now + abs(gap) / speed
            if t_arrive <= t_to:
                ts.append(t_arrive)
                ps.append(target)
                t_now, p_now = t_arrive, target
            else:
                p_now = p_now + math.copysign(speed * (t_to - t_now), gap)
        t_now = t_to
        ts.append(t_now)
        ps.append(p_now)

    for seg, d in zip(plan.segments, delays):
        advance(seg.start_s + float(d))
        target, speed = float(seg.target_deg[j]), abs(float(seg.velocity_deg_s[j]))
    if target != p_now and speed > 0.0:
        advance(t_now + abs(target - p_now) / speed)
    return np.asarray(ts), np.asarray(ps)


def _check_actual(actual_delays_s, n_segments: int | None = None) -> np.ndarray:
    lam = _finite_array("actual_delays_s", actual_delays_s)
    if lam.shape != (4,) and not (n_segments is not None and lam.shape == (n_segments, 4)):
        raise TrajectoryError(f"actual_delays_s must have shape (4,)"
                              f"{'' if n_segments is None else f' or ({n_segments}, 4)'}, got {lam.shape}")
    if (lam < 0).any():
        i = int(np.argwhere(lam < 0)[0][-1])
        raise TrajectoryError(f"actual delay of {JOINT_NAMES[i]} = {float(lam[lam < 0][0])!r} s must be ≥ 0")
    return lam


def joint_positions_at(plan: LinePlan, actual_delays_s, times_s) -> np.ndarray:
    """Exact joint positions (len(times), 4) of the simulated stations at ``times_s``.

    ``actual_delays_s`` (4,) per joint, or (n, 4) per segment and joint, seconds: when each
    station really starts a segment after its nominal start (may differ from ``plan.delays_s``).
    ``times_s`` is a scalar or 1-D array in seconds from the first segment's start;
    before 0 the joints are at the start way-point.
    :raises TrajectoryError: negative or non-finite delays, non-finite or non-1-D times.
    """
    lam = _check_actual(actual_delays_s, plan.n_points)
    t = np.atleast_1d(_finite_array("times_s", times_s))
    if t.ndim != 1:
        raise TrajectoryError(f"times_s must be a scalar or 1-D array, got shape {t.shape}")
    out = np.empty((t.size, 4))
    for j in range(4):
        bt, bp = _joint_breakpoints(plan, j, lam[..., j])
        out[:, j] = np.interp(t, bt, bp)
    return out


def tool_positions(robot: Scara, joints_deg) -> np.ndarray:
    """Tool centre (x_mm, y_mm, z_mm) for joints (N, 4); vectorised :meth:`Scara.fk`."""
    q = np.asarray(joints_deg, dtype=float)
    g = robot.g
    return np.column_stack([robot.fk_planar_batch(q[:, :2]), g.base_z_mm + q[:, 2] + g.tool_z_mm])


@dataclass(frozen=True)
class SimulatedPath:
    """A simulated move: ``times_s`` (N,), ``joints_deg`` (N, 4), ``xyz_mm`` (N, 3).

    ``point_index`` (n+1,) gives, for each interpolation instant k·T, its row in the grid.
    """

    times_s: np.ndarray
    joints_deg: np.ndarray
    xyz_mm: np.ndarray
    point_index: np.ndarray


def simulate_line(robot: Scara, plan: LinePlan, actual_delays_s,
                  samples_per_segment: int = 50) -> SimulatedPath:
    """Simulate the stations executing ``plan`` on a fine time grid.

    Each joint starts every segment ``actual_delays_s[j]`` late, moves at its commanded
    velocity until it reaches the segment target, then holds (see
    :func:`_joint_breakpoints`). The grid holds every interpolation instant k·T exactly and
    runs on until the last joint has arrived.

    :raises TrajectoryError: bad delays or ``samples_per_segment`` < 1.
    """
    m = _positive_int("samples_per_segment", samples_per_segment)
    lam = _check_actual(actual_delays_s, plan.n_points)
    n, T = plan.n_points, plan.segment_s
    t_end = max(float(_joint_breakpoints(plan, j, lam[..., j])[0][-1]) for j in range(4))
    t_main = np.linspace(0.0, n * T, n * m + 1)
    extra = max(0.0, t_end - n * T)
    n_tail = int(math.ceil(extra / (T / m))) if extra > 0 else 0
    t_tail = np.linspace(n * T, n * T + extra, n_tail + 1)[1:] if n_tail else np.empty(0)
    times = np.concatenate([t_main, t_tail])
    q = joint_positions_at(plan, lam, times)
    return SimulatedPath(times_s=times, joints_deg=q, xyz_mm=tool_positions(robot, q),
                         point_index=np.arange(n + 1) * m)


def max_line_deviation(path_xyz_mm, start_xyz_mm, end_xyz_mm) -> float:
    """Largest perpendicular distance (mm) of a path from the line through start and end.

    Distances are to the infinite line in 3-D (x, y, z); when start and end coincide the
    distance to that point is used.
    :raises TrajectoryError: non-finite input or wrong shapes ((N, 3), (3,), (3,)).
    """
    p = _finite_array("path_xyz_mm", path_xyz_mm)
    a = _finite_array("start_xyz_mm", start_xyz_mm, (3,))
    b = _finite_array("end_xyz_mm", end_xyz_mm, (3,))
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise TrajectoryError(f"path_xyz_mm must have shape (N, 3) with N ≥ 1, got {p.shape}")
    d = p - a
    u = b - a
    L = float(np.linalg.norm(u))
    if L == 0.0:
        return float(np.max(np.linalg.norm(d, axis=1)))
    u /= L
    perp = d - np.outer(d @ u, u)
    return float(np.max(np.linalg.norm(perp, axis=1)))
