"""A fleet on one machine (``python3 dev.py fleet``): a real mosquitto and PostgreSQL on
loopback in a temporary folder (:mod:`cell.plant.servers`), three simulated cells sending
their cycle records to the broker, ``cellctl historian`` writing them to PostgreSQL, and the
HMI with its line view reading it back.

Each cell is ``cellctl run --sim`` with a config of its own in ``<folder>/cell-N/`` (its log,
its calibration files, a ``plant`` section naming the broker, site ``demo``, line
``line1``, seed N), run again and again: ``--parts`` parts, then a pause of ``--pause-s``
(its part ids go on from run to run, its log is appended to, so it keeps one ``log_id``).
Between runs a cell is offline (its outbox says goodbye at the end of a run), as a cell
that is switched off is: the line view shows it. A cell's processes print to
``<folder>/cell-N/run.log``; the historian's and the HMI's to ``<folder>/*.log``.

:class:`FleetDemo` is the whole of it (``start()``, ``stop()``, ``urls``), so a test runs it
briefly; ``python -m cell.plant.demo`` runs it until Ctrl-C or SIGTERM (or ``--seconds``)
and stops every process it started, then both servers, and removes the folder (``--keep``
keeps it, with the logs).
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from cell.plant.servers import Mosquitto, Postgres, ServerError, free_port
from cell.shutdown import StopRequest

SITE, LINE = "demo", "line1"


class FleetDemo:
    """See the module doc. :param folder: where the cells' folders go (default: a new
    temporary folder, removed at :meth:`stop` unless ``keep``)."""

    def __init__(self, cells: int = 3, parts: int = 5, pause_s: float = 10.0, hmi_port: int | None = None,
                 folder: Path | None = None, keep: bool = False, recipe: str = "bracket-a"):
        self.n, self.parts, self.pause_s, self.recipe = cells, parts, pause_s, recipe
        self.hmi_port = hmi_port or free_port()
        self.folder = Path(folder) if folder else Path(tempfile.mkdtemp(prefix="cell-fleet-"))
        self.keep = keep or folder is not None
        self.broker: Mosquitto | None = None
        self.db: Postgres | None = None
        self._procs: list[subprocess.Popen] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._loops: list[threading.Thread] = []
        self.runs = [0] * cells                 #: runs of each cell finished so far

    @property
    def dsn(self) -> str:
        return self.db.dsn

    @property
    def urls(self) -> dict[str, str]:
        base = f"http://127.0.0.1:{self.hmi_port}"
        return {"line view": f"{base}/line", "HMI": f"{base}/", "broker": f"mqtt://127.0.0.1:{self.broker.port}",
                "DSN": self.dsn}

    def cell_ids(self) -> list[str]:
        return [f"{SITE}/{LINE}/cell-{k}" for k in range(1, self.n + 1)]

    # ---------------------------------------------------------------------------- life cycle
    def start(self) -> None:
        """Start the servers, the historian, the cells and the HMI; raises ServerError (and
        stops what it started) when something does not come up."""
        try:
            self.broker = Mosquitto().start()
            self.db = Postgres().start()
            self._spawn("historian", [*_cellctl(), "historian", "--broker", f"127.0.0.1:{self.broker.port}",
                                      "--dsn", self.dsn, "--client-id", "fleet-historian"], self.folder / "historian.log")
            for k in range(1, self.n + 1):
                t = threading.Thread(target=self._cell_loop, args=(k, self._config(k)), name=f"fleet-cell-{k}",
                                     daemon=True)
                t.start()
                self._loops.append(t)
            self._spawn("hmi", [*_cellctl(), "hmi", "--port", str(self.hmi_port), "--line-dsn", self.dsn,
                                "--db", str(self.folder / "cell-1" / "cell.sqlite"),
                                "--users", str(self.folder / "hmi-users.json"),
                                "--reports", str(self.folder / "reports")], self.folder / "hmi.log")
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        """Stop every process it started (SIGINT for a cell's run, SIGTERM for the historian
        and the HMI; SIGKILL after 20 s), then the servers."""
        self._stop.set()
        with self._lock:
            procs = list(self._procs)
        for p in procs:
            if p.poll() is None:                 # a cell's run ends at Ctrl-C, the services at SIGTERM
                p.send_signal(signal.SIGINT if p.args[3] == "run" else signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
        for t in self._loops:
            t.join(timeout=30)
        if self.db is not None:
            self.db.stop()
        if self.broker is not None:
            self.broker.stop()
        if not self.keep:
            shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> "FleetDemo":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # ---------------------------------------------------------------------------- the cells
    def _config(self, k: int) -> Path:
        import yaml
        folder = self.folder / f"cell-{k}"
        folder.mkdir(parents=True, exist_ok=True)
        doc = {"format": "cell-config/1", "name": f"cell-{k}",
               "plc": {"host": "127.0.0.1", "heartbeat_timeout_s": 5.0},
               "log": {"path": "cell.sqlite"},
               "calibration": {"file": "robot-calibration.json", "hand_calibration": "hand-camera.json"},
               "plant": {"host": "127.0.0.1", "port": self.broker.port, "site": SITE, "line": LINE},
               "sim": {"seed": k}}
        path = folder / "cell.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return path

    def _cell_loop(self, k: int, config: Path) -> None:
        first = 1
        log = config.parent / "run.log"
        while not self._stop.is_set():
            p = self._spawn(f"cell-{k}", [*_cellctl(), "run", "--sim", "--config", str(config), "--db",
                                          str(config.parent / "cell.sqlite"), "--recipe", self.recipe,
                                          "--cycles", str(self.parts), "--first-part", str(first)], log)
            if p is None:
                return
            p.wait()
            with self._lock:
                self._procs.remove(p)
            self.runs[k - 1] += 1
            first += self.parts
            self._stop.wait(self.pause_s)

    def _spawn(self, what: str, argv: list[str], log: Path) -> subprocess.Popen | None:
        with self._lock:
            if self._stop.is_set() and what.startswith("cell-"):
                return None
            with open(log, "ab") as out:
                p = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                     cwd=self.folder, start_new_session=True)
            self._procs.append(p)
            return p


def _cellctl() -> list[str]:
    return [sys.executable, "-m", "cell.cli"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dev.py fleet", description=__doc__.split("\n\n")[0].replace("``", ""))
    ap.add_argument("--cells", type=int, default=3, help="simulated cells (default 3)")
    ap.add_argument("--parts", type=int, default=5, help="parts per run of a cell (default 5)")
    ap.add_argument("--pause-s", type=float, default=10.0, help="pause between a cell's runs (default 10 s)")
    ap.add_argument("--hmi-port", type=int, help="the HMI's port (default: a free one)")
    ap.add_argument("--seconds", type=float, help="stop after this many seconds (default: at Ctrl-C or SIGTERM)")
    ap.add_argument("--keep", action="store_true", help="keep the folder with the cells' logs at the end")
    args = ap.parse_args(argv)
    if not 1 <= args.cells <= 20 or args.parts < 1 or args.pause_s < 0:
        ap.error("--cells 1..20, --parts >= 1 and --pause-s >= 0")
    stop = StopRequest().install()               # a handler without locks (cell/shutdown.py)
    demo = FleetDemo(args.cells, args.parts, args.pause_s, args.hmi_port, keep=args.keep)
    say = lambda text: print(text, flush=True)          # noqa: E731
    say(f"fleet: starting mosquitto, PostgreSQL, the historian, {args.cells} simulated cells and the HMI "
        f"in {demo.folder}")
    try:
        demo.start()
    except ServerError as exc:
        print(f"fleet: {exc}", file=sys.stderr)
        return 2
    try:
        width = max(map(len, demo.urls))
        for name, url in demo.urls.items():
            say(f"  {name:<{width}}  {url}")
        say(f"  {'cells':<{width}}  {', '.join(demo.cell_ids())} (logs in {demo.folder}/cell-N/)")
        say(f"  {'report':<{width}}  python3 dev.py cellctl fleet report --dsn '{demo.dsn}'")
        say("fleet: running; Ctrl-C stops everything")
        stop.wait(args.seconds)
    finally:
        say("fleet: stopping")
        demo.stop()
        say(f"fleet: stopped ({sum(demo.runs)} cell runs of {args.parts} parts)"
            + (f"; logs kept in {demo.folder}" if demo.keep else ""))
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
