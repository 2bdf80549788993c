"""Every move of the cell as seed 002 makes it: a straight line cut into interpolation
segments of ``T`` seconds, streamed to the joint stations in the recipe's mode.

Modes (``recipes/*.yaml``, ``motion.sync``):

* ``corrected`` — each station applies its set-point on reception; segment k's
  velocities are seed 002's ωᵢ = Δθᵢ / (T − λᵢ), with λᵢ the delay of *this* burst as the
  stations will see it: the wire time of the frames up to and including station i's own
  (from their bits) plus the station's latency measured on the bus at start-up. Every
  joint then reaches each interpolation point at the same instant.
* ``sync`` — set-points are written ahead and all stations apply them on one SYNC
  frame; velocities are Δθ/T.
* ``none`` — on reception, velocities Δθ/T: the joints arrive λᵢ apart (seed 002's bent
  line), kept for comparison.

The way-points follow the recipe's time law (``smooth``: seed 002 Fig. 8c's smooth start
and stop; ``linear``: equal steps). A move whose straight line cannot be planned (the
start in the other elbow configuration, or a singular interior point) is cut into the
same segments in joint space instead; the report says which (``path``). The number of
segments is chosen so that no joint exceeds the move's joint speed or its drive's
``max_velocity``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol, runtime_checkable

import numpy as np

from cell.errors import CellError, TrajectoryError
from cell.kinematics import JOINT_NAMES, Scara
from cell.motion.line import TIME_LAW_PEAK, TIME_LAWS, Segment, line_joints

if TYPE_CHECKING:
    from drivers.stations.faults import FaultRecord

Mode = Literal["corrected", "sync", "none"]
MAX_SEGMENTS = 100_000      #: a longer move is refused (at T = 10 ms: over 16 minutes)
MODES: tuple[str, ...] = ("corrected", "sync", "none")


@runtime_checkable
class Stations(Protocol):
    """What a move needs of the joint stations (``drivers.stations.JointStations``)."""

    cfg: object

    def stream(self, segments, mode: str = "reception", lead_s: float | None = None): ...
    def burst_delays(self, targets_deg, velocities_deg_s, base: int = 0x200) -> np.ndarray: ...
    def corrected_velocities(self, targets_deg, deltas_deg, segment_s: float, hint_s=None): ...
    def wait_reached(self, timeout_s: float, tol: float = 0.02) -> None: ...


@runtime_checkable
class JointMotion(Stations, Protocol):
    """Everything the cell asks of its joint stations: the moves (:class:`Stations`), and
    bring-up, reset, quick stop, the latched fault and feedback. ``drivers.stations.
    JointStations`` implements it on a real CAN interface and on the simulated wire alike
    (the simulated cell simulates the drives, not the driver)."""

    @property
    def latency_s(self) -> np.ndarray:
        """Per joint j1..j4, s: each station's measured latency after its frame."""
        ...

    @property
    def fault(self) -> FaultRecord | None:
        """The first fault latched since the last reset (a quick stop asked for included)."""
        ...

    def start(self) -> None: ...
    def shutdown(self) -> None: ...
    def reset(self) -> None: ...
    def quick_stop_all(self, reason: str = "requested") -> None: ...
    def actual_positions(self) -> np.ndarray: ...
    def drive_states(self) -> dict: ...


@dataclass(frozen=True)
class MotionSpec:
    """How to move: ``mode`` (see module doc), segment time ``segment_s`` (T, s),
    ``time_law`` (``smooth`` or ``linear``), fastest joint's speed (joint units/s)."""

    mode: Mode = "corrected"
    segment_s: float = 0.01
    time_law: str = "smooth"
    joint_speed: float = 60.0


@dataclass(frozen=True)
class MoveReport:
    """One streamed move: mode, ``path`` (``line`` or ``joints``), segment count and time,
    per-joint delay λ (j1..j4, s: the mean over segments of the burst delays the velocities
    were corrected for in ``corrected`` mode, else the first burst's), planned duration."""

    mode: str
    path: str
    segments: int
    segment_s: float
    delays_s: tuple[float, float, float, float]
    duration_s: float

    def as_dict(self) -> dict:
        return {"mode": self.mode, "path": self.path, "segments": self.segments,
                "segment_ms": round(self.segment_s * 1e3, 6),
                "delays_ms": [round(d * 1e3, 6) for d in self.delays_s]}


class Mover:
    """Plans and streams moves for one robot on one set of stations."""

    def __init__(self, robot: Scara, stations: Stations, elbow: str = "right"):
        self.robot, self.stations, self.elbow = robot, stations, elbow

    def _vmax(self, spec: MotionSpec) -> np.ndarray:
        cfg = getattr(self.stations, "cfg", None)
        # 1 % below the drive's own limit, which would clip (and so delay) a faster set-point
        limits = [0.99 * cfg.station(j).max_velocity if cfg is not None else math.inf for j in JOINT_NAMES]
        return np.minimum(float(spec.joint_speed), np.array(limits, dtype=float))

    def plan(self, q_from, q_to, spec: MotionSpec) -> tuple[list[Segment], MoveReport]:
        """Segments (velocities for ``spec.mode``) from ``q_from`` to ``q_to`` (4,) joints.

        :raises TrajectoryError: bad spec, or T not longer than a station's delay in
            ``corrected`` mode (the recipe check refuses such recipes beforehand).
        """
        if spec.mode not in MODES:
            raise TrajectoryError(f"motion mode {spec.mode!r}; choose one of {MODES}")
        if spec.time_law not in TIME_LAWS:
            raise TrajectoryError(f"time law {spec.time_law!r}; choose one of {sorted(TIME_LAWS)}")
        q0, q1 = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        T = float(spec.segment_s)
        vmax = self._vmax(spec)
        ideal = float(np.max(np.abs(q1 - q0) / vmax)) * TIME_LAW_PEAK[spec.time_law]
        n = max(1, math.ceil(ideal / T - 1e-9))
        for _ in range(6):
            joints, path = self._waypoints(q0, q1, n, spec)
            steps = np.abs(np.diff(joints, axis=0))
            slack = T
            if spec.mode == "corrected":           # corrected velocities are Δθ/(T − λ)
                lam = self.stations.burst_delays(joints[1], steps[0] / T)
                slack -= float(np.max(lam))
                if slack <= 0:
                    j = int(np.argmax(lam))
                    raise TrajectoryError(f"segment time T = {T * 1e3:.6g} ms is not longer than the delay "
                                          f"of {JOINT_NAMES[j]} λ = {lam[j] * 1e3:.6g} ms")
            over = float(np.max(np.max(steps, axis=0) / slack / vmax))
            if over <= 1.0:
                break
            n = math.ceil(n * over * 1.02)
            if n > MAX_SEGMENTS:
                raise TrajectoryError(f"move needs more than {MAX_SEGMENTS} segments of "
                                      f"{T * 1e3:.3f} ms at {spec.joint_speed:g} units/s")
        segs, delays = self._segments(joints, spec)
        return segs, MoveReport(spec.mode, path, n, T, tuple(float(d) for d in delays), n * T)

    def move(self, q_from, q_to, spec: MotionSpec, timeout_s: float, tol: float) -> MoveReport:
        """Stream the move and wait (clock time) until every joint has arrived."""
        segs, report = self.plan(q_from, q_to, spec)
        self.stations.stream(segs, mode="sync" if spec.mode == "sync" else "reception")
        self.stations.wait_reached(timeout_s, tol=tol)
        return report

    # ------------------------------------------------------------------ planning parts
    def _waypoints(self, q0: np.ndarray, q1: np.ndarray, n: int, spec: MotionSpec) -> tuple[np.ndarray, str]:
        try:
            joints = line_joints(self.robot, self.robot.fk(q0), self.robot.fk(q1), n, spec.segment_s,
                                 elbow=self.elbow, time_law=spec.time_law)[1]
            for j in (0, 3):                      # same turn as the start (IK wraps to ±180°)
                joints[:, j] += 360.0 * round((q0[j] - joints[0, j]) / 360.0)
            if np.max(np.abs(joints[0] - q0)) < 1e-6 and np.max(np.abs(joints[-1] - q1)) < 1e-6:
                joints[0], joints[-1] = q0, q1
                return joints, "line"
        except CellError:
            pass
        s = TIME_LAWS[spec.time_law](np.linspace(0.0, 1.0, n + 1))[:, None]
        joints = q0 + s * (q1 - q0)
        joints[-1] = q1
        return joints, "joints"

    def _segments(self, joints: np.ndarray, spec: MotionSpec) -> tuple[list[Segment], np.ndarray]:
        segs, lams = segments_for(self.stations, joints, spec.segment_s, spec.mode)
        return segs, (np.mean(lams, axis=0) if spec.mode == "corrected" else lams[0])


def segments_for(stations: Stations, joints, segment_s: float, mode: str) -> tuple[list[Segment], np.ndarray]:
    """The segments to stream through way-points ``joints`` (n+1, 4), one every ``segment_s``,
    with the velocities of ``mode``, and each segment's burst delays λ (n, 4), s.

    ``corrected`` velocities come from the stations (``corrected_velocities``): a velocity
    is part of its own frame, so the two are solved together.
    :raises TrajectoryError: T not longer than a delay (``corrected``).
    """
    T = float(segment_s)
    joints = np.asarray(joints, dtype=float)
    steps = np.diff(joints, axis=0)
    segs, lams = [], []
    for k in range(1, len(joints)):
        d = steps[k - 1]
        if mode == "corrected":
            try:                                                          # seed 002: Δθ/(T − λ)
                v, lam = stations.corrected_velocities(joints[k], d, T, lams[-1] if lams else None)
            except CellError as exc:
                raise TrajectoryError(str(exc)) from exc
        else:
            v = d / T
            lam = stations.burst_delays(joints[k], v, 0x400 if mode == "sync" else 0x200)
        lams.append(lam)
        segs.append(Segment(index=k, start_s=(k - 1) * T, duration_s=T,
                            target_deg=joints[k].copy(), velocity_deg_s=v))
    return segs, np.array(lams)


def check_mode(mode: str, segment_s: float, supports_sync: bool, delays_s) -> str | None:
    """Why a motion mode cannot run on these stations, or ``None``.

    :param delays_s: per-joint λ (4,) of a typical burst, s (wire time + latency).
    """
    lam = np.asarray(delays_s, dtype=float)
    slowest = int(np.argmax(lam))
    if mode == "sync" and not supports_sync:
        return "the joint stations do not support SYNC (stations[].supports_sync)"
    if mode in ("corrected", "sync") and segment_s <= lam[slowest]:
        return (f"segment time {segment_s * 1e3:.3f} ms is not longer than the delay of "
                f"{JOINT_NAMES[slowest]} (λ = {lam[slowest] * 1e3:.3f} ms measured on the bus)")
    return None
