"""structlog set-up, done once per process; every module gets its logger with ``get_logger``.

``configure(fmt="json")`` writes JSON lines (one event per line, ISO timestamps, level) to
stderr, which is what the systemd journal and log shippers want; ``fmt="console"`` is for
people at a terminal. Calling ``configure`` again replaces the set-up (tests use that).
"""
from __future__ import annotations

import logging
import sys
import threading
from typing import Literal

import structlog

_configured = False


_write_lock = threading.Lock()


class _StderrLogger:
    """Writes each rendered event to the *current* ``sys.stderr`` (which test runners and
    daemons may swap) as one line: the event and its newline in one write, under one lock,
    so lines from two threads never run together. Never raises if the stream is closed."""

    def msg(self, message: str) -> None:
        with _write_lock:
            try:
                sys.stderr.write(message + "\n")
                sys.stderr.flush()
            except (ValueError, OSError):
                pass

    log = debug = info = warning = warn = error = critical = exception = fatal = msg


def configure(fmt: Literal["json", "console"] = "console", level: str = "INFO") -> None:
    """Configure structlog for the whole process. ``level`` is a logging level name."""
    global _configured
    renderer = (structlog.processors.JSONRenderer() if fmt == "json"
                else structlog.dev.ConsoleRenderer(colors=False))
    structlog.configure(
        processors=[
            structlog.contextvars.merge_contextvars,
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            structlog.processors.StackInfoRenderer(),
            structlog.processors.format_exc_info,
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(logging.getLevelName(level.upper())),
        logger_factory=lambda *args: _StderrLogger(),
        cache_logger_on_first_use=False,
    )
    _configured = True


def get_logger(name: str) -> structlog.typing.FilteringBoundLogger:
    """Return a logger bound to ``component=name``; configures console output on first use.

    The logger is a lazy proxy: it binds on first use, so a module-level logger obeys a
    later :func:`configure` (e.g. ``cellctl --log-level``)."""
    if not _configured:
        configure()
    return structlog.get_logger(component=name)
