"""Streaming half of :class:`~drivers.stations.driver.JointStations`: line segments
(reception-applied or SYNC-applied), waiting for targets and measuring the per-station
command delay on the bus (seed 002's λ_i). Split from ``driver.py`` to keep modules small;
the methods use the driver's command helpers (``_ready``, ``_burst``, ``_send``).
"""
from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass
from typing import Literal

import can
import numpy as np

from cell.errors import CellError
from cell.log import get_logger
from drivers.stations import cia402
from drivers.stations.bus import frame_time_s

log = get_logger("stations.driver")


class StationCommandError(CellError, ValueError):
    """A command with bad values (shape, not finite, beyond limits); nothing was sent."""


@dataclass(frozen=True)
class StreamReport:
    """What :meth:`JointStations.stream` sent. Times are bus timestamps (``time.time()``
    base, the base of received frames): ``t0`` the nominal start of segment 1,
    ``sent`` (n,) when each segment's first frame (reception mode) or SYNC (sync mode)
    went out."""

    mode: str
    t0: float
    sent: np.ndarray


class StreamingMixin:
    """Methods of :class:`JointStations` that stream and measure (see the driver's docs)."""

    def stream(self, segments, mode: Literal["reception", "sync"] = "reception",
               lead_s: float | None = None) -> StreamReport:
        """Stream line segments (seed 002), blocking until the last one is sent.

        Each ``Segment`` (``cell.trajectory.line``) carries per-joint ``target_deg`` (4,)
        and ``velocity_deg_s`` (4,) (magnitudes are used) and starts at ``start_s``.

        * ``"reception"``: segment k's set-points go out at ``t0 + start_s`` in bus order
          and each station applies its own on reception (plus its delay): use velocities
          corrected with :attr:`delays_s` (``plan_line(..., delays_s=stations.delays_s)``).
        * ``"sync"``: segment k's set-points are written ahead (RPDO3) and applied by all
          stations together on the SYNC sent at ``t0 + start_s``; plan uncorrected.

        :param lead_s: time from the call to segment 1 (default: 0 for reception; for sync
            the config's ``sync_lead_s`` or the largest known delay + 5 ms if longer, so
            the first set-points have arrived when SYNC 1 goes out).
        :raises StationCommandError: bad mode, empty list, a segment with bad shape,
            non-finite values, targets beyond limits or start times not increasing
            (checked for *all* segments before anything is sent).
        :raises StationFaultError: a fault was latched before or during streaming; the
            stations are already quick-stopped.
        """
        self._ready("stream")
        if mode not in ("reception", "sync"):
            raise StationCommandError(f"stream: mode = {mode!r}; choose 'reception' or 'sync'")
        segs = list(segments)
        if not segs:
            raise StationCommandError("stream: no segments given")
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
        if lead_s is None:  # sync: the first set-points must be in (after the stations' delays) before SYNC 1
            lead = max(self.cfg.sync_lead_s, float(np.max(self._delays)) + 0.005) if mode == "sync" else 0.0
        else:
            lead = float(lead_s) if isinstance(lead_s, (int, float)) and not isinstance(lead_s, bool) else math.nan
            if not (math.isfinite(lead) and 0 <= lead <= 10):
                raise StationCommandError(f"stream: lead_s = {lead_s!r} must be in [0, 10] s")
        t0_clock = self.clock.now() + lead
        t0_bus = time.time() + lead
        sent = np.zeros(len(checked))
        if mode == "sync":
            self._burst(checked[0][1], checked[0][2], 0x400, "stream")
        for k, (start, q, v) in enumerate(checked):
            wait = t0_clock + start - self.clock.now()
            if wait > 0:
                self.clock.sleep(wait)
            if mode == "reception":
                sent[k] = self._burst(q, v, 0x200, "stream")
            else:
                with self._cmd_lock:
                    self.latch.check("stream")
                    sent[k] = self._send(0x80, b"", "stream")
                if k + 1 < len(checked):
                    self._burst(checked[k + 1][1], checked[k + 1][2], 0x400, "stream")
        return StreamReport(mode, t0_bus, sent)

    def wait_reached(self, timeout_s: float, tol: float = 0.02) -> None:
        """Block until every station reports (TPDO) its last commanded target within ``tol``
        joint units and *target reached*.

        :raises StationFaultError: a fault latched while waiting.
        :raises TimeoutError: not reached within ``timeout_s`` (names the joints still off).
        """
        deadline = time.monotonic() + timeout_s
        while True:
            self.latch.check("wait_reached")
            off = [s for s in self._stations if s.target is not None and not (
                s.pos_inc is not None and abs(s.pos_inc / s.cpu - s.target) <= tol
                and s.statusword & cia402.SW_TARGET_REACHED)]
            if not off:
                return
            if time.monotonic() > deadline:
                raise TimeoutError("targets not reached within %.2f s: %s" % (timeout_s, ", ".join(
                    f"{s.joint} at {(s.pos_inc or 0) / s.cpu:.4f} for {s.target:.4f}" for s in off)))
            time.sleep(0.002)

    def measure_delays(self, rounds: int = 5) -> np.ndarray:
        """Measure each station's command delay on the bus and use it from now on.

        Each round sends a zero-velocity set-point at the current position to every
        station in bus order (a burst, as :meth:`stream` does) and waits for each
        station's TPDO whose statusword bit 12 shows the set-point applied. Delay = that
        TPDO's receive timestamp − the burst's start − the TPDO's own frame time (seed
        002's λ_i counted from the moment the controller starts sending). Median of
        ``rounds``. :returns: (4,) per joint, seconds.
        :raises StationFaultError: fault latched. :raises TimeoutError: a station never acknowledged.
        """
        self._ready("measure_delays")
        if isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 1:
            raise StationCommandError(f"measure_delays: rounds = {rounds!r} must be a whole number ≥ 1")
        tpdo_s = frame_time_s(can.Message(arbitration_id=0x181, data=bytes(6), is_extended_id=False),
                              self.cfg.bitrate)
        samples: dict[str, list[float]] = {s.joint: [] for s in self._stations}
        q = self.actual_positions()
        for _ in range(rounds):
            before = {s.joint: (s.statusword & cia402.SW_SETPOINT_ACK, s.tpdo_count) for s in self._stations}
            t_start = time.time()
            self._burst(q, np.zeros(4), 0x200, "measure_delays")
            deadline = time.monotonic() + 1.0
            pending = {s.joint for s in self._stations}
            while pending:
                self.latch.check("measure_delays")
                for s in self._stations:
                    ack, cnt = before[s.joint]
                    if s.joint in pending and s.tpdo_count > cnt and (s.statusword & cia402.SW_SETPOINT_ACK) != ack:
                        samples[s.joint].append(s.t_tpdo - t_start - tpdo_s)
                        pending.discard(s.joint)
                if time.monotonic() > deadline:
                    raise TimeoutError(f"measure_delays: no set-point acknowledgement from {sorted(pending)}")
                time.sleep(0.0005)
            time.sleep(0.005)
        for s in self._stations:
            self._delays[s.cfg.joint_index] = max(0.0, statistics.median(samples[s.joint]))
        for s in self._stations:
            s.target = None
        log.info("delays_measured", delays_ms=[round(d * 1e3, 3) for d in self._delays])
        return self.delays_s

