"""A cell as a process of its own, for the plant path's fault test: it appends cycle records
to its own log through :class:`~cell.cyclelog.CycleLog` at a steady rate, as the controller
does at the end of each cycle, and runs the :class:`~cell.plant.outbox.PlantOutbox` on that
log, as ``Cell.start`` does with a ``plant`` section.

    python -m tests.cell.plant.cell_process --db LOG --broker HOST:PORT --cell SITE/LINE/CELL \\
        --records N --rate PER_S

It writes until the log holds ``N`` records (a restarted one resumes its own log: it goes on
from the log's count) and keeps its outbox running until SIGTERM (a clean stop) or SIGKILL
(a crash, what the test does). It prints ``ready`` once its log is open.
"""
from __future__ import annotations

import argparse
import signal
import threading
import time

from cell.cyclelog import CycleLog
from cell.plant.outbox import OutboxSettings, PlantOutbox
from cell.plant.topics import CellTopics
from tests.cell.plant.helpers import record


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--db", required=True)
    p.add_argument("--broker", required=True)
    p.add_argument("--cell", required=True)
    p.add_argument("--records", type=int, required=True)
    p.add_argument("--rate", type=float, default=100.0)
    p.add_argument("--resend-s", type=float, default=3.0)
    p.add_argument("--keepalive-s", type=int, default=5)
    args = p.parse_args()
    host, _, port = args.broker.rpartition(":")
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    log = CycleLog(args.db)
    outbox = PlantOutbox(args.db, OutboxSettings(host=host, port=int(port), topics=CellTopics.from_path(args.cell),
                                                 keepalive_s=args.keepalive_s, resend_s=args.resend_s,
                                                 poll_s=0.1))
    outbox.start()
    print("ready", flush=True)
    period, due = 1.0 / args.rate, time.monotonic()
    try:
        while not stop.is_set():
            have = log.count()
            if have >= args.records:
                stop.wait(0.2)
                continue
            log.add_cycle(record(have + 1))
            due += period
            stop.wait(max(0.0, due - time.monotonic()))
    finally:
        outbox.stop()
        log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
