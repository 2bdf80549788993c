"""The simulated station as a CANopen device, talked to by a plain canopen RemoteNode
(the canopen test_local pattern): SDO, NMT, CiA 402, set-points, limits, EMCY, hook."""
from __future__ import annotations

import struct
import time
import uuid

import canopen
import pytest

from drivers.stations.bus import open_bus
from drivers.stations.cia402 import State
from drivers.stations.config import StationsConfig
from drivers.stations.driver import JointStations
from cell.sim.stations import EDS_PATH, SimStation, SimStationConfig, SimStationSet
from tests.drivers.conftest import wait_for


@pytest.fixture
def rig():
    ch = f"s-{uuid.uuid4().hex[:8]}"
    seen = []
    st = SimStation(SimStationConfig(joint="j2", node_id=2, reception_delay_s=0.0),
                    channel=ch, on_position=lambda j, q, t: seen.append((j, q, t)))
    st.start()
    net = canopen.Network(open_bus("virtual", ch))
    net.NOTIFIER_CYCLE = 0.05
    node = net.add_node(2, str(EDS_PATH))
    net.connect()
    node.nmt.wait_for_heartbeat(2.0)
    # gear 50:1, 10000 inc/rev → 1388.89 inc/deg; limits ±100°
    node.sdo[0x6091][1].raw, node.sdo[0x6091][2].raw = 50, 1
    node.sdo[0x607D][1].raw, node.sdo[0x607D][2].raw = -138889, 138889
    node.sdo[0x6085].raw = 10_000_000
    node.nmt.state = "OPERATIONAL"
    for cw in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = cw
    yield st, net, node, seen
    net.disconnect()
    st.stop()


def test_sdo_nmt_and_enable(rig):
    st, net, node, _ = rig
    assert st.state is State.OPERATION_ENABLED
    assert node.sdo[0x6041].raw & 0x6F == 0x27
    assert node.sdo[0x1000].raw == 0x00020192
    with pytest.raises(canopen.SdoAbortedError):
        node.sdo[0x6041].raw = 0          # read-only: aborted, not crashed
    node.sdo[0x6040].raw = 0x0F          # same state again: ignored
    assert st.state is State.OPERATION_ENABLED


def test_setpoint_moves_at_commanded_speed_with_gear_conversion(rig):
    st, net, node, seen = rig
    cpu = 10000 * 50 / 360
    net.send_message(0x202, struct.pack("<iI", round(10 * cpu), round(200 * cpu)))  # 10° at 200°/s
    wait_for(lambda: seen and abs(seen[-1][1] - 10) < 1e-3, what="target reached and published")
    assert node.sdo[0x6064].raw == round(10 * cpu)
    qs = [q for j, q, t in seen]
    assert {j for j, _, _ in seen} == {1} and qs == sorted(qs) and qs[-1] == pytest.approx(10, abs=1e-3)
    ts = [t for _, q, t in seen if 0 < q < 10]
    speeds = [(b[1] - a[1]) / (b[2] - a[2]) for a, b in zip(seen, seen[1:]) if 0.5 < a[1] and b[1] < 9.5 and b[2] > a[2]]
    assert speeds and max(speeds) == pytest.approx(200, rel=0.02) and ts


def test_setpoint_beyond_limits_is_refused_with_emcy(rig):
    st, net, node, _ = rig
    net.send_message(0x202, struct.pack("<iI", 200_000, 10_000))
    emcy = node.emcy.wait(0x8612, timeout=2.0)
    assert emcy is not None and emcy.code == 0x8612
    wait_for(lambda: st.state is State.FAULT, what="fault")
    assert st.position == pytest.approx(0.0, abs=1e-9)     # never moved
    node.sdo[0x6040].raw = 0x80                            # fault reset
    assert st.state is State.SWITCH_ON_DISABLED


def test_short_rpdo_is_ignored_with_emcy(rig):
    st, net, node, _ = rig
    net.send_message(0x202, b"\x01\x02")
    emcy = node.emcy.wait(0x8210, timeout=2.0)
    assert emcy is not None
    assert st.state is State.OPERATION_ENABLED and st.position == 0.0


def test_quick_stop_ramps_down_and_holds(rig):
    st, net, node, _ = rig
    cpu = 10000 * 50 / 360
    net.send_message(0x202, struct.pack("<iI", round(90 * cpu), round(100 * cpu)))
    wait_for(lambda: st.position > 5, what="moving")
    node.sdo[0x6040].raw = 0x02
    assert st.state is State.QUICK_STOP_ACTIVE
    p = st.position
    time.sleep(0.05)
    assert st.position == pytest.approx(p, abs=0.75)   # ramp: 100²/(2·7200) ≈ 0.69° at most
    stopped = st.position
    time.sleep(0.03)
    assert st.position == stopped


def test_sim_set_validates_lengths():
    with pytest.raises(ValueError, match="needs 4 values"):
        SimStationSet(StationsConfig(), reception_delays_s=[0.0])


def test_driver_start_fails_cleanly_without_stations():
    js = JointStations.from_config({"channel": f"s-{uuid.uuid4().hex[:8]}", "boot_timeout_s": 0.1})
    from drivers.stations.driver import StationStartupError
    with pytest.raises(StationStartupError, match=r"no heartbeat within 0.1 s from j1 \(node 1\), j2"):
        js.start()
    with pytest.raises(StationStartupError, match="not started"):
        js.move_to([0, 0, 0, 0], 1)
    js.shutdown()
