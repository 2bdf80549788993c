"""Contract tests for the joint stations, written once and run against every backend
(STYLE habit 4): the simulated stations on the rate-limited virtual bus now; real drives
when marked ``hw`` (set CELL_STATIONS_HW="interface:channel", e.g. "socketcan:can0").

Tests that need fault injection (pull a station's cable, force an EMCY, put a garbage
frame on the wire) call ``backend.<hook>``; on hardware these skip unless a rig provides them.
"""
from __future__ import annotations

import os
import threading
import time
import uuid

import can
import numpy as np
import pytest

from cell.kinematics import Scara
from cell.trajectory.line import plan_line
from drivers.stations.bus import frame_time_s, open_bus
from drivers.stations.cia402 import State
from drivers.stations.config import StationsConfig
from drivers.stations.driver import JointStations, StationCommandError
from drivers.stations.faults import FaultCode, StationFaultError
from cell.sim.stations import SimStationSet
from tests.drivers.conftest import wait_for

# Short timings keep the tests fast; the margins (3x our heartbeat watchdog, 15x the drives'
# consumer of our 20 ms heartbeat) absorb the scheduling stalls of Python threads on a loaded
# 2-core CI machine, where a 120 ms consumer time once timed out during a reset.
FAST = dict(heartbeat_ms=50, heartbeat_tolerance=3.0, controller_heartbeat_ms=20, consumer_timeout_ms=300,
            tpdo_event_ms=5)
ROBOT = Scara.preset("seed002")


def wait_standstill(js, timeout=2.0):
    """Positions as soon as two TPDO readings 20 ms apart agree (the stop ramp is over)."""
    deadline = time.monotonic() + timeout
    prev = js.actual_positions()
    while True:
        time.sleep(0.02)
        now = js.actual_positions()
        if np.allclose(now, prev, atol=1e-9):
            return now
        if time.monotonic() > deadline:
            raise AssertionError(f"still moving: {prev} → {now}")
        prev = now


class SimBackend:
    name = "sim"

    def __init__(self, delays=(0.0, 0.0, 0.0, 0.0), initial=(0.0, 30.0, 50.0, 0.0), **over):
        self.cfg = StationsConfig(channel=f"t-{uuid.uuid4().hex[:8]}", **{**FAST, **over})
        self.sims = SimStationSet(self.cfg, delays, initial).start()

    def unplug(self, joint):
        self.sims.by_joint(joint).unplug()

    def replug(self, joint):
        self.sims.by_joint(joint).power_cycle()

    def inject_following_error(self, joint):
        self.sims.by_joint(joint).inject_following_error()

    def raw_bus(self):
        return open_bus("virtual", self.cfg.channel, self.cfg.bitrate)

    def drive_state(self, joint):
        return self.sims.by_joint(joint).state

    def close(self):
        self.sims.stop()


class HwBackend:
    name = "hw"

    def __init__(self, **over):
        spec = os.environ.get("CELL_STATIONS_HW")
        if not spec:
            pytest.skip("hardware contract run needs CELL_STATIONS_HW=interface:channel")
        interface, channel = spec.split(":", 1)
        self.cfg = StationsConfig(interface=interface, channel=channel, **{**FAST, **over})

    def _no(self, *a):
        pytest.skip("fault injection is not available on this hardware rig")

    unplug = replug = inject_following_error = raw_bus = drive_state = _no

    def close(self):
        pass


@pytest.fixture(params=["sim", pytest.param("hw", marks=pytest.mark.hw)])
def make(request):
    made = []

    def _make(**kw):
        backend = (SimBackend if request.param == "sim" else HwBackend)(**kw)
        made.append(backend)
        js = JointStations.from_config(backend.cfg)
        made.append(js)
        js.start()
        return backend, js

    yield _make
    for obj in reversed(made):
        (obj.shutdown if isinstance(obj, JointStations) else obj.close)()
    # python-can's cyclic tasks end within one period after stop(): no leaked threads
    for t in threading.enumerate():
        if t is not threading.current_thread() and t.name.startswith(("Cyclic send task", "sim-station", "can-wire", "stations-")):
            t.join(timeout=1.0)
            assert not t.is_alive(), f"leaked thread {t.name}"


def test_startup_reaches_operation_enabled(make):
    _, js = make()
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}
    assert js.fault is None and js.fault_code == FaultCode.NONE
    np.testing.assert_allclose(js.actual_positions(), [0.0, 30.0, 50.0, 0.0], atol=1e-3)


def test_point_to_point_move_reaches_target(make):
    _, js = make()
    target = [12.5, 45.0, 60.0, -20.0]
    duration = js.move_to(target, speed=400.0)
    assert duration == pytest.approx(max(12.5, 15.0, 10.0, 20.0) / 400.0)
    js.wait_reached(timeout_s=3.0, tol=1e-3)
    np.testing.assert_allclose(js.actual_positions(), target, atol=1e-3)


def test_bad_move_is_refused_and_sends_nothing(make):
    backend, js = make()
    before = js.actual_positions()
    with pytest.raises(StationCommandError, match="j2 = 999.0000 is outside its limits"):
        js.move_to([0, 999, 50, 0], 100)
    with pytest.raises(StationCommandError, match="j3 = nan is not a finite"):
        js.move_to([0, 30, float("nan"), 0], 100)
    with pytest.raises(StationCommandError, match="need 4 joint values"):
        js.move_to([0, 30], 100)
    with pytest.raises(StationCommandError, match="speed = -1"):
        js.move_to([0, 30, 50, 0], -1)
    time.sleep(0.03)
    np.testing.assert_allclose(js.actual_positions(), before, atol=1e-6)


@pytest.mark.parametrize("mode", ["reception", "sync"])
def test_streamed_line_reaches_its_interpolation_points(make, mode):
    sigma = 0.002
    backend, js = make(delays=(sigma, 2 * sigma, 3 * sigma, 4 * sigma))
    start, end = ROBOT.fk([0.0, 30.0, 50.0, 0.0]), None
    end = start + np.array([-40.0, 30.0, 10.0, 20.0])
    lam = js.measure_delays(rounds=3) if mode == "reception" else None
    # 100 ms segments: Python thread jitter (a few ms, more on a loaded CI machine) stays small
    # against a segment, so a SYNC that comes late does not skip an interpolation point
    plan = plan_line(ROBOT, start, end, n_points=5, segment_s=0.1, delays_s=lam)
    js.start_recording()
    report = js.stream(plan.segments, mode=mode)
    js.wait_reached(timeout_s=3.0, tol=1e-3)
    rec = np.array(js.stop_recording())
    assert report.sent.shape == (5,) and np.all(np.diff(report.sent) > 0)
    np.testing.assert_allclose(js.actual_positions(), plan.joints_deg[-1], atol=1e-3)
    # every joint passes through every interpolation point (its TPDO trace crosses it)
    for j in range(4):
        trace = rec[rec[:, 1] == j, 2]
        for k in range(1, 6):
            q = plan.joints_deg[k, j]
            assert np.min(np.abs(trace - q)) < 0.05 * max(abs(plan.joints_deg[-1, j] - plan.joints_deg[0, j]), 1) + 1e-3


def test_bad_segments_are_refused_before_anything_is_sent(make):
    _, js = make()
    plan = plan_line(ROBOT, ROBOT.fk([0, 30, 50, 0]), ROBOT.fk([10, 40, 60, 5]), 3, 0.05)
    from dataclasses import replace
    bad = [plan.segments[0], replace(plan.segments[1], target_deg=np.array([0, 30, 500.0, 0]))]
    with pytest.raises(StationCommandError, match="stream segment 1: j3 = 500.0000 is outside"):
        js.stream(bad)
    with pytest.raises(StationCommandError, match="mode = 'fast'"):
        js.stream(plan.segments, mode="fast")
    with pytest.raises(StationCommandError, match="segment 1: start_s"):
        js.stream([plan.segments[1], plan.segments[0]])
    with pytest.raises(StationCommandError, match="no segments"):
        js.stream([])
    time.sleep(0.02)
    np.testing.assert_allclose(js.actual_positions(), [0, 30, 50, 0], atol=1e-3)


def _assert_all_stopped_and_refused(js, backend, code, skip=()):
    assert js.fault_code == code
    for joint in ("j1", "j2", "j3", "j4"):
        if joint not in skip:
            wait_for(lambda: backend.drive_state(joint) in (State.QUICK_STOP_ACTIVE, State.FAULT),
                     what=f"{joint} stopped")
    with pytest.raises(StationFaultError, match=code.name):
        js.move_to([0, 30, 50, 0], 100)
    with pytest.raises(StationFaultError, match="call reset"):
        js.stream(plan_line(ROBOT, ROBOT.fk([0, 30, 50, 0]), ROBOT.fk([5, 35, 50, 0]), 2, 0.05).segments)


def test_heartbeat_lost_faults_stops_all_and_refuses_until_reset(make):
    backend, js = make()
    js.move_to([40, 60, 80, 40], 100)      # moving when the cable is pulled
    time.sleep(0.05)
    backend.unplug("j2")
    wait_for(lambda: js.fault is not None, what="fault latched")
    assert js.fault.code == FaultCode.HEARTBEAT_LOST and js.fault.joint == "j2"
    _assert_all_stopped_and_refused(js, backend, FaultCode.HEARTBEAT_LOST)
    pos = wait_standstill(js)
    time.sleep(0.05)
    np.testing.assert_allclose(js.actual_positions(), pos, atol=1e-9)   # nothing moves
    with pytest.raises(StationFaultError, match=r"still silent: j2 \(node 2\)"):
        js.reset()
    assert js.fault_code == FaultCode.HEARTBEAT_LOST  # unchanged by the refused reset
    backend.replug("j2")
    wait_for(lambda: not js.watchdog.silent(), what="j2 heartbeat back")
    js.reset()
    assert js.fault is None and set(js.drive_states().values()) == {State.OPERATION_ENABLED}
    js.move_to([1, 31, 51, 1], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)


def test_emcy_faults_and_stops_all(make):
    backend, js = make()
    backend.inject_following_error("j3")
    wait_for(lambda: js.fault is not None, what="fault latched")
    assert js.fault.code == FaultCode.EMCY_FOLLOWING_ERROR and js.fault.emcy_code == 0x8611
    assert js.fault.joint == "j3"
    _assert_all_stopped_and_refused(js, backend, FaultCode.EMCY_FOLLOWING_ERROR)
    js.reset()
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}


@pytest.mark.parametrize("frame, code", [
    (can.Message(arbitration_id=0x181, data=b"\x01\x02\x03", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x702, data=b"", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x083, data=b"\x10\x00", is_extended_id=False), FaultCode.GARBAGE_FRAME),
    (can.Message(arbitration_id=0x123, data=b"\xde\xad", is_extended_id=False), FaultCode.UNEXPECTED_FRAME),
    (can.Message(arbitration_id=0x184, is_remote_frame=True, dlc=6, is_extended_id=False), FaultCode.UNEXPECTED_FRAME),
    (can.Message(arbitration_id=0x1ABCDEF, data=b"\x00", is_extended_id=True), FaultCode.UNEXPECTED_FRAME),
    (can.Message(is_error_frame=True, is_extended_id=False), FaultCode.BUS_ERROR_FRAME),
])
def test_garbage_frame_faults_and_never_crashes(make, frame, code):
    """Policy: garbage on the wire is a fault (code per kind), never a crash."""
    backend, js = make()
    bus = backend.raw_bus()
    try:
        bus.send(frame)
        wait_for(lambda: js.fault is not None, what="fault latched")
    finally:
        bus.shutdown()
    assert js.fault.code == code
    _assert_all_stopped_and_refused(js, backend, code)
    assert js.network.notifier.exception is None    # the receive thread survived
    js.reset()
    js.move_to([2, 32, 52, 2], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)


def test_unknown_frames_can_be_logged_instead(make):
    backend, js = make(unknown_frames="log")
    bus = backend.raw_bus()
    try:
        bus.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        wait_for(lambda: js.monitor.rejected == 1, what="frame seen")
    finally:
        bus.shutdown()
    assert js.fault is None
    js.move_to([3, 33, 53, 3], 200)
    js.wait_reached(timeout_s=3.0, tol=1e-3)


def test_controller_heartbeat_stops_drives_quick_stop_themselves(make):
    backend, js = make()
    js.move_to([90, 90, 90, 90], 100)   # a long move
    time.sleep(0.05)
    js.stop_heartbeat()                   # the controller "hangs"
    for joint in ("j1", "j2", "j3", "j4"):
        wait_for(lambda: backend.drive_state(joint) is State.FAULT, what=f"{joint} in Fault")
    wait_for(lambda: js.fault is not None, what="EMCY seen")
    assert js.fault.code == FaultCode.EMCY_HEARTBEAT
    pos = wait_standstill(js)
    assert np.all(pos < 90 - 1)           # stopped on the way, not at the target
    time.sleep(0.05)
    np.testing.assert_allclose(js.actual_positions(), pos, atol=1e-9)
    js.reset()                            # heartbeat restarts, drives re-enabled
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}


def test_quick_stop_all_is_category_2_and_latches(make):
    backend, js = make()
    js.move_to([90, 90, 90, 90], 100)
    time.sleep(0.05)
    js.quick_stop_all("operator")
    _assert_all_stopped_and_refused(js, backend, FaultCode.QUICK_STOP)
    wait_for(lambda: set(js.drive_states().values()) == {State.QUICK_STOP_ACTIVE},
             what="statuswords say Quick stop active")   # category 2: powered, holding
    js.reset()
    assert set(js.drive_states().values()) == {State.OPERATION_ENABLED}


def test_rate_limit_holds_on_the_virtual_bus(make):
    backend, js = make()
    bus = backend.raw_bus()
    try:
        listener = backend.raw_bus()
        n = 300
        msg = can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False)
        js.monitor.unknown_frames = "log"
        for _ in range(n):
            bus.send(msg)
        got = []
        while len(got) < n:
            m = listener.recv(timeout=2.0)
            assert m is not None
            if m.arbitration_id == 0x123:
                got.append(m.timestamp)
        listener.shutdown()
    finally:
        bus.shutdown()
    gaps = np.diff(got)
    assert np.all(gaps >= frame_time_s(msg, 1_000_000) - 1e-6)  # float64 epoch stamps: ~0.2 µs
    assert (n - 1) / (got[-1] - got[0]) <= 1_000_000 / 111


def test_delay_measurement_sees_the_configured_delays(make):
    configured = np.array([0.005, 0.015, 0.025, 0.035])
    backend, js = make(delays=tuple(configured))
    lam = js.measure_delays(rounds=7)
    # measured = configured + frame times + thread latency (never less than configured).
    # Stations 10 ms apart: each estimate must land nearer its own station than the next,
    # which a loaded 2-core CI machine still allows (median of 7 rounds).
    assert np.all(lam >= configured - 0.0005)
    assert np.all(lam < configured + 0.009)
    np.testing.assert_allclose(js.delays_s, lam)
