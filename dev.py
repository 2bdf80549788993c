#!/usr/bin/env python3
"""Set-up and entry points for a fresh machine that has only Python 3.11 and pip.

    python3 dev.py run     build .venv if needed, then run the simulated cell (the main job)
    python3 dev.py test    build .venv if needed, then run the test suite
    python3 dev.py bench   build .venv if needed, then run every benchmark in bench/

The virtual environment is rebuilt when pyproject.toml changes (its hash is kept in
.venv/.cell-installed), so a clean clone and a stale checkout behave the same.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
STAMP = VENV / ".cell-installed"

MAIN_JOB = ["cellctl", "run", "--sim", "--cycles", "10"]


def _ensure_venv() -> None:
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if STAMP.exists() and STAMP.read_text().strip() == want and PY.exists():
        return
    if not PY.exists():
        subprocess.check_call([sys.executable, "-m", "venv", str(VENV)])
    subprocess.check_call([str(PY), "-m", "pip", "install", "-q", "-e", f"{ROOT}[test]"])
    STAMP.write_text(want)


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in {"run", "test", "bench"}:
        print(__doc__)
        return 2
    _ensure_venv()
    cmd, rest = argv[0], argv[1:]
    if cmd == "run":
        return subprocess.call([str(BIN / MAIN_JOB[0]), *MAIN_JOB[1:], *rest], cwd=ROOT)
    if cmd == "test":
        code = subprocess.call([str(PY), "-m", "pytest", *rest], cwd=ROOT)
        if code == 5:  # pytest: no tests collected -- never a pass
            print("dev.py: pytest collected no tests; failing", file=sys.stderr)
            return 1
        return code
    code = 0
    for script in sorted((ROOT / "bench").glob("bench_*.py")):
        print(f"\n## {script.name}\n", flush=True)
        code |= subprocess.call([str(PY), str(script), *rest], cwd=ROOT)
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
