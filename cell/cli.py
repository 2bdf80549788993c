"""``cellctl``: the command line of the cell controller.

Each sub-command lives in its own module under ``cell.commands`` and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``. Modules are
imported when the parser is built, so they import only the standard library and
:mod:`cell.errors` at module level: numpy, pydantic, structlog, OpenCV, pymodbus, scipy …
are imported inside the functions that run a command. ``cellctl --help`` and every
``cellctl COMMAND --help`` then cost little more than Python itself
(``tests/cell/test_cli_startup.py`` holds them to that). A run that plainly names its
command (``cellctl diagnose DIR``) imports only that command's module
(:data:`COMMAND_OF`, :func:`command_named`).
"""
from __future__ import annotations

import argparse
import gc
import importlib
import importlib.util
import os
import sys

from cell import __version__
from cell.errors import CellError

COMMAND_MODULES = (
    "cell.commands.compensate",
    "cell.commands.plan",
    "cell.commands.recipe",
    "cell.commands.report",
    "cell.commands.registers",
    "cell.commands.run",
    "cell.commands.diagnose",
    "cell.commands.calibrate",
    "cell.commands.robotcal",
    "cell.commands.logcheck",
    "cell.commands.audit",
    "cell.commands.plc",
    "cell.commands.hmi",
    "cell.commands.historian",
    "cell.commands.fleet",
)
#: each command name → the module of :data:`COMMAND_MODULES` that registers it
#: (``tests/cell/test_cli_startup.py`` holds the two together)
COMMAND_OF = {
    "compensate": "cell.commands.compensate", "plan": "cell.commands.plan",
    "recipe": "cell.commands.recipe", "report": "cell.commands.report",
    "export": "cell.commands.report", "registers": "cell.commands.registers",
    "run": "cell.commands.run", "serve": "cell.commands.run", "diagnose": "cell.commands.diagnose",
    "calibrate-camera": "cell.commands.calibrate", "calibrate": "cell.commands.robotcal",
    "log": "cell.commands.logcheck", "audit": "cell.commands.audit", "plc": "cell.commands.plc",
    "hmi": "cell.commands.hmi", "historian": "cell.commands.historian",
    "fleet": "cell.commands.fleet",
}
_VALUED = ("--log-format", "--log-level")     # the top-level options that take a value


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``cellctl`` parser: every command's, or (``command``, a name of
    :data:`COMMAND_OF`) only the module's that registers that command, the same parser for
    it without importing the fourteen others."""
    parser = argparse.ArgumentParser(prog="cellctl", description=__doc__.splitlines()[0].replace("``", "").rstrip(".") + ".")
    parser.add_argument("--version", action="version", version=f"cellctl {__version__}")
    parser.add_argument("--log-format", choices=("console", "json"), default="console",
                        help="structlog output on stderr (default console)")
    parser.add_argument("--log-level", default="WARNING", help="logging level (default WARNING)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in (COMMAND_MODULES if command not in COMMAND_OF else (COMMAND_OF[command],)):
        importlib.import_module(name).register(sub)
    return parser


def command_named(argv: list[str]) -> str | None:
    """The command ``argv`` runs when it is plainly one of :data:`COMMAND_OF` (after
    top-level options written in full), else None (help, version, an abbreviated option,
    an unknown command: the whole parser answers)."""
    it = iter(argv)
    for tok in it:
        if tok in _VALUED:
            next(it, None)
        elif tok.startswith(tuple(f"{o}=" for o in _VALUED)):
            continue
        elif tok.startswith("-"):
            return None
        else:
            return tok if tok in COMMAND_OF else None
    return None


class _LogSetUp:
    """Configures structlog (:func:`cell.log.configure`) with the command line's options at
    the moment something first imports :mod:`cell.log`, not before: structlog costs about
    50 ms of CPU to import, and most commands (``diagnose``, ``report``, ``plan`` …) never
    log. A finder and loader by protocol (``importlib.abc`` itself costs 10 ms to import),
    installed on ``sys.meta_path`` by :func:`main`; it leaves it at the first import."""

    def __init__(self, fmt: str, level: str):
        self.fmt, self.level, self.loader = fmt, level, None

    def find_spec(self, name, path=None, target=None):
        if name != "cell.log":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)        # the ordinary finders, without this one
        self.loader, spec.loader = spec.loader, self
        return spec

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        self.loader.exec_module(module)
        module.configure(self.fmt, self.level)


def configure_logging(fmt: str, level: str) -> None:
    """structlog set up with ``fmt`` and ``level`` now if :mod:`cell.log` is loaded, else
    when it is (:class:`_LogSetUp`)."""
    if "cell.log" in sys.modules:
        sys.modules["cell.log"].configure(fmt, level)
    else:
        sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _LogSetUp)]
        sys.meta_path.insert(0, _LogSetUp(fmt, level))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(command_named(sys.argv[1:] if argv is None else argv))
    args = parser.parse_args(argv)
    configure_logging(args.log_format, args.log_level)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()
        return code
    except CellError as exc:
        print(f"cellctl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (``cellctl diagnose … | head``): stop quietly, as a Unix tool
        # killed by SIGPIPE would; the interpreter's last flush must not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


def entry() -> int:
    """``cellctl``'s process entry: :func:`main`, then ``gc.freeze()``. What the command made
    is then left to reference counting when the interpreter exits: its last collections
    would otherwise pass over every object the command made (about 0.16 s of CPU after
    ``cellctl run --sim``) to free what exiting frees anyway. Callers in a process that goes
    on (tests) call :func:`main`."""
    code = main()
    gc.freeze()
    return code


if __name__ == "__main__":
    sys.exit(entry())
