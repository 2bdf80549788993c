"""What a storm leaves behind (issue 12, "keep memory flat"): after a bounded number of
connection and garbage bursts against an in-process link, on plain TCP and on the TLS
listener, every piece of per-connection state is back at its quiet count: pymodbus's
``active_connections``, the guard's peers, the loop's tasks, and live connection handlers.
Also the TLS handshake time-out: a client that connects to the TLS port and never
handshakes is closed by the server, and half-open TLS connections count against the cap.

Counts, not memory or timing: waits are bounded polls with generous upper bounds, so the
tests do not depend on machine load; RSS is the storm bench's (bench/bench_link_storm.py).
"""
from __future__ import annotations

import gc
import random
import socket
import struct
import time

import pytest
from pydantic import ValidationError
from pymodbus.client import ModbusTlsClient
from pymodbus.exceptions import ModbusIOException

from cell.clock import ManualClock
from drivers.plc import TlsConfig
from drivers.plc.access import AccessPolicy
from drivers.plc.conformance import ConformantRequestHandler
from drivers.plc.server import PlcLink
from tests.drivers.conftest import server_closed
from tests.drivers.tlscerts import Authority, client_context

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")

FC3 = struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 0, 3)


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pki")
    ca = Authority(folder)
    return {"ca": ca, "server": ca.issue("controller", server=True),
            "operator": ca.issue("plc-operator", role="Operator")}


def _link(pki=None, max_connections=4, handshake_timeout_s=5.0) -> PlcLink:
    tls = None
    if pki is not None:
        tls = TlsConfig(enabled=True, port=0, cert=str(pki["server"].cert), key=str(pki["server"].key),
                        ca=str(pki["ca"].path), handshake_timeout_s=handshake_timeout_s).listener()
    return PlcLink(clock=ManualClock(0.0), tls=tls,
                   access=AccessPolicy(max_connections=max_connections, idle_timeout_s=600.0))


def _handlers(server) -> int:
    """Connection handlers of ``server`` still alive (anything still referring to them)."""
    gc.collect()
    return sum(type(o) is ConformantRequestHandler and o.server is server for o in gc.get_objects())


def _settles(server, baseline: dict[str, int], upper_s: float = 30.0) -> dict[str, int]:
    """Poll the server's counts until they equal ``baseline`` (or ``upper_s`` passes)."""
    end = time.monotonic() + upper_s
    while True:
        now = server.counts()
        if now == baseline or time.monotonic() > end:
            return now
        time.sleep(0.05)


def _garbage(rnd: random.Random) -> bytes:
    k = rnd.randrange(5)
    if k == 0:
        return rnd.randbytes(rnd.randrange(1, 3000))                        # noise
    if k == 1:
        pdu = bytes([rnd.choice([3, 6, 16, 0x41])]) + rnd.randbytes(rnd.randrange(0, 20))
        return struct.pack(">HHHB", 7, 0, len(pdu) + 1, 1) + pdu            # framed, random PDU
    if k == 2:
        return FC3 * rnd.randrange(1, 100)                                  # pipelined requests
    if k == 3:
        return struct.pack(">HHHB", 1, 0, 200, 1) + b"\x03"                 # half a frame
    return b""                                                              # connect, say nothing


def _burst(port: int, rnd: random.Random, n: int) -> None:
    """``n`` connections at once, each sends one kind of garbage, then all close."""
    socks = []
    for _ in range(n):
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        try:
            s.sendall(_garbage(rnd))
        except OSError:
            pass                                                            # shed already
        socks.append(s)
    for s in socks:
        s.close()


def test_plain_bursts_leave_no_connection_state_behind():
    link = _link(max_connections=4)
    link.start()
    try:
        server = link._server
        modbus = server.server
        baseline = server.counts()
        assert baseline["connections"] == baseline["peers"] == 0
        rnd = random.Random(12)
        for _ in range(40):                       # 400 connections, 10 at a time over a cap of 4
            _burst(link.port, rnd, 10)
        with socket.create_connection(("127.0.0.1", link.port), timeout=5) as s:  # still serves
            s.sendall(FC3)
            assert len(s.recv(64)) == 15
        assert _settles(server, baseline) == baseline
        assert link.guard.shed > 0                # the cap was hit, and shedding left nothing
    finally:
        link.stop()
    assert _handlers(modbus) == 0


def test_tls_bursts_and_handshake_garbage_leave_no_state_behind(pki):
    link = _link(pki, max_connections=4)
    link.start()
    try:
        server = link._tls_server
        modbus = server.server
        baseline = server.counts()
        rnd = random.Random(802)
        for _ in range(20):                       # garbage and silence instead of a ClientHello
            _burst(link.tls_port, rnd, 10)
        assert _settles(server, baseline) == baseline     # the bursts leave nothing behind
        for _ in range(5):                        # real clients, served, then gone
            assert _served_over_tls(link.tls_port, pki)
        assert _settles(server, baseline) == baseline
    finally:
        link.stop()
    assert _handlers(modbus) == 0


def _served_over_tls(port: int, pki, tries: int = 3) -> bool:
    """A real TLS client connects and reads. On a loaded machine the listener may still be
    accepting the bursts' dead connections from the kernel's queue when the client comes,
    and at the connection cap it sheds a handshake that has not asked anything yet, which
    can be this one (the cap works as meant; a PLC reconnects). So a client that is shed
    tries again, up to ``tries`` times; a server that serves no one fails every try. The
    time-out is a generous upper bound, not a deadline."""
    for _ in range(tries):
        c = ModbusTlsClient("127.0.0.1", port=port, timeout=30, retries=0,
                            sslctx=client_context(pki["ca"], pki["operator"]))
        try:
            if c.connect() and not c.read_holding_registers(0, count=3).isError():
                return True
        except ModbusIOException:
            pass
        finally:
            c.close()
    return False


def test_a_client_that_never_handshakes_is_closed_after_the_time_out(pki):
    link = _link(pki, handshake_timeout_s=0.5)
    link.start()
    try:
        baseline = link._tls_server.counts()
        s = socket.create_connection(("127.0.0.1", link.tls_port), timeout=5)
        try:
            assert server_closed(s, timeout=30.0)  # closed by the server, not by us
        finally:
            s.close()
        assert _settles(link._tls_server, baseline) == baseline
    finally:
        link.stop()


def test_half_open_tls_connections_count_against_the_cap(pki):
    link = _link(pki, max_connections=2, handshake_timeout_s=30.0)
    link.start()
    silent = []
    try:
        for _ in range(6):                        # connect, never handshake
            silent.append(socket.create_connection(("127.0.0.1", link.tls_port), timeout=5))
        # the server accepts them in its own time: until it has seen all six (four shed), a
        # late one would arrive after the client, which would then be the older half-open one
        end = time.monotonic() + 30.0
        while link.tls_guard.shed < 4 and time.monotonic() < end:
            time.sleep(0.02)
        assert link.tls_guard.shed == 4 and len(link.tls_guard.peers) == 2
        c = ModbusTlsClient("127.0.0.1", port=link.tls_port, timeout=5, retries=0,
                            sslctx=client_context(pki["ca"], pki["operator"]))
        assert c.connect()                        # a silent one was shed to let it in
        assert not c.read_holding_registers(0, count=3).isError()
        c.close()
        assert len(link.tls_guard.peers) <= 2
        assert link.tls_guard.shed == 5
    finally:
        for s in silent:
            s.close()
        link.stop()


@pytest.mark.parametrize("bad", [0, -1, 61])
def test_the_handshake_time_out_is_validated(bad):
    with pytest.raises(ValidationError, match="handshake_timeout_s"):
        TlsConfig(handshake_timeout_s=bad)


def test_memory_is_trimmed_only_after_churn_and_at_a_low_rate():
    from drivers.plc import memory
    if not memory.available():
        pytest.skip("not glibc: no malloc_trim")
    trimmer = memory.Trimmer()                                              # the process's defaults
    assert (trimmer.period_s, trimmer.min_connections) == (memory.PERIOD_S, memory.MIN_CONNECTIONS)
    assert not trimmer.maybe_trim(memory.MIN_CONNECTIONS - 1, now=1000.0)    # a PLC that stays connected
    assert trimmer.maybe_trim(memory.MIN_CONNECTIONS, now=1000.0)
    assert not trimmer.maybe_trim(10 ** 6, now=1000.0 + memory.PERIOD_S / 2)  # not more often than the period
    assert trimmer.maybe_trim(10 ** 6, now=1000.0 + memory.PERIOD_S)
    s = trimmer.stats()
    assert s["trims"] == 2 and s["seconds"] >= s["last_s"] >= 0.0


def test_failed_handshakes_free_their_tls_state_without_the_cyclic_gc(pki):
    """A failed ``start_tls`` used to leave a reference cycle (exception -> traceback ->
    frame -> waiter -> exception) holding the connection's SSLProtocol and its 256 KiB
    buffer until the cyclic GC ran; with the GC off, none may be left over."""
    from asyncio.sslproto import SSLProtocol
    link = _link(pki, max_connections=4)
    link.start()
    gc.collect()
    gc.disable()
    try:
        baseline = link._tls_server.counts()
        rnd = random.Random(3)
        for _ in range(5):
            _burst(link.tls_port, rnd, 10)        # garbage and silence: failed handshakes
        assert _settles(link._tls_server, baseline) == baseline
        end = time.monotonic() + 30.0             # closes still under way finish (bounded)
        loop = link._tls_server._loop           # this link's, not other tests' TLS objects

        def mine() -> int:
            return sum(type(o) is SSLProtocol and o._loop is loop for o in gc.get_objects())
        while (left := mine()) and time.monotonic() < end:
            time.sleep(0.1)
    finally:
        gc.enable()
        link.stop()
    assert left == 0
