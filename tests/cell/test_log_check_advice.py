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


def test_diagnose_on_a_log_proposes_poses_anywhere_the_arm_can_go(tmp_path):
    # the cell's parts sit at one place: the poses that would separate the rivals must come
    # from the robot's joint limits (its preset), not from the few degrees the parts span,
    # and the command warns about nothing on stderr (no inf − inf of a fold left out)
    import json
    from cell.robots import PRESETS
    db = tmp_path / "cell.sqlite"
    run = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--cycles", "20", "--seed", "7",
                          "--db", str(db)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    out = subprocess.run([sys.executable, "-m", "cell.cli", "diagnose", str(db), "--json"], cwd=REPO,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stderr == "", out.stderr[-2000:]
    cause = json.loads(out.stdout)["cause"]
    poses = [p["readings"] for p in cause["separating_poses"]]
    assert cause["confidence"] == "ambiguous" and len(poses) >= 3, cause["label"]
    log = CycleLog(db, readonly=True)
    logged = [q for c in log.cycles(status="done") for s in c.trace if s.get("moved")
              for q in [s["joints_deg"]]]
    log.close()
    span = [max(abs(p[f"j{k + 1}"] - q[k]) for p in poses for q in logged) for k in (0, 1)]
    assert min(span) > 30.0, span                        # well beyond the parts' place
    limits = PRESETS["seed000"].limits
    for p in poses:
        assert all(limits[k][0] <= p[f"j{k + 1}"] <= limits[k][1] for k in (0, 1)), p
