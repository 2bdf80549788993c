"""The controller's scan period on wall time while recipe files arrive.

Runs the real :class:`~cell.controller.CellController` on the wall clock (as on a real
cell): its PLC link is the real pymodbus server on loopback, driven by a
:class:`~cell.sim.plc.SimPlc` (a real Modbus client) that keeps its heartbeat alive; the
recipe store reads a private copy of ``recipes/`` and audits into a real SQLite log. No
cycle runs (the stations and camera are not part of this measurement), so every scan is
the idle scan: read the PLC, step the core, write the PLC, hand recipe refreshes to the
``cell-log`` worker (refresh every 0.2 s here, five times the default, to load it).

Each phase lasts ``--seconds`` and records the time between consecutive scans:

* ``quiet``: nothing changes (the baseline of the same run);
* ``50 MB recipe arrives``: a valid-looking 50 MB ``big.yaml`` is written in 1 MB chunks;
* ``5 MB recipe arrives``: the same with 5 MB;
* ``valid edits``: ``bracket-a.yaml`` is rewritten with a new tolerance every second
  (each edit is read, parsed, validated and audited in one SQLite transaction once stable,
  0.3 s here).

    .venv/bin/python bench/bench_scan.py              # 10 s per phase
    .venv/bin/python bench/bench_scan.py --seconds 3  # quick look
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cell import log, progress  # noqa: E402
from cell.clock import MonotonicClock  # noqa: E402
from cell.controller import CellController, ControllerSettings  # noqa: E402
from cell.cycle.runner import CycleRunner  # noqa: E402
from cell.cyclelog import CycleLog  # noqa: E402
from cell.kinematics import Scara  # noqa: E402
from cell.recipes.store import RecipeStore  # noqa: E402
from cell.sim.plc import SimPlc  # noqa: E402
from drivers.plc.server import PlcLink  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SCAN_S = 0.01


class NoStations:
    """An idle cell's stations as the scan sees them: no latched fault, the arm at rest."""

    fault = None

    def actual_positions(self):
        return np.zeros(4)


def write_big(path: Path, megabytes: int, stop: threading.Event) -> None:
    """A big file written as a copy would, 1 MB at a time (a YAML comment body)."""
    chunk = (b"# " + b"x" * 1021 + b"\n") * 1024
    with open(path, "wb") as f:
        f.write(b"name: big\nnumber: 99\npart: {nominal_xy_mm: [250, 930], fiducial_radius_mm: 1.5}\n")
        for _ in range(megabytes):
            if stop.is_set():
                return
            f.write(chunk)
            f.flush()
            time.sleep(0.01)


def edit_loop(path: Path, stop: threading.Event) -> None:
    text = path.read_text()
    k = 0
    while not stop.wait(1.0):
        k += 1
        path.write_text(text.replace("tolerance_mm: 0.08", f"tolerance_mm: 0.0{5 + k % 4}"))


def run_phase(ctl: CellController, seconds: float, action) -> dict:
    stamps: list[float] = []
    orig = ctl.scan

    def scan():
        stamps.append(time.perf_counter())
        orig()
    ctl.scan = scan
    stop = threading.Event()
    worker = threading.Thread(target=action, args=(stop,), daemon=True) if action else None
    if worker:
        worker.start()
    time.sleep(seconds)
    stop.set()
    if worker:
        worker.join()
    ctl.scan = orig
    d = np.diff(stamps) * 1e3
    return {"scans": len(stamps), "p50": np.percentile(d, 50), "p99": np.percentile(d, 99),
            "max": d.max(), "late": int((d > 2 * SCAN_S * 1e3).sum())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each phase (default 10)")
    args = ap.parse_args()
    log.configure("console", "ERROR")
    tmp = Path(tempfile.mkdtemp(prefix="bench-scan-"))
    rdir = tmp / "recipes"
    shutil.copytree(REPO / "recipes", rdir)
    clock = MonotonicClock()
    cyclelog = CycleLog(tmp / "cell.sqlite")
    store = RecipeStore(rdir, commit=cyclelog.record_recipe_changes, settle_s=0.3, clock=clock)
    link = PlcLink(clock=clock)
    runner = CycleRunner(Scara.preset("seed000"), NoStations(), None, cyclelog, clock=clock)
    ctl = CellController(link, NoStations(), runner, cyclelog, store,
                         ControllerSettings(scan_s=SCAN_S, plc_heartbeat_timeout_s=1.0, recipe_refresh_s=0.2),
                         clock=clock)
    ctl.start()
    port = link.start("127.0.0.1", 0)
    plc = SimPlc("127.0.0.1", port, clock=clock)
    plc.start()
    phases = [("quiet", None),
              ("50 MB recipe arrives", lambda stop: write_big(rdir / "big.yaml", 50, stop)),
              ("5 MB recipe arrives", lambda stop: write_big(rdir / "big5.yaml", 5, stop)),
              ("valid edits every second", lambda stop: edit_loop(rdir / "bracket-a.yaml", stop))]
    rows = []
    try:
        time.sleep(1.0)
        for name, action in progress.each(phases, "phases", "phase"):
            rows.append((name, run_phase(ctl, args.seconds, action)))
    finally:
        plc.stop()
        link.stop()
        ctl.stop()
        audit = cyclelog.audit_rows()
        cyclelog.close()
    print(f"scan period {SCAN_S * 1e3:.0f} ms, wall clock, {args.seconds:.0f} s per phase; "
          f"load average (1 min) at the end {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs; "
          f"python {sys.version.split()[0]}")
    print()
    print("| phase | scans | period p50 ms | p99 ms | max ms | periods > 20 ms | p99 / quiet p99 |")
    print("|---|---|---|---|---|---|---|")
    base = rows[0][1]["p99"]
    for name, r in rows:
        print(f"| {name} | {r['scans']} | {r['p50']:.2f} | {r['p99']:.2f} | {r['max']:.2f} | {r['late']} "
              f"| {r['p99'] / base:.2f} |")
    big = [a for a in audit if "big" in a["target"]]
    edits = sum(1 for a in audit if a["action"] == "recipe_activate") - 2
    print()
    print(f"edits of bracket-a activated: {edits}")
    print(f"audit: {len(audit)} rows; the big files: "
          + "; ".join(f"{a['action']}: {a['result'].replace(str(rdir) + '/', '')}" for a in big))
    print(f"PLC heartbeat faults: {int(ctl.fault_code == 101)}; controller state {ctl.sm.state.name}")
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
