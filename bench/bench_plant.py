"""The plant path's speed: cycle records from a cell's log through a real mosquitto and
``cellctl historian`` into a real PostgreSQL 15, on this machine.

The broker is the deployed one (``deploy/mosquitto/plant.conf``: TLS, logins, ACL; ``--plain``:
anonymous TCP), started by :class:`cell.plant.servers.Mosquitto`; the historian is a
``cellctl historian`` process; the cell is this process: a ``CycleLog`` writer and the
``PlantOutbox`` on it, as in ``Cell.start``. A record counts as delivered when the
historian's watermark covering it reaches the cell (a watcher subscribed as the cell
times each watermark), so every figure is cell → broker → historian → PostgreSQL commit →
watermark back at the cell.

1. **Throughput**: ``--records`` records appear in the log at once (one SQLite
   transaction) while everything runs; records/s until the watermark covers the last.
2. **Latency at 100 records/s**: the cell logs ``--paced`` records, one every 10 ms, each
   with ``CycleLog.add_cycle`` (a durable SQLite commit); per record, from the return of
   ``add_cycle`` to the first watermark covering it: p50, p99, max.
3. **Drain after an outage**: the historian is stopped, ``--backlog`` records are logged
   (one transaction), the historian is started again; seconds from its start until the
   watermark covers the backlog (the process's start-up included), and the same with the
   broker away instead (the cell cut off; paho's reconnect wait of 1 to 5 s included).

    .venv/bin/python bench/bench_plant.py            # 20000 / 2000 / 10000 records
    .venv/bin/python bench/bench_plant.py --quick    # 2000 / 300 / 1000: a probe of the columns
"""
from __future__ import annotations

import argparse
import bisect
import os
import platform
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from cell import log as cell_log  # noqa: E402
from cell.cyclelog import CycleLog, CycleRecord, CycleStatus, utc_now  # noqa: E402
from cell.plant.mqtt import MqttLink, Security  # noqa: E402
from cell.plant.outbox import OutboxSettings, PlantOutbox  # noqa: E402
from cell.plant.servers import Mosquitto, Postgres  # noqa: E402
from cell.plant.topics import CellTopics  # noqa: E402

TOPICS = CellTopics("site1", "line1", "cell-1")
USERS = {TOPICS.path: "cell-secret", "historian": "historian-secret"}


def _record(part_id: int) -> CycleRecord:
    now = utc_now()
    return CycleRecord(part_id=part_id, recipe="bracket-a", recipe_hash="ab" * 8, started_at=now, finished_at=now,
                       status=CycleStatus.DONE, cycle_time_s=1.25, step_times={"APPROACH": 0.5, "PLACE": 0.4},
                       method="lattice", target_mm=(400.0, 10.0), initial_error_mm=0.31, final_error_mm=0.004,
                       verify_error_mm=0.005, moves=2, temp_c=21.5, trace=[{"moved": True}],
                       motion={"mode": "corrected"})


def _bulk(path: Path, n: int) -> int:
    """Append ``n`` copies of the log's last row in one transaction; returns the last id."""
    db = sqlite3.connect(path)
    cols = [r[1] for r in db.execute("PRAGMA table_info(cycles)") if r[1] != "id"]
    names = ", ".join(cols)
    with db:
        top = db.execute("SELECT max(id) FROM cycles").fetchone()[0]
        db.execute(f"WITH RECURSIVE k(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM k WHERE i < ?) "
                   f"INSERT INTO cycles ({names}) SELECT {names} FROM cycles, k WHERE cycles.id = ?", (n, top))
        last = db.execute("SELECT max(id) FROM cycles").fetchone()[0]
    db.close()
    return int(last)


class Watermarks:
    """The cell's watermark as it arrives: (monotonic time, cycle_id) of each raise."""

    def __init__(self, broker, security: Security | None, log_id: str):
        self.log_id = log_id
        self.times: list[float] = []
        self.ids: list[int] = []
        self._cv = threading.Condition()
        self.link = MqttLink(broker.host, broker.port, "bench-watermarks", security=security,
                             subscriptions=((TOPICS.watermark, 1),), on_message=self._message)

    def _message(self, generation, message) -> None:
        from cell.plant import schema
        now = time.monotonic()
        wm = schema.parse("watermark", message.topic, message.payload, TOPICS.path)
        with self._cv:
            if wm.log_id == self.log_id and (not self.ids or wm.cycle_id > self.ids[-1]):
                self.times.append(now)
                self.ids.append(wm.cycle_id)
                self._cv.notify_all()

    def wait(self, cycle_id: int, timeout: float = 600.0) -> float:
        """The time the watermark first covered ``cycle_id`` (waiting for it)."""
        with self._cv:
            if not self._cv.wait_for(lambda: self.ids and self.ids[-1] >= cycle_id, timeout):
                raise SystemExit(f"the watermark did not reach {cycle_id} within {timeout:g} s "
                                 f"(last {self.ids[-1] if self.ids else None})")
            return self.times[bisect.bisect_left(self.ids, cycle_id)]


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--records", type=int, default=20000, help="throughput: records logged at once")
    p.add_argument("--paced", type=int, default=2000, help="latency: records logged at 100/s")
    p.add_argument("--backlog", type=int, default=10000, help="drain: records logged during the outage")
    p.add_argument("--quick", action="store_true", help="2000 / 300 / 1000 records")
    p.add_argument("--plain", action="store_true", help="anonymous plain TCP instead of the deployed TLS broker")
    args = p.parse_args(argv)
    if args.quick:
        args.records, args.paced, args.backlog = 2000, 300, 1000
    cell_log.configure(level="ERROR")      # the warm-up's resend (the first record, sent before the
    #                                        historian had subscribed) is expected, not news
    tmp = Path(tempfile.mkdtemp(prefix="bench-plant-"))
    broker = Mosquitto(users=None if args.plain else USERS)
    pg = Postgres()
    broker.start()
    pg.start()
    historian = None
    cell_sec = hist_args = None
    if not args.plain:
        ca = str(broker.certificates.ca)
        cell_sec = Security(tls=True, ca_file=ca, username=TOPICS.path, password=USERS[TOPICS.path])
        (tmp / "historian.password").write_text(USERS["historian"])
        hist_args = ["--ca-file", ca, "--password-file", str(tmp / "historian.password")]

    def start_historian() -> subprocess.Popen:
        with open(tmp / "historian.log", "ab") as out:
            return subprocess.Popen([sys.executable, "-m", "cell.cli", "historian", "--broker",
                                     f"{broker.host}:{broker.port}", "--dsn", pg.dsn, "--client-id", "bench",
                                     *(hist_args or [])], cwd=REPO, stdout=out, stderr=out)

    db = tmp / "cell.sqlite"
    log = CycleLog(db)
    log.add_cycle(_record(1))
    # resend_s 5: the first record, sent before the new historian has subscribed, comes again in 5 s, not 30
    outbox = PlantOutbox(db, OutboxSettings(host=broker.host, port=broker.port, topics=TOPICS, security=cell_sec,
                                            resend_s=5.0))
    watch = Watermarks(broker, cell_sec, log.log_id)
    rows = []
    try:
        historian = start_historian()
        watch.link.start()
        outbox.start()
        watch.wait(1, 120)                                   # everything up and one record through

        t0 = time.monotonic()
        last = _bulk(db, args.records)
        took = watch.wait(last) - t0
        rows.append(("throughput: records logged at once, until the watermark covers the last",
                     f"{args.records}", f"{args.records / took:,.0f} records/s ({took:.2f} s)", "≥ 1,000 records/s"))

        written: list[tuple[int, float]] = []
        due = time.monotonic()
        for k in range(args.paced):
            rid = log.add_cycle(_record(k))
            written.append((rid, time.monotonic()))
            due += 0.01
            time.sleep(max(0.0, due - time.monotonic()))
        lat = [watch.wait(rid) - at for rid, at in written]
        rows.append(("latency at 100 records/s, p50", f"{args.paced}", f"{_pct(lat, 0.50):.3f} s", ""))
        rows.append(("latency at 100 records/s, p99", f"{args.paced}", f"{_pct(lat, 0.99):.3f} s", "≤ 1 s"))
        rows.append(("latency at 100 records/s, max", f"{args.paced}", f"{max(lat):.3f} s", ""))

        historian.terminate()
        historian.wait(60)
        last = _bulk(db, args.backlog)
        time.sleep(1.0)                                      # the outbox sends its window into the broker's queue
        t0 = time.monotonic()
        historian = start_historian()
        took = watch.wait(last) - t0
        rows.append(("drain after a historian outage: from its start to the backlog covered",
                     f"{args.backlog}", f"{took:.2f} s ({args.backlog / took:,.0f} records/s)", ""))

        broker.kill()
        last = _bulk(db, args.backlog)
        t0 = time.monotonic()
        broker.start()
        took = watch.wait(last) - t0
        rows.append(("drain after a broker outage: from its start to the backlog covered",
                     f"{args.backlog}", f"{took:.2f} s ({args.backlog / took:,.0f} records/s)", ""))
    finally:
        outbox.stop()
        watch.link.stop()
        log.close()
        if historian is not None and historian.poll() is None:
            historian.terminate()
            historian.wait(60)
        broker.stop()
        pg.stop()

    load = os.getloadavg()[0]
    print(f"Plant path on {os.cpu_count()} cores (load {load:.1f} at the end), "
          f"{'plain TCP' if args.plain else 'TLS + logins + ACL (deploy/mosquitto)'}; Python "
          f"{platform.python_version()}, mosquitto and PostgreSQL 15 on loopback, cellctl historian a process, "
          f"the cell's outbox in this one\n")
    print("| measure | records | result | goal |")
    print("|---|---:|---:|---|")
    for row in rows:
        print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
