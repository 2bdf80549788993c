"""A small Modbus TCP client on a plain socket: the simulated PLC's side of the link.

It does what :class:`~cell.sim.plc.SimPlc` needs and nothing else, by the MODBUS
Application Protocol Specification V1.1b3 and the MODBUS Messaging on TCP/IP
Implementation Guide V1.0b: FC3 (read holding registers), FC6 (write single register),
FC16 (write multiple registers) and FC23 (read/write multiple registers), one request at a
time, each waited for. It shares no code with the controller's server (pymodbus plus
``drivers/plc/conformance.py``), so the two sides check each other.

Every answer is checked whole before it is used: MBAP protocol id 0, the request's
transaction id and unit id, a length field that fits the bytes, the request's function
code, byte count and register count, the echo of a write. Anything else is a
:class:`ModbusLinkError` naming what was wrong, and so is any socket error or a time-out.
After a link error the connection is closed: a TCP stream that went out of step cannot be
resynchronised, and an answer that comes late must not be taken for the next request's.
The next request connects again. A Modbus exception response (function | 0x80 and an
exception code) is a well-formed answer: :class:`ModbusRefused`, connection kept.
"""
from __future__ import annotations

import socket
import struct
import time

from cell.errors import CellError

_MBAP = struct.Struct(">HHHB")      # transaction id, protocol id, length, unit id
_MBAP_LEN = 7
_MAX_ADU = 260                      # spec: MBAP 7 + PDU <= 253
_NAMES = {3: "read holding registers", 6: "write single register",
          16: "write multiple registers", 23: "read/write multiple registers"}
_REQ_2W = struct.Struct(">HHHBBHH")             # MBAP + FC3 address, quantity / FC6 address, value
_REQ16 = struct.Struct(">HHHBBHHB")             # MBAP + FC16 address, quantity, byte count (+ words)
_REQ23 = struct.Struct(">HHHBBHHHHB")           # MBAP + FC23 read addr, qty, write addr, qty, byte count
_ECHO = struct.Struct(">HH")                    # FC6/FC16 answer: address, value / quantity


class ModbusClientError(CellError):
    """Base of the client's errors; the message names the request (FC, host:port) and the cause."""


class ModbusLinkError(ModbusClientError):
    """No usable answer: connect, send or receive failed, time-out, or an answer that breaks
    the protocol. The connection is closed when this is raised."""


class ModbusRefused(ModbusClientError):
    """The server answered with a Modbus exception response; ``function`` is the request's
    function code, ``code`` the exception code (e.g. 2 illegal address, 3 illegal value).
    The connection stays open."""

    def __init__(self, message: str, function: int, code: int):
        super().__init__(message)
        self.function, self.code = function, code


class ModbusTcpClient:
    """Modbus TCP client of server ``host:port``, unit id ``unit`` (0..255).

    ``timeout_s``: wall seconds any one wait may take: the connect, the send, the first
    bytes of an answer, and the rest of an answer that comes in pieces. Once connected, the
    socket blocks and the kernel keeps these time-outs (``SO_SNDTIMEO``, ``SO_RCVTIMEO``):
    a send or receive is then one system call, where a socket time-out of Python's own
    polls before each (and lets go of the interpreter's lock twice).
    Addresses are 0-based protocol addresses, registers unsigned 16-bit words. Not thread
    safe: one request at a time (the simulated PLC's scan). A request when not connected
    connects first. Raises :class:`ModbusLinkError` (connection closed) or
    :class:`ModbusRefused` (connection kept) as described in the module docs, ``ValueError``
    for a quantity or value the protocol cannot carry (nothing is sent).
    """

    def __init__(self, host: str, port: int, unit: int = 1, timeout_s: float = 10.0):
        if not 0 <= unit <= 255:
            raise ValueError(f"Modbus unit id {unit} not in 0..255")
        if not timeout_s > 0:
            raise ValueError(f"Modbus timeout_s = {timeout_s} must be > 0")
        self.host, self.port, self.unit, self.timeout_s = host, port, unit, timeout_s
        self._sock: socket.socket | None = None
        self._tid = 0

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def connect(self) -> None:
        """Open the connection (TCP_NODELAY, blocking with the kernel's time-outs) if it is
        not open. Raises ModbusLinkError naming ``host:port`` and the cause."""
        if self._sock is not None:
            return
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as exc:
            raise ModbusLinkError(f"cannot connect to {self.host}:{self.port}: {exc}") from None
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as exc:
            sock.close()
            raise ModbusLinkError(f"cannot set TCP_NODELAY on the connection to "
                                  f"{self.host}:{self.port}: {exc}") from None
        _kernel_timeouts(sock, self.timeout_s)
        self._sock = sock

    def close(self) -> None:
        """Close the connection; idempotent. The next request connects again."""
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    # ------------------------------------------------------------------ requests
    def read_holding_registers(self, address: int, count: int) -> list[int]:
        """FC3: ``count`` (1..125) registers from ``address``."""
        _check_count(3, count, 125)
        _check_address(3, address)
        tid = self._next_tid()
        pdu = self._transact(3, tid, _REQ_2W.pack(tid, 0, 6, self.unit, 3, address, count))
        return self._registers(3, pdu, count)

    def read_write_registers(self, read_address: int, read_count: int, write_address: int,
                             values: list[int]) -> list[int]:
        """FC23: write ``values`` (1..121 words) at ``write_address``, then read ``read_count``
        (1..125) registers from ``read_address``, in one request (the server writes first)."""
        _check_count(23, read_count, 125)
        n = len(values)
        _check_count(23, n, 121)
        _check_address(23, read_address)
        _check_address(23, write_address)
        tid = self._next_tid()
        head = _REQ23.pack(tid, 0, 11 + 2 * n, self.unit, 23, read_address, read_count,
                           write_address, n, 2 * n)
        pdu = self._transact(23, tid, head + _words(23, values))
        return self._registers(23, pdu, read_count)

    def write_register(self, address: int, value: int) -> None:
        """FC6: ``value`` (0..65535) at ``address``; the answer must echo both."""
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"Modbus FC6: value {value} not in 0..65535")
        _check_address(6, address)
        tid = self._next_tid()
        pdu = self._transact(6, tid, _REQ_2W.pack(tid, 0, 6, self.unit, 6, address, value))
        self._echo(6, pdu, address, value, "value")

    def write_registers(self, address: int, values: list[int]) -> None:
        """FC16: ``values`` (1..123 words) from ``address``; the answer must echo address and
        quantity."""
        n = len(values)
        _check_count(16, n, 123)
        _check_address(16, address)
        tid = self._next_tid()
        head = _REQ16.pack(tid, 0, 7 + 2 * n, self.unit, 16, address, n, 2 * n)
        pdu = self._transact(16, tid, head + _words(16, values))
        self._echo(16, pdu, address, n, "quantity")

    # ------------------------------------------------------------------ one exchange
    def _next_tid(self) -> int:
        self._tid = (self._tid + 1) & 0xFFFF
        return self._tid

    def _transact(self, fc: int, tid: int, adu: bytes) -> bytes:
        """Send ``adu``, receive and check the answer's MBAP header and function code; the
        answer's PDU after the function code. Connects first when needed."""
        if self._sock is None:
            self.connect()
        sock = self._sock
        try:
            sock.sendall(adu)
            data = sock.recv(_MAX_ADU)
        except _TIMED_OUT:
            self._fail(fc, f"no answer within {self.timeout_s} s")
        except OSError as exc:
            self._fail(fc, f"connection failed: {exc}")
        if len(data) < _MBAP_LEN or len(data) != 6 + (data[4] << 8 | data[5]):
            data = self._recv_rest(fc, sock, data)
        r_tid, pid, length, unit = _MBAP.unpack_from(data)
        self._check_header(fc, pid, length)
        if r_tid != tid:
            self._fail(fc, f"transaction id {r_tid} in the answer, {tid} sent")
        if unit != self.unit:
            self._fail(fc, f"unit id {unit} in the answer, {self.unit} sent")
        r_fc = data[_MBAP_LEN]
        if r_fc == fc | 0x80:
            if length != 3:
                self._fail(fc, f"exception response with MBAP length {length}, not 3")
            code = data[_MBAP_LEN + 1]
            raise ModbusRefused(f"Modbus FC{fc} ({_NAMES[fc]}) to {self.host}:{self.port}: "
                                f"exception response, code {code:02d}", fc, code)
        if r_fc != fc:
            self._fail(fc, f"function code {r_fc} in the answer, {fc} sent")
        return data[_MBAP_LEN + 1:]

    def _check_header(self, fc: int, pid: int, length: int) -> None:
        if pid != 0:
            self._fail(fc, f"MBAP protocol id {pid} in the answer, not 0")
        if not 2 <= length <= _MAX_ADU - 6:
            self._fail(fc, f"MBAP length {length} in the answer, not in 2..{_MAX_ADU - 6}")

    def _recv_rest(self, fc: int, sock: socket.socket, data: bytes) -> bytes:
        """The whole answer when the first read did not bring exactly one frame: reads on
        until the MBAP length is there, for at most ``timeout_s`` more; checks the header as
        soon as it is whole (a bad one says nothing of how long the answer is)."""
        deadline = time.monotonic() + self.timeout_s
        buf = bytearray(data)
        need = 0
        try:
            while True:
                if not need and len(buf) >= _MBAP_LEN:
                    _, pid, length, _ = _MBAP.unpack_from(buf)
                    self._check_header(fc, pid, length)
                    need = 6 + length
                if need and len(buf) >= need:
                    if len(buf) > need:
                        self._fail(fc, f"answer of {len(buf)} bytes, its MBAP length {need - 6} "
                                       f"makes {need}")
                    return bytes(buf)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                _recv_timeout(sock, left)
                chunk = sock.recv((need or _MBAP_LEN) - len(buf))
                if not chunk:
                    self._fail(fc, f"connection closed by the server after {len(buf)} bytes of the "
                                   f"answer" if buf else "connection closed by the server before "
                                   "any answer")
                buf += chunk
        except _TIMED_OUT:
            self._fail(fc, f"answer not whole within {self.timeout_s} s: {len(buf)} of "
                           f"{need or 'at least 8'} bytes")
        except OSError as exc:
            self._fail(fc, f"connection failed after {len(buf)} bytes of the answer: {exc}")
        finally:
            if self._sock is sock:
                _recv_timeout(sock, self.timeout_s)

    def _registers(self, fc: int, pdu: bytes, count: int) -> list[int]:
        """The registers of an FC3/FC23 answer's PDU (byte count, words)."""
        if not pdu:
            self._fail(fc, "answer without a byte count")
        n = pdu[0]
        if n % 2:
            self._fail(fc, f"byte count {n} in the answer is odd")
        if n != 2 * count:
            self._fail(fc, f"byte count {n} in the answer, {2 * count} expected for {count} registers")
        if len(pdu) != 1 + n:
            self._fail(fc, f"answer has {len(pdu) - 1} data bytes, its byte count says {n}")
        return list(struct.unpack_from(f">{count}H", pdu, 1))

    def _echo(self, fc: int, pdu: bytes, address: int, value: int, what: str) -> None:
        """Check a write's answer: it echoes ``address`` and ``value`` (FC6) or quantity (FC16)."""
        if len(pdu) != 4:
            self._fail(fc, f"answer PDU of {1 + len(pdu)} bytes, not 5")
        r_address, r_value = _ECHO.unpack(pdu)
        if (r_address, r_value) != (address, value):
            self._fail(fc, f"answer echoes address {r_address} {what} {r_value}, "
                           f"sent address {address} {what} {value}")

    def _fail(self, fc: int, why: str):
        """Close the connection and raise ModbusLinkError naming the request and ``why``."""
        self.close()
        raise ModbusLinkError(f"Modbus FC{fc} ({_NAMES[fc]}) to {self.host}:{self.port}: {why}")


#: what a send or receive that waited its time-out raises: TimeoutError from a socket with a
#: time-out of Python's own, BlockingIOError (EAGAIN) from a blocking one whose kernel
#: time-out (SO_SNDTIMEO, SO_RCVTIMEO) ran out
_TIMED_OUT = (TimeoutError, BlockingIOError)


def _timeval(seconds: float) -> bytes:
    """``struct timeval`` of ``seconds`` (> 0), at least 1 µs: a zero one means no time-out."""
    sec = int(seconds)
    return struct.pack("ll", sec, max(int((seconds - sec) * 1e6), 0 if sec else 1))


def _kernel_timeouts(sock: socket.socket, seconds: float) -> None:
    """Make ``sock`` blocking with the kernel's send and receive time-outs of ``seconds``;
    where the kernel takes neither (a platform without them), Python's own time-out stays."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, _timeval(seconds))
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _timeval(seconds))
    except OSError:
        sock.settimeout(seconds)
        return
    sock.settimeout(None)


def _recv_timeout(sock: socket.socket, seconds: float) -> None:
    """The receive time-out of ``sock`` (as :func:`_kernel_timeouts` left it) is ``seconds``."""
    if sock.gettimeout() is None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _timeval(seconds))
    else:
        sock.settimeout(seconds)


def _check_count(fc: int, n: int, most: int) -> None:
    if not 1 <= n <= most:
        raise ValueError(f"Modbus FC{fc}: quantity {n} not in 1..{most}")


def _check_address(fc: int, address: int) -> None:
    if not 0 <= address <= 0xFFFF:
        raise ValueError(f"Modbus FC{fc}: address {address} not in 0..65535")


def _words(fc: int, values: list[int]) -> bytes:
    try:
        return struct.pack(f">{len(values)}H", *values)
    except struct.error:
        raise ValueError(f"Modbus FC{fc}: values {values} not all in 0..65535") from None
