"""Station fault codes, the fault latch and the bus monitor (our own ``can.Listener``).

Fault codes are what the PLC sees (one register, :class:`FaultCode`); a latched fault
also carries the station, the EMCY code if any and a readable detail.

Why our own monitor: canopen's ``MessageListener`` drops error frames and remote frames
and only logs exceptions from malformed frames; it has no heartbeat-timeout monitor
either. :class:`BusMonitor` sits on the same ``can.Notifier`` and checks *every* frame
against the table of frames the controller expects (COB-ID → allowed data lengths);
:class:`HeartbeatWatchdog` is a thread that declares a station silent once its
heartbeat is overdue and polls the CAN controller state for bus-off, on the injected clock.

Policy for frames the controller did not expect (documented, and tested):

* error frame → :attr:`FaultCode.BUS_ERROR_FRAME`; bus state ERROR → :attr:`FaultCode.BUS_OFF`;
* wrong data length on an expected COB-ID (heartbeat ≠ 1, EMCY ≠ 8, TPDO ≠ mapped
  length, SDO ≠ 8) → :attr:`FaultCode.GARBAGE_FRAME`;
* unknown COB-ID or a remote frame → :attr:`FaultCode.UNEXPECTED_FRAME` when
  ``unknown_frames="fault"`` (default: on a machine bus an unknown sender is a wiring
  or configuration error), else logged and ignored (``"log"``).

No frame, however malformed, raises out of the monitor: it never crashes the notifier.
"""
from __future__ import annotations

import collections
import enum
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Literal

import can

from cell.clock import Clock, MonotonicClock
from cell.errors import CellError
from cell.log import get_logger

log = get_logger("stations.faults")


class FaultCode(enum.IntEnum):
    """Joint-station fault codes shown to the PLC (0 = no fault). Stable numbers: never reuse."""

    NONE = 0
    HEARTBEAT_LOST = 1          #: a station's heartbeat is overdue (station silent / unplugged)
    BUS_ERROR_FRAME = 2         #: a CAN error frame was seen on the bus
    BUS_OFF = 3                 #: the controller's CAN interface went bus-off / error state
    EMCY_LIMIT = 4              #: EMCY 0x8612: a set-point beyond the software limits was refused
    EMCY_FOLLOWING_ERROR = 5    #: EMCY 0x8611: the axis lagged beyond its following-error window
    EMCY_HEARTBEAT = 6          #: EMCY 0x8130: the station lost the *controller's* heartbeat
    EMCY_OTHER = 7              #: any other EMCY code (see ``emcy_code``)
    GARBAGE_FRAME = 8           #: an expected COB-ID with a wrong data length
    UNEXPECTED_FRAME = 9        #: an unknown COB-ID or remote frame (``unknown_frames="fault"``)
    STATION_RESET = 10          #: a station rebooted (boot-up) or left NMT Operational
    DRIVE_FAULT = 11            #: a statusword reports Fault without an EMCY
    SEND_FAILED = 12            #: the CAN interface refused a frame (controller side)
    STARTUP_FAILED = 13         #: SDO configuration / enable sequence failed
    QUICK_STOP = 14             #: quick stop requested by the controller (quick_stop_all)


EMCY_TO_FAULT = {0x8612: FaultCode.EMCY_LIMIT, 0x8611: FaultCode.EMCY_FOLLOWING_ERROR,
                 0x8130: FaultCode.EMCY_HEARTBEAT}


@dataclass(frozen=True)
class FaultRecord:
    """One latched fault. ``joint``/``node_id`` are ``None`` for bus-wide faults;
    ``t_s`` is the wall time (``time.monotonic()``) it was latched, for logs only."""

    code: FaultCode
    detail: str
    joint: str | None = None
    node_id: int | None = None
    emcy_code: int | None = None
    t_s: float = field(default_factory=time.monotonic)

    def __str__(self) -> str:
        where = f" on {self.joint} (node {self.node_id})" if self.joint else ""
        emcy = f", EMCY 0x{self.emcy_code:04X}" if self.emcy_code is not None else ""
        return f"{self.code.name} ({int(self.code)}){where}{emcy}: {self.detail}"


class StationFaultError(CellError, RuntimeError):
    """A command was refused because a station fault is latched; ``.record`` holds it."""

    def __init__(self, record: FaultRecord, action: str):
        self.record = record
        super().__init__(f"{action} refused: station fault latched: {record}; call reset() first")


class FaultLatch:
    """Thread-safe first-fault latch. The first :meth:`latch` wins and runs the reaction
    callbacks once (e.g. quick-stop all stations); later faults are logged and kept in
    :attr:`history` (the latest ``HISTORY_KEEP``, so a cell that faults now and then for
    weeks stays flat). :meth:`clear` unlatches (only :meth:`JointStations.reset` calls it)."""

    HISTORY_KEEP = 256

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._record: FaultRecord | None = None
        self.history: collections.deque[FaultRecord] = collections.deque(maxlen=self.HISTORY_KEEP)
        self._reactions: list[Callable[[FaultRecord], None]] = []

    def on_latch(self, reaction: Callable[[FaultRecord], None]) -> None:
        self._reactions.append(reaction)

    @property
    def record(self) -> FaultRecord | None:
        return self._record

    def latch(self, record: FaultRecord) -> bool:
        """Latch ``record`` if nothing is latched; returns True if it became *the* fault."""
        with self._lock:
            self.history.append(record)
            first = self._record is None
            if first:
                self._record = record
        log.error("station_fault", fault=str(record), first=first)
        if first:
            for reaction in self._reactions:
                try:
                    reaction(record)
                except Exception as exc:  # a reaction must never stop the others
                    log.error("fault_reaction_failed", error=repr(exc))
        return first

    def check(self, action: str) -> None:
        """:raises StationFaultError: naming ``action`` and the latched fault."""
        rec = self._record
        if rec is not None:
            raise StationFaultError(rec, action)

    def clear(self) -> None:
        with self._lock:
            self._record = None


@dataclass(frozen=True)
class Expected:
    """One expected COB-ID: frame ``kind``, sending station and the allowed data lengths."""

    kind: Literal["heartbeat", "emcy", "sdo", "tpdo"]
    joint: str
    node_id: int
    dlc: frozenset[int]


class BusMonitor(can.Listener):
    """Checks every received frame; latches a fault for error frames and garbage.

    :param latch: the fault latch to report to.
    :param expected: COB-ID → :class:`Expected` (built by the driver from its config).
    :param unknown_frames: ``"fault"`` or ``"log"`` for unknown COB-IDs / remote frames.
    :param on_heartbeat: called ``(node_id, nmt_state)`` for each well-formed heartbeat.
    """

    def __init__(self, latch: FaultLatch, expected: dict[int, Expected],
                 unknown_frames: Literal["fault", "log"] = "fault",
                 on_heartbeat: Callable[[int, int], None] | None = None):
        self.latch = latch
        self.expected = dict(expected)
        self.unknown_frames = unknown_frames
        self.on_heartbeat = on_heartbeat
        self.seen = 0
        self.rejected = 0

    def on_message_received(self, msg: can.Message) -> None:
        try:
            exp = self.expected.get(msg.arbitration_id)
            if (exp is not None and exp.kind != "heartbeat" and len(msg.data) in exp.dlc
                    and not (msg.is_error_frame or msg.is_extended_id or msg.is_remote_frame)):
                self.seen += 1                # an expected frame as expected (TPDO, EMCY, SDO)
                return
            self._check(msg)
        except Exception as exc:  # never let a frame kill the notifier thread
            log.error("bus_monitor_error", error=repr(exc), frame=str(msg))

    def _reject(self, code: FaultCode, detail: str, exp: Expected | None = None) -> None:
        self.rejected += 1
        self.latch.latch(FaultRecord(code, detail, exp.joint if exp else None,
                                     exp.node_id if exp else None))

    def _check(self, msg: can.Message) -> None:
        self.seen += 1
        if msg.is_error_frame:
            self._reject(FaultCode.BUS_ERROR_FRAME, f"CAN error frame received: {msg}")
            return
        exp = self.expected.get(msg.arbitration_id) if not msg.is_extended_id else None
        if exp is None or msg.is_remote_frame:
            what = "remote frame" if msg.is_remote_frame else "frame with unknown COB-ID"
            detail = (f"{what} 0x{msg.arbitration_id:03X} (DLC {msg.dlc}, "
                      f"data {bytes(msg.data).hex() or '-'})")
            if self.unknown_frames == "fault":
                self._reject(FaultCode.UNEXPECTED_FRAME, detail)
            else:
                self.rejected += 1
                log.warning("unexpected_frame_ignored", detail=detail)
            return
        n = len(msg.data)
        if n not in exp.dlc:
            self._reject(FaultCode.GARBAGE_FRAME,
                         f"{exp.kind} 0x{msg.arbitration_id:03X} from {exp.joint} has "
                         f"{n} data bytes, expected {sorted(exp.dlc)}", exp)
            return
        if exp.kind == "heartbeat" and self.on_heartbeat is not None:
            self.on_heartbeat(exp.node_id, msg.data[0] & 0x7F)


class HeartbeatWatchdog:
    """Checks every ``period_s`` that latch :attr:`FaultCode.HEARTBEAT_LOST` when a station's
    heartbeat is overdue and :attr:`FaultCode.BUS_OFF` when the bus reports an error state.

    Time comes from the injected clock (the bus delivers heartbeats on that clock's time).
    A station counts as silent when no heartbeat came for ``timeout_s``; it is found at the
    next check, so within ``timeout_s + period_s``. On a clock that runs timed callbacks
    (``call_at``: the simulated clock) each check is one, run by whichever thread runs the
    clock's agenda, as the simulated drives' timers are: no thread switch of its own. On
    another clock (the wall clock) the checks run in a task, ``stations-watchdog``. Either
    way they happen at the same clock times, in the same order.

    :param stations: node_id → joint name of the watched stations.
    :param timeout_s: silence allowed, seconds (> 0).
    :param period_s: check period, seconds (> 0).
    :param bus: the CAN bus whose ``state`` is polled (``None`` to skip).
    :param clock: the clock (default: wall time).
    """

    def __init__(self, latch: FaultLatch, stations: dict[int, str], timeout_s: float,
                 period_s: float, bus: can.BusABC | None = None, clock: Clock | None = None):
        if not (timeout_s > 0 and period_s > 0):
            raise ValueError(f"timeout_s = {timeout_s}, period_s = {period_s}: both must be > 0")
        self.latch = latch
        self.stations = dict(stations)
        self.timeout_s = timeout_s
        self.period_s = period_s
        self.bus = bus
        self.clock = clock or MonotonicClock()
        self._last: dict[int, float] = {}
        self._reported: set[int] = set()
        self._bus_off_reported = False
        self._stop = self.clock.event()
        self._task = None
        self._timer = None                  # the next check's clock callback (call_at clocks)
        self._tick_lock = threading.Lock()  # a stop from outside the clock waits for a check
        #: called after every check (the driver re-sends a quick stop that did not arrive)
        self.on_check: Callable[[], None] | None = None

    def beat(self, node_id: int, nmt_state: int = 5) -> None:
        """Record a heartbeat from ``node_id`` now (called from the bus monitor)."""
        self._last[node_id] = self.clock.now()
        self._reported.discard(node_id)

    def silent(self) -> list[int]:
        """Node ids whose heartbeat is overdue right now."""
        now = self.clock.now()
        return [n for n in self.stations if now - self._last.get(n, -1e9) > self.timeout_s]

    def arm(self) -> None:
        """Start (or restart) watching: every station gets ``timeout_s`` from now."""
        now = self.clock.now()
        for n in self.stations:
            self._last[n] = now
        self._reported.clear()
        self._bus_off_reported = False
        call_at = getattr(self.clock, "call_at", None)
        if call_at is not None:
            with self._tick_lock:
                if self._timer is None:        # where a task would start: its first wait begins then
                    self._timer = call_at(now, self._tick, False)
        elif self._task is None:
            self._stop.clear()
            self._task = self.clock.spawn(self._run, "stations-watchdog")

    def stop(self) -> None:
        with self._tick_lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
        self._stop.set()
        if self._task is not None:
            self._task.join(timeout=2.0)
            self._task = None

    def _run(self) -> None:
        """The checks as a task (a clock without ``call_at``)."""
        while not self._stop.wait(self.period_s):
            self._check_safely()

    def _tick(self, check: bool = True) -> None:
        """A check as a clock callback; the next one at the time the task's wait would end
        (``now + period_s``)."""
        with self._tick_lock:
            if self._timer is None:            # stopped meanwhile
                return
            if check:
                self._check_safely()
            self._timer = self.clock.call_at(self.clock.now() + self.period_s, self._tick)

    def _check_safely(self) -> None:
        try:
            self.check()
        except Exception as exc:  # the watchdog must survive anything
            log.error("watchdog_error", error=repr(exc))

    def check(self) -> None:
        """One check: latch a fault for each newly silent station and for bus-off."""
        for n in self.silent():
            if n not in self._reported:
                self._reported.add(n)
                age = self.clock.now() - self._last.get(n, 0.0)
                self.latch.latch(FaultRecord(
                    FaultCode.HEARTBEAT_LOST,
                    f"no heartbeat for {age * 1e3:.0f} ms (allowed {self.timeout_s * 1e3:.0f} ms)",
                    self.stations[n], n))
        if self.bus is not None and getattr(self.bus, "state", None) is can.BusState.ERROR:
            if not self._bus_off_reported:
                self._bus_off_reported = True
                self.latch.latch(FaultRecord(FaultCode.BUS_OFF, "CAN interface reports bus state ERROR (bus-off)"))
        if self.on_check is not None:
            self.on_check()
