"""Modbus spec conformance, with hand-built MBAP frames on a raw socket.

First the deviations of a bare pymodbus 3.16.1 server are reproduced (if one of these
fails after a pymodbus upgrade, the fix in drivers/plc/conformance.py may be removable),
then our server is held to the MODBUS Application Protocol Specification V1.1b3.
"""
from __future__ import annotations

import random
import socket
import struct

import pytest
from pymodbus.server import ModbusTcpServer

from drivers.plc.conformance import (
    SUPPORTED, ConformantTcpServer, Frame, FramingError, MbapStream, ServerThread, check_request,
    exception_adu,
)
from drivers.plc.register_map import PLC_MAP
from drivers.plc.server import build_datastore

CMD_COIL = 16 * PLC_MAP["command_word"].address   # coil of command_word bit 0 (execute)


pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")


# ---------------------------------------------------------------- raw Modbus TCP helpers
def mbap(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def _recv_exact(s: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = s.recv(n - len(out))
        if not chunk:
            raise ConnectionError(f"closed after {len(out)} of {n} bytes")
        out += chunk
    return out


def recv_adu(s: socket.socket) -> bytes:
    head = _recv_exact(s, 6)
    return head + _recv_exact(s, int.from_bytes(head[4:6], "big"))


def transact(port: int, raw: bytes, answers: int = 1) -> list[bytes]:
    """Send ``raw`` in one ``sendall`` and read ``answers`` complete ADUs."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(raw)
        return [recv_adu(s) for _ in range(answers)]


def closed_by_server(s: socket.socket) -> bool:
    try:
        return s.recv(100) == b""
    except ConnectionResetError:
        return True


def fc3(tid: int, address: int = 0, count: int = 2) -> bytes:
    return mbap(tid, struct.pack(">BHH", 3, address, count))


# ---------------------------------------------------------------- servers
@pytest.fixture
def bare_port():
    server = ServerThread(lambda addr: ModbusTcpServer(build_datastore(PLC_MAP, None), address=addr),
                          name="bare-pymodbus")
    yield server.start()
    server.stop()


# ---------------------------------------------------------------- bare pymodbus deviates
def test_bare_pymodbus_answers_unsupported_fc_with_fc_0x80(bare_port):
    assert transact(bare_port, mbap(1, b"\x41\x00\x00")) == [mbap(1, b"\x80\x01")]


@pytest.mark.parametrize("qty", [0, 126])
def test_bare_pymodbus_answers_bad_read_quantity_with_80_01(bare_port, qty):
    assert transact(bare_port, fc3(1, 0, qty)) == [mbap(1, b"\x80\x01")]


def test_bare_pymodbus_takes_fc5_value_0x1234_as_on(bare_port):
    assert transact(bare_port, mbap(1, struct.pack(">BHH", 5, CMD_COIL, 0x1234))) == [
        mbap(1, struct.pack(">BHH", 5, CMD_COIL, 0xFF00))]


def test_bare_pymodbus_answers_only_the_first_of_two_requests(bare_port):
    with socket.create_connection(("127.0.0.1", bare_port), timeout=5) as s:
        s.sendall(fc3(7) + fc3(8))
        assert recv_adu(s)[:2] == b"\x00\x07"
        s.sendall(fc3(9))                    # the next request is answered; tid 8 never was
        assert recv_adu(s)[:2] == b"\x00\x09"


# ---------------------------------------------------------------- our server conforms
@pytest.mark.parametrize("fc", [0x2B, 0x41, 0x04, 0x08, 0x16, 0x00, 0x7F, 0x83])
def test_unsupported_function_code_answers_fc_or_0x80_with_01(link, fc):
    pdu = bytes([fc, 0x0E, 0x01, 0x00])
    assert transact(link.port, mbap(3, pdu, unit=0x11)) == [mbap(3, bytes([fc | 0x80, 1]), unit=0x11)]


@pytest.mark.parametrize("pdu, fc", [
    (struct.pack(">BHH", 3, 0, 0), 3),            # FC3 quantity 0
    (struct.pack(">BHH", 3, 0, 126), 3),          # FC3 quantity 126
    (struct.pack(">BHH", 1, 0, 2001), 1),         # FC1 quantity > 2000
    (struct.pack(">BHH", 2, 0, 0), 2),            # FC2 quantity 0
    (struct.pack(">BH", 3, 0), 3),                # FC3 PDU too short
    (struct.pack(">BHHB", 3, 0, 1, 0), 3),        # FC3 PDU too long
    (struct.pack(">BHHB", 16, 20, 1, 4) + b"\x00\x01\x00\x02", 16),   # byte count != 2*qty
    (struct.pack(">BHHB", 16, 20, 2, 4) + b"\x00\x01", 16),           # data shorter than byte count
    (struct.pack(">BHHB", 16, 20, 0, 0), 16),                         # FC16 quantity 0
    (struct.pack(">BHHB", 15, CMD_COIL, 9, 1) + b"\x01", 15),         # FC15 byte count != ceil(9/8)
    (struct.pack(">BHHHHB", 23, 0, 0, 20, 1, 2), 23),                 # FC23 read quantity 0
    (struct.pack(">BH", 6, 20), 6),               # FC6 PDU too short
])
def test_malformed_request_answers_03(link, pdu, fc):
    before = link.snapshot()
    assert transact(link.port, mbap(9, pdu)) == [mbap(9, bytes([fc | 0x80, 3]))]
    assert link.snapshot() == before


def test_largest_legal_fc16_passes_framing_and_is_judged_by_address(link):
    pdu = struct.pack(">BHHB", 16, 20, 123, 246) + b"\x00" * 246     # 253-byte PDU, the maximum
    assert transact(link.port, mbap(9, pdu)) == [mbap(9, b"\x90\x02")]


def test_fc5_value_other_than_0000_or_ff00_is_illegal_value_and_coil_unchanged(link):
    assert transact(link.port, mbap(4, struct.pack(">BHH", 5, CMD_COIL, 0x1234))) == [mbap(4, b"\x85\x03")]
    assert link.read("command_word") == 0 and link.drain_writes() == []
    ok = struct.pack(">BHH", 5, CMD_COIL, 0xFF00)
    hb = struct.pack(">BHH", 6, 1, 1)                                  # heartbeat first: owner
    assert transact(link.port, mbap(6, hb) + mbap(5, ok), answers=2) == [mbap(6, hb), mbap(5, ok)]
    assert link.read_bits("command_word")["execute"]


def test_two_requests_in_one_segment_get_two_answers_in_order(link):
    answers = transact(link.port, fc3(7) + fc3(8), answers=2)
    assert [a[:2] for a in answers] == [b"\x00\x07", b"\x00\x08"]
    assert answers[0][7:] == b"\x03\x04" + PLC_MAP.version.to_bytes(2, "big") + b"\x00\x00"  # map_version, heartbeat 0


def test_mixed_valid_and_invalid_requests_in_one_segment_keep_order(link):
    hb = mbap(9, struct.pack(">BHH", 6, 1, 1))                          # heartbeat first: owner
    raw = hb + fc3(1) + mbap(2, b"\x41") + mbap(3, struct.pack(">BHH", 6, 20, 12)) + fc3(4, 20, 1)
    answers = transact(link.port, raw, answers=5)[1:]
    assert [a[:2] for a in answers] == [b"\x00\x01", b"\x00\x02", b"\x00\x03", b"\x00\x04"]
    assert answers[1] == mbap(2, b"\xc1\x01")
    assert answers[3][7:] == b"\x03\x02\x00\x0c"                     # sees the FC6 before it


def test_many_pipelined_requests_beyond_pymodbus_buffer_are_all_answered(link):
    raw = b"".join(fc3(tid, 0, 1) for tid in range(1, 41))          # 480 bytes in one send
    answers = transact(link.port, raw, answers=40)
    assert [int.from_bytes(a[:2], "big") for a in answers] == list(range(1, 41))


def test_requests_in_separate_segments_keep_their_order_behind_a_bit_function(link):
    """A register request that arrives alone is answered at once in the read callback,
    unless something of its connection waits before it: here a coil write (FC5, answered by
    pymodbus in the worker) sent just before it in its own segment. Whenever the second
    segment comes in, the answers come in request order and the read sees the write."""
    on, off = struct.pack(">BHH", 5, CMD_COIL, 0xFF00), struct.pack(">BHH", 5, CMD_COIL, 0x0000)
    with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.sendall(mbap(1, struct.pack(">BHH", 6, 1, 1)))            # heartbeat: the owner
        assert recv_adu(s) == mbap(1, struct.pack(">BHH", 6, 1, 1))
        for tid in range(2, 202, 2):
            coil = on if tid % 4 else off
            s.sendall(mbap(tid, coil))
            s.sendall(fc3(tid + 1, PLC_MAP["command_word"].address, 1))
            assert recv_adu(s) == mbap(tid, coil)
            assert recv_adu(s) == mbap(tid + 1, struct.pack(">BBH", 3, 2, 1 if tid % 4 else 0))


def test_request_split_across_segments_is_answered_once(link):
    frame = fc3(11, 0, 3)
    with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for i in range(len(frame)):
            s.sendall(frame[i:i + 1])
        assert recv_adu(s) == mbap(11, b"\x03\x06" + PLC_MAP.version.to_bytes(2, "big") + b"\x00" * 4)


@pytest.mark.parametrize("garbage", [
    b"\x00\x01\x12\x34\x00\x06\x01\x03\x00\x00\x00\x01",    # protocol id 0x1234
    b"\x00\x01\x00\x00\x00\x00\x01",                        # length 0
    b"\x00\x01\x00\x00\x00\x01\x01",                        # length 1: no function code
    b"\x00\x01\x00\x00\xff\xff\x01" + b"\x03" * 20,         # length 65535
    b"GET / HTTP/1.1\r\nHost: plc\r\n\r\n",                 # not Modbus at all
])
def test_garbage_closes_that_connection_and_the_server_still_answers(link, garbage):
    with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:
        s.sendall(garbage)
        assert closed_by_server(s)
    assert transact(link.port, fc3(2, 0, 1)) == [mbap(2, b"\x03\x02" + PLC_MAP.version.to_bytes(2, "big"))]


def test_truncated_frame_then_disconnect_does_not_disturb_the_next_client(link):
    with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:
        s.sendall(fc3(1)[:9])
    assert transact(link.port, fc3(2, 0, 1)) == [mbap(2, b"\x03\x02" + PLC_MAP.version.to_bytes(2, "big"))]


def test_valid_frame_before_garbage_is_still_answered(link):
    with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:
        s.sendall(fc3(5, 0, 1) + b"\x00\x06\x00\x07\x00\x06\x01")
        assert recv_adu(s) == mbap(5, b"\x03\x02" + PLC_MAP.version.to_bytes(2, "big"))
        assert closed_by_server(s)


def test_random_frames_never_crash_the_server(link):
    rng = random.Random(20260101)
    with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:
        for tid in range(300):
            pdu = bytes([rng.choice([1, 2, 3, 5, 6, 15, 16, 23, rng.randrange(256)])]) + rng.randbytes(
                rng.randrange(0, 12))
            s.sendall(mbap(tid, pdu))
            answer = recv_adu(s)
            assert answer[:2] == tid.to_bytes(2, "big")
            if answer[7] & 0x80:
                assert answer[8] in (1, 2, 3), answer.hex(" ")
    assert transact(link.port, fc3(1, 0, 1)) == [mbap(1, b"\x03\x02" + PLC_MAP.version.to_bytes(2, "big"))]
    assert link.read("map_version") == PLC_MAP.version


# ---------------------------------------------------------------- pure pieces
def test_mbap_stream_keeps_partial_frames_and_rejects_bad_headers():
    stream = MbapStream()
    raw = fc3(1) + fc3(2)
    assert stream.feed(raw[:5]) == [] and stream.pending == 5
    frames = stream.feed(raw[5:15])
    assert frames == [Frame(1, 1, b"\x03\x00\x00\x00\x02")] and stream.pending == 3
    assert stream.feed(raw[15:]) == [Frame(2, 1, b"\x03\x00\x00\x00\x02")] and stream.pending == 0
    stream = MbapStream()
    assert stream.feed(fc3(2) + b"\x00\x03\x00\x01\x00\x06\x01") == [Frame(2, 1, b"\x03\x00\x00\x00\x02")]
    assert isinstance(stream.broken, FramingError) and "protocol id 1 (tid 3)" in str(stream.broken)
    with pytest.raises(FramingError, match="protocol id 1"):
        stream.feed(fc3(4))
    stream = MbapStream()
    assert stream.feed(b"\x00\x03\x00\x00\x01\x2c\x01") == []
    assert "length 300" in str(stream.broken)


def test_check_request_and_exception_adu():
    assert sorted(SUPPORTED) == [1, 2, 3, 5, 6, 15, 16, 23]
    assert check_request(b"\x03\x00\x00\x00\x7d") is None
    assert check_request(b"\x03\x00\x00\x00\x7e") == 3
    assert check_request(b"\x05\x00\x00\x00\x00") is None
    assert check_request(b"\x2b\x0e") == 1
    assert exception_adu(Frame(0x1234, 0xFF, b"\x41"), 1) == b"\x12\x34\x00\x00\x00\x03\xff\xc1\x01"


def test_conformant_server_is_a_pymodbus_tcp_server():
    assert issubclass(ConformantTcpServer, ModbusTcpServer)


# ---------------------------------------------------------------- the image answerer = pymodbus
def _register_requests() -> list[bytes]:
    """Register requests a PLC or a fuzzer sends: reads across and beyond the map, writes
    accepted and refused (read-only, reserved, half a u32, out of range, beyond the map)."""
    size, rng = PLC_MAP.size, random.Random(5)
    pdus = [struct.pack(">BHH", 3, a, n) for a, n in ((0, size), (0, 1), (size - 1, 1), (size, 1),
                                                      (size - 2, 4), (1000, 1), (65535, 1), (3, 125))]
    for name, value in (("recipe_select", 3), ("recipe_select", 1000), ("part_id", 77), ("plc_heartbeat", 9)):
        reg = PLC_MAP[name]
        words = [(value >> 16) & 0xFFFF, value & 0xFFFF] if reg.words == 2 else [value]
        pdus.append(struct.pack(f">BHHB{len(words)}H", 16, reg.address, len(words), 2 * len(words), *words))
        pdus.append(struct.pack(">BHH", 6, reg.address, words[-1]))
        pdus.append(struct.pack(f">BHHHHB{len(words)}H", 23, 0, size, reg.address, len(words),
                                2 * len(words), *words))
    for address in (0, 5, 10, 21, 24, 25, size, 200):
        pdus.append(struct.pack(">BHH", 6, address, 1))
        pdus.append(struct.pack(">BHHHHB1H", 23, size - 1, 2, address, 1, 2, 1))
    for _ in range(40):
        a, n = rng.randrange(0, size + 4), rng.randint(1, 4)
        pdus.append(struct.pack(f">BHHB{n}H", 16, a, n, 2 * n, *(rng.randrange(0, 4) for _ in range(n))))
        pdus.append(struct.pack(">BHH", 3, rng.randrange(0, size + 4), rng.randint(1, 8)))
    return pdus


def test_image_answers_match_pymodbus_datastore_answers():
    """The same requests, in the same order, to two links on the same map: one answers the
    register functions from its image, the other through pymodbus's decoder and datastore
    (its ``action`` hook on the same write decision). Every answer, the end image and the
    write events are the same."""
    from drivers.plc.server import PlcLink

    direct = PlcLink(PLC_MAP)
    via_pymodbus = PlcLink(PLC_MAP)          # not started: its image is served by the server below
    pymodbus_server = ServerThread(
        lambda addr: ConformantTcpServer(build_datastore(PLC_MAP, via_pymodbus._action), address=addr,
                                         guard=via_pymodbus.guard), name="plc-via-pymodbus")
    ports = [direct.start(), pymodbus_server.start()]
    try:
        socks = [socket.create_connection(("127.0.0.1", p), timeout=5) for p in ports]
        try:
            for tid, pdu in enumerate(_register_requests(), start=1):
                answers = []
                for s in socks:
                    s.sendall(mbap(tid, pdu))
                    answers.append(recv_adu(s))
                assert answers[0] == answers[1], (pdu.hex(), answers[0].hex(), answers[1].hex())
        finally:
            for s in socks:
                s.close()
        assert direct.snapshot() == via_pymodbus.snapshot()
        writes = [[(w.name, w.value, w.previous) for w in link.drain_writes()] for link in (direct, via_pymodbus)]
        assert writes[0] == writes[1] != []
    finally:
        direct.stop()
        pymodbus_server.stop()
