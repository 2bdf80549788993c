"""Simulated joint station: a CANopen device (canopen ``LocalNode`` with the drive's EDS)
on the simulated CAN wire, with a CiA 402 drive and an axis that follows set-points.

What the twin does on the wire, like a real integrated drive of seed 002:

* NMT: boots (boot-up frame), pre-operational, heartbeat producer (0x1017); PDOs only
  in Operational. SDO server for every object of the EDS.
* CiA 402 state machine (:mod:`drivers.stations.cia402`) stepped by the controlword (SDO
  or RPDO). Quick stop option code 6: a quick stop ramps down at 0x6085 and holds,
  powered, in *Quick stop active* (category 2 stop).
* RPDOs with transmission type 254/255 are applied on reception, those with type 0..240
  on the next SYNC (set-points written ahead, applied together). A set-point is
  (target position 0x607A, profile velocity 0x6081), in motor increments.
* Heartbeat consumer (0x1016): once the controller's first heartbeat arrived, silence
  of the consumer time → EMCY 0x8130, fault reaction (quick-stop ramp), Fault.
* EMCY: 0x8612 set-point beyond the software limits 0x607D (refused, fault);
  0x8611 following error (:meth:`SimStation.inject_following_error`); 0x8210 RPDO too
  short (ignored, no fault); 0x0000 on fault reset.
* TPDO1 (position actual value + statusword): every event-timer period (0x1800:5) and
  at once on a state change or an applied set-point (statusword bit 12 toggles per
  applied set-point: the streaming variant of profile position mode). Reaching a target
  sends nothing by itself: the next event-timer TPDO shows it.
* A frame the station cannot transmit (the wire refuses it) puts its CAN controller
  bus-off: the station leaves the bus and falls silent, as a real node does.

Reception delay (seed 002's λ = σ·i): a set-point received by RPDO takes effect
``reception_delay_s`` after its frame ended on the wire; SYNC-applied set-points take
effect at the SYNC (one frame reaches all stations at once), so the delay only has to be
shorter than the time they were written ahead.

Time: everything runs on the simulated clock (:class:`cell.sim.clock.VirtualClock`). The
station has no thread: frames arrive as clock callbacks and the axis schedules its own
next event (a due set-point, the TPDO timer, the heartbeat consumer's deadline, the end
of a stop ramp). Motion is integrated exactly between events.

Gear and units: the axis lives in motor increments. Joint value (deg; mm for j3) =
increments / (encoder increments per motor rev 0x608F × gear ratio 0x6091 / 360), i.e.
the configured gear ratio is *motor degrees per joint unit*. ``on_position(joint_index,
drive_deg, t_s)`` reports that nominal joint value whenever the axis has moved (at every
event, and whenever :attr:`SimStation.position` is read); the plant applies the true
transmission errors, not the station.
"""
from __future__ import annotations

import functools
import threading
from collections import deque
from typing import Callable

import can
import canopen
from pydantic import BaseModel, ConfigDict, Field

from cell.log import get_logger
from cell.sim.clock import Timer, VirtualClock
from drivers.stations import cia402
from drivers.stations.cia402 import Command, DriveStateMachine, Internal, State
from drivers.stations.config import JOINT_NAMES
from drivers.stations.driver import EDS_PATH
from drivers.stations.sim_bus import VirtualCanBus
from drivers.stations.sim_canopen import DriveListener, DriveNetwork, PdoCodec, pdo_codec

EMCY_LIMIT, EMCY_FOLLOWING, EMCY_HEARTBEAT, EMCY_PDO_LENGTH = 0x8612, 0x8611, 0x8130, 0x8210
#: :attr:`SimStation.applied` keeps at least this many of the latest set-points (at most
#: twice as many): a history for tests and benches, bounded so a long run stays flat
APPLIED_KEEP = 2048

PositionHook = Callable[[int, float, float], None]
#: the states the drive's events test for, as module names (an enum member's lookup on its
#: class costs ten times a global's, and every event asks)
_ENABLED, _REACTING = State.OPERATION_ENABLED, State.FAULT_REACTION_ACTIVE


class SimStationConfig(BaseModel):
    """The twin's own properties (not part of the controller's config)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    joint: str = Field(pattern=r"^j[1-4]$")
    node_id: int = Field(ge=1, le=127)
    reception_delay_s: float = Field(default=0.0, ge=0.0, le=0.5)
    initial_position: float = 0.0  #: joint units (deg; mm for j3) at power-up
    #: the twin's mechanics (encoder increments × gear / 360), used only to place the axis
    #: at ``initial_position`` at first power-up; afterwards the encoder count is the truth
    counts_per_unit: float = Field(default=10_000 / 360, gt=0)


class SimStation:
    """One simulated station. :meth:`start` plugs it into the bus; :meth:`stop` unplugs it.

    :param cfg: node id, joint, reception delay, initial position.
    :param channel, bitrate: the virtual wire to join (normally the controller's).
    :param clock: the simulated clock (the wire's).
    :param on_position: optional hook ``(joint_index, drive_deg, t_s)`` called whenever
        the axis has moved (``Plant.update_drive``).
    :param applied_keep: :attr:`applied` keeps at least this many of the latest set-points
        and at most twice as many (default :data:`APPLIED_KEEP`; a small one lets a test see
        the trimming in a few set-points).
    """

    def __init__(self, cfg: SimStationConfig, *, channel: str = "cell0", bitrate: int = 1_000_000,
                 clock: VirtualClock, on_position: PositionHook | None = None,
                 applied_keep: int = APPLIED_KEEP):
        if applied_keep < 1:
            raise ValueError(f"applied_keep must be at least 1, got {applied_keep}")
        self.cfg = cfg
        self.joint_index = JOINT_NAMES.index(cfg.joint)
        self._bus_args = (channel, bitrate)
        self.clock = clock
        self.on_position = on_position
        self.log = get_logger("stations.sim").bind(joint=cfg.joint, node_id=cfg.node_id)
        self._lock = threading.RLock()
        self._pos = 0.0            # motor increments (float)
        self._pos_set = False
        self._timer: Timer | None = None
        self._wake_at: float | None = None
        self._powered = False
        self._nmt_operational = False   # node.nmt.state == "OPERATIONAL", as of its last change
        self.network: canopen.Network | None = None
        self.node: canopen.LocalNode | None = None
        self.bus_off = False
        #: (t, target_inc, vel_inc_s) as applied, the latest ones (see ``applied_keep``)
        self.applied: list[tuple[float, int, int]] = []
        self.applied_keep = int(applied_keep)     #: see the parameter
        self.applied_count = 0     #: set-points applied since creation

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Power up and join the bus: boot-up frame, pre-operational, heartbeat on."""
        if self._powered:
            return
        self._powered = True
        self.node = canopen.LocalNode(self.cfg.node_id, canopen.import_od(str(EDS_PATH), self.cfg.node_id))
        self._values: dict[tuple[int, int], int] = {}
        self._defaults: dict[tuple[int, int], int] = {}   # the EDS's, as _value first reads them
        self._cpu: float | None = None                    # _counts_per_unit until the next write
        self._event: float | None = None                  # _event_s until the next write
        self.machine = DriveStateMachine()
        self._target = self._pos
        self._speed = 0.0
        self._ramp_v: float | None = None   # signed velocity while ramping down, inc/s
        self._setpoints: deque = deque()     # (apply_t, target, vel) for reception-applied
        self._staged: list[tuple[float, int, int]] = []  # (ready_t, target, vel) waiting for SYNC
        self._ack = False
        self._fault_code = 0
        self._cw_prev = 0
        self._hb_node = None
        self._hb_time_s = 0.0
        self._hb_last: float | None = None
        self._hb_timed_out = False
        self._dirty_tpdo = True
        self._codecs: dict[int, PdoCodec | None] = {}   # id(PDO map) -> its codec, at NMT start
        self._rx_subs: list[tuple[int, Callable]] = []   # (COB-ID, handler) of the RPDOs taken
        self._last_tpdo = -1e9
        self._last_pub: float | None = None
        self._t = self.clock.now()
        self.bus_off = False
        if not self._pos_set:
            self._pos = self.cfg.initial_position * self.cfg.counts_per_unit
            self._target = self._pos
            self._pos_set = True
        self._tpdo1 = self.node.tpdo[1]     # the one TPDO the drive sends (its map is read in place)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        channel, bitrate = self._bus_args
        net = DriveNetwork(VirtualCanBus(channel=channel, bitrate=bitrate, clock=self.clock),
                            self._on_tx_failure)
        net.add_node(self.node)
        sdo = self.node.sdo                 # requests pass the drop hook first (drop_sdo_requests)
        net.unsubscribe(sdo.rx_cobid, sdo.on_request)
        net.subscribe(sdo.rx_cobid, self._on_sdo_request)
        net.bus.attach_listeners([DriveListener(net)])
        net.subscribe(0, self._on_nmt)
        net.subscribe(0x80, self._on_sync)
        # only what this drive subscribes to (its listener skips the rest as well)
        net.bus.wants = net.subscribers.__contains__
        self.network = net
        self.machine.apply(Internal.SELF_TEST_DONE)
        self.node.nmt.send_command(0x81)   # reset node → INITIALISING, boot-up frame
        self.node.nmt.send_command(0x80)   # → PRE-OPERATIONAL, heartbeat producer starts
        self._nmt_operational = self.node.nmt.state == "OPERATIONAL"
        self._tick()

    def stop(self) -> None:
        """Switch off: leave the bus, the drive stops doing anything. Idempotent."""
        with self._lock:
            self._powered = False
            if self._timer is not None:
                self._timer.cancel()
                self._timer, self._wake_at = None, None
        self.unplug()

    def unplug(self) -> None:
        """Cut the station off the bus (a pulled cable, or its CAN controller bus-off): it
        falls silent, while the drive keeps running — its heartbeat consumer then no longer
        hears the controller and faults it (a quick-stop ramp), as a real drive does."""
        with self._lock:
            if self.network is not None:
                net, self.network = self.network, None
                if self.node is not None:
                    self.node.nmt.stop_heartbeat()
                net.disconnect()

    def power_cycle(self) -> None:
        """Switch off and on again: fresh object dictionary, position kept (absolute encoder)."""
        self.stop()
        self.start()

    def _on_tx_failure(self, exc: Exception) -> None:
        if self.bus_off:
            return
        self.log.error("station_bus_off", error=str(exc))
        self.bus_off = True
        self.clock.call_later(0.0, self.unplug)      # not from inside the send that failed

    # ------------------------------------------------------------------ observation
    @property
    def state(self) -> State:
        with self._lock:
            return self.machine.state

    @property
    def position(self) -> float:
        """Drive-side joint position now (deg; mm for j3); reported to ``on_position``."""
        with self._lock:
            self._advance(self.clock.now())
            self._publish(self.clock.now())
            return self._pos / self._counts_per_unit()

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state if self.node else "OFF"

    def drop_sdo_requests(self, n: int) -> None:
        """Fault-injection hook: the next ``n`` SDO requests go unanswered (a drive busy
        booting, a frame lost on a noisy bus)."""
        self._sdo_drops = int(n)

    def _on_sdo_request(self, can_id: int, data, timestamp) -> None:
        if getattr(self, "_sdo_drops", 0) > 0:
            self._sdo_drops -= 1
            return
        self.node.sdo.on_request(can_id, data, timestamp)

    def inject_following_error(self) -> None:
        """Fault-injection hook: the axis lagged beyond its window → EMCY 0x8611, Fault."""
        with self._lock:
            self._fault(EMCY_FOLLOWING, "following error injected")
            self._tick()

    # ------------------------------------------------------------------ object dictionary
    def _value(self, index: int, sub: int = 0) -> int:
        """The object's value as written (SDO or PDO), else its EDS default (0 if none)."""
        key = (index, sub)
        v = self._values.get(key)
        if v is not None:
            return v
        v = self._defaults.get(key)
        if v is None:
            obj = self.node.object_dictionary[index]
            obj = obj[sub] if not isinstance(obj, canopen.objectdictionary.ODVariable) else obj
            v = self._defaults[key] = obj.default if obj.default is not None else 0
        return v

    def _counts_per_unit(self) -> float:
        if self.node is None:
            return 1.0
        if self._cpu is None:
            enc = self._value(0x608F, 1) / max(self._value(0x608F, 2), 1)
            gear = self._value(0x6091, 1) / max(self._value(0x6091, 2), 1)
            self._cpu = enc * gear / 360.0
        return self._cpu

    def _event_s(self) -> float:
        """TPDO1's event timer (0x1800:5), s; until the next write."""
        if self._event is None:
            self._event = self._value(0x1800, 5) / 1000.0
        return self._event

    def _statusword(self) -> int:
        st = self.machine.state
        bits = cia402.SW_SETPOINT_ACK if self._ack else 0
        if st is _ENABLED and self._pos == self._target and self._ramp_v is None:
            bits |= cia402.SW_TARGET_REACHED
        if self._fault_code == EMCY_FOLLOWING:
            bits |= cia402.SW_FOLLOWING_ERROR
        return cia402.encode_statusword(st, bits)

    def _on_read(self, index, subindex, od):
        with self._lock:
            if index == 0x6041:
                return self._statusword()
            if index == 0x6064:
                self._advance(self.clock.now())
                return int(round(self._pos))
            if index == 0x606C:
                return int(round(self._velocity()))
            if index == 0x603F:
                return self._fault_code
            if index == 0x1001:
                return 1 if self._fault_code else 0
        return None

    def _on_write(self, index, subindex, od, data):
        value = od.decode_raw(data)
        with self._lock:
            self._values[(index, subindex)] = value
            self._cpu = self._event = None
            if index == 0x6040:
                self._controlword(value)
            elif index == 0x1016 and subindex == 1:
                self._configure_consumer(value)
            self._tick()

    # ------------------------------------------------------------------ NMT / heartbeat consumer
    def _on_nmt(self, can_id, data, timestamp):
        # canopen's NMT slave took the frame first (it subscribed first): its state is new
        self._nmt_operational = self.node.nmt.state == "OPERATIONAL"
        if len(data) != 2 or data[1] not in (0, self.cfg.node_id):
            return
        if data[0] == 0x01:  # start: (re)read the PDO configuration the master wrote
            self.node.rpdo.read()
            self.node.tpdo.read()
            rpdos = [self.node.rpdo[n] for n in (1, 2, 3)]
            self._codecs = {id(m): pdo_codec(m) for m in rpdos + [self._tpdo1]}
            self._take_rpdos(rpdos)
            with self._lock:
                self._dirty_tpdo = True
        with self._lock:
            self._tick()

    def _configure_consumer(self, value: int) -> None:
        node, time_ms = (value >> 16) & 0x7F, value & 0xFFFF
        if self._hb_node is not None and self.network is not None:
            self.network.unsubscribe(0x700 + self._hb_node, self._on_ctrl_heartbeat)
        self._hb_node = node if time_ms else None
        self._hb_time_s = time_ms / 1000.0
        self._hb_last, self._hb_timed_out = None, False
        if self._hb_node is not None and self.network is not None:
            self.network.subscribe(0x700 + node, self._on_ctrl_heartbeat)

    def _on_ctrl_heartbeat(self, can_id, data, timestamp):
        with self._lock:
            self._hb_last = self.clock.now()
            self._hb_timed_out = False
            self._tick()

    # ------------------------------------------------------------------ PDO / SYNC
    def _operational(self) -> bool:
        return self._nmt_operational and self.network is not None

    def _take_rpdos(self, rpdos: list) -> None:
        """Receive the enabled RPDOs in :meth:`_on_rpdo` itself, in place of canopen's
        ``PdoMap.on_message`` (which ``read`` subscribed): the device side is ours, and
        canopen's receive bookkeeping (a condition notified per frame for threads that
        wait for a PDO) has no reader in a drive."""
        net = self.network
        if net is None:
            return
        for cob_id, handler in self._rx_subs:
            if handler in net.subscribers.get(cob_id, ()):
                net.unsubscribe(cob_id, handler)
        self._rx_subs = []
        for m in rpdos:
            if m.on_message in net.subscribers.get(m.cob_id, ()):
                net.unsubscribe(m.cob_id, m.on_message)
            if m.enabled:
                handler = functools.partial(self._on_rpdo, m)
                net.subscribe(m.cob_id, handler)
                self._rx_subs.append((m.cob_id, handler))

    def _on_rpdo(self, pdo_map, can_id: int, data: bytes, timestamp: float) -> None:
        """One RPDO frame (a network subscriber, see :meth:`_take_rpdos`)."""
        if can_id != pdo_map.cob_id:
            return
        pdo_map.data = data
        if not self._operational():
            return
        if len(data) * 8 < pdo_map.length:
            self._emcy(EMCY_PDO_LENGTH, f"{pdo_map.name}: {len(data)} bytes, mapped {pdo_map.length} bits")
            return
        codec = self._codecs.get(id(pdo_map))
        if codec is None:
            vals = {v.index: v.od.decode_raw(v.get_data()) for v in pdo_map.map if v.length}
        else:
            vals = dict(zip(codec.indices, codec.struct.unpack_from(data)))
        now = self.clock.now()
        with self._lock:
            if 0x6040 in vals:
                self._controlword(int(vals[0x6040]))
            if 0x607A in vals:
                vel = vals.get(0x6081)
                sp = (int(vals[0x607A]), int(vel if vel is not None else self._value(0x6081)))
                if pdo_map.trans_type is not None and pdo_map.trans_type <= 240:
                    self._staged.append((now + self.cfg.reception_delay_s, *sp))
                else:
                    self._setpoints.append((now + self.cfg.reception_delay_s, *sp))
            self._tick()

    def _on_sync(self, can_id, data, timestamp):
        if not self._operational():
            return
        now = self.clock.now()
        with self._lock:
            due = [sp for sp in self._staged if sp[0] <= now]
            self._staged = [sp for sp in self._staged if sp[0] > now]
            self._advance(now)
            for _, target, vel in due:
                self._apply_setpoint(now, target, vel)
            self._tick()

    # ------------------------------------------------------------------ drive logic (lock held)
    def _controlword(self, word: int) -> None:
        prev, self._cw_prev = self._cw_prev, word
        state = self.machine.state
        cmd = cia402.decode_controlword(word, state)
        if cmd is Command.FAULT_RESET and prev & cia402.CW_FAULT_RESET_BIT:
            return  # bit 7 acts on its rising edge only
        if cmd is None:
            return
        self._advance(self.clock.now())
        v_before = self._velocity()
        try:
            new = self.machine.apply(cmd)
        except cia402.IllegalTransition as exc:
            self.log.info("controlword_ignored", controlword=f"0x{word:04X}", reason=str(exc))
            return
        if new is State.QUICK_STOP_ACTIVE:
            self._start_ramp(v_before)
        elif new is State.OPERATION_ENABLED:
            self._target, self._speed, self._ramp_v = self._pos, 0.0, None
            self._setpoints.clear()
            self._staged.clear()
        elif cmd is Command.FAULT_RESET:
            self._fault_code = 0
            self._emcy(0x0000, "fault reset")
        if new is not State.QUICK_STOP_ACTIVE and new is not State.OPERATION_ENABLED:
            self._target, self._speed, self._ramp_v = self._pos, 0.0, None
        self._dirty_tpdo = True

    def _fault(self, emcy_code: int, why: str) -> None:
        if self.machine.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return
        self._advance(self.clock.now())
        v_before = self._velocity()
        self.machine.apply(Internal.FAULT)
        self._fault_code = emcy_code
        self._start_ramp(v_before)
        self._setpoints.clear()
        self._staged.clear()
        self._dirty_tpdo = True
        self._emcy(emcy_code, why)

    def _emcy(self, code: int, why: str) -> None:
        self.log.warning("emcy", code=f"0x{code:04X}", reason=why)
        try:
            if self.network is not None:
                self.node.emcy.send(code, 1 if code else 0)
        except Exception as exc:  # unplugged or bus-off: the frame is lost
            self.log.info("emcy_not_sent", error=repr(exc))

    def _apply_setpoint(self, t: float, target: int, vel: int) -> None:
        if self.machine.state is not _ENABLED:
            return
        lo, hi = self._value(0x607D, 1), self._value(0x607D, 2)
        if not lo <= target <= hi:
            self._fault(EMCY_LIMIT, f"set-point {target} inc outside software limits [{lo}, {hi}]")
            return
        self._publish(t)                      # where the last motion ended (direction changes)
        self._target = float(target)
        self._speed = float(min(abs(vel), self._value(0x607F)))
        self._ack = not self._ack
        self._dirty_tpdo = True
        self.applied.append((t, target, vel))
        self.applied_count += 1
        if len(self.applied) > 2 * self.applied_keep:   # amortised O(1): trim by halves
            del self.applied[:-self.applied_keep]

    def _start_ramp(self, v: float) -> None:
        self._ramp_v = v
        self._setpoints.clear()
        self._staged.clear()

    def _velocity(self) -> float:
        if self._ramp_v is not None:
            return self._ramp_v
        if self._pos == self._target or self.machine.state is not _ENABLED:
            return 0.0
        return self._speed if self._target > self._pos else -self._speed

    def _advance(self, t1: float) -> None:
        """Integrate the axis exactly from ``self._t`` to ``t1``, applying due set-points."""
        while self._setpoints and self._setpoints[0][0] <= t1:
            ta, target, vel = self._setpoints.popleft()
            self._move(max(ta, self._t))
            self._apply_setpoint(max(ta, self._t), target, vel)
        self._move(t1)

    def _move(self, t1: float) -> None:
        dt = t1 - self._t
        if dt <= 0:
            return
        self._t = t1
        if self._ramp_v is not None:
            a = float(max(self._value(0x6085), 1))
            v = self._ramp_v
            t_stop = abs(v) / a
            tau = min(dt, t_stop)
            sign = 1.0 if v > 0 else -1.0
            self._pos += v * tau - sign * 0.5 * a * tau * tau
            self._ramp_v = v - sign * a * tau if t_stop - tau > 1e-12 else 0.0
            if self._ramp_v == 0.0:
                self._target = self._pos
            return
        if self.machine.state is not _ENABLED or self._speed <= 0:
            return
        gap = self._target - self._pos
        step = self._speed * dt
        self._pos = self._target if abs(gap) <= step else self._pos + (step if gap > 0 else -step)

    def _publish(self, t: float) -> None:
        if self._last_pub != self._pos and self.on_position is not None:
            self._last_pub = self._pos
            self.on_position(self.joint_index, self._pos / self._counts_per_unit(), t)

    # ------------------------------------------------------------------ events
    def _tick(self) -> None:
        """Bring the drive up to now, send what is due, schedule the next event (lock held
        or called from a clock callback)."""
        with self._lock:
            now = self.clock.now()
            self._advance(now)
            st = self.machine.state
            if (self._hb_node is not None and self._hb_last is not None and not self._hb_timed_out
                    and now >= self._hb_last + self._hb_time_s):
                self._hb_timed_out = True
                if st not in (State.SWITCH_ON_DISABLED, State.NOT_READY_TO_SWITCH_ON):
                    self._fault(EMCY_HEARTBEAT, f"controller heartbeat (node {self._hb_node}) "
                                f"silent for {self._hb_time_s * 1e3:.0f} ms")
            if self.machine.state is _REACTING and self._ramp_v == 0.0:
                self._ramp_v = None
                self.machine.apply(Internal.REACTION_DONE)
                self._dirty_tpdo = True
            self._publish(now)
            # TPDOs, their event timer included, in Operational only (a send never changes that)
            operational = self._operational()
            event_s = self._event_s() if operational else 0.0
            if operational and (self._dirty_tpdo or (event_s > 0 and now >= self._last_tpdo + event_s)):
                self._dirty_tpdo, self._last_tpdo = False, now
                self._send_tpdo()
            self._schedule(now, event_s)

    def _send_tpdo(self) -> None:
        tx = self._tpdo1
        if not (tx.enabled and tx.map):
            return
        codec = self._codecs.get(id(tx))
        if codec is None:
            for var in tx.map:
                if var.length:
                    var.set_data(var.od.encode_raw(self._live(var.index)))
        else:
            tx.data[:] = codec.struct.pack(*[self._live(i) for i in codec.indices])
        try:
            self.network.send_message(tx.cob_id, tx.data)
        except can.CanError as exc:
            self.log.info("tpdo_not_sent", error=str(exc))

    def _live(self, index: int) -> int:
        """A TPDO-mapped object's value now: position and velocity actual value, statusword;
        0 for any other object."""
        if index == 0x6064:
            return int(round(self._pos))
        if index == 0x6041:
            return self._statusword()
        if index == 0x606C:
            return int(round(self._velocity()))
        return 0

    def _schedule(self, now: float, event_s: float) -> None:
        """Wake at the next due event; ``event_s``: the TPDO event timer's period, 0 when it
        does not run (off, or not Operational)."""
        if not self._powered:
            return
        t = self._setpoints[0][0] if self._setpoints else None      # the earliest due, or None
        if event_s > 0:
            due = self._last_tpdo + event_s
            if t is None or due < t:
                t = due
        if self._hb_node is not None and self._hb_last is not None and not self._hb_timed_out:
            due = self._hb_last + self._hb_time_s
            if t is None or due < t:
                t = due
        if self._ramp_v:
            due = self._t + abs(self._ramp_v) / float(max(self._value(0x6085), 1))
            if t is None or due < t:
                t = due
        if t is not None and now > t:
            t = now
        if t == self._wake_at:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._wake_at = t
        self._timer = self.clock.call_at(t, self._on_timer) if t is not None else None

    def _on_timer(self) -> None:
        self._timer, self._wake_at = None, None
        self._tick()


class SimStationSet:
    """The four twins of one cell, built from the controller's
    :class:`~drivers.stations.config.StationsConfig` (same wire, node ids and order) plus
    per-station twin properties.

    :param stations_cfg: the controller's stations config.
    :param reception_delays_s: per station in *bus order* (seed 002: σ·1, σ·2, ...);
        default zeros.
    :param initial_positions: per joint j1..j4 (joint units); default zeros.
    :param clock: the simulated clock.
    """

    def __init__(self, stations_cfg, reception_delays_s=None, initial_positions=None, *,
                 clock: VirtualClock, on_position: PositionHook | None = None):
        n = len(stations_cfg.stations)
        delays = list(reception_delays_s) if reception_delays_s is not None else [0.0] * n
        init = list(initial_positions) if initial_positions is not None else [0.0] * 4
        if len(delays) != n or len(init) != 4:
            raise ValueError(f"reception_delays_s needs {n} values (bus order), initial_positions 4 "
                             f"(j1..j4); got {len(delays)} and {len(init)}")
        self.clock = clock
        self.stations = [
            SimStation(SimStationConfig(joint=s.joint, node_id=s.node_id, reception_delay_s=d,
                                        initial_position=init[JOINT_NAMES.index(s.joint)],
                                        counts_per_unit=s.counts_per_unit),
                       channel=stations_cfg.channel, bitrate=stations_cfg.bitrate, clock=clock,
                       on_position=on_position)
            for s, d in zip(stations_cfg.stations, delays)]

    def by_joint(self, joint: str) -> SimStation:
        return next(s for s in self.stations if s.cfg.joint == joint)

    def positions(self) -> list[float]:
        """Drive positions now, per joint j1..j4 (each reported to ``on_position``)."""
        out = [0.0] * 4
        for s in self.stations:
            out[s.joint_index] = s.position
        return out

    def start(self) -> "SimStationSet":
        for s in self.stations:
            s.start()
        return self

    def stop(self) -> None:
        for s in self.stations:
            s.stop()
