"""``cellctl`` sets structlog up with ``--log-format`` / ``--log-level`` when something
imports :mod:`cell.log`, not at start: a command that never logs (``diagnose``) does not
load structlog, and one that does logs as the options say."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TIAGO = REPO / "tests" / "data" / "real" / "tiago-mocap-train"


def probe(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                          timeout=120)


def test_diagnose_loads_neither_structlog_nor_scipy_stats():
    out = probe("import contextlib, io, json, sys\n"
                "from cell import cli\n"
                "with contextlib.redirect_stdout(io.StringIO()):\n"
                f"    code = cli.main(['diagnose', {str(TIAGO)!r}, '--json'])\n"
                "print(json.dumps([code, sorted(m for m in sys.modules if m.split('.')[0] in "
                "('structlog', 'scipy'))]))")
    assert out.returncode == 0, out.stderr[-2000:]
    code, loaded = json.loads(out.stdout)
    assert code == 0 and loaded == []


def test_a_logger_imported_later_follows_the_command_line():
    out = probe("from cell import cli\n"
                "cli.configure_logging('json', 'DEBUG')\n"
                "from cell.log import get_logger\n"
                "get_logger('probe').debug('hello', n=1)\n"
                "cli.configure_logging('console', 'WARNING')\n"
                "get_logger('probe').info('not shown')\n")
    assert out.returncode == 0, out.stderr[-2000:]
    [line] = out.stderr.splitlines()
    event = json.loads(line)
    assert (event["event"], event["level"], event["component"], event["n"]) == ("hello", "debug", "probe", 1)
