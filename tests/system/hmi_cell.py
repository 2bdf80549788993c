"""A running simulated cell with the maintenance HMI beside it, as two real processes:
``cellctl run --sim`` (the whole cell and its simulated PLC, cycling back to back on its
simulated clock; recipe edits settle on wall time, as in the product) on a private copy of
the recipes and a private log, and ``cellctl hmi`` on a free loopback port reading the same
folder and log. Used by the browser test and ``docs/screenshot_hmi.py``.

:class:`HmiProcess` runs the HMI alone, as a process of its own (``python -m
tests.system.hmi_cell serve ...``: the product's :func:`cell.hmi.server.serve` on a free
loopback port), for attacks on the network level: a lower descriptor limit, its own TMPDIR,
limits of :class:`cell.hmi.server.ServeLimits`, and optionally recipe checks that block
until the process ends (a check is the desk's injected ``cell_check``; each one entered
leaves a file in a folder, so a test waits on that state). :func:`hmi_server` runs the
product's server in a thread of the test process.

Another process's simulation can only be watched from outside, in wall time: every wait
here is a bounded poll of state (the log, the HMI's port), never a sleep that asserts timing.
"""
from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import queue
import sqlite3
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import yaml

from tests.system.conftest import REPO, make_config
from tests.waiting import wait_for

USER, ROLE, PASSWORD = "alice", "maintenance", "correct horse battery"


def poll(pred, timeout_s: float, what: str, step_s: float = 0.05):
    """``pred()``'s first true value, polled every ``step_s`` for at most ``timeout_s`` wall s."""
    return wait_for(pred, timeout_s, what, every=step_s)


def serving_url(proc: subprocess.Popen, output: list[str], timeout_s: float = 60.0) -> str:
    """The URL an HMI process prints (``serving http://...``) once it listens; every line it
    writes, then and later, is appended to ``output`` by a reader thread.

    :raises AssertionError: with what it printed, if no such line comes within ``timeout_s``.
    """
    lines: queue.Queue = queue.Queue()

    def read() -> None:
        for line in proc.stdout:
            output.append(line)
            lines.put(line)
    threading.Thread(target=read, name="hmi-output", daemon=True).start()
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
        except queue.Empty:
            raise AssertionError(f"the HMI did not start: {''.join(output)}") from None
        if "serving http://" in line:
            return line.split("serving ")[1].split()[0].rstrip("/")


@contextlib.contextmanager
def idle_cell(config_path: Path, port: int, seconds: float, wait_s: float = 90.0):
    """``with idle_cell(cfg, port, 240) as status:``: ``cellctl serve --sim --config cfg`` on
    ``port`` with no PLC, yielded once its registers say idle (``status``: that first
    :func:`cell.hmi.status.plc_status` read); terminated and waited for on exit."""
    from cell.hmi.status import plc_status
    proc = subprocess.Popen([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(config_path),
                             "--port", str(port), "--seconds", str(seconds)], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield poll(lambda: (st := plc_status("127.0.0.1", port))["reachable"] and st["state"] == "idle" and st,
                   wait_s, "the controller idle on its link")
    finally:
        proc.terminate()
        proc.wait(timeout=30)


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
        self.hmi_output: list[str] = []
        self.url = serving_url(hmi, self.hmi_output)
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


class HmiProcess:
    """``with HmiProcess(tmp, recipes=..., db=..., users=...) as h: h.url ...``: the HMI as a
    process of its own (module doc), stopped (SIGTERM, then SIGKILL) and waited for on exit.

    :param nofile: the process's descriptor limit (soft and hard), or None.
    :param block_checks: a folder: every recipe check leaves a file in it and then blocks.
    :param limits: :class:`cell.hmi.server.ServeLimits` fields, where the code has them.
    :param env: extra environment (e.g. TMPDIR).
    """

    def __init__(self, workdir: Path, recipes: Path, db: Path, users: Path, nofile: int | None = None,
                 block_checks: Path | None = None, limits: dict | None = None, env: dict | None = None):
        self.workdir = Path(workdir)
        self.args = ["--dir", str(recipes), "--db", str(db), "--users", str(users),
                     "--reports", str(self.workdir / "reports")]
        if block_checks is not None:
            self.args += ["--block-checks", str(block_checks)]
        if limits:
            self.args += ["--limits", json.dumps(limits)]
        self.nofile, self.env = nofile, env or {}
        self.output: list[str] = []

    def __enter__(self) -> "HmiProcess":
        import resource
        nofile = self.nofile

        def limit() -> None:
            if nofile is not None:
                resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.system.hmi_cell", "serve", *self.args], cwd=REPO,
                                     env=dict(os.environ, PYTHONUNBUFFERED="1", **self.env), stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, preexec_fn=limit)
        try:
            self.url = serving_url(self.proc, self.output)
        except AssertionError:
            self.__exit__(None, None, None)
            raise
        self.port = int(self.url.rsplit(":", 1)[1])
        return self

    def log(self) -> str:
        return "".join(self.output)

    def __exit__(self, *exc) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@contextlib.contextmanager
def hmi_server(settings, **limits):
    """``with hmi_server(settings) as (url, server):``: the product's server for ``settings``
    on a free loopback port, in a thread of this process (``limits``: ServeLimits fields;
    ``server.config.app`` is the application)."""
    from cell.hmi import server as srv
    sock = srv.listen("127.0.0.1", 0)
    port = sock.getsockname()[1]
    if hasattr(srv, "make_server"):
        server = srv.make_server(settings, srv.ServeLimits(**limits))
    else:                                   # the code before ServeLimits
        import uvicorn
        server = uvicorn.Server(uvicorn.Config(srv.create_app(settings), log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="hmi-server", daemon=True)
    thread.start()
    try:
        poll(lambda: server.started, 60, "the HMI server started")
        yield f"http://127.0.0.1:{port}", server
    finally:
        server.should_exit = True
        thread.join(60)


def _serve_main(argv: list[str]) -> int:
    """``serve``: the HMI for :class:`HmiProcess` (see its parameters)."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--dir", required=True)
    ap.add_argument("--db", required=True)
    ap.add_argument("--users", required=True)
    ap.add_argument("--reports", required=True)
    ap.add_argument("--block-checks")
    ap.add_argument("--limits")
    args = ap.parse_args(argv)
    import dataclasses

    from cell.hmi import server as srv
    from cell.hmi.recipes import RecipeDesk
    settings = srv.settings_from(None, args.users, args.reports, None, args.dir, args.db)
    if args.block_checks:
        markers = Path(args.block_checks)
        never = threading.Event()

        def blocking_check(recipe, text, source) -> None:
            (markers / uuid.uuid4().hex).touch()
            never.wait()
        desk = settings.desk
        settings = dataclasses.replace(settings, desk=RecipeDesk(desk.directory, blocking_check, desk.log_path,
                                                                  desk.max_bytes))
    sock = srv.listen("127.0.0.1", 0)
    print(f"serving http://127.0.0.1:{sock.getsockname()[1]}/", flush=True)
    if args.limits and "limits" in inspect.signature(srv.serve).parameters:
        srv.serve(settings, sock, srv.ServeLimits(**json.loads(args.limits)))
    else:
        srv.serve(settings, sock)
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["serve"]:
        sys.exit(_serve_main(sys.argv[2:]))
    sys.exit("usage: python -m tests.system.hmi_cell serve --dir D --db DB --users U --reports R [...]")
