"""Unit tests: CiA 402 state machine, wire timing, bus factory, config, bus monitor.
Real frames (python-can Message), real buses; no mocks."""
from __future__ import annotations

import threading
import time
import uuid

import can
import pytest

from cell.errors import CellError, ConfigError
from drivers.stations import cia402
from drivers.stations.bus import frame_bits, frame_time_s, open_bus, wire_stats
from drivers.stations.cia402 import Command, DriveStateMachine, IllegalTransition, Internal, State
from drivers.stations.config import StationsConfig
from drivers.stations.driver import JointStations
from drivers.stations.faults import (BusMonitor, Expected, FaultCode, FaultLatch, FaultRecord,
                                     HeartbeatWatchdog, StationFaultError)

# ------------------------------------------------------------------ CiA 402
# statuswords from CiA 402-2 table 30 (state bits only)
@pytest.mark.parametrize("word, state", [
    (0x0000, State.NOT_READY_TO_SWITCH_ON), (0x0040, State.SWITCH_ON_DISABLED),
    (0x0021, State.READY_TO_SWITCH_ON), (0x0023, State.SWITCHED_ON),
    (0x0027, State.OPERATION_ENABLED), (0x0007, State.QUICK_STOP_ACTIVE),
    (0x000F, State.FAULT_REACTION_ACTIVE), (0x0008, State.FAULT),
    (0x1637, State.OPERATION_ENABLED),  # + voltage, remote, target reached, ack
])
def test_statusword_decodes(word, state):
    assert cia402.decode_statusword(word) is state


@pytest.mark.parametrize("state", list(State))
def test_statusword_round_trip(state):
    assert cia402.decode_statusword(cia402.encode_statusword(state, cia402.SW_TARGET_REACHED)) is state


@pytest.mark.parametrize("bad", [-1, 0x10000, 1.5, "0x27", True])
def test_statusword_bad_input(bad):
    with pytest.raises(IllegalTransition, match="not a 16-bit"):
        cia402.decode_statusword(bad)


def test_enable_sequence_and_quick_stop():
    m = DriveStateMachine()
    m.apply(Internal.SELF_TEST_DONE)
    for cmd in cia402.path_to(m.state, State.OPERATION_ENABLED):
        m.apply(cmd)
    assert m.enabled
    assert m.apply(Command.QUICK_STOP) is State.QUICK_STOP_ACTIVE
    assert m.apply(Command.ENABLE_OPERATION) is State.OPERATION_ENABLED  # transition 16


def test_illegal_transition_raises_and_keeps_state():
    m = DriveStateMachine(State.SWITCH_ON_DISABLED)
    with pytest.raises(IllegalTransition, match="ENABLE_OPERATION is not allowed in state 'Switch on disabled'"):
        m.apply(Command.ENABLE_OPERATION)
    assert m.state is State.SWITCH_ON_DISABLED
    m = DriveStateMachine(State.FAULT)
    with pytest.raises(IllegalTransition):
        m.apply(Internal.FAULT)
    assert m.apply(Command.FAULT_RESET) is State.SWITCH_ON_DISABLED


def test_paths():
    assert cia402.path_to(State.SWITCH_ON_DISABLED, State.OPERATION_ENABLED) == [
        Command.SHUTDOWN, Command.SWITCH_ON, Command.ENABLE_OPERATION]
    assert cia402.path_to(State.FAULT, State.OPERATION_ENABLED)[0] is Command.FAULT_RESET
    assert cia402.path_to(State.FAULT, State.FAULT) == []
    with pytest.raises(IllegalTransition, match="no command sequence"):
        cia402.path_to(State.FAULT_REACTION_ACTIVE, State.OPERATION_ENABLED)


@pytest.mark.parametrize("word, state, cmd", [
    (0x06, State.SWITCH_ON_DISABLED, Command.SHUTDOWN), (0x07, State.READY_TO_SWITCH_ON, Command.SWITCH_ON),
    (0x07, State.OPERATION_ENABLED, Command.DISABLE_OPERATION), (0x0F, State.SWITCHED_ON, Command.ENABLE_OPERATION),
    (0x02, State.OPERATION_ENABLED, Command.QUICK_STOP), (0x00, State.OPERATION_ENABLED, Command.DISABLE_VOLTAGE),
    (0x80, State.FAULT, Command.FAULT_RESET), (0x80, State.OPERATION_ENABLED, None),
])
def test_controlword_decodes(word, state, cmd):
    assert cia402.decode_controlword(word, state) is cmd


# ------------------------------------------------------------------ wire timing
def test_frame_bits_bounds_and_stuffing():
    worst = frame_bits(can.Message(arbitration_id=0x000, data=bytes(8), is_extended_id=False))
    for data in (bytes(8), b"\xff" * 8, b"\x55" * 8, b"\x0f" * 8):
        for aid in (0x000, 0x181, 0x7FF):
            b = frame_bits(can.Message(arbitration_id=aid, data=data, is_extended_id=False))
            assert 111 <= b <= 135
    assert worst > 111   # long runs of zeros get stuff bits
    assert frame_bits(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False)) >= 47 + 8
    assert frame_bits(can.Message(arbitration_id=0x1FFFFFFF, data=bytes(8), is_extended_id=True)) >= 131
    assert frame_time_s(can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False), 500_000) \
        == pytest.approx(2 * frame_time_s(can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False), 1_000_000))
    with pytest.raises(ValueError, match="CAN FD"):
        frame_bits(can.Message(arbitration_id=1, data=bytes(12), is_fd=True))


def test_shared_wire_limits_two_senders_together():
    ch = f"u-{uuid.uuid4().hex[:8]}"
    a, b, rx = open_bus("virtual", ch), open_bus("virtual", ch), open_bus("virtual", ch)
    try:
        msg = can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=False)
        ts = threading.Thread(target=lambda: [a.send(msg) for _ in range(100)])
        ts.start()
        for _ in range(100):
            b.send(msg)
        ts.join()
        stamps = sorted(rx.recv(2.0).timestamp for _ in range(200))
        assert (stamps[-1] - stamps[0]) >= 199 * frame_time_s(msg, 1_000_000) - 1e-6
        assert wire_stats(ch)[0] == 200
    finally:
        for bus in (a, b, rx):
            bus.shutdown()
    assert wire_stats(ch) is None


def test_bus_factory_errors():
    with pytest.raises(ConfigError, match="'nosuchcan' is not a known CAN interface"):
        open_bus("nosuchcan", "x")
    with pytest.raises(ConfigError, match="bitrate = 2000000"):
        open_bus("virtual", "x", 2_000_000)
    with pytest.raises(ConfigError, match="only applies to the virtual"):
        open_bus("socketcan", "can0", rate_limited=False)
    ch = f"u-{uuid.uuid4().hex[:8]}"
    a = open_bus("virtual", ch, 1_000_000)
    try:
        with pytest.raises(ConfigError, match="runs at 1000000 bit/s"):
            open_bus("virtual", ch, 500_000)
    finally:
        a.shutdown()


def test_unlimited_virtual_bus_is_separate_and_fast():
    ch = f"u-{uuid.uuid4().hex[:8]}"
    a, b = open_bus("virtual", ch, rate_limited=False), open_bus("virtual", ch, rate_limited=False)
    try:
        msg = can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=False)
        for _ in range(50):
            a.send(msg)
        assert sum(1 for _ in range(50) if b.recv(1.0) is not None) == 50
    finally:
        a.shutdown()
        b.shutdown()


# ------------------------------------------------------------------ config
@pytest.mark.parametrize("data, match", [
    ({"bogus": 1}, r"stations.bogus: Extra inputs"),
    ({"bitrate": 5}, r"stations.bitrate"),
    ({"stations": [{"joint": "j1", "node_id": 1}]}, r"each of \('j1', 'j2', 'j3', 'j4'\)"),
    ({"stations": [{"joint": j, "node_id": 1} for j in ("j1", "j2", "j3", "j4")]}, "node ids must be unique"),
    ({"controller_node_id": 2}, "also a station's node id"),
    ({"consumer_timeout_ms": 40, "controller_heartbeat_ms": 50}, "must exceed"),
    ({"delays_s": [0.001]}, "one delay per station"),
    ({"delays_s": [0.001, 0.002, 0.003, -1]}, r"delays_s for j4 = -1"),
    ({"stations": [{"joint": "j1", "node_id": 1, "limits": [5, 1]}] + [{"joint": j, "node_id": i}
      for i, j in ((2, "j2"), (3, "j3"), (4, "j4"))]}, "low 5.0 must be below high 1.0"),
    ({"stations": [{"joint": "j1", "node_id": 1, "gear_ratio": 0}]}, r"stations.stations.0.gear_ratio"),
])
def test_config_errors_name_the_field(data, match):
    with pytest.raises(ConfigError, match=match):
        JointStations.from_config(data)


def test_config_default_is_seed002_order():
    cfg = StationsConfig()
    assert [s.node_id for s in cfg.stations] == [1, 2, 3, 4]
    assert cfg.station("j3").joint_limits == (0, 100)


# ------------------------------------------------------------------ bus monitor, latch, watchdog
def _monitor(unknown="fault"):
    latch = FaultLatch()
    exp = {0x701: Expected("heartbeat", "j1", 1, frozenset({1})),
           0x181: Expected("tpdo", "j1", 1, frozenset({6}))}
    beats = []
    return latch, BusMonitor(latch, exp, unknown, lambda n, s: beats.append((n, s))), beats


@pytest.mark.parametrize("msg, code", [
    (can.Message(is_error_frame=True), FaultCode.BUS_ERROR_FRAME),
    (can.Message(arbitration_id=0x181, data=b"\x00" * 7, is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x701, data=b"", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x555, data=b"\x01", is_extended_id=False), FaultCode.UNEXPECTED_FRAME),
    (can.Message(arbitration_id=0x701, is_remote_frame=True, is_extended_id=False), FaultCode.UNEXPECTED_FRAME),
    (can.Message(arbitration_id=0x181, data=bytes(6), is_extended_id=True), FaultCode.UNEXPECTED_FRAME),
])
def test_monitor_latches_garbage(msg, code):
    latch, mon, beats = _monitor()
    mon.on_message_received(msg)
    assert latch.record.code is code and beats == []


def test_monitor_accepts_good_frames_and_can_log_unknown():
    latch, mon, beats = _monitor("log")
    mon.on_message_received(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
    mon.on_message_received(can.Message(arbitration_id=0x181, data=bytes(6), is_extended_id=False))
    mon.on_message_received(can.Message(arbitration_id=0x555, data=b"\x01", is_extended_id=False))
    assert latch.record is None and beats == [(1, 5)] and mon.rejected == 1


def test_monitor_never_raises():
    latch, mon, _ = _monitor()
    mon.on_message_received(None)   # not even a frame: logged, not raised
    assert latch.record is None


def test_latch_first_fault_wins_and_reacts_once():
    latch, reacted = FaultLatch(), []
    latch.on_latch(reacted.append)
    latch.on_latch(lambda r: 1 / 0)   # a failing reaction does not stop the others
    assert latch.latch(FaultRecord(FaultCode.EMCY_LIMIT, "first", "j2", 2, 0x8612))
    assert not latch.latch(FaultRecord(FaultCode.HEARTBEAT_LOST, "second"))
    assert [r.detail for r in reacted] == ["first"] and len(latch.history) == 2
    with pytest.raises(StationFaultError, match=r"move_to refused: .*EMCY_LIMIT \(4\) on j2 \(node 2\), EMCY 0x8612") as ei:
        latch.check("move_to")
    assert isinstance(ei.value, CellError)
    latch.clear()
    latch.check("move_to")


def test_watchdog_declares_silence():
    latch = FaultLatch()
    wd = HeartbeatWatchdog(latch, {1: "j1", 2: "j2"}, timeout_s=0.05, period_s=0.005)
    wd.arm()
    try:
        deadline = time.monotonic() + 1.0
        while latch.record is None and time.monotonic() < deadline:
            wd.beat(1)
            time.sleep(0.005)
    finally:
        wd.stop()
    assert latch.record.code is FaultCode.HEARTBEAT_LOST and latch.record.joint == "j2"
    with pytest.raises(ValueError, match="must be > 0"):
        HeartbeatWatchdog(latch, {}, timeout_s=0, period_s=1)


def test_watchdog_sees_bus_off():
    ch = f"u-{uuid.uuid4().hex[:8]}"
    bus = open_bus("virtual", ch)
    latch = FaultLatch()
    wd = HeartbeatWatchdog(latch, {}, timeout_s=1.0, period_s=0.005, bus=bus)
    try:
        wd.arm()
        bus.state = can.BusState.ERROR
        deadline = time.monotonic() + 1.0
        while latch.record is None and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        wd.stop()
        bus.shutdown()
    assert latch.record.code is FaultCode.BUS_OFF and len(latch.history) == 1
