"""Who may talk to the PLC link, and how many: the allow-list, the connection cap, idle and
half-frame time-outs, and warnings that cannot flood the log.

:class:`ConnectionGuard` lives on the Modbus server's event loop (the network side; its
time-outs use the loop's clock, since they protect the operating system's resources, not
the simulated process). Every TCP connection gets a :class:`Peer` when it opens:

* an address outside :attr:`AccessPolicy.allow` is closed at once, before any request;
* a host may hold at most :attr:`AccessPolicy.max_per_host` connections (the owner's not
  counted): past it, the host's new connection sheds one of that host's own;
* at :attr:`AccessPolicy.max_connections` one connection is shed to make room, never the
  owner's (the PLC that owns the link, :mod:`drivers.plc.server`): a host that would hold
  more than any other (the new one counted) sheds its own; otherwise one of the host(s)
  holding the most is shed (of several, first one misbehaving now or within
  :data:`HOSTILE_MEMORY_S`: a fuzzer whose bad sockets were just closed still counts). So one host's flood
  sheds its own connections, never those of a host holding fewer. Among the candidates:
  first those that never sent a well-formed request, then those that sent malformed
  frames or hold a half-sent one, then the one idle the longest; with nothing to shed the
  new one is closed;
* a connection silent for ``idle_timeout_s`` is closed (not the owner's), and so is one
  that leaves a frame half-sent for ``frame_timeout_s`` (the owner's too: its stream is out
  of step).

Which connection may *write* is the register side's decision (the owner rule,
:class:`drivers.plc.server.PlcLink`); the guard tells it which peer sent a request through
:data:`CURRENT_PEER`.
"""
from __future__ import annotations

import asyncio
import contextvars
import ipaddress
import itertools
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from cell.log import get_logger

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def _log():
    return get_logger("plc.access")


@dataclass(frozen=True)
class AccessPolicy:
    """``allow``: networks a client may connect from (None: any address, for a loopback
    listener or an explicit ``allow_any``); ``max_connections``; ``idle_timeout_s``: close a
    connection silent this long; ``frame_timeout_s``: close one whose frame stays
    incomplete this long; ``max_per_host``: connections one host may hold, the owner's
    not counted (None: only the global cap)."""

    allow: tuple[Network, ...] | None = None
    max_connections: int = 8
    idle_timeout_s: float = 60.0
    frame_timeout_s: float = 5.0
    max_per_host: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.max_connections, int) or self.max_connections < 1:
            raise ValueError(f"max_connections must be an integer >= 1, got {self.max_connections!r}")
        if self.max_per_host is not None and (
                not isinstance(self.max_per_host, int) or not 1 <= self.max_per_host <= self.max_connections):
            raise ValueError(f"max_per_host must be an integer from 1 to max_connections "
                             f"({self.max_connections}), got {self.max_per_host!r}")

    def allows(self, host: str) -> bool:
        if self.allow is None:
            return True
        try:
            addr = ipaddress.ip_address(host.split("%")[0])
        except ValueError:
            return False
        if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
            addr = addr.ipv4_mapped
        return any(addr in net for net in self.allow)


def parse_allow(entries: Iterable[str], field_name: str = "plc.allow") -> tuple[Network, ...]:
    """Networks from ``entries`` (``10.0.0.5``, ``10.0.0.0/24``, ``::1``). Raises ValueError
    naming ``field_name[i]`` and the entry that does not parse."""
    out = []
    for i, e in enumerate(entries):
        try:
            out.append(ipaddress.ip_network(str(e).strip(), strict=False))
        except ValueError as exc:
            raise ValueError(f"{field_name}[{i}]: {e!r} is not an address or network ({exc})") from None
    return tuple(out)


@dataclass(eq=False)
class Peer:
    """One TCP connection: an id (unique in the process, across listeners), the client's
    host and port, when it opened and last sent anything (loop clock), when its pending half
    frame began (None: no half frame). On Modbus/TCP Security also the certificate's
    ``role`` and its ``rights`` (None on plain TCP: the owner rule alone decides)."""

    id: int
    host: str
    port: int
    opened: float
    last: float
    partial_since: float | None = None
    close: Callable[[], None] = field(default=lambda: None, repr=False)
    role: str | None = None
    rights: frozenset[str] | None = None
    asked: int = 0             #: well-formed requests received on this connection
    malformed: int = 0         #: frames received that failed the spec checks (answered 01/03)

    def __str__(self) -> str:
        addr = f"{self.host}:{self.port}" if ":" not in self.host else f"[{self.host}]:{self.port}"
        return addr if self.role is None else f"{addr} ({self.role})"


_PEER_IDS = itertools.count(1)     # one sequence for every listener of the process


#: the peer whose request is being served (set per request by the connection handler)
CURRENT_PEER: contextvars.ContextVar[Peer | None] = contextvars.ContextVar("plc_peer", default=None)


class RateLimitedWarnings:
    """At most ``burst`` warnings of one kind per ``interval_s`` (monotonic wall clock);
    the rest are counted and reported in one ``*_suppressed`` line when the next window
    opens. Bounded: one small record per kind."""

    def __init__(self, burst: int = 5, interval_s: float = 10.0,
                 now: Callable[[], float] = time.monotonic):
        self.burst, self.interval_s, self._now = burst, interval_s, now
        self._windows: dict[str, list] = {}          # kind -> [window start, emitted, dropped]

    def warning(self, kind: str, **fields) -> bool:
        """Log ``kind`` with ``fields`` unless over the limit; returns whether it was logged."""
        now = self._now()
        w = self._windows.setdefault(kind, [now, 0, 0])
        if now - w[0] >= self.interval_s:
            if w[2]:
                _log().warning(f"{kind}_suppressed", dropped=w[2], interval_s=self.interval_s)
            w[:] = [now, 0, 0]
        if w[1] >= self.burst:
            w[2] += 1
            return False
        w[1] += 1
        _log().warning(kind, **fields)
        return True

    def dropped(self, kind: str) -> int:
        """Warnings of ``kind`` suppressed in the current window."""
        return self._windows.get(kind, [0, 0, 0])[2]


#: how long a host that misbehaved (malformed or half-sent frames) still counts as hostile
#: when hosts tie for shedding, after its bad connections are gone (loop seconds)
HOSTILE_MEMORY_S = 30.0
#: hosts remembered as hostile at most (the oldest is forgotten first): memory stays bounded
HOSTILE_MAX_HOSTS = 1024


def _misbehaves(p: Peer) -> bool:
    """``p`` sent malformed frames or holds a half-sent one (a fuzzer, slowloris)."""
    return p.malformed > 0 or p.partial_since is not None


def _least_needed(peers: list[Peer]) -> Peer:
    """Of ``peers``, the one to shed first: one that never sent a well-formed request (idle
    sockets, half frames, TLS handshakes: what a storm leaves), then one that sent
    malformed frames or holds a half-sent one (a fuzzer, slowloris), else the one idle
    longest; so a client that asks at once, and asks well, is not shed by the next storm
    connection, even before its first request has been read."""
    return min(peers, key=lambda p: (p.asked > 0, not _misbehaves(p), p.last))


class ConnectionGuard:
    """The allow-list, cap and time-outs of the module docstring, for one server.
    ``is_owner(peer)`` tells which connection owns the link (never shed or idled out)."""

    def __init__(self, policy: AccessPolicy, is_owner: Callable[[Peer], bool] = lambda p: False,
                 warnings: RateLimitedWarnings | None = None):
        self.policy = policy
        self.is_owner = is_owner
        self.warn = warnings or RateLimitedWarnings()
        self.peers: dict[int, Peer] = {}
        self.refused = self.shed = self.timed_out = 0
        self.connections = 0       #: connections seen since start (refused ones included)
        #: host -> when a connection of it last left misbehaving (bounded, oldest first)
        self._hostile: OrderedDict[str, float] = OrderedDict()

    @staticmethod
    def _now() -> float:
        return asyncio.get_running_loop().time()

    def connect(self, host: str, port: int, close: Callable[[], None]) -> Peer | None:
        """A new connection from ``host:port``: its Peer, or None when refused (the caller
        closes it)."""
        self.connections += 1
        if not self.policy.allows(host):
            self.refused += 1
            self.warn.warning("plc_client_not_allowed", client=f"{host}:{port}")
            return None
        victim = None
        mine = [p for p in self.peers.values() if p.host == host and not self.is_owner(p)]
        quota = self.policy.max_per_host
        if quota is not None and len(mine) >= quota:
            # this host holds its quota: it makes room among its own connections
            victim = _least_needed(mine)
            reason = "host_quota"
        elif len(self.peers) >= self.policy.max_connections:
            victim = self._victim_at_cap(host, len(mine) + 1)
            reason = "max_connections"
            if victim is None:
                self.refused += 1
                self.warn.warning("plc_connection_refused_at_cap", client=f"{host}:{port}",
                                  max_connections=self.policy.max_connections)
                return None
        if victim is not None:
            self.shed += 1
            self.warn.warning("plc_connection_shed", client=str(victim), for_client=f"{host}:{port}",
                              reason=reason, max_connections=self.policy.max_connections,
                              max_per_host=quota)
            self.drop(victim)
            victim.close()
        now = self._now()
        peer = Peer(next(_PEER_IDS), host, port, now, now, close=close)
        self.peers[peer.id] = peer
        return peer

    def _victim_at_cap(self, host: str, new_count: int) -> Peer | None:
        """At the cap: the connection to shed for a new one from ``host`` (which would then
        hold ``new_count``), or None. The owner's connection is not counted and never shed.
        A host holding more than every other sheds its own; otherwise the connection comes
        from the other host(s) holding the most, never from a host holding fewer than the
        new one's would, and never from the new one's host on a tie."""
        by_host: dict[str, list[Peer]] = {}
        for p in self.peers.values():
            if not self.is_owner(p):
                by_host.setdefault(p.host, []).append(p)
        others = {h: v for h, v in by_host.items() if h != host}
        most = max((len(v) for v in others.values()), default=0)
        if new_count > most or not others:
            return _least_needed(by_host[host]) if by_host.get(host) else None
        # several hosts may hold the most: one misbehaving now (a connection of it sent
        # malformed frames or holds a half-sent one) goes first, even before a clean
        # host's client whose first request has not been read yet
        tied = [v for v in others.values() if len(v) == most]
        hostile = [v for v in tied if any(_misbehaves(p) for p in v) or self._was_hostile(v[0].host)]
        return _least_needed([p for v in (hostile or tied) for p in v])

    def per_host(self) -> dict[str, int]:
        """Connections held now, per client host (the owner's included)."""
        out: dict[str, int] = {}
        for p in self.peers.values():
            out[p.host] = out.get(p.host, 0) + 1
        return out

    def activity(self, peer: Peer, pending_bytes: int) -> None:
        """``peer`` sent data; ``pending_bytes`` of a frame are still incomplete."""
        now = self._now()
        peer.last = now
        if pending_bytes == 0:
            peer.partial_since = None
        elif peer.partial_since is None:
            peer.partial_since = now

    def drop(self, peer: Peer) -> None:
        if self.peers.pop(peer.id, None) is not None and _misbehaves(peer):
            # a fuzzer whose bad connections were just closed must not look clean at the
            # next tie: its host is remembered for a while (bounded)
            self._hostile.pop(peer.host, None)
            self._hostile[peer.host] = self._now()
            while len(self._hostile) > HOSTILE_MAX_HOSTS:
                self._hostile.popitem(last=False)

    def _was_hostile(self, host: str) -> bool:
        t = self._hostile.get(host)
        return t is not None and self._now() - t <= HOSTILE_MEMORY_S

    def sweep(self) -> list[Peer]:
        """Close idle connections and half-sent frames past their time-outs; returns them."""
        now = self._now()
        gone = []
        for p in list(self.peers.values()):
            half = p.partial_since is not None and now - p.partial_since > self.policy.frame_timeout_s
            idle = now - p.last > self.policy.idle_timeout_s and not self.is_owner(p)
            if half or idle:
                self.timed_out += 1
                self.warn.warning("plc_connection_timed_out", client=str(p),
                                  reason="frame never completed" if half else "idle")
                self.drop(p)
                p.close()
                gone.append(p)
        return gone

    async def sweep_forever(self, period_s: float | None = None) -> None:
        """Sweep time-outs; and after connection churn give freed memory back to the
        system (:func:`drivers.plc.memory.maybe_trim`, low rate, on this loop's thread)."""
        from drivers.plc import memory
        period = period_s or max(0.05, min(self.policy.frame_timeout_s, self.policy.idle_timeout_s) / 4)
        trimmed_at = self.connections
        while True:
            await asyncio.sleep(period)
            self.sweep()
            try:
                if memory.maybe_trim(self.connections - trimmed_at):
                    _log().info("plc_memory_trimmed", connections=self.connections - trimmed_at,
                                ms=round(memory.stats()["last_s"] * 1000, 3))
                    trimmed_at = self.connections
            except Exception as exc:   # the time-outs above must keep running whatever happens here
                self.warn.warning("plc_memory_trim_failed", error=repr(exc))
