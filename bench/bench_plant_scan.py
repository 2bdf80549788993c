"""The controller's scan period with the plant link and OPC UA off and on, in the same run.

The controller, its PLC link, the moving stations, the OPC UA server and its MES stand-in
are bench/bench_opcua_scan.py's (imported, not copied). The plant side is the deployed
one, started by the project's own :mod:`cell.plant.servers` on loopback: a mosquitto with
``deploy/mosquitto/plant.conf`` (TLS, logins, ACL), a PostgreSQL 15 and ``cellctl
historian`` as a process; the cell's :class:`~cell.plant.outbox.PlantOutbox` runs in the
controller's process, as ``Cell.start`` runs it, on the controller's log and publisher.
Phases alternate, each ``--seconds`` long, ``--rounds`` times:

* ``off``: no plant link, no OPC UA server;
* ``plant``: the outbox started, and a writer thread logging a cycle record every
  ``1/--rate`` s through the controller's own ``CycleLog`` (``add_cycle``: a durable SQLite
  commit, as the cell's log worker makes one), which the outbox sends over TLS and the
  historian commits; the phase ends when the watermark covers every record logged;
* ``plant + OPC UA``: the same, and the OPC UA server with its MES stand-in reading as
  fast as it can (bench_opcua_scan's ``on`` phase).

The last column compares each phase's median period with the median of the ``off``
phases (goal: at most 1.05). ``records`` is what the phase logged, all of it delivered
(the watermark covering it) before the next phase starts.

    .venv/bin/python bench/bench_plant_scan.py                         # 10 s per phase, 2 rounds
    .venv/bin/python bench/bench_plant_scan.py --seconds 2 --rounds 1  # quick look
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
sys.path[:0] = [str(REPO), str(BENCH)]

import bench_opcua_scan as scan  # noqa: E402
from bench_plant import TOPICS, USERS, _record  # noqa: E402

from cell import log, progress  # noqa: E402
from cell.clock import MonotonicClock  # noqa: E402
from cell.cyclelog import CycleLog  # noqa: E402
from cell.plant.mqtt import Security  # noqa: E402
from cell.plant.outbox import OutboxSettings, PlantOutbox  # noqa: E402
from cell.plant.servers import Mosquitto, Postgres  # noqa: E402
from cell.sim.plc import SimPlc  # noqa: E402


class Plant:
    """The plant side on loopback (module doc) and the cell's outbox, started per phase."""

    def __init__(self, tmp: Path, cyclelog: CycleLog, publisher):
        self.tmp, self.cyclelog, self.publisher = tmp, cyclelog, publisher
        self.broker, self.pg = Mosquitto(users=USERS), Postgres()
        self.historian: subprocess.Popen | None = None
        self.security: Security | None = None

    def start(self) -> None:
        self.broker.start()
        self.pg.start()
        ca = str(self.broker.certificates.ca)
        self.security = Security(tls=True, ca_file=ca, username=TOPICS.path, password=USERS[TOPICS.path])
        (self.tmp / "historian.password").write_text(USERS["historian"])
        with open(self.tmp / "historian.log", "ab") as out:
            self.historian = subprocess.Popen(
                [sys.executable, "-m", "cell.cli", "historian", "--broker", f"{self.broker.host}:{self.broker.port}",
                 "--dsn", self.pg.dsn, "--client-id", "bench", "--ca-file", ca,
                 "--password-file", str(self.tmp / "historian.password")], cwd=REPO, stdout=out, stderr=out)

    def stop(self) -> None:
        if self.historian is not None and self.historian.poll() is None:
            self.historian.terminate()
            self.historian.wait(60)
        self.broker.stop()
        self.pg.stop()

    def phase(self, measure, rate: float) -> dict:
        """``measure()`` (a phase's row) while the outbox sends what a writer logs at ``rate``/s."""
        outbox = PlantOutbox(self.cyclelog.path, OutboxSettings(
            host=self.broker.host, port=self.broker.port, topics=TOPICS, security=self.security, resend_s=5.0),
            publisher=self.publisher)
        outbox.start()
        stop, logged = threading.Event(), []

        def writer():
            due = time.monotonic()
            while not stop.is_set():
                logged.append(self.cyclelog.add_cycle(_record(len(logged) + 1)))
                due += 1.0 / rate
                stop.wait(max(0.0, due - time.monotonic()))
        try:
            _wait(lambda: outbox.backlog == 0, 120, "the outbox caught up before the phase")
            t = threading.Thread(target=writer, name="bench-writer", daemon=True)
            t.start()
            row = measure()
            stop.set()
            t.join(10)
            _wait(lambda: outbox.backlog == 0, 120, "every record of the phase delivered")
        finally:
            stop.set()
            outbox.stop()
        row.update(records=len(logged), status_sent=outbox.status_sent)
        return row


def _wait(probe, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not probe():
        if time.monotonic() > end:
            raise SystemExit(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.05)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each phase (default 10)")
    ap.add_argument("--rounds", type=int, default=2, help="off / plant / plant + OPC UA rounds (default 2)")
    ap.add_argument("--rate", type=float, default=10.0, help="cycle records logged per second (default 10)")
    args = ap.parse_args()
    log.configure("console", "ERROR")
    tmp = Path(tempfile.mkdtemp(prefix="bench-plant-scan-"))
    clock = MonotonicClock()
    ctl, link, cyclelog = scan.controller(tmp, clock)
    plant = Plant(tmp, cyclelog, ctl.publisher)
    plant.start()
    ctl.start()
    port = link.start("127.0.0.1", 0)
    plc = SimPlc("127.0.0.1", port, clock=clock)
    plc.start()
    rows = []
    try:
        time.sleep(1.0)
        for _ in progress.each(range(args.rounds), "rounds", "round"):
            rows.append(("off", scan.measure(ctl, args.seconds)))
            rows.append(("plant", plant.phase(lambda: scan.measure(ctl, args.seconds), args.rate)))
            rows.append(("plant + OPC UA", plant.phase(lambda: scan.phase_on(ctl, args.seconds, tmp / "pki"),
                                                       args.rate)))
    finally:
        plc.stop()
        link.stop()
        ctl.stop()
        plant.stop()
        cyclelog.close()
    print(f"scan period {scan.SCAN_S * 1e3:.0f} ms, wall clock, {args.seconds:.0f} s per phase, {args.rounds} "
          f"round(s), {args.rate:g} records/s logged and sent in the plant phases (TLS, logins, ACL); load "
          f"average (1 min) at the end {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs; "
          f"python {sys.version.split()[0]}")
    print()
    print("| phase | scans | period p50 ms | p99 ms | max ms | periods > 20 ms | scan µs p50 | records "
          "| OPC UA reads/s | p50 / off p50 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    off = float(np.median([r["p50"] for name, r in rows if name == "off"]))
    for name, r in rows:
        records = str(r["records"]) if "records" in r else "-"
        reads = f"{r['reads'] / args.seconds:.0f}" if "reads" in r else "-"
        print(f"| {name} | {r['scans']} | {r['p50']:.2f} | {r['p99']:.2f} | {r['max']:.2f} | {r['late']} "
              f"| {r['work']:.0f} | {records} | {reads} | {r['p50'] / off:.3f} |")
    print()
    summary = []
    for phase in ("plant", "plant + OPC UA"):
        on = [r for name, r in rows if name == phase]
        summary.append(f"{phase} / off: {float(np.median([r['p50'] for r in on])) / off:.3f}")
    print(f"median period {'; '.join(summary)} (goal ≤ 1.05); every record logged was delivered; "
          f"PLC heartbeat faults: {int(ctl.fault_code == 101)}")
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
