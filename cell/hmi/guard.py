"""ASGI middleware in front of every HMI request: trusted hosts and proxies, body limits,
response headers, resource errors. Each refuses before the application reads anything.

* :class:`TrustedHost` — the ``Host`` header must name this server: the listen address,
  ``localhost``, ``127.0.0.1``, ``[::1]`` or a name given with ``--allowed-host``; any other
  is answered 400 (a page of another site whose name was re-pointed at this machine, DNS
  rebinding, gets nothing). Only from a trusted proxy address (``--trusted-proxy``, loopback
  by default) are ``X-Forwarded-Proto`` and ``X-Forwarded-Host`` honoured: the request's
  scheme and host become the forwarded ones (so the Origin check of a POST made through a
  TLS proxy compares against ``https://`` and the public name), and the forwarded host must
  be allowed too. The client address is never taken from a header.
* :class:`BodyLimit` — a body larger than ``max_bytes`` is refused before it is read: a
  too-large ``Content-Length`` at once, a chunked body as soon as its bytes pass the limit
  (413). ``multipart/form-data`` is expected nowhere and refused at once (415); so is a
  body on a GET or HEAD (400). Any answer given before the whole body was read closes the
  connection, so the rest is never read.
* :class:`ResponseHeaders` — ``Referrer-Policy: same-origin`` (no URL of the HMI leaves
  for another site; ``no-referrer`` would make browsers send ``Origin: null`` on our own
  form posts, which the Origin check then refuses), ``X-Content-Type-Options: nosniff`` and
  ``X-Frame-Options: DENY`` on every answer; ``Cache-Control: no-store`` on every answer
  but the static files (pages and JSON show cell data and the CSRF token).
* :class:`ResourceErrors` — a request that fails because the process is out of file
  descriptors is answered 503, logged as one rate-limited line, never a traceback each.
"""
from __future__ import annotations

import ipaddress
from typing import Iterable

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from cell.hmi.netguard import RateLimitedLog, resource_error

LOCAL_NAMES = ("localhost", "127.0.0.1", "::1")


async def refuse(send: Send, status: int, text: str, headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    """Answer ``status`` with ``text`` and close the connection."""
    body = (text.rstrip("\n") + "\n").encode("utf-8")
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"),
                            (b"content-length", str(len(body)).encode()), (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


def _header(scope: Scope, name: bytes) -> str | None:
    for k, v in scope["headers"]:
        if k == name:
            return v.decode("latin-1")
    return None


def host_name(host: str) -> str:
    """The name part of a ``Host`` value, lower case: ``[::1]:8080`` → ``::1``."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _address_in(addr: str, nets: tuple) -> bool:
    try:
        ip = ipaddress.ip_address(addr)
    except ValueError:
        return False
    return any(ip in n for n in nets)


class TrustedHost:
    """See the module doc. ``allowed``: host names (any case; IPv6 without brackets);
    ``trusted_proxies``: addresses or networks whose forwarded headers are honoured."""

    def __init__(self, app: ASGIApp, allowed: Iterable[str], trusted_proxies: Iterable[str] = ("127.0.0.1", "::1")):
        self.app = app
        self.allowed = frozenset(host_name(h) for h in (*LOCAL_NAMES, *allowed) if h)
        self.proxies = tuple(ipaddress.ip_network(p, strict=False) for p in trusted_proxies)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        host = _header(scope, b"host")
        if host is None or host_name(host) not in self.allowed:
            return await refuse(send, 400, f"unknown host name {host!r}: open the HMI by a name it serves "
                                           "(cellctl hmi --allowed-host NAME adds one)")
        client = scope.get("client")
        if client and _address_in(client[0], self.proxies):
            proto = (_header(scope, b"x-forwarded-proto") or "").split(",")[0].strip().lower()
            fwd_host = (_header(scope, b"x-forwarded-host") or "").split(",")[0].strip()
            if fwd_host:
                if host_name(fwd_host) not in self.allowed:
                    return await refuse(send, 400, f"unknown forwarded host name {fwd_host!r}: "
                                                   "cellctl hmi --allowed-host NAME adds one")
                scope = dict(scope, headers=[(k, v) for k, v in scope["headers"] if k != b"host"]
                             + [(b"host", fwd_host.encode("latin-1"))])
            if proto in ("http", "https"):
                scope = dict(scope, scheme=proto)
        await self.app(scope, receive, send)


class BodyTooLarge(Exception):
    """A chunked body went past the limit while it was read."""


class BodyLimit:
    """See the module doc. ``max_bytes``: the largest body any route takes."""

    NO_BODY = frozenset({"GET", "HEAD"})

    def __init__(self, app: ASGIApp, max_bytes: int):
        self.app, self.max_bytes = app, int(max_bytes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = _header(scope, b"content-length")
        chunked = "chunked" in (_header(scope, b"transfer-encoding") or "").lower()
        has_body = chunked or (length is not None and length.strip() != "0")
        if (_header(scope, b"content-type") or "").lower().lstrip().startswith("multipart/"):
            return await refuse(send, 415, "multipart bodies are not taken here")
        if has_body and scope["method"] in self.NO_BODY:
            return await refuse(send, 400, f"a {scope['method']} request takes no body")
        if length is not None and (not length.strip().isdigit() or int(length) > self.max_bytes):
            return await refuse(send, 413, f"request too large (at most {self.max_bytes} bytes)")
        got, read_all, started = 0, not has_body, False

        async def counted() -> Message:
            nonlocal got, read_all
            message = await receive()
            if message["type"] == "http.request":
                got += len(message.get("body", b""))
                if got > self.max_bytes:
                    raise BodyTooLarge()
                read_all = read_all or not message.get("more_body", False)
            return message

        async def sending(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                if not read_all:                 # answered early: never read the rest
                    message = dict(message, headers=[*message.get("headers", []), (b"connection", b"close")])
            await send(message)

        try:
            await self.app(scope, counted, sending)
        except BodyTooLarge:
            if not started:
                await refuse(send, 413, f"request too large (at most {self.max_bytes} bytes)")


class ResponseHeaders:
    """See the module doc."""

    ALWAYS = ((b"referrer-policy", b"same-origin"), (b"x-content-type-options", b"nosniff"),
              (b"x-frame-options", b"DENY"))

    def __init__(self, app: ASGIApp, static_prefix: str = "/static/"):
        self.app, self.static_prefix = app, static_prefix

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        static = scope["path"].startswith(self.static_prefix)

        async def sending(message: Message) -> None:
            if message["type"] == "http.response.start":
                names = {k.lower() for k, _ in message.get("headers", [])}
                extra = [h for h in self.ALWAYS if h[0] not in names]
                if not static:
                    extra = [h for h in extra if h[0] != b"cache-control"] + [(b"cache-control", b"no-store")]
                    message = dict(message, headers=[h for h in message.get("headers", [])
                                                     if h[0].lower() != b"cache-control"])
                message = dict(message, headers=[*message.get("headers", []), *extra])
            await send(message)

        await self.app(scope, receive, sending)


class ResourceErrors:
    """See the module doc."""

    def __init__(self, app: ASGIApp, log: RateLimitedLog):
        self.app, self.log = app, log

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        started = False

        async def sending(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, sending)
        except OSError as exc:
            if not resource_error(exc) or scope["type"] != "http":
                raise
            self.log.note(f"request-{exc.errno}", f"cellctl hmi: a request failed: {exc.strerror}; answered 503")
            if not started:
                await refuse(send, 503, "the HMI is out of resources: try again shortly")
