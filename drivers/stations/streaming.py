"""Streaming half of :class:`~drivers.stations.driver.JointStations`: line segments
(reception-applied or SYNC-applied), waiting for targets, and seed 002's command delay λ_i
of each station: the wire time of the frames up to and including the station's own
(computed from their bits) plus the station's own latency (measured on the bus). Split
from ``driver.py`` to keep modules small; the methods use the driver's command helpers
(``_ready``, ``_burst``, ``_send``, ``_await``).
"""
from __future__ import annotations

import functools
import math
import statistics
import struct
import time
from dataclasses import dataclass
from typing import Literal

import can
import numpy as np

from cell.errors import CellError
from cell.log import get_logger
from drivers.stations import cia402
from drivers.stations.bus import FrameLayout, data_frame_bits, frame_time_s

_SETPOINT = struct.Struct("<iI")                     # the driver's set-point frame layout
_TARGET, _VELOCITY = struct.Struct("<i"), struct.Struct("<I")   # its two fields apart

log = get_logger("stations.driver")


@functools.lru_cache(maxsize=4096)
def _setpoint_layout(cob_id: int, target_inc: int) -> FrameLayout:
    return FrameLayout(cob_id, _TARGET.pack(target_inc), _SETPOINT.size)


@functools.lru_cache(maxsize=16384)
def _setpoint_bits(cob_id: int, target_inc: int, velocity_inc: int) -> int:
    """Bits on the wire of the set-point frame ``cob_id`` carrying ``target_inc`` and
    ``velocity_inc``. Cached: a joint that stands still, or comes back to a target, sends
    the same frames again (about half of a cycle's set-points), and the correction tries
    a few velocities per frame."""
    return _setpoint_layout(cob_id, target_inc).bits(_VELOCITY.pack(velocity_inc))


class StationCommandError(CellError, ValueError):
    """A command with bad values (shape, not finite, beyond limits); nothing was sent."""


def _asked(s, T: float, sent: float, lat: float, need: float) -> int:
    """The set-point velocity (increments/s, at least 1) that takes station ``s`` over
    ``need`` increments in what is left of T once its frame is on the bus (``sent``, s into
    the burst) and its reception delay ``lat`` has passed. Raises StationCommandError when
    nothing is left (T not longer than λ) or the velocity is above its max_velocity."""
    left = T - sent - lat
    if left <= 0:
        raise StationCommandError(
            f"segment time T = {T * 1e3:.6g} ms is not longer than the delay of {s.joint} "
            f"λ = {(sent + lat) * 1e3:.6g} ms")
    if need / left > s.top_inc:
        raise StationCommandError(
            f"{s.joint} would need {need / left / s.cpu:.6g} units/s to arrive in "
            f"T − λ = {left * 1e3:.6g} ms, above its max_velocity {s.cfg.max_velocity:g}")
    return max(1, round(need / left))


@dataclass(frozen=True)
class StreamReport:
    """What :meth:`JointStations.stream` sent. Times are bus timestamps (the base of
    received frames: the simulated clock on the virtual wire, ``time.time()`` on
    hardware): ``t0`` the nominal start of segment 1, ``sent`` (n,) the end of each
    segment's first frame (reception mode) or of its SYNC (sync mode) on the wire."""

    mode: str
    t0: float
    sent: np.ndarray


class StreamingMixin:
    """Methods of :class:`JointStations` that stream and measure (see the driver's docs)."""

    def _bus_now(self) -> float:
        clock = getattr(self.network.bus, "clock", None)
        return clock.now() if clock is not None else time.time()

    def stream(self, segments, mode: Literal["reception", "sync"] = "reception",
               lead_s: float | None = None) -> StreamReport:
        """Stream line segments (seed 002), blocking until the last one is sent.

        Each ``Segment`` (``cell.motion.line``) carries per-joint ``target_deg`` (4,)
        and ``velocity_deg_s`` (4,) (magnitudes are used) and starts at ``start_s``.

        * ``"reception"``: segment k's set-points go out at ``t0 + start_s`` in bus order
          and each station applies its own on reception (plus its latency): give
          velocities corrected with :meth:`burst_delays` for seed 002's correction, or
          plain Δθ/T for none.
        * ``"sync"``: segment k's set-points are written ahead (RPDO3) and applied by all
          stations together on the SYNC sent at ``t0 + start_s``; give plain Δθ/T.

        :param lead_s: time from the call to segment 1 (default: 0 for reception; for sync
            the config's ``sync_lead_s`` or the slowest station's delay + 5 ms if longer,
            so the first set-points are in before SYNC 1).
        :raises StationCommandError: bad mode, empty list, a segment with bad shape,
            non-finite values, targets beyond limits or start times not increasing
            (checked for *all* segments before anything is sent), or sync mode on
            stations that do not support it.
        :raises StationFaultError: a fault was latched before or during streaming; the
            stations are already quick-stopped.
        """
        self._ready("stream")
        if mode not in ("reception", "sync"):
            raise StationCommandError(f"stream: mode = {mode!r}; choose 'reception' or 'sync'")
        if mode == "sync" and not self.supports_sync:
            raise StationCommandError("stream: sync mode needs SYNC support on every station "
                                      "(stations[].supports_sync)")
        segs = list(segments)
        if not segs:
            raise StationCommandError("stream: no segments given")
        checked = self._checked_at_once(segs) or self._checked(segs)
        if lead_s is None:  # sync: the first set-points must be in before SYNC 1
            lead = 0.0
            if mode == "sync":
                slowest = float(np.max(self.burst_delays(checked[0][1], checked[0][2], 0x400)))
                lead = max(self.cfg.sync_lead_s, slowest + 0.005)
        else:
            lead = float(lead_s) if isinstance(lead_s, (int, float)) and not isinstance(lead_s, bool) else math.nan
            if not (math.isfinite(lead) and 0 <= lead <= 10):
                raise StationCommandError(f"stream: lead_s = {lead_s!r} must be in [0, 10] s")
        t0_clock = self.clock.now() + lead
        t0_bus = self._bus_now() + lead
        sent = np.zeros(len(checked))
        if mode == "sync":
            self._burst(checked[0][1], checked[0][2], 0x400, "stream")
        for k, (start, q, v) in enumerate(checked):
            self.clock.sleep_until(t0_clock + start)
            if mode == "reception":
                sent[k] = self._burst(q, v, 0x200, "stream")
            else:
                with self._cmd_lock:
                    self.latch.check("stream")
                    sent[k] = self._send(0x80, b"", "stream")
                if k + 1 < len(checked):
                    self._burst(checked[k + 1][1], checked[k + 1][2], 0x400, "stream")
        return StreamReport(mode, t0_bus, sent)

    def _checked_at_once(self, segs: list) -> list[tuple[float, np.ndarray, np.ndarray]] | None:
        """(start, targets, velocities) of every segment when all of them pass
        :meth:`stream`'s checks, tested on the stacked arrays; None when one does not (or is
        not a Segment), for :meth:`_checked` to name the first fault."""
        try:
            q = np.array([seg.target_deg for seg in segs], dtype=float)
            v = np.array([seg.velocity_deg_s for seg in segs], dtype=float)
            starts = [float(seg.start_s) for seg in segs]
        except (AttributeError, TypeError, ValueError):
            return None
        n = len(segs)
        if q.shape != (n, 4) or v.shape != (n, 4) or not (np.isfinite(q).all() and np.isfinite(v).all()):
            return None
        lo, hi = np.full(4, -math.inf), np.full(4, math.inf)
        for s in self._stations:
            lo[s.index], hi[s.index] = s.cfg.joint_limits
        if not ((q >= lo).all() and (q <= hi).all()):
            return None
        prev = -math.inf
        for start in starts:
            if not (math.isfinite(start) and start > prev):
                return None
            prev = start
        return list(zip(starts, q, v))

    def _checked(self, segs: list) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """:meth:`_checked_at_once`'s result, segment by segment: raises
        :class:`StationCommandError` naming the first segment that fails a check."""
        prev = -math.inf
        checked = []
        for i, seg in enumerate(segs):
            try:
                q = self._check_targets(seg.target_deg, f"stream segment {i}")
                v = np.asarray(seg.velocity_deg_s, dtype=float)
                start = float(seg.start_s)
            except AttributeError as exc:
                raise StationCommandError(f"stream segment {i}: not a Segment ({exc})") from None
            if v.shape != (4,) or not np.all(np.isfinite(v)):
                raise StationCommandError(f"stream segment {i}: velocity_deg_s must be 4 finite values, got {v!r}")
            if not (math.isfinite(start) and start > prev):
                raise StationCommandError(f"stream segment {i}: start_s = {start!r} must be finite and after {prev}")
            prev = start
            checked.append((start, q, v))
        return checked

    def burst_delays(self, targets_deg, velocities_deg_s, base: int = 0x200) -> np.ndarray:
        """Seed 002's delay λ (4,) per joint, s, for one burst of exactly these set-points:
        the wire time from the burst's first bit to the end of each station's frame, from
        the frames' own bits on an idle bus, plus that station's latency (:attr:`latency_s`).

        :param targets_deg, velocities_deg_s: (4,) per joint, as they will be sent.
        :param base: 0x200 for reception-applied set-points, 0x400 for SYNC-applied ones.
        """
        q = np.asarray(targets_deg, dtype=float)
        v = np.asarray(velocities_deg_s, dtype=float)
        out = np.zeros(4)
        t = 0.0
        for s in self._stations:
            j = s.cfg.joint_index
            t += data_frame_bits(base + s.cfg.node_id, self._setpoint_frame(s, q[j], v[j])) / self.cfg.bitrate
            out[j] = t + self._latency[j]
        return out

    def corrected_velocities(self, targets_deg, deltas_deg, segment_s: float,
                             hint_s=None) -> tuple[np.ndarray, np.ndarray]:
        """Seed 002's corrected velocities ωᵢ = Δθᵢ / (T − λᵢ) for one reception-applied burst,
        solved together with the frames that carry them.

        A velocity is part of its own frame, so it changes the frame's bits and with them
        λᵢ (the end of the frame on the wire, plus the station's latency). Station by station
        in bus order, the frames before it being fixed, the velocity and its frame are made
        to agree; where they cannot (a stuff bit flips back and forth), the whole increment
        per second whose frame comes closest is taken.

        :param targets_deg: (4,) segment targets per joint; ``deltas_deg`` (4,) the joint
            steps of the segment (target − previous target); ``segment_s`` T, s; ``hint_s``
            (4,) λ of a similar burst (the previous segment's) to start from, or None.
        :returns: (velocities (4,) joint units/s, signed like the steps; λ (4,) s).
        :raises StationCommandError: T not longer than a station's λ (the correction does
            not exist: lengthen T or shorten the bus delays), or a corrected velocity above
            the station's ``max_velocity``.
        """
        T = float(segment_s)
        # plain floats throughout: round() and indexing are slow on numpy's scalars
        q = np.asarray(targets_deg, dtype=float).tolist()
        d = np.asarray(deltas_deg, dtype=float).tolist()
        hint = None if hint_s is None else np.asarray(hint_s, dtype=float).tolist()
        vel, lam = [0.0] * 4, [0.0] * 4
        rate = float(self.cfg.bitrate)
        latency = self._latency.tolist()
        t = 0.0
        for s in self._stations:
            j, cpu = s.index, s.cpu
            need = abs(d[j]) * cpu                        # increments to travel
            lat = latency[j]
            cob, target_inc = 0x200 + s.node_id, round(q[j] * cpu)
            # the velocity a frame of b bits asks for: _asked(..., t + b/rate, ...)
            if hint is not None and T > hint[j]:
                v_inc = max(1, round(need / (T - hint[j])))
            else:
                b = _setpoint_bits(cob, target_inc, max(1, round(need / T)))
                v_inc = _asked(s, T, t + b / rate, lat, need)
            b = _setpoint_bits(cob, target_inc, v_inc)
            seen = [v_inc]
            for _ in range(6):
                nxt = _asked(s, T, t + b / rate, lat, need)
                if nxt == v_inc:
                    break
                if nxt in seen:       # a cycle: the next steps only repeat what was seen and checked
                    nxt = None
                    break
                v_inc = nxt
                b = _setpoint_bits(cob, target_inc, v_inc)
                seen.append(v_inc)
            else:
                nxt = None
            if nxt is None:                              # a flip-flop between frame lengths
                v_inc = self._closest_consistent(seen, need, T - t - lat, rate,
                                                 functools.partial(_setpoint_bits, cob, target_inc))
                b = _setpoint_bits(cob, target_inc, v_inc)
            end = t + b / rate
            vel[j] = math.copysign(v_inc / cpu, d[j]) if d[j] else v_inc / cpu
            lam[j] = end + lat
            t = end
        return np.array(vel), np.array(lam)

    @staticmethod
    def _closest_consistent(seen: list[int], need: float, budget: float, rate: float, bits_of) -> int:
        """The whole increments per second that best agree with their own frame, when the
        iteration flips between frame lengths. A velocity ``c`` agrees with a frame length
        ``b`` when ``c`` is what ``b`` asks for, ``c_b = need / (budget − b/rate)``, and its frame
        is ``b`` bits long. Near each ``c_b`` (within 32 increments/s: parts per million of it)
        the nearest velocity whose frame has that length is a candidate; the lengths met while
        iterating come first, the lengths around them only if those give none."""
        met = sorted({bits_of(v) for v in seen})
        for lengths in (met, None):
            if lengths is None:                  # the lengths around: built only when needed
                lengths = [b for b in range(met[0] - 6, met[-1] + 7) if b not in met]
            best: tuple[float, int] | None = None
            for b in lengths:
                left = budget - b / rate
                if left <= 0:
                    continue
                c_b = need / left
                r = round(c_b)
                hit = r if r >= 1 and bits_of(r) == b else None
                for k in range(1, 33) if hit is None else ():   # r, then r - k before r + k
                    if r - k >= 1 and bits_of(r - k) == b:
                        hit = r - k
                    elif r + k >= 1 and bits_of(r + k) == b:
                        hit = r + k
                    else:
                        continue
                    break
                if hit is not None and (best is None or abs(hit - c_b) < best[0]):
                    best = (abs(hit - c_b), hit)
            if best is not None:
                return best[1]
        return min(seen, key=lambda c: abs(c - need / max(budget - bits_of(c) / rate, 1e-12)))

    def wait_reached(self, timeout_s: float, tol: float = 0.02) -> None:
        """Block (clock time) until every station reports (TPDO) its last commanded target
        within ``tol`` joint units and *target reached*.

        :raises StationFaultError: a fault latched while waiting.
        :raises TimeoutError: not reached within ``timeout_s`` (names the joints still off).
        """
        def off():
            self.latch.check("wait_reached")
            return [s for s in self._stations if s.target is not None and not (
                s.pos_inc is not None and abs(s.pos_inc / s.cpu - s.target) <= tol
                and s.statusword & cia402.SW_TARGET_REACHED)]
        if not self._await(lambda: not off(), timeout_s):
            raise TimeoutError("targets not reached within %.2f s: %s" % (timeout_s, ", ".join(
                f"{s.joint} at {(s.pos_inc or 0) / s.cpu:.4f} for {s.target:.4f}" for s in off())))

    def measure_delays(self, rounds: int = 5) -> np.ndarray:
        """Measure each station's latency on the bus and use it from now on.

        Each round sends every station, one at a time, a zero-velocity set-point at its
        current position and waits for the TPDO whose statusword bit 12 shows it applied.
        Latency = that TPDO's start on the wire (its receive timestamp − its own frame
        time) − the end of the set-point frame (the bus's timestamp of what we sent; on
        an interface that gives none, the time ``send`` returned, which adds the frame's
        own time). Median of ``rounds``. Sets :attr:`latency_s`; returns it (4,) per joint, s.

        :raises StationFaultError: fault latched. :raises TimeoutError: a station never acknowledged.
        """
        self._ready("measure_delays")
        if isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 1:
            raise StationCommandError(f"measure_delays: rounds = {rounds!r} must be a whole number ≥ 1")
        samples: dict[str, list[float]] = {s.joint: [] for s in self._stations}
        for _ in range(rounds):
            for s in self._stations:
                if s.pos_inc is None:
                    raise TimeoutError(f"measure_delays: {s.joint} has not reported a position")
                before = (s.statusword & cia402.SW_SETPOINT_ACK, s.tpdo_count)
                frame = _SETPOINT.pack(s.pos_inc, 0)
                with self._cmd_lock:
                    self.latch.check("measure_delays")
                    t_end = self._send(0x200 + s.cfg.node_id, frame, "measure_delays")

                def acked(s=s, before=before):
                    self.latch.check("measure_delays")
                    return s.tpdo_count > before[1] and (s.statusword & cia402.SW_SETPOINT_ACK) != before[0]
                if not self._await(acked, 1.0):
                    raise TimeoutError(f"measure_delays: no set-point acknowledgement from {s.joint}")
                tpdo_s = frame_time_s(can.Message(arbitration_id=0x180 + s.cfg.node_id, data=s.tpdo_data,
                                                  is_extended_id=False), self.cfg.bitrate)
                samples[s.joint].append(s.t_tpdo - tpdo_s - t_end)
            self.clock.sleep(0.005)
        for s in self._stations:
            self._latency[s.cfg.joint_index] = max(0.0, statistics.median(samples[s.joint]))
            s.target = None
        log.info("latency_measured", latency_ms=[round(d * 1e3, 4) for d in self._latency])
        return self.latency_s
