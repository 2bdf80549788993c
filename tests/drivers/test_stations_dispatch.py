"""FrameDispatch: the controller's TPDOs go straight to the driver, the rest to canopen.

Unit tests of the routing with recording listeners, then the real driver on simulated
stations: its positions and statuswords follow the TPDOs while canopen's PDO map of TPDO1
never sees one (nothing else reads it), and the bus monitor still sees every frame."""
from __future__ import annotations

import can
import numpy as np

from drivers.stations.dispatch import FrameDispatch
from drivers.stations.driver import JointStations
from drivers.stations.sim import SimStationSet
from tests.drivers.test_stations_sim import _cell_cfg


class Seen(can.Listener):
    def __init__(self):
        self.frames = []

    def on_message_received(self, msg):
        self.frames.append(msg)


def frame(cob_id: int, data: bytes = b"\x01\x02", **kw) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, timestamp=1.5, **kw)


def test_frames_with_a_handler_go_to_it_alone_and_the_rest_to_the_fallback():
    canopen_side, got = Seen(), []
    d = FrameDispatch(canopen_side, {0x181: lambda data, t: got.append((bytes(data), t))})
    tpdo, heartbeat, sdo = frame(0x181), frame(0x701, b"\x05"), frame(0x581, bytes(8))
    for msg in (tpdo, heartbeat, sdo):
        d.on_message_received(msg)
    assert got == [(b"\x01\x02", 1.5)]
    assert canopen_side.frames == [heartbeat, sdo]


def test_error_and_remote_frames_reach_no_handler_as_canopen_drops_them():
    canopen_side, got = Seen(), []
    d = FrameDispatch(canopen_side, {0x181: lambda data, t: got.append(data)})
    d.on_message_received(can.Message(arbitration_id=0x181, is_error_frame=True))
    d.on_message_received(can.Message(arbitration_id=0x181, is_remote_frame=True, is_extended_id=False))
    assert got == [] and canopen_side.frames == []


def test_a_failing_handler_is_logged_and_reception_goes_on():
    canopen_side, got = Seen(), []

    def bad(data, t):
        raise RuntimeError("boom")
    d = FrameDispatch(canopen_side, {0x181: bad, 0x182: lambda data, t: got.append(t)})
    d.on_message_received(frame(0x181))                    # does not raise
    d.on_message_received(frame(0x182))
    assert got == [1.5]


def test_the_driver_reads_its_tpdos_past_canopens_pdo_map_and_the_monitor_sees_all(vclock):
    cfg = _cell_cfg()
    sims = SimStationSet(cfg, None, (0.0, 30.0, 50.0, 0.0), clock=vclock).start()
    js = JointStations.from_config(cfg, clock=vclock)
    js.start()
    try:
        net = js.network
        assert isinstance(net.listeners[0], FrameDispatch) and net.listeners[-1] is js.monitor
        counts = [s.tpdo_count for s in js._stations]
        seen = js.monitor.seen
        js.move_to([10.0, 40.0, 60.0, 10.0], 200.0)
        js.wait_reached(timeout_s=2.0, tol=1e-3)
        assert np.allclose(js.actual_positions(), [10.0, 40.0, 60.0, 10.0], atol=1e-3)
        assert all(s.tpdo_count > c for s, c in zip(js._stations, counts))
        assert js.monitor.seen - seen >= sum(s.tpdo_count - c for s, c in zip(js._stations, counts))
        for s in js._stations:                             # canopen's map of TPDO1 saw none
            assert s.node.tpdo[1].timestamp is None and not s.node.tpdo[1].is_received
    finally:
        js.shutdown()
        sims.stop()

