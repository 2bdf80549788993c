"""``cellctl``: the command line of the cell controller.

Each sub-command lives in its own module under ``cell.commands`` and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``. Modules are
imported when the parser is built, so they import only the standard library and
:mod:`cell.errors` at module level: numpy, pydantic, structlog, OpenCV, pymodbus, scipy …
are imported inside the functions that run a command. ``cellctl --help`` and every
``cellctl COMMAND --help`` then cost little more than Python itself
(``tests/cell/test_cli_startup.py`` holds them to that).
"""
from __future__ import annotations

import argparse
import importlib
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
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cellctl", description=__doc__.splitlines()[0].replace("``", "").rstrip(".") + ".")
    parser.add_argument("--version", action="version", version=f"cellctl {__version__}")
    parser.add_argument("--log-format", choices=("console", "json"), default="console",
                        help="structlog output on stderr (default console)")
    parser.add_argument("--log-level", default="WARNING", help="logging level (default WARNING)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from cell import log          # structlog: only once a command runs, not for --help
    log.configure(args.log_format, args.log_level)
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


if __name__ == "__main__":
    sys.exit(main())
