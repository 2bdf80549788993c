"""A cell as a process of its own, for the plant path's fault test: it logs cycles through
:class:`~cell.cyclelog.CycleLog` at a steady rate the way the controller does, and runs the
:class:`~cell.plant.outbox.PlantOutbox` on that log, as ``Cell.start`` does with a ``plant``
section.

    python -m tests.cell.plant.cell_process --db LOG --broker HOST:PORT --cell SITE/LINE/CELL \\
        --records N --rate PER_S [--hold-at K --hold-stage running|logged]

Each cycle as the controller has it: ``begin_cycle`` before the first move, the moves (a
third of the period), ``add_cycle`` (the row), the PLC told (a third), ``settle_cycle``;
every fifth cycle the PLC was told a fault the row did not say, so its settle corrects the
row. At its start it does what the controller does with a cycle the last run left in
flight (``recover_interrupted``: recorded as aborted, fault 503) and then what the PLC's
reset does (``clear_interrupted``). With ``--hold-at K`` the K-th cycle of the log stops in
``--hold-stage`` (begun, or its row logged and the PLC not told) until the process is killed.

It writes until the log holds ``N`` records (a restarted one resumes its own log) and keeps
its outbox running until SIGTERM (a clean stop) or SIGKILL (a crash, what the test does). It
prints ``ready`` once its log is open.
"""
from __future__ import annotations

import argparse
import signal
import threading
import time

from cell.cyclelog import CycleLog, CycleStatus
from cell.plant.outbox import OutboxSettings, PlantOutbox
from cell.plant.topics import CellTopics
from tests.cell.plant.helpers import record

TOLD_FAULT = 102        #: what the PLC was told for every fifth cycle (the row said done)


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--db", required=True)
    p.add_argument("--broker", required=True)
    p.add_argument("--cell", required=True)
    p.add_argument("--records", type=int, required=True)
    p.add_argument("--rate", type=float, default=100.0)
    p.add_argument("--resend-s", type=float, default=3.0)
    p.add_argument("--keepalive-s", type=int, default=5)
    p.add_argument("--hold-at", type=int, default=0, help="stop the K-th cycle of the log in --hold-stage")
    p.add_argument("--hold-stage", choices=("running", "logged"), default="logged")
    args = p.parse_args()
    host, _, port = args.broker.rpartition(":")
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    log = CycleLog(args.db)
    if log.recover_interrupted() is not None:     # the controller's start, then the PLC's reset
        log.clear_interrupted()
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
            k = have + 1
            rec = record(k)
            log.begin_cycle(rec.part_id, rec.recipe, rec.recipe_hash, rec.started_at)
            if k == args.hold_at and args.hold_stage == "running":
                stop.wait()
                break
            stop.wait(period / 3)
            cycle_id = log.add_cycle(rec)
            if k == args.hold_at:
                stop.wait()
                break
            stop.wait(period / 3)
            if k % 5 == 0:
                log.settle_cycle(rec.started_at, cycle_id, CycleStatus.FAULT, TOLD_FAULT, "told a fault")
            else:
                log.settle_cycle(rec.started_at, cycle_id, rec.status, 0, "")
            due += period
            stop.wait(max(0.0, due - time.monotonic()))
    finally:
        outbox.stop()
        log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
