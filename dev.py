#!/usr/bin/env python3
"""Set-up and entry points for a fresh machine that has only Python 3.11 and pip.

    python3 dev.py run            build .venv if needed, then run the simulated cell (the main job)
    python3 dev.py test [ARGS]    build .venv and the test tools if needed, then run the test suite
    python3 dev.py bench [ARGS]   build .venv if needed, then run every benchmark in bench/
    python3 dev.py fleet [ARGS]   build .venv, mosquitto and PostgreSQL if needed, then run a fleet of
                                  three simulated cells, the plant historian and the line view
    python3 dev.py cellctl ARGS   build .venv if needed, then run any cellctl command

Any working directory will do. The virtual environment is rebuilt when pyproject.toml
changes (its hash is kept in .venv/.cell-installed), so a clean clone and a stale checkout
behave the same; a build says each step on stderr (pip's own progress too, on a terminal)
and how long it took. ``test`` also installs the system tools some tests drive, from Debian's
packages, when they are missing and this user may (root with apt-get): Chromium and
ChromeDriver (the browser tests of the HMI and the reports), mbpoll (an independent
Modbus client), mosquitto and PostgreSQL (the plant path's broker and historian database,
tests/cell/plant). Without them those tests skip, except under CI=true, where they fail.
``fleet`` installs mosquitto and PostgreSQL the same way (it needs both) and runs
``cell/plant/demo.py`` until Ctrl-C; ``run`` never needs a broker.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
STAMP = VENV / ".cell-installed"

MAIN_JOB = ["cellctl", "run", "--sim", "--cycles", "10"]
# test tools from Debian's packages: command -> package
TEST_TOOLS = {"chromium": "chromium", "chromedriver": "chromium-driver", "mbpoll": "mbpoll",
              "mosquitto": "mosquitto", "initdb": "postgresql"}
# what the fleet demo needs (cell/plant/demo.py): the broker and the historian's database
FLEET_TOOLS = {"mosquitto": "mosquitto", "initdb": "postgresql"}
FLEET_JOB = ["-m", "cell.plant.demo"]
# where Debian puts tools that are not on an ordinary user's PATH (PostgreSQL's are versioned)
TOOL_FOLDERS = ("/usr/sbin", "/usr/lib/postgresql/*/bin")


def _say(text: str) -> None:
    """One line of what dev.py is doing, on stderr (stdout is the command's)."""
    print(f"dev.py: {text}", file=sys.stderr, flush=True)


def _ensure_venv() -> None:
    """Build .venv from pyproject.toml unless its stamp says it is up to date. A build
    takes minutes on a fresh clone, so each step says what it does on stderr, and the end
    how long it took; pip shows its own progress when stderr is a terminal. A failed step
    exits with its code and leaves the stamp as it was, so the next run tries again."""
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if STAMP.exists() and STAMP.read_text().strip() == want and PY.exists():
        return
    t0 = time.monotonic()
    why = ("first run" if not PY.exists() else "pyproject.toml changed" if STAMP.exists()
           else "an earlier build did not finish")
    _say(f"building {VENV} ({why}); this can take a few minutes")
    if not PY.exists():
        _say(f"creating the virtual environment (python -m venv {VENV})")
        _step([sys.executable, "-m", "venv", str(VENV)], "creating the virtual environment")
    _say(f"installing the pinned packages of pyproject.toml (pip install -e '.[test]'); "
         f"{time.monotonic() - t0:.0f} s so far")
    quiet = [] if sys.stderr.isatty() else ["-q"]
    _step([str(PY), "-m", "pip", "install", *quiet, "-e", f"{ROOT}[test]"], "pip install")
    STAMP.write_text(want)
    _say(f"{VENV} ready in {time.monotonic() - t0:.0f} s")


def _step(argv: list[str], what: str) -> None:
    """Run one build step with its output on stderr; a failure ends dev.py with its code."""
    code = _call(argv, stdout=sys.stderr)
    if code != 0:
        _say(f"{what} failed (exit {code}); {VENV} is not ready, the next run tries again")
        sys.exit(code if 0 < code < 256 else 1)


def _ensure_tools(tools: dict[str, str] = TEST_TOOLS, what: str = "test tools",
                       without: str = "the tests that drive them skip") -> bool:
    """Install the missing ``tools`` (command -> Debian package) with apt-get when this user
    may; say what happens without them if not. True when none is missing at the end."""
    missing = sorted({pkg for cmd, pkg in tools.items() if not _have_tool(cmd)})
    if not missing:
        return True
    apt = shutil.which("apt-get")
    if apt is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        print(f"dev.py: {', '.join(missing)} not installed (apt-get install {' '.join(missing)}); "
              f"{without}", file=sys.stderr, flush=True)
        return False
    print(f"dev.py: installing {what} from Debian's packages: {', '.join(missing)}", flush=True)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    quiet = {"stdout": subprocess.DEVNULL, "env": env}
    if subprocess.call([apt, "install", "-y", "-q", "--no-install-recommends", *missing], **quiet) != 0:
        subprocess.call([apt, "update", "-q"], **quiet)
        if subprocess.call([apt, "install", "-y", "-q", "--no-install-recommends", *missing], **quiet) != 0:
            print(f"dev.py: could not install {', '.join(missing)}; {without}", file=sys.stderr, flush=True)
            return False
    return True


def _have_tool(cmd: str) -> bool:
    """True if ``cmd`` is on PATH or in one of :data:`TOOL_FOLDERS`."""
    import glob
    return shutil.which(cmd) is not None or any(
        os.access(os.path.join(folder, cmd), os.X_OK) for pattern in TOOL_FOLDERS for folder in glob.glob(pattern))


def _call(argv: list[str], **kwargs) -> int:
    """``subprocess.call`` that passes a SIGTERM for dev.py on to the command: without it
    ``dev.py bench`` or ``test`` stopped by ``kill`` left its benchmark or pytest running."""
    child = subprocess.Popen(argv, **kwargs)
    previous = signal.signal(signal.SIGTERM, lambda signum, _frame: child.send_signal(signum))
    try:
        return child.wait()
    finally:
        signal.signal(signal.SIGTERM, previous)


def _become(argv: list[str]) -> int:
    """Run ``argv`` in this process's place (POSIX), so a stop signal meant for the command
    (``kill``, ``timeout``, a service manager, Ctrl-C) reaches it, not only dev.py: with a
    child process, SIGTERM ended dev.py and left ``serve`` or ``hmi`` running, orphaned."""
    if os.name != "posix":
        return subprocess.call(argv)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(argv[0], argv)


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in {"run", "test", "bench", "cellctl", "fleet"}:
        print(__doc__)
        return 2
    _ensure_venv()
    cmd, rest = argv[0], argv[1:]
    if cmd in {"run", "cellctl"}:
        # the caller's working directory: cellctl resolves its own defaults against the project
        argv = [str(BIN / MAIN_JOB[0]), *MAIN_JOB[1:], *rest] if cmd == "run" else [str(BIN / "cellctl"), *rest]
        return _become(argv)
    if cmd == "fleet":
        if not _ensure_tools(FLEET_TOOLS, "the fleet's broker and database", "the fleet cannot start"):
            return 1
        return _become([str(PY), *FLEET_JOB, *rest])
    if cmd == "test":
        _ensure_tools(without="the tests that drive them skip (fail under CI=true)")
        code = _call([str(PY), "-m", "pytest", *rest], cwd=ROOT)
        if code == 5:  # pytest: no tests collected -- never a pass
            print("dev.py: pytest collected no tests; failing", file=sys.stderr)
            return 1
        return code
    code = 0
    for script in sorted((ROOT / "bench").glob("bench_*.py")):
        print(f"\n## {script.name}\n", flush=True)
        rc = _call([str(PY), str(script), *rest], cwd=ROOT)
        if rc == -signal.SIGTERM:            # stopped: not the next benchmark either
            return 128 + signal.SIGTERM
        code |= rc
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
