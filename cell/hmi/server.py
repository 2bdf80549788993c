"""Build the HMI from the cell config and serve it with uvicorn, bounded.

:func:`settings_from` takes what the controller uses from the cell config (recipe folder,
``recipes.max_bytes``, the cycle log, the robot and stations for the recipe checks) so the
HMI checks recipes as ``cellctl recipe validate [--config]`` and the controller do.

:func:`make_server` is uvicorn with :class:`ServeLimits`: the h11 protocol of
:mod:`cell.hmi.netguard` (request-read time-out, connection cap), keep-alive time-out,
``limit_concurrency`` as a backstop above the cap, a graceful shutdown that gives requests
in flight ``graceful_s`` and then cancels them (their blocking work is abandoned on daemon
threads, :mod:`cell.hmi.work`), so SIGTERM stops the server in bounded time; accept errors
(out of file descriptors) are logged at a bounded rate.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import resource
import socket
from dataclasses import dataclass
from pathlib import Path

from cell.errors import ConfigError
from cell.hmi.app import HmiSettings, create_app
from cell.hmi.netguard import RateLimitedLog, accept_error_handler, protocol_class

FD_RESERVE = 64                        #: descriptors kept for files, the log, threads


def default_max_connections() -> int:
    """256, or fewer when the process's descriptor limit leaves less than that beside
    :data:`FD_RESERVE` (at least 8)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return 256
    return max(8, min(256, soft - FD_RESERVE))


@dataclass(frozen=True)
class ServeLimits:
    """How much the network may ask of the HMI (seconds, counts).

    ``request_timeout_s``: a request's headers and body must arrive within it;
    ``keep_alive_s``: an idle connection is closed after it; ``max_connections``: open
    connections (None: :func:`default_max_connections`); ``graceful_s``: what requests in
    flight get when the server is told to stop; ``log_interval_s``: one line per kind of
    trouble (accept errors) and interval.
    """

    request_timeout_s: float = 10.0
    keep_alive_s: int = 5
    max_connections: int | None = None
    graceful_s: int = 5
    log_interval_s: float = 10.0


def settings_from(config: str | None, users: str, reports: str, plc: tuple[str, int] | None = None,
                  recipes: str | None = None, db: str | None = None, *, listen_host: str = "127.0.0.1",
                  allowed_hosts: tuple[str, ...] = (),
                  trusted_proxies: tuple[str, ...] = ("127.0.0.1", "::1"), line_dsn: str | None = None,
                  line_links: tuple[tuple[str, str], ...] = ()) -> HmiSettings:
    """:class:`HmiSettings` for the cell config at ``config`` (None: the built-in defaults,
    as ``cellctl recipe validate`` without ``--config``); ``recipes``/``db`` override the
    config's folder and log; the hosts and proxies, and the line view's DSN and links, as
    :class:`HmiSettings` takes them.
    Raises ConfigError naming a bad config or users file, or a proxy that is no address."""
    from cell.config import CellConfig
    from cell.hmi.recipes import RecipeDesk
    from cell.hmi.users import Users
    from cell.recipes.validation import checks_for
    cfg = CellConfig.load(config) if config else CellConfig().with_paths()
    check, _ = checks_for(cfg, with_stations=bool(config))
    rdir = Path(recipes or cfg.recipes.directory)
    if not rdir.is_dir():
        raise ConfigError(f"{rdir}: no recipe folder here (pass --config or --dir)")
    log_path = Path(db or cfg.log.path)
    desk = RecipeDesk(rdir, check, log_path, cfg.recipes.max_bytes)
    for p in trusted_proxies:
        try:
            ipaddress.ip_network(p, strict=False)
        except ValueError:
            raise ConfigError(f"--trusted-proxy {p!r}: expected an address or network, e.g. 127.0.0.1") from None
    return HmiSettings(desk=desk, log_path=log_path, users=Users(users), reports=Path(reports), plc=plc,
                       cell_name=cfg.name, listen_host=listen_host, allowed_hosts=tuple(allowed_hosts),
                       trusted_proxies=tuple(trusted_proxies), line_dsn=line_dsn or None,
                       line_links=tuple(line_links))


def listen(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host``:``port`` (0: a free port).

    :raises ConfigError: the address is taken or not this machine's.
    """
    try:
        family = socket.AF_INET6 if ipaddress.ip_address(host).version == 6 else socket.AF_INET
    except ValueError:
        family = socket.AF_INET                        # a host name: resolved by bind
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(64)
    except OSError as exc:
        sock.close()
        raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


def make_server(settings: HmiSettings, limits: ServeLimits = ServeLimits()):
    """A ``uvicorn.Server`` for ``settings`` with ``limits`` (module doc); run it with
    ``server.run(sockets=[sock])``, stop it with ``server.should_exit = True`` or SIGTERM."""
    import uvicorn
    cap = limits.max_connections or default_max_connections()
    log = RateLimitedLog(logging.getLogger("cell.hmi"), limits.log_interval_s)

    class HmiServer(uvicorn.Server):
        async def startup(self, sockets=None) -> None:
            asyncio.get_running_loop().set_exception_handler(accept_error_handler(log))
            await super().startup(sockets=sockets)

    config = uvicorn.Config(create_app(settings), http=protocol_class(limits.request_timeout_s, cap),
                            log_level="warning", access_log=False, server_header=False, proxy_headers=False,
                            timeout_keep_alive=limits.keep_alive_s, limit_concurrency=cap + 1,
                            timeout_graceful_shutdown=limits.graceful_s, lifespan="off")
    return HmiServer(config)


def serve(settings: HmiSettings, sock: socket.socket, limits: ServeLimits = ServeLimits()) -> None:
    """Serve on ``sock`` until interrupted (SIGINT/SIGTERM; see :func:`make_server`)."""
    make_server(settings, limits).run(sockets=[sock])
