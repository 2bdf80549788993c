"""The simulated CAN wire (drivers.stations.sim_bus) on the discrete-event clock: slot timing from
each frame's exact bits, FIFO order, push delivery to listeners and pull-mode ``recv`` in
clock time, frames the wire refuses, and what a refused transmit does to the controller
(SEND_FAILED) and to a station (bus-off → the controller loses its heartbeat).

Every time below is simulated and exact: the assertions hold to 1e-12 s (float rounding
of sums of bit times), whatever the host's load."""
from __future__ import annotations

import threading

import can
import numpy as np
import pytest

from cell.clock import ClockError, MonotonicClock
from cell.errors import ConfigError
from cell.kinematics import Scara
from cell.sim.clock import VirtualClock
from drivers.stations.bus import frame_bits, open_bus
from drivers.stations.cia402 import State
from drivers.stations.config import JOINT_NAMES, StationConfig, StationsConfig
from drivers.stations.driver import JointStations
from drivers.stations.faults import FaultCode, StationFaultError
from drivers.stations.sim import SimStationSet
from drivers.stations.sim_bus import VirtualCanBus, VirtualWire, wire_stats
from tests.drivers.conftest import clock_wait_for, drain, unique_channel

EXACT = 1e-12


def _msg(aid=0x201, data=bytes(8), **kw):
    return can.Message(arbitration_id=aid, data=data, is_extended_id=kw.pop("is_extended_id", False), **kw)


class _Recorder(can.Listener):
    def __init__(self, clock):
        self.clock = clock
        self.got: list[tuple[float, float, int, str]] = []   # (clock now, stamp, id, thread)

    def on_message_received(self, msg):
        self.got.append((self.clock.now(), msg.timestamp, msg.arbitration_id, threading.current_thread().name))


@pytest.fixture
def wire(vclock):
    """Factory of buses on one fresh channel of ``vclock``; all shut down afterwards and the
    wire must be gone then."""
    ch = unique_channel("w")
    opened = []

    def _open(**kw):
        bus = open_bus("virtual", ch, kw.pop("bitrate", 1_000_000), clock=vclock, **kw)
        opened.append(bus)
        return bus

    _open.channel = ch
    yield _open
    for bus in opened:
        bus.shutdown()
    assert wire_stats(ch) is None, "a bus was left on the wire"


# ------------------------------------------------------------------ slot timing
def test_one_frame_occupies_its_bits_over_the_bitrate(vclock, wire):
    a, b = wire(), wire()
    msg = _msg(0x181, bytes.fromhex("0102030405060708"))
    t0 = vclock.now()
    a.send(msg)
    assert a.last_tx_timestamp == pytest.approx(t0 + frame_bits(msg) / 1e6, abs=EXACT)
    got = b.recv(1.0)                       # pull mode: waits in clock time
    assert got.arbitration_id == 0x181 and bytes(got.data) == bytes(msg.data)
    assert got.timestamp == pytest.approx(t0 + frame_bits(msg) / 1e6, abs=EXACT)
    assert vclock.now() == got.timestamp    # recv returned exactly at the end of the slot
    assert a.recv(0) is None                # a sender does not hear itself


@pytest.mark.parametrize("bitrate", [1_000_000, 500_000, 125_000])
def test_n_frames_take_exactly_the_sum_of_their_bit_times(vclock, wire, bitrate):
    a, b = wire(bitrate=bitrate, tx_queue=64), wire(bitrate=bitrate)
    # different payloads and identifiers: different stuff bits, different slot lengths
    frames = [_msg(0x100 + i, bytes([i * 37 % 256] * (i % 9))) for i in range(40)]
    frames += [_msg(0x1ABCDE0 + i, bytes(8), is_extended_id=True) for i in range(5)]
    frames += [can.Message(arbitration_id=0x702, is_remote_frame=True, dlc=1, is_extended_id=False)]
    bits = [frame_bits(m) for m in frames]
    assert len(set(bits)) > 5
    t0 = vclock.now()
    for m in frames:
        a.send(m)
    stamps = [b.recv(1.0).timestamp for _ in frames]
    expected = t0 + np.cumsum(bits) / bitrate
    np.testing.assert_allclose(stamps, expected, rtol=0, atol=EXACT)
    assert wire_stats(wire.channel) == (len(frames), sum(bits))
    assert stamps[-1] - t0 == pytest.approx(sum(bits) / bitrate, abs=EXACT)


def test_a_frame_waits_for_a_busy_wire_and_not_for_an_idle_one(vclock, wire):
    a, b = wire(), wire()
    m1, m2 = _msg(0x201), _msg(0x202, b"\x01")
    t0 = vclock.now()
    a.send(m1)
    vclock.sleep(20e-6)                     # m1 still on the wire
    b.send(m2)
    assert b.last_tx_timestamp == pytest.approx(t0 + (frame_bits(m1) + frame_bits(m2)) / 1e6, abs=EXACT)
    vclock.sleep(0.01)                      # idle wire: the next frame starts at once
    t1 = vclock.now()
    a.send(m1)
    assert a.last_tx_timestamp == pytest.approx(t1 + frame_bits(m1) / 1e6, abs=EXACT)


def test_fifo_in_the_order_send_was_called_not_by_identifier(vclock, wire):
    a, b, rx = wire(), wire(), wire()
    order = [(a, 0x700), (b, 0x080), (a, 0x010), (b, 0x7FF), (b, 0x001), (a, 0x400)]
    for bus, aid in order:
        bus.send(_msg(aid, b"\x00"))
    got = [rx.recv(1.0) for _ in order]
    assert [m.arbitration_id for m in got] == [aid for _, aid in order]
    assert np.all(np.diff([m.timestamp for m in got]) > 0)


def test_listeners_get_frames_from_the_clock_at_the_end_of_the_slot(vclock, wire):
    tx, pushed, pulled = wire(), wire(), wire()
    rec = _Recorder(vclock)

    class Broken(can.Listener):
        def on_message_received(self, msg):
            raise RuntimeError("listener bug")

    pushed.attach_listeners([Broken(), rec])      # a failing listener does not stop the others
    frames = [_msg(0x181 + i, bytes(i)) for i in range(3)]
    for m in frames:
        tx.send(m)
    vclock.sleep(0.001)
    assert [g[2] for g in rec.got] == [0x181, 0x182, 0x183]
    for now, stamp, _, thread in rec.got:
        assert now == stamp                       # delivered exactly at the slot's end
        # run by the clock's agenda in the thread that waited for it: no notifier thread
        assert thread == threading.current_thread().name
    assert pushed.recv(0) is None                 # pushed frames are not queued as well
    assert [m.timestamp for m in drain(pulled)] == [g[1] for g in rec.got]


def test_send_own_delivers_the_frame_itself_and_send_a_copy(vclock, wire):
    tx, rx = wire(), wire()
    rec = []
    rx.attach_listeners([type("L", (can.Listener,), {"on_message_received": lambda self, m: rec.append(m)})()])
    kept, own = _msg(0x181, b"\x01"), _msg(0x182, b"\x02")
    tx.send(kept)
    tx.send_own(own)
    vclock.sleep(0.001)
    assert rec[0] is not kept and kept.timestamp == 0.0     # the sender's frame untouched
    assert rec[1] is own and own.timestamp == tx.last_tx_timestamp and own.is_rx
    with pytest.raises(can.CanOperationError, match="9 data bytes"):   # the same refusals
        tx.send_own(_msg(0x183, bytes(9)))


def test_a_frame_carries_its_data_as_sent_when_the_buffer_changes_before_its_slot_ends(vclock, wire):
    """python-can's Message shares a bytearray it is given (so does its copy); a drive's PDO
    buffer changes with its next frame, which may go before this one's slot ends."""
    tx, rx = wire(), wire()
    rec = []
    rx.attach_listeners([type("L", (can.Listener,), {"on_message_received": lambda self, m: rec.append(m)})()])
    buf = bytearray(b"\x01\x02")
    tx.send(can.Message(arbitration_id=0x181, data=buf, is_extended_id=False))
    buf[:] = b"\x03\x04"
    tx.send_own(can.Message(arbitration_id=0x181, data=buf, is_extended_id=False))
    buf[:] = b"\x05\x06"                         # both still on the wire
    vclock.sleep(0.001)
    assert [bytes(m.data) for m in rec] == [b"\x01\x02", b"\x03\x04"]


def test_a_bus_gets_the_identifiers_it_wants_asked_again_on_reroute(vclock, wire):
    from drivers.stations.sim_canopen import DriveNetwork
    tx, rx, every = wire(), wire(), wire()
    wanted = {0x181}
    rx.wants = wanted.__contains__

    def sent(*ids):
        for i in ids:
            tx.send(_msg(i))
        vclock.sleep(0.001)
        assert [m.arbitration_id for m in drain(every)] == list(ids)   # wants None: every frame
        return [m.arbitration_id for m in drain(rx)]
    assert sent(0x181, 0x182) == [0x181]
    wanted.add(0x182)
    rx.reroute()                                 # its owner says the answers changed
    assert sent(0x181, 0x182) == [0x181, 0x182]
    net = DriveNetwork(rx, lambda exc: None)     # a drive's network: its subscriptions reroute
    rx.wants = net.subscribers.__contains__
    assert sent(0x183) == []
    net.subscribe(0x183, lambda *a: None)
    assert sent(0x183) == [0x183]
    net.unsubscribe(0x183)
    assert sent(0x183) == []


def test_the_bits_a_wire_remembers_are_frame_bits(vclock, wire):
    tx, _ = wire(tx_queue=64), wire()
    w = tx._wire
    frames = [_msg(0x181, b"\x01\x02"), _msg(0x181, b"\x01\x02"), _msg(0x181, b"\x01\x03"),
              _msg(0x182, b"\x01\x02"), _msg(0x181, b"\x01\x02\x00"),
              _msg(0x181, b"\x01\x02", is_extended_id=True), _msg(0x181, is_remote_frame=True, dlc=2)]
    for m in frames:
        assert w._frame_bits(m) == frame_bits(m)
    assert len(w._bits) == 4                                 # standard data frames only, each once
    w.BITS_KEEP = 4
    assert w._frame_bits(_msg(0x183, b"")) == frame_bits(_msg(0x183, b"")) and len(w._bits) == 1


def test_pull_mode_recv_waits_in_clock_time_for_a_frame(vclock, wire):
    tx, rx = wire(), wire()
    vclock.call_later(0.1, tx.send, _msg(0x123, b"\x42"))        # sent later, by the clock itself
    t1 = vclock.now()
    got = rx.recv(1.0)
    assert got.timestamp == pytest.approx(t1 + 0.1 + frame_bits(got) / 1e6, abs=EXACT)
    assert vclock.now() == got.timestamp          # returned at the end of the frame's slot
    vclock.call_later(0.2, tx.send, _msg(0x124, b"\x43"))
    got = rx.recv(None)                            # no time-out: waits as long as it takes
    assert got.arbitration_id == 0x124 and vclock.now() == got.timestamp


def test_pull_mode_recv_times_out_in_clock_time(vclock, wire, monkeypatch):
    _, rx = wire(), wire()
    # python-can's recv loop reads the wall clock; make that wall clock run 30 ms per reading,
    # so the outcome does not depend on how fast the host is
    readings = iter(np.arange(0.0, 10.0, 0.03))
    monkeypatch.setattr("can.bus.time", lambda: float(next(readings)))
    t0 = vclock.now()
    assert rx.recv(0.05) is None
    assert vclock.now() == pytest.approx(t0 + 0.05, abs=EXACT)   # the whole time-out, in clock time


def test_pull_mode_recv_outside_the_clock_is_an_error(vclock, wire):
    rx = wire()
    errors = []

    def outsider():
        try:
            rx.recv(0.01)
        except ClockError as exc:
            errors.append(str(exc))

    th = threading.Thread(target=outsider, name="outsider")
    th.start()
    th.join(5.0)
    assert errors and "does not keep this clock's time" in errors[0]
    assert rx.recv(0) is None                     # a time-out of 0 never waits: allowed anywhere


def test_send_periodic_runs_on_the_clock_without_drift(vclock, wire):
    tx, rx = wire(), wire()
    msg = _msg(0x77F, b"\x05")
    t0 = vclock.now()
    task = tx.send_periodic(msg, 0.02)
    vclock.sleep(0.1 + 1e-9)
    task.stop()
    vclock.sleep(0.1)
    stamps = [m.timestamp for m in drain(rx)]
    np.testing.assert_allclose(stamps, t0 + 0.02 * np.arange(6) + frame_bits(msg) / 1e6, rtol=0, atol=1e-9)


# ------------------------------------------------------------------ refused frames
@pytest.mark.parametrize("msg, reason", [
    (can.Message(arbitration_id=0x201, data=bytes(8), is_fd=True, is_extended_id=False), "CAN FD frames"),
    (can.Message(arbitration_id=0x201, data=bytes(9), is_extended_id=False), "9 data bytes"),
    (can.Message(arbitration_id=0x800, data=b"\x01", is_extended_id=False), "identifier beyond 11 bits"),
    (can.Message(arbitration_id=0x20000000, data=b"\x01", is_extended_id=True), "identifier beyond 29 bits"),
])
def test_frames_the_wire_cannot_carry_are_refused(vclock, wire, msg, reason):
    tx, rx = wire(), wire()
    with pytest.raises(can.CanOperationError, match=f"frame 0x{msg.arbitration_id:X} not sent: {reason}"):
        tx.send(msg)
    vclock.sleep(0.001)
    assert rx.recv(0) is None and wire_stats(wire.channel) == (0, 0)   # nothing went out
    tx.send(_msg())                                                    # the bus still works
    assert rx.recv(0.001) is not None


def test_transmit_queue_overflow_is_refused_until_the_wire_drains(vclock, wire):
    tx, rx = wire(tx_queue=3), wire()
    for i in range(3):
        tx.send(_msg(0x200 + i))
    with pytest.raises(can.CanOperationError, match=r"0x2FF not sent: transmit queue full \(3 frames waiting"):
        tx.send(_msg(0x2FF))
    first_out = tx.last_tx_timestamp - 2 * frame_bits(_msg()) / 1e6
    vclock.sleep_until(first_out)              # one frame delivered: one place free again
    tx.send(_msg(0x203))
    with pytest.raises(can.CanOperationError, match="transmit queue full"):
        tx.send(_msg(0x2FF))
    vclock.sleep(0.01)
    assert [m.arbitration_id for m in drain(rx)] == [0x200, 0x201, 0x202, 0x203]


def test_shutdown_from_the_clock_lets_queued_frames_out(vclock, wire):
    rx = wire()
    ch = wire.channel
    tx = open_bus("virtual", ch, clock=vclock)
    for i in range(4):
        tx.send(_msg(0x300 + i))
    end = tx.last_tx_timestamp
    tx.shutdown()                                # a participant: waits for the wire
    assert vclock.now() == end
    assert [m.arbitration_id for m in drain(rx)] == [0x300, 0x301, 0x302, 0x303]


# ------------------------------------------------------------------ configuration
def test_config_errors(vclock):
    ch = unique_channel("w")
    for clock in (None, MonotonicClock()):
        with pytest.raises(ConfigError, match="runs on the simulated clock; got"):
            open_bus("virtual", ch, clock=clock)
        with pytest.raises(ConfigError, match="runs on the simulated clock"):
            VirtualCanBus(channel=ch, clock=clock)
    with pytest.raises(ConfigError, match="bitrate = 2000000"):
        open_bus("virtual", ch, 2_000_000, clock=vclock)
    with pytest.raises(ConfigError, match="tx_queue = 0"):
        open_bus("virtual", ch, clock=vclock, tx_queue=0)
    with pytest.raises(ConfigError, match="'nosuchcan' is not a known CAN interface"):
        open_bus("nosuchcan", "x")
    assert wire_stats(ch) is None                # nothing refused joined the wire
    a = open_bus("virtual", ch, 1_000_000, clock=vclock)
    other = VirtualClock()
    try:
        with pytest.raises(ConfigError, match="runs at 1000000 bit/s; cannot open it at 500000"):
            open_bus("virtual", ch, 500_000, clock=vclock)
        with pytest.raises(ConfigError, match="already on another clock"):
            open_bus("virtual", ch, 1_000_000, clock=other)
        assert isinstance(a._wire, VirtualWire) and len(a._wire.buses) == 1
    finally:
        a.shutdown()
        other.close()
    assert wire_stats(ch) is None                # the last bus left: the wire is gone ...
    b = open_bus("virtual", ch, 500_000, clock=vclock)   # ... so the channel is free again
    b.shutdown()


# ------------------------------------------------------------------ refused transmits in the cell
ROBOT = Scara.preset("seed002")


class _Cell:
    """A started cell: ``cfg``, ``sims``, ``js``, a ``sniff`` bus opened before anything
    else, and ``t_armed`` (the clock time ``start()`` returned: the watchdog's arming)."""


@pytest.fixture
def cell(vclock):
    """Four simulated stations and the driver on one wire of ``vclock`` (started)."""
    made = []

    def _make(**over) -> _Cell:
        c = _Cell()
        c.cfg = StationsConfig(channel=unique_channel("c"), heartbeat_ms=50, heartbeat_tolerance=1.5,
                               controller_heartbeat_ms=20, consumer_timeout_ms=60, tpdo_event_ms=5,
                               stations=tuple(StationConfig(joint=j, node_id=i + 1, limits=tuple(ROBOT.g.limits[i]))
                                              for i, j in enumerate(JOINT_NAMES)), **over)
        c.sniff = open_bus("virtual", c.cfg.channel, c.cfg.bitrate, clock=vclock)
        made.append(c.sniff)
        c.sims = SimStationSet(c.cfg, None, (0.0, 30.0, 50.0, 0.0), clock=vclock).start()
        made.append(c.sims)
        c.js = JointStations.from_config(c.cfg, clock=vclock)
        made.append(c.js)
        c.js.start()
        c.t_armed = vclock.now()
        return c

    yield _make
    for obj in reversed(made):
        (obj.shutdown if isinstance(obj, (JointStations, can.BusABC)) else obj.stop)()
        if isinstance(obj, can.BusABC):
            assert wire_stats(obj._wire.channel) is None, "a bus was left on the wire"


def _from_node(frames, node):
    """Frames a station sent (EMCY, TPDO1, SDO answer, heartbeat)."""
    return [m for m in frames if m.arbitration_id in (0x080 + node, 0x180 + node, 0x580 + node, 0x700 + node)]


def test_driver_send_refused_latches_send_failed(vclock, cell):
    js = cell().js
    latched = []
    js.latch.on_latch(lambda r: latched.append(vclock.now()))
    t = vclock.now()
    js.move_to([10, 40, 60, 10], 100)            # 4 frames in the transmit queue
    js.move_to([11, 41, 61, 11], 100)            # 8: the queue is full, the wire has not moved
    with pytest.raises(StationFaultError, match=r"move_to refused: .*SEND_FAILED \(12\).*"
                                                r"frame 0x201 not sent: .*transmit queue full") as ei:
        js.move_to([12, 42, 62, 12], 100)
    assert ei.value.record.code is FaultCode.SEND_FAILED and int(js.fault_code) == 12
    assert latched == [t]                        # latched at once, at the refused send
    with pytest.raises(StationFaultError, match="SEND_FAILED"):
        js.move_to([0, 30, 50, 0], 100)          # and every command is refused from now on
    vclock.sleep(0.2)
    assert js.fault_code is FaultCode.SEND_FAILED and len(latched) == 1
    js.reset()                                   # the cause is gone once the queue drained
    assert js.fault is None and set(js.drive_states().values()) == {State.OPERATION_ENABLED}


def test_stations_are_quick_stopped_after_send_failed(vclock, cell):
    c = cell()
    sims, js = c.sims, c.js
    js.move_to([40, 60, 80, 40], 100)
    js.move_to([41, 61, 81, 41], 100)
    with pytest.raises(StationFaultError):
        js.move_to([42, 62, 82, 42], 100)
    vclock.sleep(0.2)
    assert {s.state for s in sims.stations} <= {State.QUICK_STOP_ACTIVE, State.FAULT}


def test_station_transmit_refused_goes_bus_off_and_heartbeat_is_lost(vclock, cell):
    c = cell(unknown_frames="log")               # the flood below is not a station's frame
    js, j2 = c.js, c.sims.by_joint("j2")
    latched = []
    js.latch.on_latch(lambda r: latched.append((vclock.now(), r)))
    flood = open_bus("virtual", c.cfg.channel, c.cfg.bitrate, clock=vclock, tx_queue=32)
    try:
        # 12 SDO uploads of 0x1000 at once: j2 answers each as it arrives, but its answers
        # queue behind the rest of the flood until its own transmit queue (8) overflows
        for _ in range(12):
            flood.send(_msg(0x602, bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])))
        t_off = clock_wait_for(vclock, lambda: j2.bus_off, timeout=0.01, what="j2 bus-off", step=10e-6)
        clock_wait_for(vclock, lambda: js.fault is not None, timeout=0.5, what="fault latched")
        vclock.sleep(0.05)
    finally:
        flood.shutdown()
    frames = drain(c.sniff)
    assert j2.bus_off and j2.network is None                     # it left the bus
    answers = [m for m in frames if m.arbitration_id == 0x582 and m.timestamp > c.t_armed]
    assert 0 < len(answers) < 12                                  # it answered until refused
    drained = t_off + 0.005                                       # flood and queued answers are out
    assert [m for m in _from_node(frames, 2) if m.timestamp > drained] == []        # silent since
    for n in (1, 3, 4):                                           # while the others keep reporting
        assert len([m for m in _from_node(frames, n) if m.timestamp > drained]) >= 10
    # the controller latches HEARTBEAT_LOST within [timeout, timeout + one watchdog period]
    # of the last heartbeat it heard from j2 (or of arming, if none came since)
    last_beat = max([c.t_armed] + [m.timestamp for m in frames if m.arbitration_id == 0x702])
    t_fault, rec = latched[0]
    assert rec.code is FaultCode.HEARTBEAT_LOST and rec.joint == "j2" and rec.node_id == 2
    timeout, period = 1.5 * 0.05, min(0.02, 50 / 4000)
    assert last_beat + timeout - 1e-9 < t_fault <= last_beat + timeout + period + 1e-9
    with pytest.raises(StationFaultError, match=r"still silent: j2 \(node 2\)"):
        js.reset()
    j2.power_cycle()
    assert not j2.bus_off
    clock_wait_for(vclock, lambda: not js.watchdog.silent(), what="j2 heard again")
    js.reset()
    assert js.fault is None and set(js.drive_states().values()) == {State.OPERATION_ENABLED}
