"""Build the HMI from the cell config and serve it with uvicorn.

:func:`settings_from` takes what the controller uses from the cell config (recipe folder,
``recipes.max_bytes``, the cycle log, the robot and stations for the recipe checks) so the
HMI checks recipes as ``cellctl recipe validate [--config]`` and the controller do.
"""
from __future__ import annotations

import ipaddress
import socket
from pathlib import Path

from cell.errors import ConfigError
from cell.hmi.app import HmiSettings, create_app


def settings_from(config: str | None, users: str, reports: str, plc: tuple[str, int] | None = None,
                  recipes: str | None = None, db: str | None = None) -> HmiSettings:
    """:class:`HmiSettings` for the cell config at ``config`` (None: the built-in defaults,
    as ``cellctl recipe validate`` without ``--config``); ``recipes``/``db`` override the
    config's folder and log. Raises ConfigError naming a bad config or users file."""
    from cell.config import CellConfig
    from cell.hmi.recipes import RecipeDesk
    from cell.hmi.users import Users
    from cell.recipe_validation import checks_for
    cfg = CellConfig.load(config) if config else CellConfig().with_paths()
    check, _ = checks_for(cfg, with_stations=bool(config))
    rdir = Path(recipes or cfg.recipes.directory)
    if not rdir.is_dir():
        raise ConfigError(f"{rdir}: no recipe folder here (pass --config or --dir)")
    log_path = Path(db or cfg.log.path)
    desk = RecipeDesk(rdir, check, log_path, cfg.recipes.max_bytes)
    return HmiSettings(desk=desk, log_path=log_path, users=Users(users), reports=Path(reports), plc=plc,
                       cell_name=cfg.name)


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


def serve(settings: HmiSettings, sock: socket.socket) -> None:
    """Serve on ``sock`` until interrupted (SIGINT/SIGTERM)."""
    import uvicorn

    config = uvicorn.Config(create_app(settings), log_level="warning", access_log=False,
                            server_header=False, proxy_headers=False)
    uvicorn.Server(config).run(sockets=[sock])
