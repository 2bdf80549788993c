"""A refused command changes nothing: ``run --sim`` beside a running ``serve --sim`` on the
same log is refused before it moves the log, and a fresh run keeps every previous log under
a name of its own. Both run the real ``cellctl`` in child processes."""
from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from cell.cyclelog import CycleLog
from tests.system.conftest import REPO, make_config


def _config(tmp_path):
    cfg = make_config(tmp_path, heartbeat_timeout_s=5.0)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
    return cfg, path


def _files(folder):
    """name -> inode of every file in ``folder`` (what a refused command must leave alone)."""
    return {p.name: p.stat().st_ino for p in folder.iterdir() if p.is_file()}


def test_run_beside_a_serving_controller_is_refused_and_moves_nothing(tmp_path):
    cfg, path = _config(tmp_path)
    serve = subprocess.Popen([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(path),
                              "--port", "0"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        first = serve.stdout.readline()          # printed once the log is open and the link listens
        assert "serving" in first, (first, serve.poll())
        log = tmp_path / "cell.sqlite"
        before = _files(tmp_path)
        assert "cell.sqlite" in before
        out = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                              "--recipe", "fast-a", "--cycles", "1"], cwd=REPO, capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 2, out.stdout + out.stderr
        assert "in use by another controller" in out.stderr
        # the serving controller's log is where it was, the same file, and nothing was kept aside
        after = _files(tmp_path)
        assert {k: after.get(k) for k in before} == before           # no file moved or replaced
        assert all(k.endswith(("-wal", "-shm")) for k in set(after) - set(before))   # SQLite's own
        assert not list(tmp_path.glob("cell.prev*"))
        reader = CycleLog(log, readonly=True)    # readers still find it
        reader.close()
    finally:
        serve.terminate()
        serve.communicate(timeout=60)
    assert serve.returncode == 0


@pytest.mark.slow
def test_fresh_runs_keep_every_previous_log(tmp_path):
    cfg, path = _config(tmp_path)
    log = tmp_path / "cell.sqlite"
    inodes = []
    for _ in range(3):
        out = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                              "--recipe", "fast-a", "--cycles", "1"], cwd=REPO, capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 0, out.stderr[-2000:]
        inodes.append(log.stat().st_ino)
    kept = sorted(tmp_path.glob("cell.prev-*.sqlite"))
    # the first two runs' logs, each under its own name, each still a log of one cycle
    assert {p.stat().st_ino for p in kept} == set(inodes[:2])
    for p in kept:
        r = CycleLog(p, readonly=True)
        try:
            assert r.count() == 1
        finally:
            r.close()
    assert "previous log kept as" in out.stderr and kept[-1].name in out.stderr


def test_keep_previous_never_overwrites_and_moves_the_wal_along(tmp_path):
    from datetime import datetime, timezone

    from cell.cyclelog.file import keep_previous
    now = datetime(2026, 11, 25, 12, 0, 0, tzinfo=timezone.utc)
    log = tmp_path / "cell.sqlite"
    for i in range(2):
        log.write_bytes(b"log %d" % i)
        (tmp_path / "cell.sqlite-wal").write_bytes(b"wal %d" % i)
        kept = keep_previous(log, now)
        assert kept.name == ("cell.prev-20261125T120000Z.sqlite" if i == 0 else
                             "cell.prev-20261125T120000Z-2.sqlite")
        assert kept.read_bytes() == b"log %d" % i
        assert (tmp_path / (kept.name + "-wal")).read_bytes() == b"wal %d" % i
        assert not log.exists() and not (tmp_path / "cell.sqlite-wal").exists()
    assert keep_previous(log, now) is None                 # nothing there: nothing moved


def test_keep_previous_that_cannot_move_leaves_the_log_in_place(tmp_path):
    """The log's own link succeeds, its -wal's fails (a folder cannot be hard-linked, even
    by root): the log and its sidecar stay where they were and no half copy is left."""
    from cell.errors import LogError
    from cell.cyclelog.file import keep_previous
    log = tmp_path / "cell.sqlite"
    log.write_bytes(b"log")
    (tmp_path / "cell.sqlite-wal").mkdir()
    try:
        keep_previous(log)
    except LogError as exc:
        assert "cannot keep the previous cycle log" in str(exc) and str(log) in str(exc)
    else:
        raise AssertionError("keep_previous did not fail")
    assert log.read_bytes() == b"log" and (tmp_path / "cell.sqlite-wal").is_dir()
    assert not list(tmp_path.glob("cell.prev*"))
