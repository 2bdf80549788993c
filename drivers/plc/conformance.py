"""Spec-conformant request framing and validation in front of pymodbus 3.16.1.

Measured on loopback against a bare ``pymodbus.server.ModbusTcpServer`` (raw MBAP frames;
reproduced in ``tests/drivers/test_plc_conformance.py``), pymodbus deviates from the
MODBUS Application Protocol Specification V1.1b3 in ways a PLC notices:

=====================================  =====================  ==========================
request                                pymodbus 3.16.1        spec (and this module)
=====================================  =====================  ==========================
unsupported function code, e.g. 0x41   ``80 01``              ``C1 01`` (FC | 0x80, 01)
FC3 quantity 0 or 126                  ``80 01``              ``83 03``
FC5 value 0x1234                       accepted as ON         ``85 03``, coil unchanged
two requests in one TCP segment        only the first answer  both answered, in order
=====================================  =====================  ==========================

Causes: the decoder raises on any decode problem and the handler answers with function
code 0 (``requesthandler.py``); ``WriteSingleCoilRequest`` maps every non-zero value to ON;
``handleFrame`` returns after the first frame and ``ModbusProtocol.send`` clears the receive
buffer, dropping frames that arrived together.

Fix (no monkeypatching): :class:`ConformantTcpServer` is a documented subclass of
``ModbusTcpServer`` whose per-connection handler (:class:`ConformantRequestHandler`, a
``ServerRequestHandler`` subclass) runs a thin pre-decoder: :class:`MbapStream` cuts the byte
stream into MBAP frames, :func:`check_request` applies the spec's per-function checks
(function supported -> 01; quantity, byte count and PDU length -> 03; FC5 value -> 03)
and only well-formed requests reach pymodbus's own decoder and ``handle_request``. Every
frame of a segment is answered, in arrival order, by one worker task per connection.
A broken MBAP header (protocol id not 0, length < 2 or > 254) cannot be resynchronised in a
TCP stream: the connection is closed; the server keeps serving other clients.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import ssl
import struct
import threading
from collections.abc import Callable
from typing import NamedTuple

from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

from cell.errors import CellError
from cell.log import get_logger
from drivers.plc.access import CURRENT_PEER, ConnectionGuard, Peer


def _log():
    # looked up per use: a logger bound at import would keep the set-up of import time
    return get_logger("plc.conformance")


MBAP_LEN = 7            # tid(2) pid(2) length(2) unit(1)
MAX_PDU = 253           # spec: ADU <= 260 bytes on TCP
MAX_PENDING = 64        # requests queued on one connection before it is closed
MAX_UNREAD = 64 * 1024  # answer bytes a client has left unread before it is closed
#: bytes taken from a socket per read: asyncio's own reads are 256 KiB (one fresh
#: allocation per read, shrunk to what came); ours go into one buffer per server
READ_CHUNK = 16 * 1024
HANDSHAKE_TIMEOUT_S = 5.0   # TLS: a client must finish its handshake within this
MAX_EARLY = MAX_PENDING * (MBAP_LEN + MAX_PDU)   # TLS: request bytes kept across the handshake's end
ILLEGAL_FUNCTION, ILLEGAL_DATA_ADDRESS, ILLEGAL_DATA_VALUE, SERVER_DEVICE_FAILURE = 1, 2, 3, 4


class ServerStartError(CellError):
    """A Modbus server could not start listening."""


class FramingError(CellError):
    """An MBAP header that cannot be valid; the TCP stream is out of step (close it)."""


class Frame(NamedTuple):
    """One MBAP frame of a request: transaction id, unit id and PDU. A named tuple: one is
    made for every request a client sends, and a frozen dataclass costs several times more
    to make."""

    tid: int
    unit: int
    pdu: bytes   # function code + data


class MbapStream:
    """Incremental MBAP framer for one TCP connection: ``feed(bytes) -> [Frame, ...]``.

    Keeps an incomplete tail for the next call. A protocol id other than 0 or a length
    field outside 2..254 breaks the stream (it cannot be resynchronised): ``feed`` returns
    the complete frames before the bad header and sets ``broken`` to a :class:`FramingError`;
    feeding a broken stream raises that error.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.broken: FramingError | None = None

    def feed(self, data: bytes) -> list[Frame]:
        if self.broken is not None:
            raise self.broken
        self._buf += data
        frames: list[Frame] = []
        while len(self._buf) >= MBAP_LEN:
            tid, pid, length, unit = struct.unpack_from(">HHHB", self._buf)
            if pid != 0:
                self.broken = FramingError(f"MBAP protocol id {pid} (tid {tid}), expected 0")
            elif not 2 <= length <= MAX_PDU + 1:
                self.broken = FramingError(f"MBAP length {length} (tid {tid}) outside 2..{MAX_PDU + 1}")
            if self.broken is not None:
                self._buf.clear()
                break
            if len(self._buf) < 6 + length:
                break  # wait for the rest of this frame
            frames.append(Frame(tid, unit, bytes(self._buf[MBAP_LEN:6 + length])))
            del self._buf[:6 + length]
        return frames

    @property
    def pending(self) -> int:
        """Bytes held for an incomplete frame."""
        return len(self._buf)


def _fixed(n: int) -> Callable[[bytes], bool]:
    return lambda pdu: len(pdu) == n


def _read_qty(limit: int) -> Callable[[bytes], bool]:
    def ok(pdu: bytes) -> bool:
        return len(pdu) == 5 and 1 <= struct.unpack_from(">H", pdu, 3)[0] <= limit
    return ok


def _write_coil(pdu: bytes) -> bool:
    return len(pdu) == 5 and struct.unpack_from(">H", pdu, 3)[0] in (0x0000, 0xFF00)


def _write_multi(limit: int, bytes_for: Callable[[int], int]) -> Callable[[bytes], bool]:
    def ok(pdu: bytes) -> bool:
        if len(pdu) < 6:
            return False
        qty, nbytes = struct.unpack_from(">HB", pdu, 3)
        return 1 <= qty <= limit and nbytes == bytes_for(qty) and len(pdu) == 6 + nbytes
    return ok


def _read_write_multi(pdu: bytes) -> bool:
    if len(pdu) < 10:
        return False
    _, rq, _, wq, nbytes = struct.unpack_from(">HHHHB", pdu, 1)
    return 1 <= rq <= 125 and 1 <= wq <= 121 and nbytes == 2 * wq and len(pdu) == 10 + nbytes


#: Function codes this server supports -> structural check (False -> exception 03).
#: Quantity limits are the spec's: 2000 bits / 125 registers read, 1968 bits / 123 registers
#: written, FC23 125 read + 121 written.
SUPPORTED: dict[int, Callable[[bytes], bool]] = {
    0x01: _read_qty(2000),                                   # read coils
    0x02: _read_qty(2000),                                   # read discrete inputs
    0x03: _read_qty(125),                                    # read holding registers
    0x05: _write_coil,                                       # write single coil
    0x06: _fixed(5),                                         # write single register
    0x0F: _write_multi(1968, lambda q: (q + 7) // 8),        # write multiple coils
    0x10: _write_multi(123, lambda q: 2 * q),                # write multiple registers
    0x17: _read_write_multi,                                 # read/write multiple registers
}


#: The register functions a server's ``registers`` answerer serves (the rest go to pymodbus).
REGISTER_FCS = frozenset((0x03, 0x06, 0x10, 0x17))


def check_request(pdu: bytes, supported: dict[int, Callable[[bytes], bool]] = SUPPORTED) -> int | None:
    """Spec checks a server makes before touching data: exception code to answer, or None.

    01 if the function code is not supported (including 0x80..0xFF); 03 if quantity, byte
    count, total length or (FC5) output value is invalid. Address (02) and value-in-range
    (03) checks are the datastore's, after this.
    """
    check = supported.get(pdu[0])
    if check is None:
        return ILLEGAL_FUNCTION
    return None if check(pdu) else ILLEGAL_DATA_VALUE


def exception_pdu(function_code: int, code: int) -> bytes:
    """The exception PDU answering ``function_code``: (function code | 0x80, ``code``)."""
    return bytes(((function_code | 0x80) & 0xFF, code))


def adu(frame: Frame, pdu: bytes) -> bytes:
    """MBAP header + ``pdu``, answering ``frame`` (its transaction and unit id)."""
    return struct.pack(">HHHB", frame.tid, 0, len(pdu) + 1, frame.unit) + pdu


def exception_adu(frame: Frame, code: int) -> bytes:
    """MBAP + exception PDU (function code | 0x80, ``code``) answering ``frame``."""
    return adu(frame, exception_pdu(frame.pdu[0], code))


class ConformantRequestHandler(ServerRequestHandler, asyncio.BufferedProtocol):
    """pymodbus connection handler with the spec pre-decoder in front (see module doc).

    Frames are answered strictly in arrival order by one worker task; valid register
    requests go to the server's ``registers`` answerer if it has one, the others are
    decoded and executed by pymodbus (``DecodePDU`` + ``handle_request``), so the datastore
    and its action see exactly what a bare pymodbus server would. A register request that
    arrives alone while the worker has nothing is answered at once in the read callback
    (:meth:`_answered_at_once`): the same answer, without the queue and the worker's wake-up.

    Memory: it is an ``asyncio.BufferedProtocol``, so the transport reads into the
    server's one :data:`READ_CHUNK` buffer (:meth:`get_buffer`) instead of allocating
    256 KiB per read and shrinking it. Under a storm those short-lived 256 KiB blocks
    came from the heap between long-lived small objects, and the C allocator could not
    give the heap back (RSS grew every storm round; found by bench/bench_link_storm.py).
    On a TLS listener the guard sees the TCP connection *before* its handshake (allow-list,
    cap and shedding apply to half-open connections too) and TLS is started on it with
    our own handshake time-out (:meth:`_start_tls`). asyncio hands on what came in the same
    read as the client's last handshake message before :meth:`_start_tls` resumes: it is
    kept and answered once the role is taken (a client sending at once under load).
    """

    def __init__(self, owner, trace_packet, trace_pdu, trace_connect):
        super().__init__(owner, trace_packet, trace_pdu, trace_connect)
        # We consume every byte ourselves; lift pymodbus's receive cap, which silently drops
        # a read bigger than it: 516 bytes would drop a segment of pipelined requests, and
        # 64 KiB still dropped asyncio's reads (up to 256 KiB) under a flood of pipelined
        # requests, putting the stream out of step (found by bench/bench_link_storm.py).
        # Nothing accumulates here: every read is consumed whole by :class:`MbapStream`.
        # (Reads are at most READ_CHUNK now, see get_buffer.)
        self.max_buffer_size = 1 << 20
        self._stream = MbapStream()
        self._queue: asyncio.Queue[Frame | None] = asyncio.Queue()
        self._worker: asyncio.Task | None = None
        self._busy = False        # the worker holds a frame (from taking it to its answer)
        self._handshake: asyncio.Task | None = None
        self._early = bytearray()  # TLS: what arrived between the handshake's end and _start_tls's
        self.guard: ConnectionGuard | None = getattr(owner, "guard", None)
        self.peer: Peer | None = None

    # asyncio.BufferedProtocol: read into the server's buffer, consumed at once (below)
    def get_buffer(self, sizehint: int) -> memoryview:
        return self.server.read_view

    def buffer_updated(self, nbytes: int) -> None:
        # copied out before anything else can read into the shared buffer: the loop is
        # single-threaded and this call consumes it synchronously. Straight to our framer:
        # pymodbus's data_received only buffers what callback_data leaves (it leaves nothing)
        # and keeps a debug dump of every frame
        self.callback_data(bytes(self.server.read_view[:nbytes]))

    def callback_connected(self) -> None:
        super().callback_connected()
        if self.guard is None:
            return
        info = self.transport.get_extra_info("peername") if self.transport else None
        host, port = (str(info[0]), int(info[1])) if info else ("?", 0)
        self.peer = self.guard.connect(host, port, self.close)
        if self.peer is None:
            self.close()
        elif getattr(self.server, "sslctx", None) is not None:
            self._handshake = asyncio.get_running_loop().create_task(self._start_tls())

    async def _start_tls(self) -> None:
        """Modbus/TCP Security: TLS on this (already admitted) TCP connection, with our
        handshake time-out; then the role from the client's certificate. A handshake that
        fails or does not finish in time closes the connection (logged, rate-limited)."""
        raw, server = self.transport, self.server
        try:
            tls = await asyncio.get_running_loop().start_tls(
                raw, self, server.sslctx, server_side=True,
                ssl_handshake_timeout=server.handshake_timeout_s,
                ssl_shutdown_timeout=server.handshake_timeout_s)
        except asyncio.CancelledError as exc:      # the server is stopping
            _drop_tracebacks(exc)
            raise
        except Exception as exc:   # timed out, refused certificate, not TLS, closed
            _drop_tracebacks(exc)
            if not self.is_closing:
                _warn("plc_tls_handshake_failed", self.guard, client=str(self.peer or ""),
                      error=f"{type(exc).__name__}: {exc}"[:200])
                self.close()
            return
        finally:
            self._handshake = None
        if tls is None or self.is_closing or self.peer is None:
            # shed or timed out during the handshake (start_tls returns None when the
            # connection was closed cleanly before the handshake ended)
            if tls is not None:
                tls.abort()
            self.close()
            return
        self.transport = tls
        self._take_role(server.roles)
        if self.peer is None:
            self.close()
            return
        early, self._early = bytes(self._early), bytearray()
        if early:
            self.callback_data(early)

    def _take_role(self, roles: dict[str, frozenset[str]]) -> None:
        """Modbus/TCP Security: the peer's role from its (already verified) certificate;
        no role, or one the config does not list: the connection is refused."""
        from drivers.plc.tls import ROLE_OID, role_of
        ssl_object = self.transport.get_extra_info("ssl_object")
        der = ssl_object.getpeercert(binary_form=True) if ssl_object is not None else None
        role, subject = role_of(der) if der else (None, "no certificate")
        reason = None
        if role is None:
            reason = f"certificate has no role extension (OID {ROLE_OID})"
        elif role.casefold() not in roles:
            reason = f"role {role!r} is not in plc.tls.roles ({', '.join(sorted(roles))})"
        if reason is not None:
            self.guard.warn.warning("plc_tls_client_refused", client=str(self.peer), subject=subject,
                                    reason=reason)
            self.guard.drop(self.peer)
            self.peer = None
            return
        self.peer.role, self.peer.rights = role, roles[role.casefold()]
        _log().info("plc_tls_client", client=str(self.peer), subject=subject,
                    rights=sorted(self.peer.rights))

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        if self._handshake is not None:
            # TLS: requests the client sent right behind its last handshake message reach us
            # from asyncio's TLS layer before _start_tls resumes; kept (bounded) until it has
            # taken the role, then answered
            if len(self._early) + len(data) <= MAX_EARLY:
                self._early += data
            return len(data)
        if self._stream.broken is not None or (self.guard is not None and self.peer is None):
            return len(data)   # closing (or refused at connect): ignore whatever still arrives
        frames = self._stream.feed(data)
        for frame in frames:
            code = check_request(frame.pdu)
            if self.peer is not None:
                if code is None:
                    self.peer.asked += 1      # a well-formed request: shed such a client last
                else:
                    self.peer.malformed += 1  # a fuzzer's: shed before a client that asks well
            if len(frames) > 1 or not self._answered_at_once(frame, code):
                self._queue.put_nowait(frame)
        if self.peer is not None:
            self.guard.activity(self.peer, self._stream.pending)
        if self._queue.qsize() > MAX_PENDING and self._stream.broken is None:
            # a client that sends without reading answers: the guide's NumberMaxOfServerTransaction
            self._stream.broken = FramingError(f"more than {MAX_PENDING} requests pending")
        if self._stream.broken is not None:
            _warn("modbus_framing_error", self.guard, error=str(self._stream.broken),
                  client=str(self.peer or ""))
            self._queue.put_nowait(None)   # answer the frames before it, then close
        if self._worker is None:
            self._worker = asyncio.get_running_loop().create_task(self._serve())
        return len(data)

    def close(self, reconnect: bool = False) -> None:
        """Close this connection (shed, timed out, refused or out of step): its worker task
        goes with it. pymodbus calls no ``callback_disconnected`` for a close it did not see
        coming from the peer, so without this the worker would wait on its queue forever,
        one task per closed connection."""
        worker, self._worker = self._worker, None
        if worker is not None and worker is not asyncio.current_task():
            worker.cancel()
        # a handshake under way ends with the transport closed below (start_tls fails and
        # _start_tls returns); cancelling it instead left a reference cycle to its TLS state
        if self.guard is not None and self.peer is not None:
            self.guard.drop(self.peer)
        super().close(reconnect)

    def callback_disconnected(self, exc: Exception | None) -> None:
        if self.guard is not None and self.peer is not None:
            self.guard.drop(self.peer)
        if self._worker is not None:
            self._worker.cancel()
            self._worker = None
        super().callback_disconnected(exc)

    def _answered_at_once(self, frame: Frame, code: int | None) -> bool:
        """Answer ``frame`` now, in the read callback, if it is a well-formed register
        request that came alone, nothing of this connection waits before it (queue empty,
        worker idle) and its client reads its answers; True if answered. The PLC's usual
        request is such a one, and this saves it the queue and a wake-up of the worker (an
        event-loop turn). Anything else is left to the worker, in arrival order, so the
        answers, their order and the pending and unread limits are the worker's."""
        if (code is not None or self._busy or not self._queue.empty() or self.server.registers is None
                or frame.pdu[0] not in REGISTER_FCS or self._gone()
                or self.transport.get_write_buffer_size() > MAX_UNREAD):
            return False
        try:
            answer = adu(frame, self.server.registers(frame.pdu, self.peer))
        except Exception as exc:  # as in the worker: one bad request never ends the connection
            _warn("modbus_request_failed", self.guard, error=repr(exc), tid=frame.tid,
                  client=str(self.peer or ""))
            answer = exception_adu(frame, SERVER_DEVICE_FAILURE)
        self._send_raw(answer)
        return True

    async def _serve(self) -> None:
        while True:
            self._busy = False
            frame = await self._queue.get()
            self._busy = True
            if frame is None or self._gone():
                self.close()
                return
            if self.transport.get_write_buffer_size() > MAX_UNREAD:
                # a client that sends without reading its answers: they would pile up in
                # memory with no bound (asyncio keeps every write); close it
                _warn("modbus_client_not_reading", self.guard, client=str(self.peer or ""),
                      unread_bytes=self.transport.get_write_buffer_size())
                self.close()
                return
            try:
                await self._answer(frame)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # one bad request must never kill the connection's worker
                _warn("modbus_request_failed", self.guard, error=repr(exc), tid=frame.tid,
                      client=str(self.peer or ""))
                self._send_raw(exception_adu(frame, SERVER_DEVICE_FAILURE))

    async def _answer(self, frame: Frame) -> None:
        code = check_request(frame.pdu)
        if code is not None:
            self._send_raw(exception_adu(frame, code))
            return
        if self.server.registers is not None and frame.pdu[0] in REGISTER_FCS:
            self._send_raw(adu(frame, self.server.registers(frame.pdu, self.peer)))
            return
        pdu = self.framer.decoder.decode(frame.pdu)
        if pdu is None:  # passed our checks yet pymodbus cannot decode it
            self._send_raw(exception_adu(frame, SERVER_DEVICE_FAILURE))
            return
        pdu.dev_id, pdu.transaction_id = frame.unit, frame.tid
        self.last_pdu, self.last_addr = pdu, None
        CURRENT_PEER.set(self.peer)   # the datastore's action decides writes by who sent them
        await self.handle_request()   # pymodbus: datastore_update + send, exceptions -> 04

    def _gone(self) -> bool:
        """The connection is closed or closing: nothing more is answered on it (asyncio logs
        a warning for every write to a lost connection, unthrottled)."""
        return self.transport is None or self.transport.is_closing()

    def _send_raw(self, adu: bytes) -> None:
        """Write an answer we built (pymodbus's send would only add its debug dump)."""
        if not self._gone():
            self.transport.write(adu)


def _drop_tracebacks(exc: BaseException | None) -> None:
    """Forget the tracebacks of ``exc`` and the exceptions it chains. A failed ``start_tls``
    raises the exception its waiter future holds, and the traceback holds ``start_tls``'s
    frame, which holds the waiter: a reference cycle that kept the connection's
    ``SSLProtocol`` (with asyncio's 256 KiB read buffer) until the cyclic GC ran."""
    seen = 0
    while exc is not None and seen < 8:
        exc.__traceback__ = None
        exc, seen = exc.__context__ or exc.__cause__, seen + 1


def _warn(kind: str, guard: ConnectionGuard | None, **fields) -> None:
    """A warning about the network side, rate-limited when the server has a guard."""
    if guard is not None:
        guard.warn.warning(kind, **fields)
    else:
        _log().warning(kind, **fields)


class ConformantTcpServer(ModbusTcpServer):
    """``ModbusTcpServer`` whose connections use :class:`ConformantRequestHandler`.

    Same constructor as ``ModbusTcpServer`` plus ``guard``: a
    :class:`~drivers.plc.access.ConnectionGuard` (allow-list, cap, time-outs), or None for
    none (the comparisons in the tests); and ``registers``: ``registers(pdu, peer) ->
    response PDU`` answers the register functions (FC3, FC6, FC16, FC23) of well-formed
    requests directly (:meth:`drivers.plc.server.PlcLink.answer_registers`), without
    pymodbus's decoder and datastore, which cost more than the rest of the request path
    together; None: pymodbus answers everything. Start with
    ``await serve_forever(background=True)``.
    """

    def __init__(self, *args, guard: ConnectionGuard | None = None,
                 registers: Callable[[bytes, Peer | None], bytes] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.guard = guard
        self.registers = registers
        # every connection of this server reads into this one buffer (see get_buffer)
        self.read_view = memoryview(bytearray(READ_CHUNK))

    def callback_new_connection(self):
        return ConformantRequestHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class ConformantTlsServer(ConformantTcpServer):
    """:class:`ConformantTcpServer` over TLS: Modbus/TCP Security. The MBAP framing stays
    (the spec carries the whole Modbus/TCP ADU in TLS), so the request path is the plain
    one's; ``sslctx`` should require client certificates (:func:`drivers.plc.tls.server_context`);
    ``roles`` maps a certificate's role (case-folded) to its rights.

    It listens on plain TCP and starts TLS on each connection the guard admits
    (``loop.start_tls``), instead of pymodbus's ``create_server(ssl=...)``: there, the
    handshake ran before any code of ours saw the connection, with asyncio's 60 s
    time-out, outside the connection cap, and a failed handshake left its handler in
    ``active_connections`` for good. ``handshake_timeout_s`` bounds the handshake (and the
    TLS shutdown of a closed connection)."""

    def __init__(self, *args, sslctx: ssl.SSLContext, roles: dict[str, frozenset[str]],
                 handshake_timeout_s: float = HANDSHAKE_TIMEOUT_S, **kwargs):
        if not handshake_timeout_s > 0:
            raise ValueError(f"handshake_timeout_s must be > 0, got {handshake_timeout_s}")
        if kwargs.get("guard") is None:
            # TLS is started for connections the guard admits: without one it never would be
            raise ValueError("ConformantTlsServer needs a guard")
        self.sslctx = sslctx
        self.handshake_timeout_s = float(handshake_timeout_s)
        self.roles = roles
        super().__init__(*args, **kwargs)


class ServerThread:
    """Run one pymodbus TCP server on its own event loop in a named daemon thread.

    ``factory(address)`` builds the server (``ConformantTcpServer`` or, for comparisons,
    a bare ``ModbusTcpServer``) inside the loop, as pymodbus requires a running loop.
    """

    def __init__(self, factory: Callable[[tuple[str, int]], ModbusTcpServer], name: str):
        self._factory = factory
        self._name = name
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self.port: int | None = None
        self.server: ModbusTcpServer | None = None

    def call(self, fn: Callable[[], object], timeout_s: float = 10.0) -> object:
        """``fn()`` run on the server's loop thread (its state is the loop's alone); its result."""
        if self._loop is None:
            raise ServerStartError(f"{self._name}: not running")

        async def run():
            return fn()
        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(timeout_s)

    def counts(self) -> dict[str, int]:
        """Per-connection state held now: pymodbus's ``connections``, the guard's ``peers``
        and the loop's ``tasks`` (the sweep and this query included). A storm that has
        ended must leave these at their quiet values (tests/drivers/test_plc_storm_state.py)."""
        server = self.server

        def count():
            guard = getattr(server, "guard", None)
            return {"connections": len(server.active_connections),
                    "peers": len(guard.peers) if guard is not None else 0,
                    "tasks": len(asyncio.all_tasks())}
        return self.call(count)  # type: ignore[return-value]

    def start(self, host: str = "127.0.0.1", port: int = 0, timeout_s: float = 10.0) -> int:
        """Listen on ``host:port`` (0 = any free port), return the port. Raises
        :class:`ServerStartError` if the server cannot listen or is already running."""
        if self._thread is not None:
            raise ServerStartError(f"{self._name}: already running on port {self.port}")
        ready: concurrent.futures.Future[int] = concurrent.futures.Future()
        thread = threading.Thread(target=self._run, args=(host, port, ready), name=self._name,
                                  daemon=True)
        thread.start()
        try:
            self.port = ready.result(timeout=timeout_s)
        except Exception as exc:
            thread.join(timeout=timeout_s)
            raise ServerStartError(f"{self._name}: cannot listen on {host}:{port}: {exc}") from exc
        self._thread = thread
        return self.port

    def stop(self) -> None:
        """Close the listener and every connection, join the thread. Idempotent."""
        if self._thread is None:
            return
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=10)
        self._thread = self._loop = self._stop = None
        self.port = self.server = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    def _run(self, host: str, port: int, ready: concurrent.futures.Future) -> None:
        loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve(host, port, ready))
        finally:
            loop.close()

    async def _serve(self, host: str, port: int, ready: concurrent.futures.Future) -> None:
        try:
            server = self._factory((host, port))
            await server.serve_forever(background=True)
        except Exception as exc:
            ready.set_exception(exc)
            return
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        self.server = server
        guard = getattr(server, "guard", None)
        if guard is not None:
            asyncio.get_running_loop().create_task(guard.sweep_forever(), name="plc-connection-sweep")
        ready.set_result(server.transport.sockets[0].getsockname()[1])  # type: ignore[union-attr]
        await self._stop.wait()
        await server.shutdown()
        await asyncio.sleep(0)  # let transports run their close callbacks
        tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
