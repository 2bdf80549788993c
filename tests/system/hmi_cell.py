"""A running simulated cell with the maintenance HMI beside it, as two real processes:
``cellctl run --sim`` (the whole cell and its simulated PLC, cycling back to back on its
simulated clock; recipe edits settle on wall time, as in the product) on a private copy of
the recipes and a private log, and ``cellctl hmi`` on a free loopback port reading the same
folder and log. Used by the browser test and ``docs/screenshot_hmi.py``.

Another process's simulation can only be watched from outside, in wall time: every wait
here is a bounded poll of state (the log, the HMI's port), never a sleep that asserts timing.
"""
from __future__ import annotations

import os
import queue
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml

from tests.system.conftest import REPO, make_config

USER, ROLE, PASSWORD = "alice", "maintenance", "correct horse battery"


def poll(pred, timeout_s: float, what: str, step_s: float = 0.05):
    """``pred()``'s first true value, polled every ``step_s`` for at most ``timeout_s`` wall s."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(step_s)


def query(db: Path, sql: str, args: tuple = ()) -> list[tuple]:
    """Rows of ``sql`` on the log, read-only ([] while the log or its tables do not exist)."""
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return con.execute(sql, args).fetchall()
    except sqlite3.OperationalError:
        return []
    finally:
        con.close()


class SimCellWithHmi:
    """``with SimCellWithHmi(tmp) as c: c.url ...``: both processes up, at least one cycle
    logged; both stopped (and waited for) on exit."""

    def __init__(self, workdir: Path, recipe: str = "fast-a", settle_s: float = 0.5, cycles: int = 100_000):
        self.workdir = Path(workdir)
        self.recipe, self.settle_s, self.cycles = recipe, settle_s, cycles
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> "SimCellWithHmi":
        from cell.hmi.users import set_user
        cfg = make_config(self.workdir, settle_s=self.settle_s)
        self.config_path = self.workdir / "cell.yaml"
        self.config_path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
        self.recipes = Path(cfg.recipes.directory)
        self.db = Path(cfg.log.path)
        self.users = self.workdir / "hmi-users.json"
        set_user(self.users, USER, ROLE, PASSWORD)
        self.reports = self.workdir / "reports"
        try:
            self._start()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _start(self) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        cellctl = [sys.executable, "-m", "cell.cli"]
        self.cell_log = open(self.workdir / "cell.out", "w")
        self.procs.append(subprocess.Popen(
            [*cellctl, "run", "--sim", "--config", str(self.config_path), "--recipe", self.recipe,
             "--cycles", str(self.cycles)], cwd=REPO, env=env, stdout=self.cell_log, stderr=subprocess.STDOUT))
        hmi = subprocess.Popen(
            [*cellctl, "hmi", "--config", str(self.config_path), "--port", "0", "--users", str(self.users),
             "--reports", str(self.reports)], cwd=REPO, env=env, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)
        self.procs.append(hmi)
        lines: queue.Queue = queue.Queue()
        self.hmi_output: list[str] = []

        def read() -> None:
            for line in hmi.stdout:
                self.hmi_output.append(line)
                lines.put(line)
        threading.Thread(target=read, name="hmi-stdout", daemon=True).start()
        deadline = time.monotonic() + 60
        while True:
            try:
                line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"the HMI did not start: {''.join(self.hmi_output)}") from None
            if "serving http://" in line:
                self.url = line.split("serving ")[1].split()[0].rstrip("/")
                break
        poll(lambda: query(self.db, "SELECT COUNT(*) FROM cycles") and
             query(self.db, "SELECT COUNT(*) FROM cycles")[0][0] >= 1, 120, "the first logged cycle")
        if self.procs[0].poll() is not None:
            raise AssertionError(f"the cell stopped: {(self.workdir / 'cell.out').read_text()[-2000:]}")

    def __exit__(self, *exc) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
        for p in reversed(self.procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if getattr(self, "cell_log", None):
            self.cell_log.close()
