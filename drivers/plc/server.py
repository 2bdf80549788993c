"""PlcLink: the controller's side of the PLC link, a Modbus TCP server over one register map.

The controller never touches pymodbus: it calls :class:`PlcLink` (``read``/``write``/
``snapshot``/``next_write``...) from its own thread. Inside, a spec-conformant pymodbus
server (:class:`drivers.plc.conformance.ConformantTcpServer`) runs on its own event loop in
the thread ``plc-modbus-server``.

Data path. The register image (``map.size`` words) lives here, guarded by one lock. The
register functions (FC3, FC6, FC16, FC23: all a PLC's scan uses) are answered from the
image itself (:meth:`PlcLink.answer_registers`), read under the lock so 32-bit pairs are
never torn. A write is validated whole against the map *before* anything changes, then
applied to the image, and one :class:`PlcWrite` event is queued per named register. A
refused write answers exception 01/02/03 and changes nothing. The bit functions go through
pymodbus: its datastore is generated from the map (a ``SimDevice``: one ``SimData`` per
register and per reserved gap) and its documented ``action`` hook bridges it to the same
image and the same write decision.

Threads: controller thread(s) <-> ``self._lock`` <-> event-loop thread. Events cross in a
bounded deque (oldest dropped, counted in ``dropped_writes``).
"""
from __future__ import annotations

import collections
import struct
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from cell.clock import Clock, MonotonicClock
from cell.errors import CellError
from cell.log import get_logger
from drivers.plc.access import CURRENT_PEER, AccessPolicy, ConnectionGuard, Peer
from drivers.plc.conformance import (ConformantTcpServer, ConformantTlsServer, ServerStartError, ServerThread,
                                     exception_pdu)
from drivers.plc.register_map import PLC_MAP, PlcWriteRejected, RegisterMap, RegType


def _log():
    # looked up per use: a logger bound at import would keep the set-up of import time
    return get_logger("plc.server")


_BIT_FCS = (1, 2, 5, 15)


class PlcLinkError(CellError):
    """The link cannot do what was asked (cannot listen, started twice, ...)."""


@dataclass(frozen=True)
class PlcWrite:
    """One register the PLC wrote: clock time ``t`` (s), register name, new and previous
    value, and the client that wrote it (``host:port``; empty for a link without guard)."""

    t: float
    name: str
    value: int
    previous: int
    peer: str = ""


@dataclass(frozen=True)
class TlsListener:
    """A Modbus/TCP Security listener: the server ``context`` (client certificates
    required, :func:`drivers.plc.tls.server_context`), ``roles`` (case-folded role ->
    rights), where to listen, and the time a client has to finish its TLS handshake
    (``handshake_timeout_s``; closed after it)."""

    context: object
    roles: Mapping[str, frozenset[str]]
    host: str = "127.0.0.1"
    port: int = 802
    handshake_timeout_s: float = 5.0


@dataclass(frozen=True)
class Refusal:
    """Writes refused since the last :meth:`PlcLink.take_refusals`, one entry per client
    host, role and reason: ``count`` of them, the first at clock time ``t``."""

    t: float
    client: str
    role: str | None
    reason: str
    count: int


#: distinct (host, role, reason) entries kept between two takes; the rest are summed in one
MAX_REFUSAL_KEYS = 32


def build_datastore(register_map: RegisterMap, action) -> SimDevice:
    """pymodbus datastore generated from ``register_map``: one holding-register block 0..size-1.

    u16 and bit fields are ``REGISTERS``, u32 ``UINT32`` (high word first), reserved gaps
    ``REGISTERS`` reading 0; addresses >= size are outside the block (pymodbus answers 02).
    Access (RO, reserved, u32 halves) and ranges are enforced in ``action`` against the map,
    not with pymodbus's ``readonly`` flag, so that every refusal is decided in one place,
    logged and counted. ``action`` is the ``SimDevice`` action coroutine.
    """
    simdata = []
    for addr in range(register_map.size):
        hit = register_map.at(addr)
        if hit is None:
            simdata.append(SimData(addr, datatype=DataType.REGISTERS))
        elif hit[1] == 0:
            dtype = DataType.UINT32 if hit[0].type is RegType.U32 else DataType.REGISTERS
            simdata.append(SimData(addr, datatype=dtype))
    # id 0: answer every unit id (a Modbus TCP server is addressed by IP, not unit id)
    return SimDevice(id=0, simdata=simdata, use_bit_addressing=True, action=action)


class PlcLink:
    """Modbus TCP server for the PLC, with thread-safe accessors for the controller.

    ``register_map``: the table served (default :data:`PLC_MAP`); ``clock``: time source for
    event stamps and heartbeat watchdog (default monotonic); ``quiet``: registers whose PLC
    writes update the image (and the heartbeat time) but are not queued as events
    (default: ``plc_heartbeat``, written every PLC scan); ``max_events``: event queue bound.

    The controller side may write any named register (RO ones are its outputs); the PLC
    may write only RW registers, in range, 32-bit registers whole.

    **One writer.** ``access`` (:class:`~drivers.plc.access.AccessPolicy`: allow-list,
    connection cap, time-outs) guards the connections. Of the allowed clients, only the one
    that owns the link may write any register; the others may read. The owner is the first
    client to write ``plc_heartbeat`` while the link has no owner, and stays owner until
    its heartbeat has not changed for ``heartbeat_timeout_s`` on ``clock`` (the controller's
    watchdog time-out). If its connection closes, a new connection from the same host may
    take over at once (the PLC reconnecting). Once the owner is silent past the time-out, a
    connection from its host may take over, and from another host only if an allow-list
    (``access.allow``) names that host: with no allow-list the link stays with the PLC's
    host for the life of the process (a site that moves its PLC to another address names
    it in ``plc.allow``, or restarts the controller).
    Another client's write is refused with exception 01 and changes nothing, so a rogue
    cannot keep the link alive with its own heartbeat. (A map without ``plc_heartbeat``
    has no link time-out: any allowed client may write.)

    **Roles.** ``tls`` (:class:`TlsListener`) adds a Modbus/TCP Security listener on the
    same image. Its clients carry a role, and the role's rights
    (:func:`drivers.plc.tls.rights_needed`) decide their writes, so a maintenance station
    may select a recipe while the PLC owns the link. The heartbeat stays owned: only the
    owner's counts, and a role with no right cannot own the link. ``plain=False`` serves
    TLS only. Every
    refused write (not the owner, or a right missing) is counted per client and reason for
    the controller's audit trail (:meth:`take_refusals`).
    """

    def __init__(self, register_map: RegisterMap = PLC_MAP, clock: Clock | None = None,
                 quiet: Iterable[str] | None = None, max_events: int = 1024,
                 access: AccessPolicy | None = None, heartbeat_timeout_s: float = 1.0,
                 tls: TlsListener | None = None, plain: bool = True):
        self.map = register_map
        self._clock = clock or MonotonicClock()
        if quiet is None:
            quiet = [n for n in ("plc_heartbeat",) if n in register_map]
        self._quiet = frozenset(quiet)
        for name in self._quiet:
            self.map[name]  # raises PlcMapError for an unknown name
        self._lock = threading.Lock()
        self._image = [0] * register_map.size
        if "map_version" in register_map:
            self._put("map_version", register_map.version)
        self._events: collections.deque[PlcWrite] = collections.deque(maxlen=max_events)
        self._events_cv = threading.Condition()
        self._dropped = 0
        self._rejected = 0
        self._hb_change: float | None = None
        self._hb_timeout = float(heartbeat_timeout_s)
        self._owner: Peer | None = None
        self._refusals: dict[tuple[str, str | None, str], list] = {}
        self.guard = ConnectionGuard(access or AccessPolicy(), is_owner=self._is_owner)
        self._plain = plain
        self._server = ServerThread(
            lambda address: ConformantTcpServer(build_datastore(self.map, self._action), address=address,
                                                guard=self.guard, registers=self.answer_registers),
            name="plc-modbus-server")
        self.tls = tls
        self.tls_guard: ConnectionGuard | None = None
        self._tls_server: ServerThread | None = None
        if tls is not None:
            self.tls_guard = ConnectionGuard(access or AccessPolicy(), is_owner=self._is_owner,
                                             warnings=self.guard.warn)
            self._tls_server = ServerThread(
                lambda address: ConformantTlsServer(build_datastore(self.map, self._action), address=address,
                                                    guard=self.tls_guard, sslctx=tls.context,
                                                    registers=self.answer_registers,
                                                    roles=dict(tls.roles),
                                                    handshake_timeout_s=tls.handshake_timeout_s),
                name="plc-modbus-tls-server")

    # ------------------------------------------------------------------ lifecycle
    def start(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (0 = any free port) and, with ``tls``, on its host and
        port; return the plain port (the TLS port if ``plain`` is False).

        Raises :class:`PlcLinkError` if already running or an address cannot be bound
        (then nothing listens).
        """
        if self._server.running or (self._tls_server is not None and self._tls_server.running):
            raise PlcLinkError(f"PLC link already running on port {self.port or self.tls_port}")
        started = []
        try:
            if self._plain:
                started.append(self._listen(self._server, host, port, "plain"))
            if self._tls_server is not None:
                started.append(self._listen(self._tls_server, self.tls.host, self.tls.port, "tls"))
        except PlcLinkError:
            self.stop()
            raise
        return started[0]

    def _listen(self, server: ServerThread, host: str, port: int, kind: str) -> int:
        try:
            port = server.start(host, port)
        except ServerStartError as exc:
            raise PlcLinkError(f"PLC link ({kind}) cannot listen on {host}:{port}: {exc.__cause__}") from exc
        _log().info("plc_link_listening", host=host, port=port, transport=kind)
        return port

    def stop(self) -> None:
        """Close all PLC connections and the listeners; join the server threads. Idempotent."""
        for server in (self._server, self._tls_server):
            if server is not None and server.running:
                port = server.port
                server.stop()
                _log().info("plc_link_stopped", port=port)

    @property
    def port(self) -> int | None:
        """Plain Modbus TCP port listened on while running, else None."""
        return self._server.port

    @property
    def tls_port(self) -> int | None:
        """Modbus/TCP Security port listened on while running, else None."""
        return self._tls_server.port if self._tls_server is not None else None

    def __enter__(self) -> PlcLink:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ controller side
    def read(self, name: str) -> int:
        """Current value of register ``name``. Raises PlcMapError for an unknown name."""
        reg = self.map[name]
        a = reg.address
        with self._lock:
            return (self._image[a] << 16) | self._image[a + 1] if reg.words == 2 else self._image[a]

    def read_bits(self, name: str) -> dict[str, bool]:
        """Named bits of bit-field register ``name``."""
        return self.map.bits(name, self.read(name))

    def write(self, name: str, value: int) -> None:
        """Set register ``name`` (any access: RO registers are the controller's outputs).

        Raises PlcMapError (unknown name, not an int, out of range); nothing changes then.
        """
        self.write_many({name: value})

    def write_many(self, values: Mapping[str, int]) -> None:
        """Set several registers atomically: a PLC read sees all of them or none.

        All values are validated first; on PlcMapError nothing changes.
        """
        words = {name: self.map.to_words(name, value) for name, value in values.items()}
        with self._lock:
            for name, w in words.items():
                a = self.map[name].address
                self._image[a:a + len(w)] = w

    def set_bits(self, name: str, **flags: bool) -> int:
        """Set/clear named bits of bit-field register ``name`` atomically; return the new value.

        e.g. ``link.set_bits("status_word", busy=False, done=True)``. Raises PlcMapError for
        an unknown register or bit name (nothing changes).
        """
        reg = self.map[name]
        with self._lock:
            value = self.map.with_bits(name, self._image[reg.address], flags)
            self._image[reg.address] = self.map.check(name, value)
        return value

    def snapshot(self) -> dict[str, int]:
        """All named registers, read under one lock (a consistent image)."""
        with self._lock:
            image = list(self._image)
        return self.map.decode_image(image)

    def next_write(self, timeout: float | None = 0.0) -> PlcWrite | None:
        """Oldest PLC write event not yet taken, waiting up to ``timeout`` *wall* seconds (None =
        forever). The controller polls :meth:`drain_writes` once per scan instead; a task of
        the simulated clock must not wait here (nothing can arrive while it holds the clock).

        Returns None on timeout. Events come in the order the PLC's requests were served.
        """
        with self._events_cv:
            if not self._events and timeout != 0.0:
                self._events_cv.wait_for(lambda: bool(self._events), timeout)
            return self._events.popleft() if self._events else None

    def drain_writes(self) -> list[PlcWrite]:
        """All queued PLC write events, oldest first (empties the queue). An empty queue is
        seen without the lock (a deque's length is read atomically): a write queued meanwhile
        is the next call's, as it would be right after the lock is let go."""
        if not self._events:
            return []
        with self._events_cv:
            out = list(self._events)
            self._events.clear()
        return out

    @property
    def last_heartbeat_change(self) -> float | None:
        """Clock time (s) the PLC last wrote a *different* ``plc_heartbeat``; None if never."""
        with self._lock:
            return self._hb_change

    @property
    def owner(self) -> str | None:
        """``host:port`` of the client that owns the link now, or None."""
        with self._lock:
            return str(self._owner) if self._owner is not None and not self._expired() else None

    def take_refusals(self) -> list[Refusal]:
        """Writes refused for who sent them (not the owner, or a role without the right)
        since the last call, one entry per client host, role and reason; empties the
        record. Bounded: past :data:`MAX_REFUSAL_KEYS` entries the rest are summed under
        client ``*``."""
        with self._lock:
            out = [Refusal(t, host, role, reason, n) for (host, role, reason), (t, n) in self._refusals.items()]
            self._refusals.clear()
        return out

    def _note_refusal(self, peer: Peer | None, reason: str) -> None:
        """Count one refused write (lock held)."""
        key = (peer.host if peer is not None else "", peer.role if peer is not None else None, reason)
        if key not in self._refusals and len(self._refusals) >= MAX_REFUSAL_KEYS:
            key = ("*", None, "more clients and reasons")
        entry = self._refusals.setdefault(key, [self._clock.now(), 0])
        entry[1] += 1

    @property
    def rejected_writes(self) -> int:
        """PLC write requests refused with an exception since start."""
        with self._lock:
            return self._rejected

    @property
    def dropped_writes(self) -> int:
        """Events dropped because the queue was full (the controller did not drain it)."""
        with self._events_cv:
            return self._dropped

    # ------------------------------------------------------------------ PLC side (loop thread)
    def _put(self, name: str, value: int) -> None:
        a = self.map[name].address
        w = self.map.to_words(name, value)
        self._image[a:a + len(w)] = w

    async def _action(self, func_code: int, start: int, address: int, count: int,
                      registers: list[int], values: list[int] | list[bool] | None) -> ExcCodes | None:
        """pymodbus ``SimDevice`` action, for the requests pymodbus serves (the bit
        functions): decide a write, then give pymodbus the whole current image to answer from."""
        code = self._plc_write(func_code, address, values, CURRENT_PEER.get()) if values is not None else None
        with self._lock:
            registers[:len(self._image)] = self._image
        return ExcCodes(code) if code is not None else None

    def answer_registers(self, pdu: bytes, peer: Peer | None) -> bytes:
        """The response PDU to a register request (FC3, FC6, FC16, FC23), answered from the
        image. ``pdu`` has passed :func:`~drivers.plc.conformance.check_request` (function,
        quantities, byte counts and length are well-formed). A read beyond the map answers
        02; a write is decided as :meth:`_plc_write` decides it (FC23 writes, then reads, as
        the spec and pymodbus order it)."""
        fc = pdu[0]
        if fc == 3:
            start, qty = struct.unpack_from(">HH", pdu, 1)
            return self._read_pdu(fc, start, qty)
        if fc == 6:
            address, value = struct.unpack_from(">HH", pdu, 1)
            code = self._plc_write(fc, address, [value], peer)
            return pdu if code is None else exception_pdu(fc, code)
        if fc == 16:
            address, qty = struct.unpack_from(">HH", pdu, 1)
            code = self._plc_write(fc, address, list(struct.unpack_from(f">{qty}H", pdu, 6)), peer)
            return pdu[:5] if code is None else exception_pdu(fc, code)
        if fc == 23:
            read_at, read_qty, write_at, write_qty = struct.unpack_from(">HHHH", pdu, 1)
            code = self._plc_write(fc, write_at, list(struct.unpack_from(f">{write_qty}H", pdu, 10)), peer)
            return self._read_pdu(fc, read_at, read_qty) if code is None else exception_pdu(fc, code)
        raise ValueError(f"function code {fc} is not a register function")

    def _read_pdu(self, fc: int, start: int, qty: int) -> bytes:
        with self._lock:
            if start + qty > len(self._image):
                return exception_pdu(fc, ExcCodes.ILLEGAL_ADDRESS)
            words = self._image[start:start + qty]
        return struct.pack(f">BB{qty}H", fc, 2 * qty, *words)

    def _plc_write(self, func_code: int, address: int, values: list[int] | list[bool],
                   peer: Peer | None) -> int | None:
        """Decide and apply one PLC write request: None if applied, else the Modbus exception
        code answered (the map refuses it, or ``peer`` may not write it; counted and logged)."""
        events: list[PlcWrite] = []
        rejected: PlcWriteRejected | None = None
        not_owner: str | None = None
        lacking: str | None = None
        with self._lock:
            try:
                if func_code in _BIT_FCS:
                    current = {r.name: self._image[r.address] for r in self.map
                               if r.type is RegType.BITFIELD}
                    new = self.map.decode_plc_bit_write(address, list(values), current)
                else:
                    new = self.map.decode_plc_write(address, [int(v) for v in values])
            except PlcWriteRejected as exc:
                self._rejected += 1
                rejected = exc
            else:
                lacking = self._missing_right(peer, new)
                not_owner = None if lacking is not None else self._refuse_writer(peer, new)
                if lacking is None and not_owner is None:
                    self._apply_plc_write(new, events, peer)
                else:
                    self._rejected += 1
                    self._note_refusal(peer, f"role lacks right {lacking}" if lacking is not None
                                       else "not the link owner")
        if lacking is not None:
            self.guard.warn.warning("plc_write_refused_role", client=str(peer), role=peer.role,
                                    missing=lacking, fc=func_code, address=address,
                                    registers=sorted(new))
            return 1
        if not_owner is not None:
            self.guard.warn.warning("plc_write_not_owner", client=str(peer), owner=not_owner,
                                    fc=func_code, address=address)
            return 1
        if rejected is not None:
            self.guard.warn.warning("plc_write_rejected", fc=func_code, address=address,
                                    code=rejected.modbus_code, reason=str(rejected),
                                    client=str(peer or ""))
            return rejected.modbus_code
        if events:
            with self._events_cv:
                room = self._events.maxlen - len(self._events)  # type: ignore[operator]
                self._dropped += max(0, len(events) - room)
                self._events.extend(events)
                self._events_cv.notify_all()
        return None

    def _missing_right(self, peer: Peer | None, new: dict[str, int]) -> str | None:
        """The right ``peer``'s role lacks for writing ``new``, or None (lock held; plain
        TCP peers have no role: the owner rule alone decides)."""
        if peer is None or peer.rights is None:
            return None
        from drivers.plc.tls import missing_right, rights_needed
        current = {n: self._read_unlocked(n) for n in new}
        return missing_right(peer.rights, rights_needed(self.map, new, current))

    def _connected(self, peer: Peer) -> bool:
        return any(g is not None and peer.id in g.peers for g in (self.guard, self.tls_guard))

    def _expired(self) -> bool:
        """The owner's heartbeat has not changed for the time-out (lock held)."""
        return self._hb_change is None or self._clock.now() - self._hb_change > self._hb_timeout

    def _is_owner(self, peer: Peer) -> bool:
        with self._lock:
            return peer is self._owner and not self._expired()

    def _refuse_writer(self, peer: Peer | None, new: dict[str, int]) -> str | None:
        """None if ``peer`` may write ``new`` (taking ownership if it may), else a text
        naming the owner (lock held). No peer: a request from outside the guard (none)."""
        if peer is None or peer is self._owner and not self._expired():
            return None
        if peer.rights is not None and "plc_heartbeat" not in new:
            return None             # TLS: the role's rights decide (checked before); the heartbeat is owned
        owner_gone = self._owner is None or not self._connected(self._owner)
        same_host = self._owner is None or self._owner.host == peer.host
        may_claim = self._owner is None or (self._expired() and (same_host or self._named(peer.host))) or (
            owner_gone and same_host)
        if may_claim and ("plc_heartbeat" in new or "plc_heartbeat" not in self.map):
            previous = self._owner
            self._owner = peer      # the link is ok only once its heartbeat changes
            _log().info("plc_link_owner", client=str(peer),
                        previous=str(previous) if previous is not None else None)
            return None
        if self._owner is not None and self._expired() and not same_host:
            return (f"{self._owner} (silent; only its host {self._owner.host} or a host plc.allow names "
                    "may take the link over)")
        return str(self._owner) if self._owner is not None else "none (write plc_heartbeat first)"

    def _named(self, host: str) -> bool:
        """``host`` is named by an allow-list (of either listener): a host the site chose
        for its PLC, so it may take a silent link over."""
        return any(g is not None and g.policy.allow is not None and g.policy.allows(host)
                   for g in (self.guard, self.tls_guard))

    def _apply_plc_write(self, new: dict[str, int], events: list[PlcWrite], peer: Peer | None = None) -> None:
        """Apply map-validated PLC values to the image (lock held), changing only the words
        of registers whose value changed; collect an event per register written (changed
        or not: a PLC writing the same value again is still a write)."""
        now = self._clock.now()
        who = None                    # the writer's name, made for its first event
        image = self._image
        for name, value in new.items():
            reg = self.map[name]
            a = reg.address
            previous = (image[a] << 16) | image[a + 1] if reg.words == 2 else image[a]
            if value != previous:
                if reg.words == 2:
                    image[a], image[a + 1] = (value >> 16) & 0xFFFF, value & 0xFFFF
                else:
                    image[a] = value
                if name == "plc_heartbeat":
                    self._hb_change = now
            if name not in self._quiet:
                if who is None:
                    who = str(peer) if peer is not None else ""
                events.append(PlcWrite(now, name, value, previous, who))

    def _read_unlocked(self, name: str) -> int:
        reg = self.map[name]
        a = reg.address
        return (self._image[a] << 16) | self._image[a + 1] if reg.words == 2 else self._image[a]
