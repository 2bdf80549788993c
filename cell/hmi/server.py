"""Build the HMI from the cell config and serve it with uvicorn.

:func:`settings_from` takes what the controller uses from the cell config (recipe folder,
``recipes.max_bytes``, the cycle log, the robot and stations for the recipe checks) so the
HMI checks recipes as ``cellctl recipe validate [--config]`` and the controller do.
"""
from __future__ import annotations

from pathlib import Path

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
    cfg = CellConfig.load(config) if config else CellConfig()
    check, _ = checks_for(cfg, with_stations=bool(config))
    rdir = Path(recipes or cfg.recipes.directory)
    log_path = Path(db or cfg.log.path)
    desk = RecipeDesk(rdir, check, log_path, cfg.recipes.max_bytes)
    return HmiSettings(desk=desk, log_path=log_path, users=Users(users), reports=Path(reports), plc=plc,
                       cell_name=cfg.name)


def serve(settings: HmiSettings, host: str, port: int, ready=None) -> None:
    """Serve until interrupted (SIGINT/SIGTERM). ``ready(port)`` is called once listening."""
    import uvicorn

    config = uvicorn.Config(create_app(settings), host=host, port=port, log_level="warning",
                            access_log=False, server_header=False, proxy_headers=False)
    server = uvicorn.Server(config)
    if ready is not None:
        started = server.startup

        async def startup(sockets=None):
            await started(sockets)
            if server.started:
                ready(server.servers[0].sockets[0].getsockname()[1])
        server.startup = startup
    server.run()
