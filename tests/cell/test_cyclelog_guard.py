"""The cycle log guards itself: one writer, checked at open, clear errors (exit 2 from
cellctl), the cycle in flight survives a crash, rows say what the PLC was told.

Each test reproduces a field-probe finding named in its doc."""
import os
import resource
import shutil
import signal
import sqlite3
import subprocess
import sys

import pytest

from cell.cyclelog import CycleLog
from cell.errors import LogError
from cell.faults import Fault

from tests.cell.test_cyclelog import record
from tests.privileges import as_unprivileged, give_to_nobody, nobody_dir

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture
def sound(tmp_path):
    """A closed log of 300 cycles (about 40 pages)."""
    path = tmp_path / "cell.sqlite"
    log = CycleLog(path)
    for i in range(300):
        log.add_cycle(record(i))
    log.close()
    return path


def damaged_copy(sound, name, offset_from_end=None, at_middle=False, truncate_page=False):
    path = sound.with_name(name)
    shutil.copy(sound, path)
    size = path.stat().st_size
    if truncate_page:
        os.truncate(path, size - 4096)
        return path
    with open(path, "r+b") as f:
        f.seek(size // 2 if at_middle else size - offset_from_end)
        f.write(b"\xa5" * 300)
    return path


def test_a_second_controller_on_the_same_log_is_refused(tmp_path):
    """Probe: two controllers ran on one log file together, their rows interleaved."""
    first = CycleLog(tmp_path / "cell.sqlite")
    try:
        with pytest.raises(LogError, match=r"in use by another controller \(pid \d+, since .*\); stop "
                                           r"that one first"):
            CycleLog(tmp_path / "cell.sqlite")
        reader = CycleLog(tmp_path / "cell.sqlite", readonly=True)   # readers need no lock
        assert reader.count() == 0
        reader.close()
    finally:
        first.close()
    CycleLog(tmp_path / "cell.sqlite").close()          # the lock went with the first writer


def test_the_lock_goes_with_a_killed_process(tmp_path):
    path = tmp_path / "cell.sqlite"
    child = subprocess.Popen([sys.executable, "-c", "import sys, time; from cell.cyclelog import CycleLog; "
                              f"CycleLog({str(path)!r}); print('locked', flush=True); time.sleep(60)"],
                             cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "locked"
        with pytest.raises(LogError, match=f"pid {child.pid}"):
            CycleLog(path)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    CycleLog(path).close()                              # kill -9 leaves no stale lock


@pytest.mark.parametrize("how", ["middle", "last page", "last page header", "truncated"])
def test_a_damaged_log_refuses_to_open_for_writing(sound, how):
    """Probe: a log corrupted in the middle was opened without a check (every write then
    failed); one whose last page was broken took new rows silently."""
    path = {"middle": lambda: damaged_copy(sound, "m.sqlite", at_middle=True),
            "last page": lambda: damaged_copy(sound, "l.sqlite", offset_from_end=3996),
            "last page header": lambda: damaged_copy(sound, "h.sqlite", offset_from_end=4096),
            "truncated": lambda: damaged_copy(sound, "t.sqlite", truncate_page=True)}[how]()
    before = path.read_bytes()
    with pytest.raises(LogError) as err:
        CycleLog(path)
    msg = str(err.value)
    assert str(path) in msg and "damaged" in msg
    assert f"mv {path} {path}.damaged" in msg and "cellctl log check" in msg
    assert path.read_bytes() == before                  # nothing written to it


def test_a_file_that_is_not_a_database_is_named_so(tmp_path):
    path = tmp_path / "cell.sqlite"
    path.write_bytes(b"this is not SQLite" * 300)
    with pytest.raises(LogError, match="not an SQLite database"):
        CycleLog(path)
    with pytest.raises(LogError, match="not an SQLite database"):
        CycleLog(path, readonly=True)


def test_a_log_whose_folder_cannot_be_made_is_a_clear_error(tmp_path):
    (tmp_path / "var").write_text("a file where the folder should be")
    with pytest.raises(LogError, match="cannot create the cycle log's folder"):
        CycleLog(tmp_path / "var" / "cell.sqlite")


def test_a_read_only_log_is_a_clear_error(sound):
    """Checked as ``nobody`` (tests/privileges.py): root writes read-only files."""
    with nobody_dir() as folder:
        path = folder / "cell.sqlite"
        shutil.copy(sound, path)
        give_to_nobody(path)
        path.chmod(0o444)

        def check():
            with pytest.raises(PermissionError):        # the condition itself, for this user
                open(path, "r+b")
            with pytest.raises(LogError, match="cannot be written") as err:
                CycleLog(path)
            return str(err.value)
        message = as_unprivileged(check)
        assert str(path) in message
        assert path.read_bytes() == sound.read_bytes()   # nothing written to it


def _serve(cfg_path, preexec=None):
    return subprocess.run([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(cfg_path),
                           "--port", "0", "--seconds", "0"], cwd=REPO, capture_output=True, text=True,
                          timeout=120, preexec_fn=preexec)


def _config(tmp_path, db):
    from tests.system.conftest import make_config
    import yaml
    cfg = make_config(tmp_path)
    cfg = cfg.model_copy(update={"log": cfg.log.model_copy(update={"path": str(db)})})
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
    return path


def test_serve_on_a_corrupt_log_exits_2_with_a_message_not_a_traceback(tmp_path):
    """Probe: a corrupt header ended in a raw traceback with exit 1."""
    db = tmp_path / "cell.sqlite"
    db.write_bytes(b"\x00garbage" * 1000)
    out = _serve(_config(tmp_path, db))
    assert out.returncode == 2, out.stderr
    assert "not an SQLite database" in out.stderr and "Traceback" not in out.stderr


def test_serve_on_a_full_disk_exits_2_with_a_message_not_a_traceback(tmp_path):
    """Probe: a full disk at start-up ended in a raw traceback with exit 1. The child may
    write no file larger than 0 bytes (RLIMIT_FSIZE): every write fails as on a full disk."""
    db = tmp_path / "cell.sqlite"
    cfg = _config(tmp_path, db)

    def full_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))
    out = _serve(cfg, full_disk)
    assert out.returncode == 2, out.stderr
    assert str(db) in out.stderr and "Traceback" not in out.stderr
    assert "disk is full" in out.stderr or "cannot" in out.stderr


def test_log_check_names_the_damage_and_passes_a_sound_log(sound):
    def check(path):
        return subprocess.run([sys.executable, "-m", "cell.cli", "log", "check", "--db", str(path)],
                              cwd=REPO, capture_output=True, text=True, timeout=60)
    ok = check(sound)
    assert ok.returncode == 0 and "integrity_check: ok" in ok.stdout and "verdict: sound" in ok.stdout
    assert "cycles: 300" in ok.stdout and "audit chain: ok" in ok.stdout
    bad = check(damaged_copy(sound, "m.sqlite", at_middle=True))
    assert bad.returncode == 1 and "DAMAGED" in bad.stdout
    assert "page" in bad.stdout or "malformed" in bad.stdout      # names what is broken
    assert check(sound.with_name("none.sqlite")).returncode == 2


# ------------------------------------------------------------------------------ the cycle in flight
def test_a_cycle_in_flight_at_a_crash_is_recorded_as_aborted_503_at_the_next_start(tmp_path):
    """Probe: after a kill during motion the controller came up with no fault, no row."""
    log = CycleLog(tmp_path / "cell.sqlite")
    log.begin_cycle(77, "bracket-a", "h" * 64, "2026-11-23T10:00:00.000+00:00")
    log.close()                                         # the process dies here
    log = CycleLog(tmp_path / "cell.sqlite")
    got = log.recover_interrupted()
    assert (got.part_id, got.recipe) == (77, "bracket-a")
    [row] = log.cycles()
    assert (row.id, row.part_id, row.status, row.fault_code) == (got.cycle_id, 77, "aborted", Fault.INTERRUPTED)
    assert "interrupted by a controller restart" in row.fault_text
    log.close()
    log = CycleLog(tmp_path / "cell.sqlite")            # a second restart before the PLC reset
    assert log.recover_interrupted() == got and log.count() == 1      # reported again, no new row
    log.clear_interrupted()                             # the PLC reset fault 503
    assert log.recover_interrupted() is None and log.open_cycle() is None
    log.close()


def test_a_row_written_but_never_told_to_the_plc_is_corrected_at_the_next_start(tmp_path):
    """Probe: a kill between the row's commit and the done bit left a row saying done."""
    log = CycleLog(tmp_path / "cell.sqlite")
    rec = record(5)
    log.begin_cycle(5, rec.recipe, rec.recipe_hash, rec.started_at)
    cid = log.add_cycle(rec)
    assert log.open_cycle()["stage"] == "logged"
    log.close()                                         # dies before the PLC saw done
    log = CycleLog(tmp_path / "cell.sqlite")
    assert log.recover_interrupted().cycle_id == cid
    [row] = log.cycles()
    assert (row.status, row.fault_code) == ("aborted", 503)
    assert row.fault_text == "controller restarted before the PLC was told: was done"
    assert row.final_error_mm == rec.final_error_mm     # what was measured stays
    log.close()


def test_settle_closes_the_cycle_and_corrects_the_row_only_if_the_plc_was_told_otherwise(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    a, b = record(1), record(2)
    for rec, told in ((a, ("done", 0, "")), (b, ("aborted", 101, "PLC heartbeat lost"))):
        log.begin_cycle(rec.part_id, rec.recipe, rec.recipe_hash, rec.started_at)
        cid = log.add_cycle(rec)
        corrected = log.settle_cycle(rec.started_at, cid, *told)
        assert corrected == (told[0] != "done") and log.open_cycle() is None
    rows = log.cycles()
    assert [(r.status, r.fault_code, r.fault_text) for r in rows] == [
        ("done", 0, ""), ("aborted", 101, "PLC heartbeat lost")]
    assert log.recover_interrupted() is None
    log.close()


def test_nothing_moves_when_the_log_cannot_record_the_cycle_start(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    log._db.execute("PRAGMA query_only = ON")            # every write now fails inside SQLite
    with pytest.raises(sqlite3.OperationalError):
        log.begin_cycle(1, "r", "h", "t")
    log.close()
