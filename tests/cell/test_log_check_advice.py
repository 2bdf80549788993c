"""``cellctl log check`` on a log it cannot read gives steps that end somewhere: it names the
damage and how to get the cell running again, never "run log check" on the moved file."""
from __future__ import annotations

import subprocess
import sys

from cell.cyclelog import CycleLog
from tests.system.conftest import REPO


def test_log_check_on_an_unreadable_log_advises_steps_that_do_not_loop(tmp_path):
    path = tmp_path / "cell.sqlite"
    log = CycleLog(path)
    log.close()
    data = bytearray(path.read_bytes())
    data[:16] = b"garbage, not SQL"                 # the header: not a database any more
    path.write_bytes(bytes(data))
    out = subprocess.run([sys.executable, "-m", "cell.cli", "log", "check", "--db", str(path)],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1, out.stdout + out.stderr
    assert f"cannot be read: {path}: cycle log: cannot open: it is not an SQLite database" in out.stdout
    assert "log check" not in out.stdout                         # no advice to run itself again
    assert f"mv {path} {path}.damaged" in out.stdout and f"sqlite3 {path}.damaged .recover" in out.stdout


def test_diagnose_on_a_log_too_short_names_the_log_not_a_csv_it_never_had(tmp_path):
    db = tmp_path / "cell.sqlite"
    run = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--cycles", "2", "--db", str(db)],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    out = subprocess.run([sys.executable, "-m", "cell.cli", "diagnose", str(db)], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert f"{db}: its done cycles give" in out.stderr and "log more cycles" in out.stderr
    assert "points.csv" not in out.stderr
