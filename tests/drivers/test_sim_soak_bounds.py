"""What the simulated cell keeps per cycle stays bounded however long it runs (a soak of
``cellctl serve --sim`` must stay flat): every check here is a count on the simulated
clock, never a wall time."""
from __future__ import annotations

import pytest

from drivers.stations.driver import JointStations
from drivers.stations.sim import APPLIED_KEEP, SimStation, SimStationConfig, SimStationSet
import drivers.stations.sim_bus as canbus
from tests.drivers.test_stations_sim import CPU, _cell_cfg, _close, _rig, _setpoint


@pytest.fixture
def rig(vclock):
    r = _rig(vclock, heartbeat=False, applied_keep=4)
    yield r
    _close(r)


def test_applied_set_points_keep_only_the_latest(rig):
    clock, st = rig.clock, rig.st
    sent = []
    for k in range(1, 26):
        target, vel = round(0.01 * k * CPU), 100_000
        t_end = _setpoint(rig, target, vel)
        clock.sleep_until(t_end + 1e-4)              # the frame is on the wire and applied
        sent.append((t_end, target, vel))
        assert len(st.applied) <= 2 * 4               # never more than twice the kept number
    assert st.applied_count == 25
    assert len(st.applied) >= 4
    assert st.applied == sent[-len(st.applied):]      # the latest ones, in order, unchanged


def test_applied_set_points_keep_the_default_number_unless_told(vclock):
    cfg = SimStationConfig(joint="j2", node_id=2)
    assert SimStation(cfg, clock=vclock).applied_keep == APPLIED_KEEP
    with pytest.raises(ValueError, match="applied_keep must be at least 1"):
        SimStation(cfg, clock=vclock, applied_keep=0)


def test_fault_history_keeps_only_the_latest_records():
    from drivers.stations.faults import FaultCode, FaultLatch, FaultRecord
    latch = FaultLatch()
    reacted = []
    latch.on_latch(reacted.append)
    n = FaultLatch.HISTORY_KEEP + 50
    for k in range(n):
        latch.latch(FaultRecord(FaultCode.QUICK_STOP, f"stop {k}"))
        if k % 7 == 6:
            latch.clear()                                # reset now and then: a new first fault
    assert len(latch.history) == FaultLatch.HISTORY_KEEP
    assert [r.detail for r in latch.history] == [f"stop {k}" for k in range(50, n)]
    assert len(reacted) == (n + 6) // 7                  # one reaction per first fault, none lost


def test_every_bus_of_the_stations_hands_frames_to_listeners_and_queues_none(vclock):
    """python-can's VirtualBus keeps an unbounded receive queue per bus for ``recv``; on the
    cell's wire every bus has listeners, so nothing may pile up there."""
    cfg = _cell_cfg()
    sims = SimStationSet(cfg, None, None, clock=vclock).start()
    js = JointStations.from_config(cfg, clock=vclock)
    try:
        js.start()
        frames0 = canbus.wire_stats(cfg.channel)[0]
        vclock.sleep(2.0)                                # heartbeats, TPDOs every 20 ms
        wire = canbus._wires[cfg.channel]
        assert wire.frames - frames0 > 400
        assert len(wire.buses) == 5                      # 4 drives + the controller
        assert all(b._listeners is not None and b.queue.qsize() == 0 for b in wire.buses)
    finally:
        js.shutdown()
        sims.stop()
