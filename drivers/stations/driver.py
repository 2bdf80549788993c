"""Controller side of the joint stations: one :class:`JointStations` for all four CANopen
drives (canopen ``RemoteNode`` on a python-can bus chosen by name in the config).

Wire layout (per station with node id ``n``; set up by :meth:`JointStations.start`):

=========  ===========  =====================================================  ==========
COB-ID     direction    content                                                applied
=========  ===========  =====================================================  ==========
0x200+n    RPDO1 →      target 0x607A (i32, inc) + profile velocity 0x6081      on receipt
0x300+n    RPDO2 →      controlword 0x6040                                     on receipt
0x400+n    RPDO3 →      target + profile velocity                              on SYNC
0x180+n    ← TPDO1      position actual value 0x6064 + statusword 0x6041       event timer
0x700+n    ← heartbeat  NMT state every ``heartbeat_ms``                        watched
0x080+n    ← EMCY       fault codes                                            latched
0x700+c    heartbeat →  the controller (node ``controller_node_id``)           consumed
=========  ===========  =====================================================  ==========

Threads: the bus's receive side (python-can's notifier thread on hardware, the simulated
clock's thread on the virtual wire) runs the TPDO/EMCY callbacks and our
:class:`~drivers.stations.faults.BusMonitor`; the watchdog task checks heartbeats;
the bus's cyclic task sends the controller heartbeat; :meth:`stream` runs in the
caller's thread and timestamps each set-point burst. Every wait (SDO answers, boot-up,
targets reached) is a wait on the injected clock. A latched fault quick-stops all
stations from whichever thread found it, under the command lock, so no set-point can
follow the quick stop.

Safety: after any fault every command but :meth:`reset` / :meth:`shutdown` raises
:class:`~drivers.stations.faults.StationFaultError` naming the latched fault.
"""
from __future__ import annotations

import math
import struct
import threading
import time
from pathlib import Path
from typing import Sequence

import can
import canopen
import numpy as np

from cell.clock import Clock, MonotonicClock
from cell.log import get_logger
from drivers.stations import cia402
from drivers.stations.bus import connect_network, open_bus
from drivers.stations.cia402 import Command, State
from drivers.stations.config import JOINT_NAMES, StationConfig, StationsConfig
from drivers.stations.dispatch import FrameDispatch
from drivers.stations.faults import (EMCY_TO_FAULT, BusMonitor, Expected, FaultCode, FaultLatch,
                                     FaultRecord, HeartbeatWatchdog, StationFaultError)
from drivers.stations.bringup import BringUpMixin, StationStartupError, _remote_node  # noqa: F401
from drivers.stations.streaming import _SETPOINT, StationCommandError, StreamingMixin, StreamReport  # noqa: F401

#: the drives' electronic data sheet (object dictionary), shared by controller and twin
EDS_PATH = Path(__file__).with_name("scara_axis.eds")

log = get_logger("stations.driver")
_CONTROLWORD = struct.Struct("<H")
_I32 = 2 ** 31 - 1
_TPDO1 = struct.Struct("<iH")                 # position actual value, statusword
_STATES: dict[int, State | None] = {}         # statusword → its CiA 402 state (None: none)


def _state_of(statusword: int) -> State | None:
    """:func:`cia402.decode_statusword` of a TPDO's statusword (16 bits), ``None`` where it
    encodes no state; remembered per word (a drive reports a handful of them)."""
    try:
        return _STATES[statusword]
    except KeyError:
        pass
    try:
        state = cia402.decode_statusword(statusword)
    except cia402.IllegalTransition:
        state = None
    _STATES[statusword] = state
    return state


class _Station:
    """Controller-side record of one station: config, RemoteNode, latest TPDO."""

    def __init__(self, cfg: StationConfig, node: canopen.RemoteNode):
        self.cfg, self.node = cfg, node
        self.index, self.node_id = cfg.joint_index, cfg.node_id   # per command: looked up once
        self.cpu = cfg.counts_per_unit
        #: the fastest set-point the station takes, increments/s (its max_velocity, within u32)
        self.top_inc = min(cfg.max_velocity * self.cpu, 2 ** 32 - 1)
        self.pos_inc: int | None = None
        self.statusword = 0
        self.t_tpdo = 0.0
        self.tpdo_data = b""
        self.tpdo_count = 0
        self.fault_tpdos = 0
        self.target: float | None = None

    @property
    def joint(self) -> str:
        return self.cfg.joint


class JointStations(BringUpMixin, StreamingMixin):
    """All joint stations of one cell behind one object.

    Lifecycle: :meth:`from_config` → :meth:`start` (Operation enabled) → commands
    (:meth:`move_to`, :meth:`stream`) → :meth:`shutdown`. A fault latches (see
    :attr:`fault`); :meth:`reset` clears it once its cause is gone and re-enables.
    Arrays are always per joint j1..j4 in joint units (deg; mm for j3).
    """

    def __init__(self, cfg: StationsConfig, clock: Clock | None = None):
        self.cfg = cfg
        self.clock = clock or MonotonicClock()
        self._changed = self.clock.event()     # set by every TPDO, heartbeat and fault
        self.latch = FaultLatch()
        self.latch.on_latch(self._react)
        self.latch.on_latch(lambda record: self._changed.set())
        self._cmd_lock = threading.RLock()
        self._stations: list[_Station] = []
        self._by_node: dict[int, _Station] = {}
        self.network: canopen.Network | None = None
        self.monitor: BusMonitor | None = None
        self.watchdog: HeartbeatWatchdog | None = None
        self._hb_task = None
        self._started = False
        self._expect_operational = False
        self._recording: list[tuple[float, int, float]] | None = None
        self._heard: dict[int, int | None] = {}  # node id → NMT state of its last heartbeat
        self._quick_stop_at = -1e9              # clock time the last quick stop was sent
        self._latency = np.zeros(4)            # per joint: frame end → set-point applied, s
        if cfg.delays_s != "measure":
            for s, d in zip(cfg.stations, cfg.delays_s):
                self._latency[s.joint_index] = d

    @classmethod
    def from_config(cls, data, clock: Clock | None = None) -> "JointStations":
        """Build from the ``stations`` config section (mapping or :class:`StationsConfig`).

        :raises ConfigError: naming each bad field. Opens nothing (see :meth:`start`).
        """
        return cls(StationsConfig.load(data), clock)

    # ================================================================== start-up
    def start(self) -> None:
        """Open the bus, wait for every station's heartbeat, configure them by SDO (heartbeats,
        gear, limits, PDO mapping), NMT start, controller heartbeat on, CiA 402 enable
        sequence to *Operation enabled*, watchdog armed; measures delays if configured.

        :raises StationStartupError: a station did not boot or refused its configuration
            (everything opened so far is closed again).
        :raises StationStartupError: also when the CAN interface could not be opened (missing,
            down, no driver), naming ``stations.interface`` and ``stations.channel``.
        """
        if self._started:
            return
        c = self.cfg
        try:
            bus = open_bus(c.interface, c.channel, c.bitrate, clock=self.clock)
        except (can.CanError, OSError) as exc:      # python-can raises either, by interface
            hint = (f" (ip link set {c.channel} up type can bitrate {c.bitrate})"
                    if c.interface == "socketcan" else "")
            raise StationStartupError(
                f"cannot open the CAN bus: stations.interface {c.interface!r}, stations.channel "
                f"{c.channel!r}: {exc}; check that the interface exists and is up{hint}") from None
        net = canopen.Network(bus)
        net.NOTIFIER_CYCLE = 0.05
        dispatch = FrameDispatch(net.listeners[0])      # TPDOs straight to us, the rest to canopen
        net.listeners[0] = dispatch
        od_path = str(EDS_PATH)
        for sc in c.stations:
            node = _remote_node(sc.node_id, od_path, self.clock)
            node.sdo.RESPONSE_TIMEOUT = c.sdo_timeout_s
            node.sdo.MAX_RETRIES = c.sdo_attempts      # canopen re-sends an unanswered request
            net.add_node(node)
            st = _Station(sc, node)
            self._stations.append(st)
            self._by_node[sc.node_id] = st
            node.tpdo.read(from_od=True)
            dispatch.handlers[0x180 + sc.node_id] = self._tpdo_handler(st)
            node.emcy.add_callback(self._emcy_callback(st))
        self.watchdog = HeartbeatWatchdog(
            self.latch, {s.cfg.node_id: s.joint for s in self._stations},
            timeout_s=c.heartbeat_tolerance * c.heartbeat_ms / 1000.0,
            period_s=min(0.02, c.heartbeat_ms / 4000.0), bus=bus, clock=self.clock)
        self.watchdog.on_check = self._enforce_quick_stop
        self.monitor = BusMonitor(self.latch, self._expected(), c.unknown_frames, self._on_heartbeat)
        net.listeners.append(self.monitor)
        self.network = net
        connect_network(net)
        try:
            self._wait_boot()
            self._configure_all()
            self._hb_task = net.send_periodic(0x700 + c.controller_node_id, [0x05],
                                              c.controller_heartbeat_ms / 1000.0)
            self._enable_all()
        except BaseException:
            self._close()
            raise
        self._expect_operational = True
        self._started = True
        self.watchdog.arm()
        if c.delays_s == "measure":
            self.measure_delays()
        log.info("stations_started", joints=[s.joint for s in self._stations], channel=c.channel)

    def _expected(self) -> dict[int, Expected]:
        exp = {}
        for s in self._stations:
            n, j = s.cfg.node_id, s.joint
            exp[0x700 + n] = Expected("heartbeat", j, n, frozenset({1}))
            exp[0x080 + n] = Expected("emcy", j, n, frozenset({8}))
            exp[0x580 + n] = Expected("sdo", j, n, frozenset({8}))
            exp[0x180 + n] = Expected("tpdo", j, n, frozenset({6}))
        return exp

    def _on_heartbeat(self, node_id: int, state: int) -> None:
        self._heard[node_id] = state
        if not self._changed.is_set():
            self._changed.set()
        if self.watchdog is not None:
            self.watchdog.beat(node_id, state)
        if self._expect_operational and state != 0x05:
            st = self._by_node[node_id]
            what = "rebooted (boot-up)" if state == 0 else f"left NMT Operational (state {state})"
            self.latch.latch(FaultRecord(FaultCode.STATION_RESET, what, st.joint, node_id))

    # ================================================================== callbacks (notifier thread)
    def _tpdo_handler(self, s: _Station):
        """The handler of ``s``'s TPDO1 (position, statusword), called by the network's
        :class:`~drivers.stations.dispatch.FrameDispatch` with the frame's data and time."""
        changed = self._changed

        def on_tpdo(data: bytearray, timestamp: float) -> None:
            if len(data) != 6:
                return  # the bus monitor latches GARBAGE_FRAME for it
            pos, sw = _TPDO1.unpack_from(data)
            s.pos_inc, s.statusword, s.t_tpdo = pos, sw, timestamp
            s.tpdo_data = bytes(data)
            s.tpdo_count += 1
            if not changed.is_set():      # set: whoever waits has not cleared it yet, and reads after
                changed.set()
            rec = self._recording
            if rec is not None:
                rec.append((timestamp, s.cfg.joint_index, pos / s.cpu))
            state = _state_of(sw)
            if state is None:
                return
            # A drive in Fault normally announced it by EMCY first; the statusword alone
            # latches DRIVE_FAULT only when a second TPDO still shows it and nothing else did.
            s.fault_tpdos = s.fault_tpdos + 1 if state in (State.FAULT, State.FAULT_REACTION_ACTIVE) else 0
            if s.fault_tpdos >= 2 and self._expect_operational and self.latch.record is None:
                self.latch.latch(FaultRecord(FaultCode.DRIVE_FAULT, f"statusword 0x{sw:04X} reports {state.label}",
                                             s.joint, s.cfg.node_id))
        return on_tpdo

    def _emcy_callback(self, s: _Station):
        def on_emcy(err) -> None:
            if err.code & 0xFF00 == 0:
                return  # error reset
            code = EMCY_TO_FAULT.get(err.code, FaultCode.EMCY_OTHER)
            self.latch.latch(FaultRecord(code, f"EMCY {err}", s.joint, s.cfg.node_id, err.code))
        return on_emcy

    def _react(self, record: FaultRecord) -> None:
        """First fault: quick-stop every station (category 2), whatever thread we are in."""
        with self._cmd_lock:
            self._quick_stop_at = self.clock.now()
            self._send_controlword_all(Command.QUICK_STOP)

    def _enforce_quick_stop(self) -> None:
        """While a fault is latched, a station whose statusword still says *Operation
        enabled* did not get the quick stop (its frame was refused, e.g. a full transmit
        queue): send it again, at every watchdog check, until it stops."""
        if self.latch.record is None or not self._expect_operational or self.network is None:
            return
        if self.clock.now() - self._quick_stop_at < self.watchdog.period_s:
            return                            # give the last one time to show in a TPDO
        moving = [s for s in self._stations if s.tpdo_count and s.statusword & 0x6F == 0x27]
        if not moving:
            return
        self._quick_stop_at = self.clock.now()
        with self._cmd_lock:
            self._send_controlword_all(Command.QUICK_STOP, moving)   # a refusal: again next check

    def _send_controlword_all(self, cmd: Command, stations=None) -> None:
        """Send ``cmd`` to ``stations`` (default every one), in bus order; a refused frame is
        logged and the others still get theirs."""
        if self.network is None or self.network.bus is None:
            return
        for s in self._stations if stations is None else stations:
            try:
                self.network.send_message(0x300 + s.cfg.node_id, _CONTROLWORD.pack(cmd.word))
            except Exception as exc:  # keep stopping the others
                log.error("controlword_send_failed", joint=s.joint, error=repr(exc))

    # ================================================================== commands
    def _ready(self, action: str) -> None:
        if not self._started:
            raise StationStartupError(f"{action} refused: the stations are not started (call start())")
        self.latch.check(action)

    def _check_targets(self, targets, what: str) -> np.ndarray:
        try:
            a = np.asarray(targets, dtype=float) if not isinstance(targets, str) else np.array([])
        except (TypeError, ValueError):
            raise StationCommandError(f"{what}: {targets!r} is not a list of 4 numbers") from None
        if a.shape != (4,):
            raise StationCommandError(f"{what}: need 4 joint values (j1..j4), got shape {a.shape}")
        for s in self._stations:
            v = a[s.cfg.joint_index]
            lo, hi = s.cfg.joint_limits
            if not math.isfinite(v):
                raise StationCommandError(f"{what}: {s.joint} = {float(v)!r} is not a finite number")
            if not lo <= v <= hi:
                raise StationCommandError(f"{what}: {s.joint} = {v:.4f} is outside its limits [{lo}, {hi}]")
        return a

    def _setpoint_frame(self, s: _Station, target: float, vel: float) -> bytes:
        # at least 1 increment/s: a drive given 0 would stop short of a target a fraction
        # of an increment away (the smooth time law's first and last steps are tiny)
        vel_inc = min(max(1, round(abs(float(vel)) * s.cpu)), 2 ** 32 - 1)
        return _SETPOINT.pack(round(float(target) * s.cpu), vel_inc)

    def _send(self, cob_id: int, data: bytes, action: str) -> float:
        """Send one frame under the command lock; returns its bus timestamp (the end of its
        slot where the bus tells, else the time ``send`` returned)."""
        try:
            self.network.send_message(cob_id, data)
        except (can.CanError, RuntimeError) as exc:
            self.latch.latch(FaultRecord(FaultCode.SEND_FAILED, f"{action}: frame 0x{cob_id:03X} not sent: {exc}"))
            raise StationFaultError(self.latch.record, action) from exc
        stamp = getattr(self.network.bus, "last_tx_timestamp", None)
        return time.time() if stamp is None else stamp

    def _burst(self, targets: np.ndarray, vels: np.ndarray, base: int, action: str) -> float:
        """Send one set-point per station in bus order; returns the first frame's timestamp."""
        q = np.asarray(targets, dtype=float).tolist()     # plain floats: numpy's scalars are slow
        v = np.asarray(vels, dtype=float).tolist()
        with self._cmd_lock:
            self.latch.check(action)
            t_first = None
            for s in self._stations:
                j = s.index
                t = self._send(base + s.node_id, self._setpoint_frame(s, q[j], v[j]), action)
                t_first = t if t_first is None else t_first
                s.target = q[j]
            return t_first

    def move_to(self, targets_deg: Sequence[float], speed: float) -> float:
        """Point-to-point move: all joints start together and arrive together.

        :param targets_deg: (4,) joint targets j1..j4 (deg; mm for j3), within limits.
        :param speed: the fastest joint's speed, joint units/s (> 0); every joint is also
            held to its ``max_velocity``.
        :returns: the planned duration in seconds (from the actual positions now).
        :raises StationCommandError: bad shape/values/limits or speed (nothing sent).
        :raises StationFaultError: a fault is latched (nothing sent).
        """
        self._ready("move_to")
        q = self._check_targets(targets_deg, "move_to")
        if isinstance(speed, bool) or not isinstance(speed, (int, float)) or not (math.isfinite(speed) and speed > 0):
            raise StationCommandError(f"move_to: speed = {speed!r} must be a finite number > 0")
        delta = np.abs(q - self.actual_positions())
        vmax = np.array([min(speed, self.cfg.station(j).max_velocity) for j in JOINT_NAMES])
        duration = float(np.max(delta / vmax))
        vel = delta / duration if duration > 0 else np.zeros(4)
        self._burst(q, vel, 0x200, "move_to")
        return duration

    def actual_positions(self) -> np.ndarray:
        """Latest reported positions (4,), joint units, from the stations' TPDOs.

        :raises StationStartupError: when a station has not reported yet.
        """
        out = np.zeros(4)
        for s in self._stations:
            if s.pos_inc is None:
                raise StationStartupError(f"{s.joint} (node {s.cfg.node_id}) has not reported a position yet")
            out[s.cfg.joint_index] = s.pos_inc / s.cpu
        return out

    def drive_states(self) -> dict[str, State]:
        """CiA 402 state per joint from the latest statusword."""
        return {s.joint: cia402.decode_statusword(s.statusword) if s.tpdo_count else State.NOT_READY_TO_SWITCH_ON
                for s in self._stations}

    @property
    def fault(self) -> FaultRecord | None:
        """The latched fault, or ``None``."""
        return self.latch.record

    @property
    def fault_code(self) -> FaultCode:
        """Latched fault code for the PLC (:attr:`FaultCode.NONE` when healthy)."""
        rec = self.latch.record
        return rec.code if rec else FaultCode.NONE

    @property
    def latency_s(self) -> np.ndarray:
        """Per-joint station latency (4,), s: from the end of a set-point frame on the wire
        to the drive applying it; configured, or measured by :meth:`measure_delays`."""
        return self._latency.copy()

    @property
    def supports_sync(self) -> bool:
        """Every station applies synchronous set-points on SYNC (config ``supports_sync``)."""
        return all(s.supports_sync for s in self.cfg.stations)

    def quick_stop_all(self, reason: str = "requested") -> None:
        """CiA 402 quick stop of every station (category 2: ramp down, hold powered) and
        latch :attr:`FaultCode.QUICK_STOP`; nothing moves again until :meth:`reset`."""
        if not self.latch.latch(FaultRecord(FaultCode.QUICK_STOP, f"quick stop {reason}")):
            self._react(self.latch.record)  # already latched: stop again anyway

    def stop_heartbeat(self) -> None:
        """Stop sending the controller heartbeat (as a hung controller would): the stations'
        consumers then fault them after ``consumer_timeout_ms``. Used by :meth:`shutdown`."""
        if self._hb_task is not None:
            self._hb_task.stop()
            self._hb_task = None

    def reset(self) -> None:
        """Clear the latched fault and bring every station back to *Operation enabled*
        (full re-configuration, so a power-cycled station works again).

        :raises StationFaultError: the cause persists (a station still silent, bus-off);
            nothing changed.
        :raises StationStartupError: re-configuration failed (a STARTUP_FAILED fault is latched).
        """
        if not self._started:
            raise StationStartupError("reset refused: the stations are not started (call start())")
        silent = self.watchdog.silent()
        rec = self.latch.record
        if silent and rec is not None:
            names = ", ".join(f"{self._by_node[n].joint} (node {n})" for n in silent)
            raise StationFaultError(rec, f"reset (still silent: {names})")
        if getattr(self.network.bus, "state", None) is can.BusState.ERROR and rec is not None:
            raise StationFaultError(rec, "reset (bus still in ERROR state)")
        # Not under the command lock: SDO answers come through the notifier thread, which
        # must stay free to run a fault reaction. Callers do not command during reset().
        self._expect_operational = False
        self.latch.clear()
        try:
            if self._hb_task is None:
                self._hb_task = self.network.send_periodic(
                    0x700 + self.cfg.controller_node_id, [0x05], self.cfg.controller_heartbeat_ms / 1000.0)
            self._configure_all()
            self._enable_all()
        except (StationStartupError, can.CanError) as exc:
            self.latch.latch(FaultRecord(FaultCode.STARTUP_FAILED, str(exc)))
            raise
        self._expect_operational = True
        for s in self._stations:
            s.node.emcy.reset()
        self.watchdog.arm()
        log.info("stations_reset")

    def start_recording(self) -> None:
        """Start keeping every TPDO position as (bus timestamp s, joint index, joint value)."""
        self._recording = []

    def stop_recording(self) -> list[tuple[float, int, float]]:
        rec, self._recording = self._recording or [], None
        return rec

    def shutdown(self) -> None:
        """Disable the drives (Disable voltage → Switch on disabled), stop heartbeat and watchdog,
        close the bus. Idempotent; never raises for bus errors."""
        if self.watchdog is not None:
            self.watchdog.stop()
        if self._started:
            with self._cmd_lock:
                self._expect_operational = False
                self._send_controlword_all(Command.DISABLE_VOLTAGE)
        self._started = False
        self._close()

    def _close(self) -> None:
        self.stop_heartbeat()
        if self.watchdog is not None:
            self.watchdog.stop()
        if self.network is not None:
            net, self.network = self.network, None
            try:
                net.disconnect()
            except Exception as exc:
                log.error("bus_close_failed", error=repr(exc))
