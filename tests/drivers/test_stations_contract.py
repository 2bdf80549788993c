"""Contract tests for the joint stations, written once and run against every backend
: the simulated stations on the virtual wire of a simulated clock now; real
drives when marked ``hw`` (set CELL_STATIONS_HW="interface:channel", e.g. "socketcan:can0").

The simulated backend runs on a :class:`~cell.sim.clock.VirtualClock`: the test's thread
keeps its time (``clock.attach()``), every wait is ``clock.sleep`` and every instant is
exact, so the timing below is asserted to the frame (or to 1e-9 s), not with margins for
thread jitter. Checks that need the simulated twin's own view (when a set-point was
applied, where an axis is at an exact instant) or a sniffing bus go through ``backend.<hook>``;
on hardware those skip unless a rig provides them. The hardware backend uses wall time
(:class:`~cell.clock.MonotonicClock`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import struct
import threading

import can
import numpy as np
import pytest

from cell.clock import MonotonicClock
from cell.kinematics import Scara
from cell.motion.line import plan_line
from cell.sim.clock import VirtualClock
from drivers.stations.bus import frame_bits, frame_time_s, open_bus
from drivers.stations.cia402 import State
from drivers.stations.config import JOINT_NAMES, StationConfig, StationsConfig
from drivers.stations.driver import JointStations, StationCommandError
from drivers.stations.faults import FaultCode, StationFaultError
from drivers.stations.sim import SimStationSet
from drivers.stations.sim_bus import wire_stats
from tests.drivers.conftest import clock_wait_for, drain, unique_channel

# Short timings keep the tests short in simulated time; on the simulated clock they are
# exact, so no margin for thread scheduling is needed.
FAST = dict(heartbeat_ms=50, heartbeat_tolerance=1.5, controller_heartbeat_ms=20, consumer_timeout_ms=60,
            tpdo_event_ms=5)
ROBOT = Scara.preset("seed002")
START = (0.0, 30.0, 50.0, 0.0)
CPU = 10_000 * 50 / 360            #: increments per joint unit (default encoder and gear)
INC = 1 / CPU                      #: one increment in joint units
MAX_FRAME_S = 135e-6               #: longest 8-byte standard frame at 1 Mbit/s
EVENT_S = FAST["tpdo_event_ms"] / 1000


def _stations(station_kw=None):
    """The four stations in bus order j1..j4 (node 1..4) with the seed 002 joint limits."""
    station_kw = station_kw or {}
    return tuple(StationConfig(joint=j, node_id=i + 1, limits=tuple(ROBOT.g.limits[i]), **station_kw.get(j, {}))
                 for i, j in enumerate(JOINT_NAMES))


class SimBackend:
    name = "sim"

    def __init__(self, delays=(0.0, 0.0, 0.0, 0.0), initial=START, station_kw=None, **over):
        self.clock = VirtualClock()
        self.cfg = StationsConfig(channel=unique_channel("t"), stations=_stations(station_kw), **{**FAST, **over})
        self.sims = SimStationSet(self.cfg, delays, initial, clock=self.clock)
        self._buses = []

    def start(self):
        self.sims.start()

    def unplug(self, joint):
        self.sims.by_joint(joint).unplug()

    def replug(self, joint):
        self.sims.by_joint(joint).power_cycle()

    def inject_following_error(self, joint):
        self.sims.by_joint(joint).inject_following_error()

    def raw_bus(self, **kw):
        """A bus of our own on the cell's wire: sends, and (no listeners) keeps what it hears.
        Shut down by the test or at the latest by :meth:`close`."""
        bus = open_bus("virtual", self.cfg.channel, self.cfg.bitrate, clock=self.clock, **kw)
        self._buses.append(bus)
        return bus

    def drive_state(self, joint):
        return self.sims.by_joint(joint).state

    def applied(self, joint):
        """The twin's applied set-points [(clock time, target inc, velocity inc/s)]."""
        return list(self.sims.by_joint(joint).applied)

    def position(self, joint):
        """The twin's axis position now (joint units), exact."""
        return self.sims.by_joint(joint).position

    def close(self):
        for bus in self._buses:
            bus.shutdown()
        self.sims.stop()


class HwBackend:
    name = "hw"

    def __init__(self, delays=None, initial=None, station_kw=None, **over):
        spec = os.environ.get("CELL_STATIONS_HW")
        if not spec:
            pytest.skip("hardware contract run needs CELL_STATIONS_HW=interface:channel")
        interface, channel = spec.split(":", 1)
        self.clock = MonotonicClock()
        self.cfg = StationsConfig(interface=interface, channel=channel, stations=_stations(station_kw),
                                  **{**FAST, **over})

    def start(self):
        pass

    def _no(self, *a, **kw):
        pytest.skip("fault injection / the twin's view is not available on this hardware rig")

    unplug = replug = inject_following_error = raw_bus = drive_state = applied = position = _no

    def close(self):
        pass


@pytest.fixture(params=["sim", pytest.param("hw", marks=pytest.mark.hw)])
def make(request):
    """``make(**kw) → (backend, js)``: one backend (its own clock, which the test's thread
    keeps from then on) and a started driver. ``backend.t_started`` is the clock time
    ``start()`` returned (the heartbeat watchdog's arming)."""
    made = []
    attached = contextlib.ExitStack()

    def _make(**kw):
        assert not made, "one backend per test"
        backend = (SimBackend if request.param == "sim" else HwBackend)(**kw)
        made.append(backend)
        attached.enter_context(backend.clock.attach())
        backend.start()
        js = JointStations.from_config(backend.cfg, clock=backend.clock)
        made.append(js)
        js.start()
        backend.t_started = backend.clock.now()
        return backend, js

    yield _make
    try:
        for obj in reversed(made):
            (obj.shutdown if isinstance(obj, JointStations) else obj.close)()
    finally:
        attached.close()
    if made and made[0].name == "sim":
        made[0].clock.close()
        assert wire_stats(made[0].cfg.channel) is None, "a bus was left on the wire"
        leaked = [t.name for t in threading.enumerate() if t.name == "stations-watchdog"]
        assert not leaked, f"leaked threads {leaked}"


def _latch_times(js, clock):
    """Clock times at which faults are latched, from now on."""
    when = []
    js.latch.on_latch(lambda record: when.append(clock.now()))
    return when


def wait_standstill(js, clock, timeout=1.0):
    """Positions as soon as two TPDO readings 20 ms (clock) apart agree (the stop ramp is over)."""
    deadline = clock.now() + timeout
    prev = js.actual_positions()
    while True:
        clock.sleep(0.02)
        now = js.actual_positions()
        if np.array_equal(now, prev):
            return now
        if clock.now() > deadline:
            raise AssertionError(f"still moving: {prev} → {now}")
        prev = now


# ------------------------------------------------------------------ start-up and moves
def test_startup_reaches_operation_enabled(make):
    backend, js = make()
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}
    assert js.fault is None and js.fault_code == FaultCode.NONE
    # the TPDOs report the encoder rounded to whole increments
    np.testing.assert_allclose(js.actual_positions(), START, rtol=0, atol=0.5 * INC + 1e-12)
    np.testing.assert_array_equal(js.latency_s, np.zeros(4))
    assert js.supports_sync
    if backend.name == "sim":
        assert 0 < backend.t_started < js.cfg.boot_timeout_s
        assert all(backend.applied(j) == [] for j in JOINT_NAMES)   # enabling moves nothing


def test_point_to_point_move_arrives_when_the_profile_says(make):
    backend, js = make()
    clock = backend.clock
    target = [12.5, 45.0, 60.0, -20.0]
    t_cmd = clock.now()
    duration = js.move_to(target, speed=400.0)
    assert duration == pytest.approx(max(12.5, 15.0, 10.0, 20.0) / 400.0)
    js.wait_reached(timeout_s=3.0, tol=1e-3)
    t_seen = clock.now()
    np.testing.assert_allclose(js.actual_positions(), target, rtol=0, atol=0.5 * INC + 1e-12)
    assert t_seen - t_cmd >= duration            # no joint beats the profile
    if backend.name != "sim":
        return
    arrivals = []
    for j, joint in enumerate(JOINT_NAMES):
        ((t_apply, tgt, vel),) = backend.applied(joint)
        assert tgt == round(target[j] * CPU)
        # all joints start together (within the burst's wire time, maybe behind frames
        # already queued) and arrive together: the duration after, to one increment of travel
        assert t_cmd < t_apply <= t_cmd + 8 * MAX_FRAME_S
        t_arrive = t_apply + abs(tgt - START[j] * CPU) / vel
        assert abs(t_arrive - (t_apply + duration)) <= 1.0 / vel
        arrivals.append(t_arrive)
    # arrival is reported by the next event-timer TPDO (plus its frame, maybe behind the others')
    assert max(arrivals) < t_seen <= max(arrivals) + EVENT_S + 4 * MAX_FRAME_S
    for joint, q in zip(JOINT_NAMES, target):
        assert backend.position(joint) == pytest.approx(round(q * CPU) * INC, abs=1e-9)


def test_bad_move_is_refused_and_sends_nothing(make):
    backend, js = make()
    clock = backend.clock
    sniff = backend.raw_bus() if backend.name == "sim" else None
    before = js.actual_positions()
    with pytest.raises(StationCommandError, match="j2 = 999.0000 is outside its limits"):
        js.move_to([0, 999, 50, 0], 100)
    with pytest.raises(StationCommandError, match=r"j3 = -0.5000 is outside its limits \[0.0, 100.0\]"):
        js.move_to([0, 30, -0.5, 0], 100)
    with pytest.raises(StationCommandError, match="j3 = nan is not a finite"):
        js.move_to([0, 30, float("nan"), 0], 100)
    with pytest.raises(StationCommandError, match="need 4 joint values"):
        js.move_to([0, 30], 100)
    with pytest.raises(StationCommandError, match="speed = -1"):
        js.move_to([0, 30, 50, 0], -1)
    with pytest.raises(StationCommandError, match="speed = True"):
        js.move_to([0, 30, 50, 0], True)
    clock.sleep(0.03)
    np.testing.assert_array_equal(js.actual_positions(), before)
    assert js.fault is None
    if sniff is not None:
        frames = drain(sniff)
        sniff.shutdown()
        assert sum(0x181 <= m.arbitration_id <= 0x184 for m in frames) >= 4 * 5   # the TPDOs went on
        assert [m for m in frames if m.arbitration_id >> 7 in (0x4, 0x6, 0x8) or m.arbitration_id == 0x80] == []
        assert all(backend.applied(j) == [] for j in JOINT_NAMES)


# ------------------------------------------------------------------ streaming (seed 002)
def _corrected_segments(js, plan):
    """Seed 002's correction per segment: ω = Δθ / (T − λ) with λ = ``burst_delays`` of the
    very frames that go out (their bits depend on ω: iterate to the fixed point)."""
    T = plan.segment_s
    out = []
    for k, seg in enumerate(plan.segments):
        delta = np.abs(plan.joints_deg[k + 1] - plan.joints_deg[k])
        v = delta / T
        for _ in range(20):
            v_next = delta / (T - js.burst_delays(seg.target_deg, v))
            if np.array_equal(v_next, v):
                break
            v = v_next
        out.append(dataclasses.replace(seg, velocity_deg_s=v))
    return out


@pytest.mark.parametrize("mode", ["reception", "sync"])
def test_streamed_line_puts_every_joint_on_every_interpolation_point_together(make, mode):
    sigma, T, n, lead = 0.002, 0.1, 5, 0.02
    delays = (sigma, 2 * sigma, 3 * sigma, 4 * sigma)
    backend, js = make(delays=delays)
    clock = backend.clock
    start = ROBOT.fk(list(START))
    plan = plan_line(ROBOT, start, start + np.array([-40.0, 30.0, 10.0, 20.0]), n_points=n, segment_s=T)
    if mode == "reception":
        lam = js.measure_delays(rounds=3)
        if backend.name == "sim":
            np.testing.assert_allclose(lam, delays, rtol=0, atol=1e-9)
        segments = _corrected_segments(js, plan)
    else:
        segments = plan.segments           # applied together on SYNC: plain Δθ/T
    sync_s = frame_time_s(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False), js.cfg.bitrate)
    t0 = clock.now() + lead
    # where the joints must be: reception — at t0 + k·T (when burst k+1 starts);
    # sync — at the end of SYNC k+1 on the wire (one segment after the SYNC that applied k)
    instants = [t0 + k * T + (sync_s if mode == "sync" else 0.0) for k in range(1, n + 1)]
    samples = []
    if backend.name == "sim":
        def sampler():
            for t in instants:
                clock.sleep_until(t)
                samples.append([backend.position(j) for j in JOINT_NAMES])
        clock.spawn(sampler, "sampler")
    n_before = {j: len(backend.applied(j)) for j in JOINT_NAMES} if backend.name == "sim" else {}
    js.start_recording()
    report = js.stream(segments, mode=mode, lead_s=lead)
    js.wait_reached(timeout_s=3.0, tol=1e-3)
    rec = np.array(js.stop_recording())
    assert report.mode == mode and report.sent.shape == (n,) and np.all(np.diff(report.sent) > 0)
    np.testing.assert_allclose(js.actual_positions(), plan.joints_deg[-1], rtol=0, atol=0.5 * INC + 1e-9)
    # every joint passes through every interpolation point (its TPDO trace crosses it)
    for j in range(4):
        trace = rec[rec[:, 1] == j, 2]
        for k in range(1, n + 1):
            span = max(abs(plan.joints_deg[-1, j] - plan.joints_deg[0, j]), 1)
            assert np.min(np.abs(trace - plan.joints_deg[k, j])) < 0.05 * span + 1e-3
    if backend.name != "sim":
        return
    applied = {j: backend.applied(j)[n_before[j]:] for j in JOINT_NAMES}   # after measure_delays' probes
    assert all(len(a) == n for a in applied.values())
    if mode == "sync":
        # every SYNC went out when planned (idle wire) and all four applied on it, together
        np.testing.assert_allclose(report.sent, t0 + T * np.arange(n) + sync_s, rtol=0, atol=1e-9)
        for k in range(n):
            assert {applied[j][k][0] for j in JOINT_NAMES} == {report.sent[k]}
    else:
        first = js.cfg.stations[0].joint_index            # first on the bus
        for k, seg in enumerate(segments):
            lam_k = js.burst_delays(seg.target_deg, seg.velocity_deg_s)
            burst_start = report.sent[k] - (lam_k[first] - js.latency_s[first])
            assert burst_start == pytest.approx(t0 + seg.start_s, abs=1e-9)   # burst on time
            for j, joint in enumerate(JOINT_NAMES):
                t_apply, tgt, vel = applied[joint][k]
                # each station applies λ_j after the burst started: its frame's wire time + latency
                assert t_apply == pytest.approx(burst_start + lam_k[j], abs=1e-9)
                assert tgt == round(plan.joints_deg[k + 1, j] * CPU)
                p_from = START[j] * CPU if k == 0 else applied[joint][k - 1][1]
                # ... and its corrected velocity brings it there at burst start + T: exactly
                # but for whole increments (target and velocity), i.e. within 1 inc of travel
                t_arrive = t_apply + abs(tgt - p_from) / vel
                assert abs(t_arrive - (burst_start + T)) <= 1.0 / vel, (k, joint, t_arrive - burst_start - T)
    # at each instant every joint is on its interpolation point (to the encoder increment)
    assert len(samples) == n
    np.testing.assert_allclose(samples, plan.joints_deg[1:], rtol=0, atol=INC)


def test_bad_segments_are_refused_before_anything_is_sent(make):
    backend, js = make()
    clock = backend.clock
    sniff = backend.raw_bus() if backend.name == "sim" else None
    plan = plan_line(ROBOT, ROBOT.fk([0, 30, 50, 0]), ROBOT.fk([10, 40, 60, 5]), 3, 0.05)
    bad = [plan.segments[0], dataclasses.replace(plan.segments[1], target_deg=np.array([0, 30, 500.0, 0]))]
    with pytest.raises(StationCommandError, match="stream segment 1: j3 = 500.0000 is outside"):
        js.stream(bad)
    with pytest.raises(StationCommandError, match="stream segment 1: j3 = 500.0000 is outside"):
        js.stream(bad, mode="sync")       # sync mode writes ahead: still nothing before the check
    with pytest.raises(StationCommandError, match="mode = 'fast'"):
        js.stream(plan.segments, mode="fast")
    with pytest.raises(StationCommandError, match="segment 1: start_s"):
        js.stream([plan.segments[1], plan.segments[0]])
    with pytest.raises(StationCommandError, match="no segments"):
        js.stream([])
    with pytest.raises(StationCommandError, match="segment 2: velocity_deg_s must be 4 finite"):
        js.stream([*plan.segments[:2], dataclasses.replace(plan.segments[2], velocity_deg_s=np.array([1.0, np.inf, 0, 0]))])
    with pytest.raises(StationCommandError, match="segment 0: not a Segment"):
        js.stream([object()])
    with pytest.raises(StationCommandError, match="lead_s = -1"):
        js.stream(plan.segments, lead_s=-1)
    clock.sleep(0.02)
    np.testing.assert_allclose(js.actual_positions(), [0, 30, 50, 0], rtol=0, atol=0.5 * INC + 1e-12)
    assert js.fault is None
    if sniff is not None:
        frames = drain(sniff)
        sniff.shutdown()
        assert [m for m in frames if m.arbitration_id >> 7 in (0x4, 0x8) or m.arbitration_id == 0x80] == []


def test_sync_mode_needs_every_station_to_support_it(make):
    backend, js = make(station_kw={"j3": {"supports_sync": False}})
    assert js.supports_sync is False
    plan = plan_line(ROBOT, ROBOT.fk([0, 30, 50, 0]), ROBOT.fk([5, 35, 55, 5]), 2, 0.05)
    with pytest.raises(StationCommandError, match="sync mode needs SYNC support on every station"):
        js.stream(plan.segments, mode="sync")
    report = js.stream(plan.segments, mode="reception")      # reception mode is for everyone
    js.wait_reached(timeout_s=2.0, tol=1e-3)
    assert report.mode == "reception"
    np.testing.assert_allclose(js.actual_positions(), plan.joints_deg[-1], rtol=0, atol=0.5 * INC + 1e-9)


# ------------------------------------------------------------------ faults
def _assert_all_stopped_and_refused(js, backend, code, skip=()):
    assert js.fault_code == code
    for joint in JOINT_NAMES:
        if joint not in skip:
            # the quick stop the latch sent is on the wire behind at most a few frames
            clock_wait_for(backend.clock, lambda: backend.drive_state(joint) in (
                State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE, State.FAULT),
                timeout=8 * MAX_FRAME_S, step=10e-6, what=f"{joint} stopping")
    with pytest.raises(StationFaultError, match=code.name):
        js.move_to([0, 30, 50, 0], 100)
    with pytest.raises(StationFaultError, match="call reset"):
        js.stream(plan_line(ROBOT, ROBOT.fk([0, 30, 50, 0]), ROBOT.fk([5, 35, 50, 0]), 2, 0.05).segments)


def test_heartbeat_lost_faults_stops_all_and_refuses_until_reset(make):
    backend, js = make()
    clock = backend.clock
    sniff = backend.raw_bus()
    latched = _latch_times(js, clock)
    js.move_to([40, 60, 80, 40], 100)      # moving when the cable is pulled
    clock.sleep(0.05)
    t_unplug = clock.now()
    backend.unplug("j2")
    clock_wait_for(clock, lambda: js.fault is not None, timeout=0.2, what="fault latched")
    assert js.fault.code == FaultCode.HEARTBEAT_LOST and js.fault.joint == "j2" and js.fault.node_id == 2
    frames = drain(sniff)
    sniff.shutdown()
    beats = [m.timestamp for m in frames if m.arbitration_id == 0x702]
    assert beats and max(beats) <= t_unplug + MAX_FRAME_S           # j2 has been silent since
    last = max(beats + [backend.t_started])
    timeout = js.cfg.heartbeat_tolerance * js.cfg.heartbeat_ms / 1000
    period = min(0.02, js.cfg.heartbeat_ms / 4000)
    assert last + timeout - 1e-9 < latched[0] <= last + timeout + period + 1e-9
    # j2 is off the bus and cannot hear the quick stop (see test_stations_sim for its own reaction)
    _assert_all_stopped_and_refused(js, backend, FaultCode.HEARTBEAT_LOST, skip=("j2",))
    pos = wait_standstill(js, clock)
    clock.sleep(0.05)
    np.testing.assert_array_equal(js.actual_positions(), pos)       # nothing moves
    with pytest.raises(StationFaultError, match=r"still silent: j2 \(node 2\)"):
        js.reset()
    assert js.fault_code == FaultCode.HEARTBEAT_LOST                 # unchanged by the refused reset
    backend.replug("j2")
    clock_wait_for(clock, lambda: not js.watchdog.silent(), timeout=0.2, what="j2 heartbeat back")
    js.reset()
    assert js.fault is None and set(js.drive_states().values()) == {State.OPERATION_ENABLED}
    assert len(latched) == 1                                          # nothing else went wrong since
    js.move_to([1, 31, 51, 1], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)


def test_emcy_faults_and_stops_all(make):
    backend, js = make()
    clock = backend.clock
    sniff = backend.raw_bus()
    latched = _latch_times(js, clock)
    t_inject = clock.now()
    backend.inject_following_error("j3")
    clock_wait_for(clock, lambda: js.fault is not None, timeout=0.01, what="fault latched")
    assert js.fault.code == FaultCode.EMCY_FOLLOWING_ERROR and js.fault.emcy_code == 0x8611
    assert js.fault.joint == "j3" and js.fault.node_id == 3
    (emcy,) = [m for m in drain(sniff) if m.arbitration_id == 0x083]
    sniff.shutdown()
    assert bytes(emcy.data[:3]) == b"\x11\x86\x01"                  # code 0x8611, error register
    # latched the instant the EMCY frame ended on the wire, sent at once (behind ≤ 4 frames)
    assert latched == [emcy.timestamp]
    assert t_inject < emcy.timestamp <= t_inject + 5 * MAX_FRAME_S
    _assert_all_stopped_and_refused(js, backend, FaultCode.EMCY_FOLLOWING_ERROR)
    js.reset()
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}
    js.move_to([2, 32, 52, 2], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)


@pytest.mark.parametrize("frame, code", [
    (can.Message(arbitration_id=0x181, data=b"\x01\x02\x03", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x702, data=b"", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x083, data=b"\x10\x00", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x584, data=bytes(9)[:7], is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x123, data=b"\xde\xad", is_extended_id=False), FaultCode.UNEXPECTED_FRAME),
    (can.Message(arbitration_id=0x184, is_remote_frame=True, dlc=6, is_extended_id=False), FaultCode.UNEXPECTED_FRAME),
    (can.Message(arbitration_id=0x1ABCDEF, data=b"\x00", is_extended_id=True), FaultCode.UNEXPECTED_FRAME),
    (can.Message(is_error_frame=True, is_extended_id=False), FaultCode.BUS_ERROR_FRAME),
])
def test_garbage_frame_faults_and_never_crashes(make, frame, code):
    """Policy: garbage on the wire is a fault (code per kind), never a crash."""
    backend, js = make()
    clock = backend.clock
    latched = _latch_times(js, clock)
    bus = backend.raw_bus()
    try:
        bus.send(frame)
        t_end = bus.last_tx_timestamp
        clock_wait_for(clock, lambda: js.fault is not None, timeout=0.01, what="fault latched")
    finally:
        bus.shutdown()
    assert js.fault.code == code
    assert latched == [t_end]                  # the monitor judged the frame the instant it ended
    _assert_all_stopped_and_refused(js, backend, code)
    # the receive side survived: every station's TPDOs still come in
    counts = [s.tpdo_count for s in js._stations]
    clock.sleep(2 * EVENT_S)
    assert all(after > before for after, before in zip([s.tpdo_count for s in js._stations], counts))
    js.reset()
    js.move_to([2, 32, 52, 2], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)


def test_unknown_frames_can_be_logged_instead(make):
    backend, js = make(unknown_frames="log")
    clock = backend.clock
    bus = backend.raw_bus()
    try:
        bus.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        t_end = bus.last_tx_timestamp
        t_seen = clock_wait_for(clock, lambda: js.monitor.rejected == 1, timeout=0.01, step=1e-6, what="frame seen")
    finally:
        bus.shutdown()
    assert t_end <= t_seen < t_end + 1e-6
    assert js.fault is None
    js.move_to([3, 33, 53, 3], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)
    assert js.monitor.rejected == 1


def test_controller_heartbeat_lost_drives_fault_themselves(make):
    backend, js = make()
    clock = backend.clock
    sniff = backend.raw_bus()
    latched = _latch_times(js, clock)
    js.move_to([90, 90, 90, 90], 100)   # a long move
    clock.sleep(0.05)
    js.stop_heartbeat()                   # the controller "hangs"
    t_stop = clock.now()
    clock.sleep(MAX_FRAME_S)              # a heartbeat already queued is out now
    beats = [m.timestamp for m in drain(sniff) if m.arbitration_id == 0x700 + js.cfg.controller_node_id]
    t_last = max(beats)
    assert t_stop - js.cfg.controller_heartbeat_ms / 1000 < t_last <= t_stop + MAX_FRAME_S
    # each drive's consumer times out exactly consumer_timeout_ms after the last heartbeat it heard
    t_fault = t_last + js.cfg.consumer_timeout_ms / 1000
    clock.sleep_until(t_fault - 1e-6)
    assert {backend.drive_state(j) for j in JOINT_NAMES} == {State.OPERATION_ENABLED}
    assert js.fault is None
    clock.sleep_until(t_fault + 1e-6)
    assert {backend.drive_state(j) for j in JOINT_NAMES} <= {State.FAULT_REACTION_ACTIVE, State.FAULT}
    clock_wait_for(clock, lambda: js.fault is not None, timeout=5 * MAX_FRAME_S, step=1e-6, what="EMCY seen")
    assert js.fault.code == FaultCode.EMCY_HEARTBEAT and js.fault.emcy_code == 0x8130
    pos = wait_standstill(js, clock)
    emcys = [m for m in drain(sniff) if 0x81 <= m.arbitration_id <= 0x84]
    sniff.shutdown()
    assert sorted(m.arbitration_id for m in emcys) == [0x81, 0x82, 0x83, 0x84]   # every drive said why
    assert all(bytes(m.data[:2]) == b"\x30\x81" for m in emcys)
    # the EMCYs went out at the fault instant, one after another; the first one latched
    assert latched == [min(m.timestamp for m in emcys)]
    assert t_fault < min(m.timestamp for m in emcys) and max(m.timestamp for m in emcys) <= t_fault + 8 * MAX_FRAME_S
    assert np.all(pos < 90 - 1)           # stopped on the way, not at the target
    assert {backend.drive_state(j) for j in JOINT_NAMES} == {State.FAULT}
    clock.sleep(0.05)
    np.testing.assert_array_equal(js.actual_positions(), pos)
    js.reset()                            # heartbeat restarts, drives re-enabled
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}
    clock.sleep(3 * js.cfg.consumer_timeout_ms / 1000)
    assert js.fault is None               # the drives hear the controller again


def test_quick_stop_all_is_category_2_and_latches(make):
    backend, js = make()
    clock = backend.clock
    sniff = backend.raw_bus() if backend.name == "sim" else None
    js.move_to([90, 90, 90, 90], 100)
    clock.sleep(0.05)
    t_q = clock.now()
    js.quick_stop_all("operator")
    _assert_all_stopped_and_refused(js, backend, FaultCode.QUICK_STOP)
    clock_wait_for(clock, lambda: set(js.drive_states().values()) == {State.QUICK_STOP_ACTIVE},
                   timeout=EVENT_S + 8 * MAX_FRAME_S, what="statuswords say Quick stop active")
    if sniff is not None:
        # category 2, exactly: from the instant its controlword ended on the wire, each axis
        # ramps down at quick_stop_decel and then holds, powered, where the ramp ended
        cws = {m.arbitration_id - 0x300: m for m in drain(sniff) if 0x301 <= m.arbitration_id <= 0x304}
        sniff.shutdown()
        stops = []
        for j, joint in enumerate(JOINT_NAMES):
            cw = cws[j + 1]
            assert bytes(cw.data) == b"\x02\x00" and t_q < cw.timestamp <= t_q + 5 * MAX_FRAME_S
            ((t_apply, tgt, vel),) = backend.applied(joint)
            sign = 1.0 if tgt > START[j] * CPU else -1.0
            p_cw = START[j] * CPU + sign * vel * (cw.timestamp - t_apply)         # increments
            a = round(js.cfg.station(joint).quick_stop_decel * CPU)
            stops.append((joint, cw.timestamp + vel / a, (p_cw + sign * vel * vel / (2 * a)) * INC))
        for joint, t_stop, p_stop in stops:
            assert clock.now() < t_stop - 1e-4
        for joint, t_stop, p_stop in sorted(stops, key=lambda s: s[1]):
            clock.sleep_until(t_stop - 1e-4)
            assert abs(backend.position(joint) - p_stop) > 1e-6           # still ramping
            clock.sleep_until(t_stop + 1e-9)
            assert backend.position(joint) == pytest.approx(p_stop, abs=1e-6)
        clock.sleep(0.1)
        for joint, _, p_stop in stops:
            assert backend.position(joint) == pytest.approx(p_stop, abs=1e-6)   # holding there
            assert backend.drive_state(joint) is State.QUICK_STOP_ACTIVE       # powered, no fault
    js.reset()
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}


# ------------------------------------------------------------------ the wire and the delays
def test_wire_timing_holds_on_the_cell_bus(make):
    backend, js = make(unknown_frames="log")
    clock = backend.clock
    n = 300
    msg = can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False)
    f = frame_bits(msg) / js.cfg.bitrate
    bus, listener = backend.raw_bus(tx_queue=n), backend.raw_bus()
    try:
        frames0, bits0 = wire_stats(js.cfg.channel)
        t_first = clock.now()
        for _ in range(n):
            bus.send(msg)
        clock.sleep(n * f + 0.001)
        frames1, bits1 = wire_stats(js.cfg.channel)
        got = [m.timestamp for m in drain(listener) if m.arbitration_id == 0x123]
    finally:
        listener.shutdown()
        bus.shutdown()
    assert len(got) == n
    # queued together: back to back, each exactly its bits long, whatever else the cell sends
    np.testing.assert_allclose(np.diff(got), f, rtol=0, atol=1e-12)
    assert got[0] - f >= t_first - 1e-12
    assert got[-1] - got[0] == pytest.approx((n - 1) * f, abs=1e-9)
    assert frames1 - frames0 >= n and bits1 - bits0 >= n * frame_bits(msg)
    assert js.monitor.rejected == n and js.fault is None


def test_delay_measurement_sees_the_configured_delays(make):
    configured = np.array([0.005, 0.015, 0.025, 0.035])
    backend, js = make(delays=tuple(configured))
    clock = backend.clock
    sniff = backend.raw_bus() if backend.name == "sim" else None
    t_before = clock.now()
    lam = js.measure_delays(rounds=7)
    np.testing.assert_array_equal(js.latency_s, lam)
    assert np.all(lam >= 0)
    if sniff is not None:
        # exact on the simulated wire: end of the set-point frame → applied
        np.testing.assert_allclose(lam, configured, rtol=0, atol=1e-9)
        # one station at a time: the next probe goes out only after the previous one was applied
        probes = [m for m in drain(sniff) if 0x201 <= m.arbitration_id <= 0x204]
        sniff.shutdown()
        assert [m.arbitration_id - 0x200 for m in probes] == [1, 2, 3, 4] * 7
        for a, b in zip(probes, probes[1:]):
            assert b.timestamp > a.timestamp + configured[a.arbitration_id - 0x201]
        assert probes[0].timestamp > t_before
        assert all(len(backend.applied(j)) == 7 for j in JOINT_NAMES)   # zero-velocity probes
    # seed 002's λ for one burst: wire time of the frames up to each station's own + its latency
    q = np.array([1.0, 31.0, 51.0, -1.0])
    v = np.array([10.0, 0.0, 5.0, 1e-6])      # velocities go out as at least 1 increment/s
    frames = [struct.pack("<iI", round(q[j] * CPU), max(1, round(v[j] * CPU))) for j in range(4)]
    wire = np.cumsum([frame_bits(can.Message(arbitration_id=0x201 + j, data=frames[j], is_extended_id=False))
                      for j in range(4)]) / js.cfg.bitrate
    np.testing.assert_allclose(js.burst_delays(q, v), wire + lam, rtol=0, atol=1e-12)
    sync_wire = np.cumsum([frame_bits(can.Message(arbitration_id=0x401 + j, data=frames[j], is_extended_id=False))
                           for j in range(4)]) / js.cfg.bitrate
    np.testing.assert_allclose(js.burst_delays(q, v, base=0x400), sync_wire + lam, rtol=0, atol=1e-12)


def test_corrected_velocities_agree_with_their_own_frames(make):
    """Seed 002's ω = Δθ/(T − λ) where λ includes the frame that carries ω: over many bursts,
    where each joint stands at T (λ recomputed from the frames actually built, ω as the
    frame carries it in whole increments/s) is its target to within half an increment, below
    what the drive itself can resolve;
    T not above λ is refused naming the joint."""
    backend, js = make(delays=(0.0005, 0.001, 0.0015, 0.002), delays_s="measure")
    rng = np.random.default_rng(5)
    T = 0.01
    worst = 0.0
    for _ in range(300):
        q = np.array(START) + rng.uniform(-5, 5, 4)
        d = rng.uniform(-2, 2, 4)
        v, lam = js.corrected_velocities(q, d, T)
        again = js.burst_delays(q, v)                      # the frames that will really go out
        v_sent = np.maximum(1, np.round(np.abs(v) * CPU))  # what they carry, increments/s
        short = np.abs(d) * CPU - v_sent * (T - again)       # increments still to go at T
        worst = max(worst, float(np.max(np.abs(short))))
        np.testing.assert_allclose(again, lam, rtol=0, atol=3 / js.cfg.bitrate)   # a few bits at most
    assert worst < 0.5, worst
    with pytest.raises(StationCommandError, match="not longer than the delay of j4"):
        js.corrected_velocities(np.array(START), np.full(4, 0.1), 0.002)
    with pytest.raises(StationCommandError, match="j1 would need .* units/s .* above its max_velocity 720"):
        js.corrected_velocities(np.array(START), np.ones(4), 0.002)


def _corrected_six_steps(js, q, d, T, hint):
    """corrected_velocities' velocities as its definition says: per station six steps of
    velocity -> frame -> velocity at most, then the closest consistent one (the reference
    for its early end at a cycle)."""
    from drivers.stations.streaming import _setpoint_bits
    rate, lat, t, vel, flips = float(js.cfg.bitrate), js.latency_s.tolist(), 0.0, [0.0] * 4, 0
    for s in js._stations:
        j, cpu = s.index, s.cpu
        need, cob, target_inc = abs(d[j]) * cpu, 0x200 + s.node_id, round(q[j] * cpu)
        if hint is not None and T > hint[j]:
            v_inc = max(1, round(need / (T - hint[j])))
        else:
            b = _setpoint_bits(cob, target_inc, max(1, round(need / T)))
            v_inc = max(1, round(need / (T - (t + b / rate) - lat[j])))
        b, seen = _setpoint_bits(cob, target_inc, v_inc), [v_inc]
        for _ in range(6):
            nxt = max(1, round(need / (T - (t + b / rate) - lat[j])))
            if nxt == v_inc:
                break
            v_inc = nxt
            b = _setpoint_bits(cob, target_inc, v_inc)
            seen.append(v_inc)
        else:
            flips += 1
            v_inc = js._closest_consistent(seen, need, T - t - lat[j], rate,
                                           lambda v: _setpoint_bits(cob, target_inc, v))
            b = _setpoint_bits(cob, target_inc, v_inc)
        t += b / rate
        vel[j] = math.copysign(v_inc / cpu, d[j]) if d[j] else v_inc / cpu
    return vel, flips


def test_corrected_velocities_end_a_cycle_as_six_steps_would(make):
    """A velocity whose frame flips between two lengths: the search stops at the first
    repeat, with the velocity six steps and the closest consistent one give, to the bit."""
    backend, js = make(delays=(0.0005, 0.001, 0.0015, 0.002), delays_s="measure")
    rng = np.random.default_rng(9)
    T, hint, flips = 0.01, None, 0
    for _ in range(400):
        q = np.array(START) + rng.uniform(-5, 5, 4)
        d = rng.uniform(-2, 2, 4)
        v, lam = js.corrected_velocities(q, d, T, hint)
        ref, n = _corrected_six_steps(js, q.tolist(), d.tolist(), T, None if hint is None else hint.tolist())
        assert v.tolist() == ref
        hint, flips = lam, flips + n
    assert flips > 20, flips                               # the case is met, often


def test_delays_measured_at_start_when_configured_so(make):
    configured = (0.001, 0.002, 0.003, 0.004)
    backend, js = make(delays=configured, delays_s="measure")
    if backend.name == "sim":
        np.testing.assert_allclose(js.latency_s, configured, rtol=0, atol=1e-9)
    assert js.fault is None and set(js.drive_states().values()) == {State.OPERATION_ENABLED}
