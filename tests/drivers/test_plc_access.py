"""Who may talk to the PLC link (issue 12): the allow-list, one writer, the connection cap and
the time-outs, warnings that cannot flood. Real pymodbus clients and raw sockets on loopback;
a "rogue host" is a socket bound to 127.0.0.2 (Linux routes all of 127/8 to lo). The owner's
link time-out runs on a ManualClock; network time-outs are waited for by polling, never timed."""
from __future__ import annotations

import ipaddress
import socket
import struct
import time

import pytest
from pymodbus.client import ModbusTcpClient

from cell.clock import ManualClock
from drivers.plc import PlcConfig
from drivers.plc.access import AccessPolicy, RateLimitedWarnings, parse_allow
from drivers.plc.server import PlcLink
from tests.drivers.conftest import server_closed, wait_for

pytestmark = pytest.mark.usefixtures("no_leaked_plc_threads")
LOOPBACK_ONLY = (ipaddress.ip_network("127.0.0.1/32"),)


def _link(**policy) -> PlcLink:
    link = PlcLink(clock=ManualClock(100.0), access=AccessPolicy(**policy), heartbeat_timeout_s=1.0)
    link.start()
    return link


def _client(port: int, source: str = "127.0.0.1") -> ModbusTcpClient:
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0, source_address=(source, 0))
    assert c.connect()
    return c


def _raw(port: int, source: str = "127.0.0.1") -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.settimeout(5)
    s.bind((source, 0))
    s.connect(("127.0.0.1", port))
    return s


def _read_hb() -> bytes:
    """An MBAP read of the heartbeat register (FC3, address 1, 1 register)."""
    return struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 1, 1)


def test_a_host_outside_the_allow_list_is_closed_before_any_request():
    link = _link(allow=LOOPBACK_ONLY)
    try:
        rogue = _raw(link.port, "127.0.0.2")
        rogue.sendall(_read_hb())
        assert server_closed(rogue), "the rogue's connection stayed open"
        rogue.close()
        ok = _client(link.port)                          # the allowed PLC is served
        assert ok.read_holding_registers(0, count=1).registers[0] > 0
        ok.close()
        assert link.guard.refused == 1
    finally:
        link.stop()


def test_only_the_owner_writes_and_a_second_client_cannot_keep_the_link_alive():
    link = _link()
    clock = link._clock
    plc, rogue = _client(link.port), _client(link.port, "127.0.0.2")
    try:
        assert not plc.write_register(1, 1).isError()                      # heartbeat: owner
        assert link.owner is not None and link.owner.startswith("127.0.0.1:")
        assert link.last_heartbeat_change == 100.0
        rr = rogue.write_register(20, 7)                                   # recipe select
        assert rr.isError() and rr.exception_code == 1 and link.read("recipe_select") == 0
        assert rogue.read_holding_registers(20, count=1).registers == [0]   # reads are served
        # the PLC goes silent; the rogue's heartbeat changes nothing
        clock.advance(0.6)
        assert rogue.write_register(1, 99).exception_code == 1
        assert link.read("plc_heartbeat") == 1 and link.last_heartbeat_change == 100.0
        clock.advance(0.6)                                    # 1.2 s: the watchdog would trip now
        assert link.owner is None
        # silent past the time-out, with no allow-list: another host still cannot take over,
        # neither by its heartbeat nor by a command (a reset, an execute)
        assert rogue.write_register(1, 100).exception_code == 1
        assert rogue.write_register(20, 4).exception_code == 1
        assert link.owner is None and link.read("plc_heartbeat") == 1 and link.read("recipe_select") == 0
        assert link.drain_writes() == []
        # the PLC's own host (a new connection: the PLC restarted) takes it back
        plc.close()
        plc = _client(link.port)
        assert not plc.write_register(1, 2).isError()
        assert link.owner.startswith("127.0.0.1:") and link.last_heartbeat_change == pytest.approx(101.2)
        assert not plc.write_register(20, 5).isError()
        assert [(w.name, w.value, w.peer.split(":")[0]) for w in link.drain_writes()] == \
            [("recipe_select", 5, "127.0.0.1")]
        refused = {(r.client, r.reason): r.count for r in link.take_refusals()}
        assert refused == {("127.0.0.2", "not the link owner"): 4}
    finally:
        plc.close()
        rogue.close()
        link.stop()


def test_a_host_the_allow_list_names_may_take_a_silent_link_over():
    """A site that moves its PLC names the new address in plc.allow: once the old PLC is
    silent past the time-out, the named host owns the link; a host not named never does."""
    allow = (ipaddress.ip_network("127.0.0.1/32"), ipaddress.ip_network("127.0.0.2/32"),
             ipaddress.ip_network("127.0.0.3/32"))
    link = _link(allow=allow)
    clock = link._clock
    old, new = _client(link.port), _client(link.port, "127.0.0.2")
    try:
        assert not old.write_register(1, 1).isError()
        assert new.write_register(1, 7).exception_code == 1          # not while the PLC beats
        clock.advance(1.2)
        assert not new.write_register(1, 8).isError()
        assert link.owner.startswith("127.0.0.2:")
        assert old.write_register(1, 2).exception_code == 1           # the new owner beats now
    finally:
        old.close()
        new.close()
        link.stop()


def test_at_the_cap_the_longest_idle_connection_is_shed_never_the_owner():
    link = _link(max_connections=2)
    try:
        plc = _client(link.port)
        assert not plc.write_register(1, 1).isError()                      # owner
        idle = _raw(link.port)
        newcomer = _client(link.port, "127.0.0.2")
        assert newcomer.read_holding_registers(0, count=1).registers[0] > 0
        assert server_closed(idle), "the idle connection was not shed"
        assert not plc.write_register(1, 3).isError()                      # the owner survives
        assert link.guard.shed == 1
        plc.close()
        newcomer.close()
        idle.close()
    finally:
        link.stop()


def test_idle_connections_and_half_sent_frames_are_closed():
    link = _link(idle_timeout_s=0.3, frame_timeout_s=0.3)
    try:
        silent = _raw(link.port)
        half = _raw(link.port)
        half.sendall(b"\x00\x01\x00")                         # 3 bytes of an MBAP header
        assert server_closed(silent) and server_closed(half)
        assert link.guard.timed_out == 2 and link.guard.peers == {}
    finally:
        link.stop()


def test_warnings_are_rate_limited_with_a_count_of_what_was_dropped(capsys):
    now = [0.0]
    w = RateLimitedWarnings(burst=2, interval_s=10.0, now=lambda: now[0])
    assert [w.warning("plc_write_not_owner", client="x") for _ in range(5)] == [True, True, False,
                                                                                  False, False]
    assert w.dropped("plc_write_not_owner") == 3
    now[0] = 11.0
    assert w.warning("plc_write_not_owner", client="x")
    err = capsys.readouterr().err
    assert err.count("plc_write_not_owner ") + err.count("plc_write_not_owner\x1b") >= 1
    assert "plc_write_not_owner_suppressed" in err and "dropped=3" in err


@pytest.mark.parametrize("kwargs, words", [
    ({"allow": ["10.0.0.300"]}, "allow[0]: '10.0.0.300' is not an address or network"),
    ({"allow": ["10.0.0.5", "plc-1"]}, "allow[1]: 'plc-1' is not an address or network"),
    ({"host": "0.0.0.0"}, "listens on every interface and allow is empty"),
    ({"host": "::"}, "write allow_any: true to mean it"),
])
def test_bad_access_config_names_the_field(kwargs, words):
    with pytest.raises(ValueError) as exc:
        PlcConfig(**kwargs)
    assert words in str(exc.value)


def test_access_policy_from_the_config():
    assert PlcConfig().access_policy().allow is None                         # loopback listener
    assert PlcConfig(host="0.0.0.0", allow_any=True).access_policy().allow is None
    p = PlcConfig(host="0.0.0.0", allow=["10.0.0.0/24", "::1"]).access_policy()
    assert p.allows("10.0.0.77") and p.allows("::1") and p.allows("::ffff:10.0.0.8")
    assert not p.allows("10.0.1.1") and not p.allows("127.0.0.1")
    assert parse_allow(["192.168.1.7"]) == (ipaddress.ip_network("192.168.1.7/32"),)


def test_closed_connections_leave_no_task_behind():
    """A storm of shed and timed-out connections must not leave one worker task each."""
    import asyncio

    link = _link(max_connections=2, idle_timeout_s=0.2)
    try:
        socks = []
        for _ in range(12):
            s = _raw(link.port)
            s.sendall(_read_hb())                         # starts the connection's worker
            socks.append(s)
        assert all(server_closed(s) for s in socks[:-2])        # shed at the cap, then idled out
        assert all(server_closed(s) for s in socks[-2:])
        loop = link._server._loop
        fut = asyncio.run_coroutine_threadsafe(_tasks(), loop)
        names = fut.result(timeout=10)
        # left: the server's own task and the sweep; no connection worker
        assert [n for n in names if "sweep_forever" not in n and "ServerThread" not in n] == [], names
        for s in socks:
            s.close()
    finally:
        link.stop()


async def _tasks() -> list[str]:
    import asyncio
    return [f"{t.get_name()} {t.get_coro().__qualname__}" for t in asyncio.all_tasks()
            if t is not asyncio.current_task() and not t.done()]


def test_a_client_that_sends_without_reading_is_closed_and_the_stream_stays_in_step(capsys):
    """Storm bench: fuzzers that never read their answers made the server's memory grow
    (asyncio buffers every answer) and left it high; and a read over 64 KiB was silently
    dropped by pymodbus, putting the stream out of step ("MBAP protocol id 14"). Such a
    client is closed now, for what it is (too many requests pending, or answers unread)."""
    link = _link()
    try:
        s = _raw(link.port)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        burst = b"".join(struct.pack(">HHHBBHH", i, 0, 6, 1, 3, 0, 125) for i in range(500))
        try:
            for _ in range(100):
                s.sendall(burst)
        except OSError:
            pass                                              # closed under our feet: expected
        assert server_closed(s)
        assert link.guard.peers == {}
        s.close()
        err = capsys.readouterr().err
        assert "requests pending" in err or "modbus_client_not_reading" in err
        assert "protocol id" not in err
    finally:
        link.stop()


def test_a_storm_of_idle_sockets_cannot_shed_a_client_that_asks():
    """Storm bench: at the cap, a new client was shed by the next storm connection before
    its request was served (3 of 6 served). Connections that never sent a well-formed
    request are shed first now."""
    link = _link(max_connections=4)
    try:
        reader = _raw(link.port)
        reader.sendall(_read_hb())
        assert len(reader.recv(64)) == 11                       # served once: a known client
        storm = [_raw(link.port) for _ in range(20)]            # idle sockets, never a request
        for _ in range(3):
            reader.sendall(_read_hb())
            assert len(reader.recv(64)) == 11
        late = _raw(link.port)                                  # a new client, asking at once
        late.sendall(_read_hb())
        assert len(late.recv(64)) == 11
        storm += [_raw(link.port) for _ in range(5)]
        late.sendall(_read_hb())
        assert len(late.recv(64)) == 11
        assert sum(server_closed(s, 2.0) for s in storm) >= len(storm) - 2
        for s in storm + [reader, late]:
            s.close()
    finally:
        link.stop()


# ---------------------------------------------------------------- per-host quota (issue 12)
def _guard_state(link: PlcLink, seen: int, upper_s: float = 30.0) -> dict[str, int]:
    """The guard's connections per host once it has seen ``seen`` connections since start
    (a bounded poll on the server's own loop: counts, never a timing)."""
    deadline = time.monotonic() + upper_s
    while True:
        seen_now, hosts = link._server.call(lambda: (link.guard.connections, link.guard.per_host()))
        if seen_now >= seen or time.monotonic() > deadline:
            return hosts
        time.sleep(0.02)


def _asks(s: socket.socket) -> bool:
    s.sendall(_read_hb())
    return len(s.recv(64)) == 11


def test_one_hosts_flood_stays_within_its_quota_and_never_sheds_another_hosts_connections():
    """A host past ``max_per_host`` sheds its own connections; the other host's reader and
    the owner (from a third address) keep theirs."""
    link = _link(max_connections=8, max_per_host=3)
    try:
        plc = _client(link.port)
        assert not plc.write_register(1, 1).isError()                  # 127.0.0.1 owns the link
        reader = _raw(link.port, "127.0.0.3")
        assert _asks(reader)
        flood = [_raw(link.port, "127.0.0.2") for _ in range(40)]      # idle sockets, never a request
        hosts = _guard_state(link, seen=42)
        assert hosts == {"127.0.0.1": 1, "127.0.0.3": 1, "127.0.0.2": 3}, hosts
        assert sum(server_closed(s, 5.0) for s in flood[:-3]) == 37          # the flood shed its own, oldest first
        assert _asks(reader)                                           # the other host is still served
        assert not plc.write_register(1, 2).isError()                  # and the owner still writes
        assert link.guard.shed == 37
        for s in flood + [reader]:
            s.close()
        plc.close()
    finally:
        link.stop()


def test_at_the_cap_the_host_holding_the_most_is_shed_and_a_host_with_fewer_keeps_its_own():
    """Global cap 6, no quota: host .2 fills the link; a connection from host .3 (which
    holds fewer) sheds one of .2's; .2's next connections shed its own, never .3's, even
    .3's that never asked (a TLS client in its handshake has not asked yet)."""
    link = _link(max_connections=6)
    try:
        plc = _client(link.port)
        assert not plc.write_register(1, 1).isError()                  # owner: never counted, never shed
        flood = [_raw(link.port, "127.0.0.2") for _ in range(5)]       # the link is full
        assert _guard_state(link, seen=6) == {"127.0.0.1": 1, "127.0.0.2": 5}
        quiet = _raw(link.port, "127.0.0.3")                           # sends nothing, like a handshake
        assert _guard_state(link, seen=7) == {"127.0.0.1": 1, "127.0.0.2": 4, "127.0.0.3": 1}
        assert server_closed(flood[0], 5.0)                                  # .2's oldest made room
        flood += [_raw(link.port, "127.0.0.2") for _ in range(30)]
        hosts = _guard_state(link, seen=37)
        assert hosts == {"127.0.0.1": 1, "127.0.0.2": 4, "127.0.0.3": 1}, hosts
        assert _asks(quiet)                                            # .3's connection survived
        assert not plc.write_register(1, 2).isError()
        other = _raw(link.port, "127.0.0.4")                           # another host with fewer: .2 pays
        assert _asks(other)
        assert _guard_state(link, seen=38) == {"127.0.0.1": 1, "127.0.0.2": 3, "127.0.0.3": 1,
                                               "127.0.0.4": 1}
        again = _raw(link.port, "127.0.0.3")                           # .3 would hold 2 < 3: .2 pays
        assert _guard_state(link, seen=39) == {"127.0.0.1": 1, "127.0.0.2": 2, "127.0.0.3": 2,
                                               "127.0.0.4": 1}
        third = _raw(link.port, "127.0.0.3")                           # .3 would hold 3 > 2: its own,
        assert _guard_state(link, seen=40) == {"127.0.0.1": 1, "127.0.0.2": 2, "127.0.0.3": 2,
                                               "127.0.0.4": 1}
        assert server_closed(again, 5.0)                                     # the one that never asked
        assert _asks(quiet) and _asks(third) and _asks(other)
        # a tie: .4 would hold 2 like .2 and .3; not its own, but the tied hosts' least
        # needed: .2's sockets that never asked, not .3's that ask
        fourth = _raw(link.port, "127.0.0.4")
        assert _guard_state(link, seen=41) == {"127.0.0.1": 1, "127.0.0.2": 1, "127.0.0.3": 2,
                                               "127.0.0.4": 2}
        assert _asks(quiet) and _asks(third) and _asks(other) and _asks(fourth)
        assert not plc.write_register(1, 3).isError()
        for s in flood + [quiet, other, again, third, fourth]:
            s.close()
        plc.close()
    finally:
        link.stop()


def test_at_the_cap_a_fuzzer_is_shed_before_a_client_that_asks_well():
    """Fuzz storm: the legitimate reader was shed when every fuzzing socket had sent a
    well-formed request too and been active more recently; one that sent malformed frames
    goes first now."""
    link = _link(max_connections=3)
    try:
        good, third = _raw(link.port, "127.0.0.2"), _raw(link.port, "127.0.0.4")
        assert _asks(good) and _asks(third)                            # good is idle the longest ...
        bad = _raw(link.port, "127.0.0.3")
        bad.sendall(struct.pack(">HHHBB", 9, 0, 2, 1, 0x41))          # unsupported function: 01
        assert bad.recv(64)[7:] == bytes([0xC1, 1])
        assert _asks(bad)                                              # and one good request
        newcomer = _raw(link.port, "127.0.0.5")                        # ... yet the fuzzer goes first
        assert _asks(newcomer)
        assert server_closed(bad, 5.0) and _asks(good) and _asks(third)
        for s in (good, bad, third, newcomer):
            s.close()
    finally:
        link.stop()


def test_at_the_cap_a_half_sent_frame_is_shed_before_a_new_client_that_has_not_asked_yet():
    """Fuzz storm: a new client whose request the server had not read yet was shed for a
    fuzzing socket that kept sending a frame it never completed (more recent, so idle
    less long)."""
    link = _link(max_connections=2)
    try:
        fresh = _raw(link.port, "127.0.0.2")                           # connected, nothing sent yet
        assert _guard_state(link, seen=1) == {"127.0.0.2": 1}
        half = _raw(link.port, "127.0.0.3")
        half.sendall(struct.pack(">HHHB", 1, 0, 200, 1) + b"\x03")    # a frame that never completes
        def half_seen():
            return [p.partial_since is not None for p in link.guard.peers.values() if p.host == "127.0.0.3"]
        wait_for(lambda: link._server.call(half_seen) == [True], timeout=10,
                 what="the server to read the half frame")
        newcomer = _raw(link.port, "127.0.0.4")
        assert _asks(newcomer)
        assert server_closed(half, 5.0) and _asks(fresh)
        for s in (fresh, half, newcomer):
            s.close()
    finally:
        link.stop()


def test_on_a_tie_a_misbehaving_host_is_shed_before_a_clean_hosts_new_client():
    """Fuzz storm: the legitimate host (reader and a new client) held as many connections
    as each fuzzing host; a fuzzing host's next connection shed the new client, whose
    request had not been read yet, as the oldest connection that had not asked."""
    link = _link(max_connections=4)
    try:
        reader = _raw(link.port, "127.0.0.1")
        assert _asks(reader)
        fresh = _raw(link.port, "127.0.0.1")                           # a new client, not asked yet
        fuzz = _raw(link.port, "127.0.0.2")
        fuzz.sendall(struct.pack(">HHHBB", 9, 0, 2, 1, 0x41))          # malformed: 01
        assert fuzz.recv(64)[7:] == bytes([0xC1, 1])
        assert _asks(fuzz)                                             # and it asks, more recently
        other = _raw(link.port, "127.0.0.2")                           # .2 holds 2, as .1 does: the cap
        assert _guard_state(link, seen=4) == {"127.0.0.1": 2, "127.0.0.2": 2}
        newcomer = _raw(link.port, "127.0.0.3")                        # .3 would hold 1: .1 or .2 pays
        assert _guard_state(link, seen=5) == {"127.0.0.1": 2, "127.0.0.2": 1, "127.0.0.3": 1}
        assert server_closed(other, 5.0)                                     # the misbehaving host's
        assert _asks(fresh) and _asks(reader) and _asks(newcomer)
        for s in (reader, fresh, fuzz, other, newcomer):
            s.close()
    finally:
        link.stop()


def test_on_a_tie_a_host_whose_bad_connection_just_left_is_still_shed_first():
    """16-round storm bench: 6 of 96 new clients were reset during the fuzz storm. A fuzzing
    host whose malformed connections had just been closed looked clean at the next tie,
    and the clean host's new client (its request not read yet) went first. A host that
    misbehaved is remembered for a while (bounded)."""
    link = _link(max_connections=4)
    try:
        reader = _raw(link.port, "127.0.0.1")
        assert _asks(reader)
        fresh = _raw(link.port, "127.0.0.1")                           # a new client, not asked yet
        bad = _raw(link.port, "127.0.0.2")
        bad.sendall(struct.pack(">HHHBB", 9, 0, 2, 1, 0x41))           # malformed: 01
        assert bad.recv(64)[7:] == bytes([0xC1, 1])
        bad.close()                                                    # the fuzzer's bad socket leaves
        wait_for(lambda: link._server.call(link.guard.per_host) == {"127.0.0.1": 2}, timeout=30,
                 what="the server to see the fuzzer's socket go")
        polite = [_raw(link.port, "127.0.0.2") for _ in range(2)]      # the same host, asking well now
        assert all(_asks(c) for c in polite)
        assert _guard_state(link, seen=5) == {"127.0.0.1": 2, "127.0.0.2": 2}
        newcomer = _raw(link.port, "127.0.0.3")                        # a tie of .1 and .2: .2 pays
        assert _guard_state(link, seen=6) == {"127.0.0.1": 2, "127.0.0.2": 1, "127.0.0.3": 1}
        assert _asks(fresh) and _asks(reader) and _asks(newcomer)
        for s in (reader, fresh, newcomer, *polite):
            s.close()
    finally:
        link.stop()


def test_the_hostile_hosts_remembered_are_bounded():
    import asyncio

    from drivers.plc import access
    from drivers.plc.access import AccessPolicy, ConnectionGuard, Peer

    async def churn():
        g = ConnectionGuard(AccessPolicy())                            # allow None: any address
        for i in range(access.HOSTILE_MAX_HOSTS + 50):
            p = g.connect(f"10.0.{i // 250}.{i % 250}", 1000, lambda: None)
            p.malformed = 1
            g.drop(p)
        return g
    g = asyncio.run(churn())
    assert len(g._hostile) == access.HOSTILE_MAX_HOSTS and not g.peers
    assert "10.0.0.0" not in g._hostile                                 # the oldest forgotten first


def test_the_owners_connection_does_not_count_against_its_hosts_quota():
    link = _link(max_connections=8, max_per_host=1)
    try:
        plc = _client(link.port)
        assert not plc.write_register(1, 1).isError()                  # owner
        hmi = _raw(link.port)                                          # same host: its one connection
        assert _asks(hmi)
        more = _raw(link.port)                                         # past the quota: sheds hmi, not the PLC
        assert _guard_state(link, seen=3) == {"127.0.0.1": 2}
        assert server_closed(hmi, 5.0) and _asks(more)
        assert not plc.write_register(1, 2).isError()
        hmi.close()
        more.close()
        plc.close()
    finally:
        link.stop()


@pytest.mark.parametrize("kwargs, field, words", [
    ({"max_connections_per_host": "four"}, "max_connections_per_host", "valid integer"),
    ({"max_connections_per_host": 0}, "max_connections_per_host", "greater than or equal to 1"),
    ({"max_connections_per_host": 2.5}, "max_connections_per_host", "valid integer"),
    ({"max_connections_per_host": 9}, "", "max_connections_per_host (9) is more than max_connections (8)"),
    ({"max_connections": 2, "max_connections_per_host": 3}, "", "is more than max_connections (2)"),
])
def test_a_bad_per_host_quota_names_the_field(kwargs, field, words):
    with pytest.raises(ValueError) as exc:
        PlcConfig(**kwargs)
    assert field in str(exc.value) and words in str(exc.value)


def test_a_bad_per_host_quota_in_the_config_file_names_file_line_and_field(tmp_path):
    from cell.config import CellConfig
    from cell.errors import ConfigError
    for value, words in (("lots", "valid integer"), ("20", "is more than max_connections (8)")):
        cfg = tmp_path / "cell.yaml"
        cfg.write_text(f"format: cell-config/1\nplc:\n  max_connections: 8\n  max_connections_per_host: {value}\n")
        with pytest.raises(ConfigError) as exc:
            CellConfig.load(cfg)
        assert f"cell.yaml:4: plc.max_connections_per_host: " in str(exc.value) and words in str(exc.value), \
            str(exc.value)


def test_the_quota_reaches_the_access_policy_and_the_policy_checks_it():
    assert PlcConfig().access_policy().max_per_host == 4
    assert PlcConfig(max_connections=3, max_connections_per_host=2).access_policy().max_per_host == 2
    for bad in (0, 9, "2"):
        with pytest.raises(ValueError, match="max_per_host must be an integer from 1 to max_connections"):
            AccessPolicy(max_connections=8, max_per_host=bad)
