"""The HMI's connections, bounded: a request-read time-out, a connection cap, quiet errors.

uvicorn's h11 protocol closes idle keep-alive connections, but a connection that never
completes its request (slowloris: headers sent a byte at a time, or a body that never ends)
is kept forever, and nothing caps how many are open, so enough of them exhaust the
process's file descriptors. :func:`protocol_class` makes an ``H11Protocol`` subclass that:

* **times the request read**: from a connection's start, or the first byte of its next
  request, the whole request (headers and body) must arrive within ``request_timeout_s``,
  else the connection is closed;
* **caps open connections** at ``max_connections``: a new connection beyond it sheds the
  oldest connection that has no request in progress (waiting for, or still sending, its
  request headers: what a slow attacker holds); if every connection has a request in
  progress, the new one is answered 503 and closed.

:class:`RateLimitedLog` writes one line per kind of trouble and interval, with a count of
what it did not write, never a traceback per event; :func:`accept_error_handler` routes the
event loop's "accept failed: out of file descriptors" errors (EMFILE, ENFILE, ENOBUFS,
ENOMEM) to it and leaves everything else to asyncio's default handler.
"""
from __future__ import annotations

import asyncio
import errno
import logging
import threading
import time
from collections import OrderedDict
from typing import Any, Callable

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

#: errors that mean the process ran out of descriptors or memory for a socket
RESOURCE_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
_REFUSED = (b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: text/plain; charset=utf-8\r\n"
            b"content-length: 41\r\nconnection: close\r\n\r\ntoo many connections: try again shortly.\n")


class RateLimitedLog:
    """``note(kind, text)``: log ``text`` (warning) unless a line of the same ``kind`` was
    written less than ``interval_s`` ago; a line written after a quiet spell says how many
    were left out. Thread-safe; times from ``clock`` (seconds)."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0, clock: Callable[[], float] = time.monotonic):
        self.logger, self.interval_s, self.clock = logger, float(interval_s), clock
        self._last: dict[str, float] = {}
        self._left_out: dict[str, int] = {}
        self._lock = threading.Lock()

    def note(self, kind: str, text: str) -> bool:
        """Whether a line was written."""
        now = self.clock()
        with self._lock:
            last = self._last.get(kind)
            if last is not None and now - last < self.interval_s:
                self._left_out[kind] = self._left_out.get(kind, 0) + 1
                return False
            n = self._left_out.pop(kind, 0)
            self._last[kind] = now
        more = f" ({n} more like it since the last line)" if n else ""
        self.logger.warning("%s%s", text, more)
        return True


def resource_error(exc: BaseException | None) -> bool:
    """Whether ``exc`` is the process running out of descriptors or socket memory."""
    return isinstance(exc, OSError) and exc.errno in RESOURCE_ERRNOS


def accept_error_handler(log: RateLimitedLog) -> Callable[[asyncio.AbstractEventLoop, dict], None]:
    """An event-loop exception handler: resource errors (accept out of descriptors, as
    asyncio reports them and retries a second later) become one rate-limited line each;
    everything else goes to the loop's default handler."""

    def handle(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        exc = context.get("exception")
        if resource_error(exc):
            log.note(f"accept-{exc.errno}", f"cellctl hmi: cannot accept connections: {exc.strerror} "
                                            f"({errno.errorcode.get(exc.errno, exc.errno)}); retrying")
            return
        loop.default_exception_handler(context)

    return handle


class GuardedH11Protocol(H11Protocol):
    """``H11Protocol`` with the request-read time-out and the connection cap (module doc).
    Use :func:`protocol_class`, which sets the class attributes below."""

    request_timeout_s: float = 10.0
    max_connections: int = 256
    open_connections: OrderedDict            #: of one server: protocol -> None, oldest first

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        self._request_timer: asyncio.TimerHandle | None = None
        self._refused = False
        open_ = self.open_connections
        if len(open_) >= self.max_connections:
            victim = next((p for p in open_ if p._idle()), None)
            if victim is None:
                self._refused = True
                transport.write(_REFUSED)
                transport.close()
                return
            victim._shed()
        open_[self] = None
        super().connection_made(transport)
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._refused:
            return
        self._disarm()
        self.open_connections.pop(self, None)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        if self._request_timer is None and self.conn.their_state is h11.IDLE:
            self._arm()                          # the first byte of the next request
        super().data_received(data)
        if self.conn.their_state not in (h11.IDLE, h11.SEND_BODY):
            self._disarm()                       # the whole request is in

    def _idle(self) -> bool:
        """No request in progress: waiting for one, or for the rest of its headers."""
        return (self.cycle is None or self.cycle.response_complete) and self.conn.their_state is h11.IDLE

    def _shed(self) -> None:
        self.open_connections.pop(self, None)
        self._disarm()
        self.transport.close()

    def _arm(self) -> None:
        if self._request_timer is None:
            self._request_timer = self.loop.call_later(self.request_timeout_s, self._request_timed_out)

    def _disarm(self) -> None:
        if self._request_timer is not None:
            self._request_timer.cancel()
            self._request_timer = None

    def _request_timed_out(self) -> None:
        self._request_timer = None
        if self.conn.their_state in (h11.IDLE, h11.SEND_BODY) and not self.transport.is_closing():
            self.transport.close()


def protocol_class(request_timeout_s: float, max_connections: int) -> type[GuardedH11Protocol]:
    """A :class:`GuardedH11Protocol` subclass for one server: its own registry of open
    connections, at most ``max_connections``, each request read within ``request_timeout_s``."""
    return type("HmiH11Protocol", (GuardedH11Protocol,),
                {"request_timeout_s": float(request_timeout_s), "max_connections": int(max_connections),
                 "open_connections": OrderedDict()})
