"""The simulated station's own PDO path: one ``struct`` per PDO map gives the same bytes as
canopen's per-variable encoding, and each RPDO is taken by exactly one handler however
often the master starts the node."""
from __future__ import annotations

import struct

import can
import canopen
import pytest

from drivers.stations.driver import EDS_PATH
from drivers.stations.sim_canopen import DriveListener, pdo_codec
from tests.drivers.test_stations_sim import _setpoint, rig  # noqa: F401 -- the rig fixture


@pytest.fixture
def node():
    n = canopen.Network().add_node(canopen.LocalNode(2, canopen.import_od(str(EDS_PATH), 2)))
    n.rpdo.read(from_od=True)
    n.tpdo.read(from_od=True)
    return n


@pytest.mark.parametrize("values", [(0, 0), (-2**31, 0xFFFF), (2**31 - 1, 0x1237), (-138889, 0x0627)])
def test_tpdo_codec_packs_the_bytes_canopen_would(node, values):
    tx = node.tpdo[1]
    codec = pdo_codec(tx)
    assert codec is not None and codec.indices == (0x6064, 0x6041)
    live = dict(zip(codec.indices, values))
    for var in tx.map:                        # canopen's own path, variable by variable
        if var.length:
            var.set_data(var.od.encode_raw(live[var.index]))
    assert codec.struct.pack(*values) == bytes(tx.data)


def test_rpdo_codec_reads_what_canopen_reads(node):
    rx = node.rpdo[1]
    codec = pdo_codec(rx)
    data = struct.pack("<iI", -123456, 987654)
    rx.data = bytearray(data)
    want = {v.index: v.od.decode_raw(v.get_data()) for v in rx.map if v.length}
    assert dict(zip(codec.indices, codec.struct.unpack_from(data))) == want == {0x607A: -123456, 0x6081: 987654}


def test_a_map_off_whole_bytes_takes_canopens_path(node):
    tx = node.tpdo[1]
    tx.clear()
    tx.add_variable(0x6041, length=4)         # half a statusword: no struct for that
    tx.add_variable(0x6064)
    assert pdo_codec(tx) is None
    tx.clear()
    assert pdo_codec(tx) is None             # nothing mapped


def test_an_rpdo_is_taken_once_after_the_node_is_started_again(rig):  # noqa: F811
    st = rig.st
    rig.node.nmt.state = "OPERATIONAL"        # a second NMT start: the maps are read again
    rig.clock.sleep(0.001)
    assert st.network.subscribers[0x202] == [h for _, h in st._rx_subs if _ == 0x202]
    assert len(st.network.subscribers[0x202]) == 1
    t_end = _setpoint(rig, 1000, 100_000)
    rig.clock.sleep(0.005)
    assert st.applied == [(t_end, 1000, 100_000)] and st.applied_count == 1


def test_the_drive_listener_hands_data_frames_to_the_subscribers_in_order():
    net = canopen.Network()
    got = []
    net.subscribe(0x202, lambda *a: got.append(("first", *a)))
    net.subscribe(0x202, lambda *a: got.append(("second", *a)))
    listener = DriveListener(net)
    listener.on_message_received(can.Message(arbitration_id=0x202, data=b"\x01\x02", timestamp=1.5,
                                             is_extended_id=False))
    assert got == [("first", 0x202, bytearray(b"\x01\x02"), 1.5), ("second", 0x202, bytearray(b"\x01\x02"), 1.5)]
    del got[:]
    listener.on_message_received(can.Message(arbitration_id=0x202, is_remote_frame=True, is_extended_id=False))
    listener.on_message_received(can.Message(arbitration_id=0x202, is_error_frame=True, is_extended_id=False))
    listener.on_message_received(can.Message(arbitration_id=0x203, data=b"\x01", is_extended_id=False))
    assert got == []                          # remote and error frames dropped, as canopen drops them
    net.subscribe(0x203, lambda *a: got.append(a))   # subscribed later: seen from then on
    listener.on_message_received(can.Message(arbitration_id=0x203, data=b"\x01", is_extended_id=False))
    assert got == [(0x203, bytearray(b"\x01"), 0.0)]


@pytest.mark.parametrize("rig", [{"heartbeat": False}], indirect=True)
def test_tpdos_and_their_event_timer_only_in_operational(rig):  # noqa: F811
    clock, st = rig.clock, rig.st
    clock.sleep(0.05)
    assert len(rig.tpdos) >= 5                       # the 10 ms event timer runs
    rig.node.nmt.state = "PRE-OPERATIONAL"
    clock.sleep(0.001)
    del rig.tpdos[:]
    runs = clock.callbacks_run
    clock.sleep(0.1)
    assert rig.tpdos == [] and st._wake_at is None  # no TPDO, and no wake-up for one
    assert clock.callbacks_run == runs
    rig.node.nmt.state = "OPERATIONAL"
    t_start = clock.now()
    clock.sleep(0.0305)
    stamps = [t for t, _ in rig.tpdos]
    assert len(stamps) == 4 and t_start < stamps[0] < t_start + 0.001   # at once (NMT start), then every 10 ms
    assert [round(b - a, 9) for a, b in zip(stamps, stamps[1:])] == [0.01, 0.01, 0.01]
