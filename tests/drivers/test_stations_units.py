"""Unit tests: CiA 402 state machine, frame bits, bus factory, config, bus monitor, fault
latch, heartbeat watchdog (on the simulated clock). Real frames (python-can Message), real
buses; no mocks. The wire itself is tested in test_canbus.py."""
from __future__ import annotations

import threading

import can
import numpy as np
import pytest

from cell.errors import CellError, ConfigError
from drivers.stations import cia402
from drivers.stations.bus import FrameLayout, data_frame_bits, frame_bits, frame_time_s, open_bus
from drivers.stations.cia402 import Command, DriveStateMachine, IllegalTransition, Internal, State
from drivers.stations.config import JOINT_NAMES, StationConfig, StationsConfig
from drivers.stations.driver import EDS_PATH, JointStations
from drivers.stations.faults import (BusMonitor, Expected, FaultCode, FaultLatch, FaultRecord,
                                     HeartbeatWatchdog, StationFaultError)
from tests.drivers.conftest import unique_channel

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


# the drive's words as CiA 402-2 builds them: the state's bits (table 30), voltage enabled
# (bit 4) in Ready to switch on, Switched on, Operation enabled and Quick stop active, remote
# (bit 9) always, and any other bit the caller sets where the state's mask leaves room
@pytest.mark.parametrize("state, word", [
    (State.NOT_READY_TO_SWITCH_ON, 0x0200), (State.SWITCH_ON_DISABLED, 0x0240),
    (State.READY_TO_SWITCH_ON, 0x0231), (State.SWITCHED_ON, 0x0233),
    (State.OPERATION_ENABLED, 0x0237), (State.QUICK_STOP_ACTIVE, 0x0217),
    (State.FAULT_REACTION_ACTIVE, 0x020F), (State.FAULT, 0x0208),
])
def test_statusword_encodes(state, word):
    assert cia402.encode_statusword(state) == word
    extra = cia402.SW_TARGET_REACHED | cia402.SW_SETPOINT_ACK | cia402.SW_FOLLOWING_ERROR
    assert cia402.encode_statusword(state, extra) == word | extra
    mask = state.value[0]
    for bits in range(1 << 16):                    # the state's own bits never change
        assert cia402.encode_statusword(state, bits) & mask == state.value[1]
        assert cia402.encode_statusword(state, bits) == word | (bits & ~mask & 0xFFFF)


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


def _reference_bits(aid: int, data: bytes, extended: bool = False, remote: bool = False, dlc=None) -> int:
    """ISO 11898-1 written out bit by bit (independent of the table-driven production code):
    arbitration + control + data + CRC-15, stuffed (a complementary bit after five equal
    ones, which starts the next run), + CRC delimiter, ACK, EOF, intermission (13)."""
    dlc = len(data) if dlc is None else dlc
    rtr = "1" if remote else "0"
    if extended:
        bits = "0" + f"{aid >> 18:011b}" + "11" + f"{aid & 0x3FFFF:018b}" + rtr + "00"
    else:
        bits = "0" + f"{aid:011b}" + rtr + "00"
    bits += f"{dlc:04b}" + ("" if remote else "".join(f"{b:08b}" for b in data))
    crc = 0
    for b in bits:
        feedback = int(b) ^ (crc >> 14)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= 0x4599
    bits += f"{crc:015b}"
    stuffed, run, last = 0, 0, None
    for b in bits:
        run = run + 1 if b == last else 1
        last = b
        if run == 5:
            stuffed += 1
            last, run = ("1" if b == "0" else "0"), 1
    return len(bits) + stuffed + 13


def test_frame_bits_match_the_standard_bit_by_bit():
    rng = np.random.default_rng(2002)
    cases = [(0x000, bytes(8)), (0x7FF, b"\xff" * 8), (0x555, b""), (0x080, b""), (0x181, b"\x0f" * 8)]
    cases += [(int(rng.integers(0, 0x800)), rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes())
              for _ in range(300)]
    for aid, data in cases:
        msg = can.Message(arbitration_id=aid, data=data, is_extended_id=False)
        assert frame_bits(msg) == _reference_bits(aid, data), (hex(aid), data.hex())
        assert data_frame_bits(aid, data) == frame_bits(msg)
    for _ in range(100):
        aid = int(rng.integers(0, 0x20000000))
        data = rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes()
        msg = can.Message(arbitration_id=aid, data=data, is_extended_id=True)
        assert frame_bits(msg) == _reference_bits(aid, data, extended=True), (hex(aid), data.hex())
    remote = can.Message(arbitration_id=0x181, is_remote_frame=True, dlc=6, is_extended_id=False)
    assert frame_bits(remote) == _reference_bits(0x181, b"", remote=True, dlc=6)
    assert frame_bits(can.Message(is_error_frame=True)) == 17


def test_frame_layout_counts_as_the_standard_for_any_tail():
    rng = np.random.default_rng(2024)
    for _ in range(300):
        aid, dlc = int(rng.integers(0, 0x800)), int(rng.integers(0, 9))
        data = rng.integers(0, 256, dlc, dtype=np.uint8).tobytes()
        head = int(rng.integers(0, dlc + 1))
        layout = FrameLayout(aid, data[:head], dlc)
        assert layout.bits(data[head:]) == _reference_bits(aid, data), (hex(aid), data.hex(), head)
    with pytest.raises(ValueError, match="tail of 3 bytes"):
        FrameLayout(0x201, b"\x00" * 4, 8).bits(b"\x00" * 3)
    with pytest.raises(ValueError, match="at most 8"):
        FrameLayout(0x201, b"", 9)


def test_set_point_frame_bits_are_the_frames_own_cached_or_not():
    from drivers.stations.streaming import _SETPOINT, _setpoint_bits
    rng = np.random.default_rng(7)
    for _ in range(2):                                    # the second round from the cache
        for cob, target, vel in zip(rng.integers(0x201, 0x205, 200), rng.integers(-2 ** 31, 2 ** 31, 200),
                                    rng.integers(0, 2 ** 32, 200)):
            frame = _SETPOINT.pack(int(target), int(vel))
            assert _setpoint_bits(int(cob), int(target), int(vel)) == data_frame_bits(int(cob), frame)


def test_bus_factory_errors():
    with pytest.raises(ConfigError, match="'nosuchcan' is not a known CAN interface"):
        open_bus("nosuchcan", "x")
    with pytest.raises(ConfigError, match="runs on the simulated clock"):
        open_bus("virtual", unique_channel("u"))          # no clock: the virtual wire needs one


# ------------------------------------------------------------------ config
@pytest.mark.parametrize("data, match", [
    ({"bogus": 1}, r"stations.bogus: unknown field"),
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


@pytest.mark.parametrize("data, match", [
    ({"rate_limited": False}, r"stations.rate_limited: unknown field"),      # removed with the real wire
    ({"tpdo_event_ms": 10_001}, r"stations.tpdo_event_ms"),
    ({"tpdo_event_ms": 0}, r"stations.tpdo_event_ms"),
    ({"stations": [{"joint": "j1", "node_id": 1, "limits": [-2e6, 2e6]}] + [{"joint": j, "node_id": i}
      for i, j in ((2, "j2"), (3, "j3"), (4, "j4"))]}, "do not fit a 32-bit position"),
    ({"stations": [{"joint": "j1", "node_id": 1, "supports_sync": "maybe"}]}, r"supports_sync"),
])
def test_config_errors_of_the_new_fields(data, match):
    with pytest.raises(ConfigError, match=match):
        StationsConfig.load(data)


def test_config_defaults():
    cfg = StationsConfig()
    assert [s.node_id for s in cfg.stations] == [1, 2, 3, 4]
    assert JOINT_NAMES == ("j1", "j2", "j3", "j4")
    assert [s.joint_index for s in cfg.stations] == [0, 1, 2, 3]
    # limits=None: the drive's whole 32-bit range (no preset), symmetric and just inside it
    j3 = cfg.station("j3")
    lo, hi = j3.joint_limits
    assert lo == -hi and hi * j3.counts_per_unit == pytest.approx(2 ** 31 - 2)
    assert j3.counts_per_unit == pytest.approx(10_000 * 50 / 360)
    assert all(s.supports_sync for s in cfg.stations)
    assert StationsConfig.load({"tpdo_event_ms": 10_000}).tpdo_event_ms == 10_000
    assert EDS_PATH.name == "scara_axis.eds" and EDS_PATH.is_file()


def test_supports_sync_and_latency_from_config():
    st = [StationConfig(joint=j, node_id=i + 1, supports_sync=(j != "j3")) for i, j in enumerate(JOINT_NAMES)]
    js = JointStations.from_config({"stations": st, "delays_s": [0.004, 0.001, 0.003, 0.002]})
    assert js.supports_sync is False
    np.testing.assert_array_equal(js.latency_s, [0.004, 0.001, 0.003, 0.002])
    # bus order ≠ joint order: delays_s is in bus order, latency_s per joint j1..j4
    order = [StationConfig(joint=j, node_id=n) for j, n in (("j3", 1), ("j1", 2), ("j4", 3), ("j2", 4))]
    js = JointStations.from_config({"stations": order, "delays_s": [0.001, 0.002, 0.003, 0.004]})
    assert js.supports_sync is True
    np.testing.assert_array_equal(js.latency_s, [0.002, 0.004, 0.001, 0.003])
    js.latency_s[0] = 99.0                             # a copy: the driver's value is safe
    assert js.latency_s[0] == 0.002


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


def test_watchdog_declares_silence_within_one_period(vclock):
    latch, when = FaultLatch(), []
    latch.on_latch(lambda r: when.append(vclock.now()))
    timeout, period = 0.05, 0.005
    wd = HeartbeatWatchdog(latch, {1: "j1", 2: "j2"}, timeout_s=timeout, period_s=period, clock=vclock)
    t_arm = vclock.now()
    wd.arm()
    try:
        while latch.record is None and vclock.now() < t_arm + 1.0:
            wd.beat(1)                        # j1 keeps beating, j2 never does
            vclock.sleep(0.001)
        assert wd.silent() == [2]
    finally:
        wd.stop()
    assert latch.record.code is FaultCode.HEARTBEAT_LOST and latch.record.joint == "j2"
    assert latch.record.node_id == 2 and len(latch.history) == 1      # j1 was never reported
    # silent = overdue by more than timeout_s, found at the next check: (timeout, timeout + period]
    assert t_arm + timeout - 1e-9 < when[0] <= t_arm + timeout + period + 1e-9
    with pytest.raises(ValueError, match="must be > 0"):
        HeartbeatWatchdog(latch, {}, timeout_s=0, period_s=1)


def test_watchdog_reports_a_station_once_and_again_after_it_came_back(vclock):
    latch = FaultLatch()
    wd = HeartbeatWatchdog(latch, {3: "j3"}, timeout_s=0.02, period_s=0.004, clock=vclock)
    wd.arm()
    try:
        vclock.sleep(0.1)
        assert [r.code for r in latch.history] == [FaultCode.HEARTBEAT_LOST]   # once, not per check
        latch.clear()
        t_beat = vclock.now()
        wd.beat(3)
        assert wd.silent() == []
        vclock.sleep(0.1)
        assert len(latch.history) == 2 and latch.record.joint == "j3"
        assert "no heartbeat for" in latch.record.detail and "allowed 20 ms" in latch.record.detail
    finally:
        wd.stop()
    assert t_beat > 0 and wd._task is None


class _TaskClock:
    """The simulated clock without timed callbacks: what a wall clock offers a watchdog."""

    def __init__(self, clock):
        self._clock = clock

    def __getattr__(self, name):
        if name in ("call_at", "call_later"):
            raise AttributeError(name)
        return getattr(self._clock, name)


class _CheckTimes(HeartbeatWatchdog):
    def check(self) -> None:
        self.times.append((self.clock.now(), threading.current_thread().name))
        super().check()


def test_watchdog_checks_at_the_same_times_as_a_callback_and_as_a_task():
    """On the simulated clock the checks are clock callbacks (no thread of their own); on
    a clock without call_at, a task. Same clock times either way, re-armed or not."""
    from cell.sim.clock import VirtualClock
    runs = {}
    for mode in ("callback", "task"):
        vclock = VirtualClock(start=1.2345)
        clock = vclock if mode == "callback" else _TaskClock(vclock)
        wd = _CheckTimes(FaultLatch(), {1: "j1"}, timeout_s=1.0, period_s=0.003, clock=clock)
        wd.times = []
        with vclock.attach("test"):
            wd.arm()
            try:
                vclock.sleep(0.0101)
                wd.arm()                              # re-armed while running: the period goes on
                vclock.sleep(0.0101)
            finally:
                wd.stop()
            vclock.sleep(0.01)                        # stopped: no more checks
        vclock.close()
        runs[mode] = ([t for t, _ in wd.times], {name for _, name in wd.times})
    assert runs["callback"][0] == runs["task"][0] and len(runs["task"][0]) == 6
    assert runs["task"][1] == {"stations-watchdog"} and "stations-watchdog" not in runs["callback"][1]


def test_watchdog_sees_bus_off(vclock):
    bus = open_bus("virtual", unique_channel("u"), clock=vclock)
    latch, when = FaultLatch(), []
    latch.on_latch(lambda r: when.append(vclock.now()))
    wd = HeartbeatWatchdog(latch, {}, timeout_s=1.0, period_s=0.005, bus=bus, clock=vclock)
    try:
        wd.arm()
        vclock.sleep(0.0123)
        assert latch.record is None               # ACTIVE bus: nothing to report
        t_err = vclock.now()
        bus.state = can.BusState.ERROR
        vclock.sleep(0.05)
    finally:
        wd.stop()
        bus.shutdown()
    assert latch.record.code is FaultCode.BUS_OFF and len(latch.history) == 1   # reported once
    assert t_err < when[0] <= t_err + 0.005 + 1e-9                              # at the next check
