"""The simulated PLC's own Modbus TCP client (cell/sim/modbus_client.py) on real sockets.

Happy paths against the controller's real server (PlcLink) and a bare pymodbus server on
the same datastore; every bad answer from :class:`FakeServer`, a real socket peer that
answers each request with bytes the test crafts. Each bad answer must give an error naming
what was wrong, and leave the client disconnected; the next request connects again.
"""
from __future__ import annotations

import socket
import struct
import threading
import time

import pytest
from pymodbus.server import ModbusTcpServer

from cell.clock import ManualClock
from cell.sim.modbus_client import ModbusLinkError, ModbusRefused, ModbusTcpClient
from drivers.plc.conformance import ServerThread
from drivers.plc.register_map import PLC_MAP
from drivers.plc.server import PlcLink, build_datastore

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")

HB = PLC_MAP["plc_heartbeat"].address
CLOSE = object()          # FakeServer action: close the connection


def _recv_exact(conn: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = conn.recv(n - len(out))
        if not chunk:
            return out
        out += chunk
    return out


class FakeServer:
    """A loopback server that accepts connections one after the other, reads whole MBAP
    requests and answers each with ``reply(request)``: a list of actions, each bytes to send
    (sent as a segment of its own, 20 ms apart) or ``CLOSE``. An empty list answers nothing.
    ``requests`` and ``connections`` keep what came."""

    def __init__(self, reply):
        self.reply = reply
        self.requests: list[bytes] = []
        self.connections = 0
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.1)
        self.port = self._listener.getsockname()[1]
        self._quit = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake-modbus-server", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._quit.is_set():
            try:
                conn, _ = self._listener.accept()
            except socket.timeout:
                continue
            self.connections += 1
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._serve(conn)

    def _serve(self, conn: socket.socket) -> None:
        while True:
            head = _recv_exact(conn, 7)
            if len(head) < 7:
                return                                  # the client closed
            request = head + _recv_exact(conn, struct.unpack_from(">H", head, 4)[0] - 1)
            self.requests.append(request)
            for i, action in enumerate(self.reply(request)):
                if action is CLOSE:
                    return
                if i:
                    time.sleep(0.02)
                conn.sendall(action)

    def close(self) -> None:
        self._quit.set()
        self._thread.join(timeout=5)
        self._listener.close()


def answer(request: bytes, pdu: bytes, tid: int | None = None, pid: int = 0,
           length: int | None = None, unit: int | None = None) -> bytes:
    """An MBAP frame answering ``request`` with ``pdu``; any header field can be set."""
    r_tid, _, _, r_unit = struct.unpack_from(">HHHB", request)
    return struct.pack(">HHHB", r_tid if tid is None else tid, pid,
                       len(pdu) + 1 if length is None else length,
                       r_unit if unit is None else unit) + pdu


def good_pdu(request: bytes, words: int | None = None) -> bytes:
    """The right answer's PDU: registers 0, 1, 2, ... for a read, the echo for a write."""
    fc = request[7]
    if fc in (3, 23):
        n = struct.unpack_from(">H", request, 10)[0] if words is None else words
        return struct.pack(f">BB{n}H", fc, 2 * n, *range(n))
    return request[7:12]                                 # FC6: address, value; FC16: address, quantity


def good(request: bytes) -> list:
    return [answer(request, good_pdu(request))]


@pytest.fixture
def fake(request):
    """A FakeServer answering by the test's ``reply`` (indirect parametrisation or ``good``)."""
    server = FakeServer(getattr(request, "param", good))
    yield server
    server.close()


def client_of(port: int, timeout_s: float = 5.0) -> ModbusTcpClient:
    return ModbusTcpClient("127.0.0.1", port, unit=1, timeout_s=timeout_s)


# ------------------------------------------------------------------ the real servers
@pytest.fixture(params=["PlcLink", "bare pymodbus"])
def server_port(request):
    """The controller's server, or a bare pymodbus server on the same datastore (all zero:
    no map_version, no access rules)."""
    if request.param == "PlcLink":
        link = PlcLink(clock=ManualClock(0.0))
        yield link.start()
        link.stop()
    else:
        bare = ServerThread(lambda addr: ModbusTcpServer(build_datastore(PLC_MAP, None), address=addr),
                            name="bare-pymodbus")
        yield bare.start()
        bare.stop()


def test_reads_and_writes_against_a_real_server(server_port):
    c = client_of(server_port)
    try:
        image = c.read_holding_registers(0, PLC_MAP.size)
        assert len(image) == PLC_MAP.size and image[HB] == 0
        image = c.read_write_registers(0, PLC_MAP.size, HB, [41])     # the write comes first
        assert image[HB] == 41
        c.write_register(PLC_MAP["recipe_select"].address, 3)
        c.write_registers(PLC_MAP["part_id"].address, [0x0001, 0x86A0])
        values = PLC_MAP.decode_image(c.read_holding_registers(0, PLC_MAP.size))
        assert (values["recipe_select"], values["part_id"], values["plc_heartbeat"]) == (3, 100_000, 41)
        assert c.read_holding_registers(HB, 1) == [41]
    finally:
        c.close()
    assert not c.connected


def test_a_refused_write_is_an_exception_response_and_keeps_the_connection():
    link = PlcLink(clock=ManualClock(0.0))
    c = client_of(link.start())
    try:
        c.read_write_registers(0, 1, HB, [1])                         # owns the link
        owner = link.owner
        with pytest.raises(ModbusRefused, match=r"FC6 \(write single register\) .*exception response, "
                                                r"code 02") as refused:
            c.write_register(PLC_MAP["map_version"].address, 2)        # read-only
        assert (refused.value.function, refused.value.code) == (6, 2)
        with pytest.raises(ModbusRefused) as refused:
            c.write_registers(PLC_MAP["recipe_select"].address, [1000])  # out of range
        assert (refused.value.function, refused.value.code) == (16, 3)
        assert c.connected and link.owner == owner                     # the same connection
        assert c.read_holding_registers(0, 1) == [PLC_MAP.version]
    finally:
        c.close()
        link.stop()


def test_a_server_that_goes_away_is_a_link_error_and_one_on_the_same_port_is_reconnected():
    link = PlcLink(clock=ManualClock(0.0))
    port = link.start()
    c = client_of(port, timeout_s=2.0)
    try:
        c.read_write_registers(0, 1, HB, [1])
        link.stop()
        with pytest.raises(ModbusLinkError, match=f"FC23 .* to 127.0.0.1:{port}: connection"):
            c.read_write_registers(0, 1, HB, [2])
        assert not c.connected
        with pytest.raises(ModbusLinkError, match=f"cannot connect to 127.0.0.1:{port}"):
            c.read_holding_registers(0, 1)
        assert not c.connected
        link = PlcLink(clock=ManualClock(0.0))
        link.start(port=port)
        assert c.read_write_registers(0, 1, HB, [3]) == [PLC_MAP.version]
        assert link.read("plc_heartbeat") == 3
    finally:
        c.close()
        link.stop()


# ------------------------------------------------------------------ the happy paths, byte by byte
def test_requests_are_the_spec_frames_with_a_new_transaction_id_each(fake):
    c = client_of(fake.port)
    try:
        assert c.read_holding_registers(5, 3) == [0, 1, 2]
        assert c.read_write_registers(0, 2, 1, [0xBEEF]) == [0, 1]
        c.write_register(11, 0x1234)
        c.write_registers(24, [1, 0x86A0])
    finally:
        c.close()
    assert [r.hex(" ") for r in fake.requests] == [
        "00 01 00 00 00 06 01 03 00 05 00 03",
        "00 02 00 00 00 0d 01 17 00 00 00 02 00 01 00 01 02 be ef",
        "00 03 00 00 00 06 01 06 00 0b 12 34",
        "00 04 00 00 00 0b 01 10 00 18 00 02 04 00 01 86 a0",
    ]
    assert fake.connections == 1


def _in_pieces(request: bytes) -> list:
    frame = answer(request, good_pdu(request))
    return [frame[:3], frame[3:9], frame[9:]]


@pytest.mark.parametrize("fake", [_in_pieces], indirect=True)
def test_an_answer_in_pieces_is_put_together(fake):
    c = client_of(fake.port)
    try:
        assert c.read_holding_registers(0, 70) == list(range(70))
        c.write_register(3, 4)
        assert c.connected
    finally:
        c.close()


def test_transaction_ids_wrap_at_65536(fake):
    c = client_of(fake.port)
    try:
        for _ in range(65537):
            c._next_tid()
        c.read_holding_registers(0, 1)
    finally:
        c.close()
    assert fake.requests[0][:2] == b"\x00\x02"


# ------------------------------------------------------------------ bad answers
def _pdu_of(words: int):
    return lambda req: [answer(req, good_pdu(req, words))]


BAD = {   # name: (reply, request to make, what the error must say)
    "protocol id": (lambda req: [answer(req, good_pdu(req), pid=1)], "fc3",
                    "MBAP protocol id 1 in the answer, not 0"),
    "transaction id": (lambda req: [answer(req, good_pdu(req), tid=99)], "fc3",
                       "transaction id 99 in the answer, 1 sent"),
    "unit id": (lambda req: [answer(req, good_pdu(req), unit=7)], "fc23",
                "unit id 7 in the answer, 1 sent"),
    "length 1": (lambda req: [answer(req, b"", length=1)], "fc3",
                 "MBAP length 1 in the answer, not in 2..254"),
    "length 300": (lambda req: [answer(req, good_pdu(req), length=300)], "fc3",
                   "MBAP length 300 in the answer, not in 2..254"),
    "length beyond the bytes": (lambda req: [answer(req, good_pdu(req), length=20), CLOSE], "fc6",
                                "connection closed by the server after 12 bytes of the answer"),
    "length short of the bytes": (lambda req: [answer(req, good_pdu(req), length=4)], "fc6",
                                  "answer of 12 bytes, its MBAP length 4 makes 10"),
    "function code": (lambda req: [answer(req, b"\x04\x02\x00\x00")], "fc3",
                      "function code 4 in the answer, 3 sent"),
    "exception frame length": (lambda req: [answer(req, b"\x86\x02\x00")], "fc6",
                               "exception response with MBAP length 4, not 3"),
    "odd byte count": (lambda req: [answer(req, b"\x03\x03\x00\x01\x02")], "fc3",
                       "byte count 3 in the answer is odd"),
    "byte count not the quantity": (_pdu_of(1), "fc3",
                                    "byte count 2 in the answer, 4 expected for 2 registers"),
    "byte count beyond the data": (lambda req: [answer(req, b"\x03\x04\x00\x01")], "fc3",
                                   "answer has 2 data bytes, its byte count says 4"),
    "no byte count": (lambda req: [answer(req, b"\x17")], "fc23", "answer without a byte count"),
    "FC6 echo value": (lambda req: [answer(req, b"\x06\x00\x05\x00\x04")], "fc6",
                       "answer echoes address 5 value 4, sent address 5 value 3"),
    "FC6 echo address": (lambda req: [answer(req, b"\x06\x00\x06\x00\x03")], "fc6",
                         "answer echoes address 6 value 3, sent address 5 value 3"),
    "FC16 echo quantity": (lambda req: [answer(req, b"\x10\x00\x05\x00\x01")], "fc16",
                           "answer echoes address 5 quantity 1, sent address 5 quantity 2"),
    "write answer length": (lambda req: [answer(req, b"\x10\x00\x05")], "fc16",
                            "answer PDU of 3 bytes, not 5"),
    "closed before answering": (lambda req: [CLOSE], "fc3",
                                "connection closed by the server before any answer"),
    "closed mid-answer": (lambda req: [answer(req, good_pdu(req))[:9], CLOSE], "fc23",
                          "connection closed by the server after 9 bytes of the answer"),
    "silence": (lambda req: [], "fc3", "no answer within 0.3 s"),
    "half an answer, then silence": (lambda req: [answer(req, good_pdu(req))[:5]], "fc3",
                                     "answer not whole within 0.3 s: 5 of at least 8 bytes"),
    "half a body, then silence": (lambda req: [answer(req, good_pdu(req))[:10]], "fc3",
                                  "answer not whole within 0.3 s: 10 of 13 bytes"),
}
REQUESTS = {
    "fc3": (3, lambda c: c.read_holding_registers(0, 2)),
    "fc23": (23, lambda c: c.read_write_registers(0, 2, 1, [7])),
    "fc6": (6, lambda c: c.write_register(5, 3)),
    "fc16": (16, lambda c: c.write_registers(5, [1, 2])),
}


@pytest.mark.parametrize("fake, request_name, says",
                         [pytest.param(reply, req, says, id=name) for name, (reply, req, says) in BAD.items()],
                         indirect=["fake"])
def test_a_bad_answer_is_a_link_error_naming_what_was_wrong_and_the_next_request_reconnects(
        fake, request_name, says):
    fc, make = REQUESTS[request_name]
    c = client_of(fake.port, timeout_s=0.3)
    try:
        with pytest.raises(ModbusLinkError) as raised:
            make(c)
        assert str(raised.value).endswith(f": {says}")
        assert str(raised.value).startswith(f"Modbus FC{fc} (")
        assert f"to 127.0.0.1:{fake.port}: " in str(raised.value)
        assert not c.connected
        fake.reply = good                    # the next request: a new connection, a good answer
        make(c)
        assert c.connected
    finally:
        c.close()
    assert fake.connections == 2


@pytest.mark.parametrize("request_name", ["fc3", "fc23", "fc6", "fc16"])
def test_an_exception_response_is_refused_with_its_code_and_the_connection_stays(request_name):
    fc, make = REQUESTS[request_name]
    fake = FakeServer(lambda req: [answer(req, bytes([req[7] | 0x80, 4]))])
    c = client_of(fake.port)
    try:
        with pytest.raises(ModbusRefused, match=f"FC{fc} .*exception response, code 04") as refused:
            make(c)
        assert (refused.value.function, refused.value.code) == (fc, 4)
        assert c.connected
        fake.reply = good
        make(c)
    finally:
        c.close()
        fake.close()
    assert fake.connections == 1


def test_nobody_listening_is_a_link_error_naming_host_and_port():
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    c = client_of(port, timeout_s=0.5)
    with pytest.raises(ModbusLinkError, match=f"^cannot connect to 127.0.0.1:{port}: "):
        c.connect()
    with pytest.raises(ModbusLinkError, match=f"^cannot connect to 127.0.0.1:{port}: "):
        c.read_holding_registers(0, 1)                 # a request connects first
    assert not c.connected


@pytest.mark.parametrize("call, says", [
    (lambda c: c.read_holding_registers(0, 0), "FC3: quantity 0 not in 1..125"),
    (lambda c: c.read_holding_registers(0, 126), "FC3: quantity 126 not in 1..125"),
    (lambda c: c.read_holding_registers(70_000, 1), "FC3: address 70000 not in 0..65535"),
    (lambda c: c.read_write_registers(0, 1, 0, []), "FC23: quantity 0 not in 1..121"),
    (lambda c: c.read_write_registers(0, 1, -1, [1]), "FC23: address -1 not in 0..65535"),
    (lambda c: c.write_register(0, 65536), "FC6: value 65536 not in 0..65535"),
    (lambda c: c.write_registers(0, [1] * 124), "FC16: quantity 124 not in 1..123"),
    (lambda c: c.write_registers(0, [1, -2]), r"FC16: values \[1, -2\] not all in 0..65535"),
])
def test_what_the_protocol_cannot_carry_is_refused_before_anything_is_sent(fake, call, says):
    c = client_of(fake.port)
    try:
        with pytest.raises(ValueError, match=says):
            call(c)
    finally:
        c.close()
    assert fake.requests == []


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="unit id 256 not in 0..255"):
        ModbusTcpClient("127.0.0.1", 1, unit=256)
    with pytest.raises(ValueError, match="timeout_s = 0 must be > 0"):
        ModbusTcpClient("127.0.0.1", 1, timeout_s=0)
