"""Faults over many parts: the default simulated cell, nominal and calibrated, several seeds.

Each run is what ``cellctl run --sim --cycles N --seed S`` does (the cell through its PLC
link, recipe bracket-a); "calibrated" runs the kinematic calibration of seed 001 on the
same simulated cell first (``cellctl calibrate kinematics --sim``) and loads it. Figures come
from each run's cycle log: faults, compensation moves per part, first-move and verified
error, and the parts a verification above tolerance sent back for an extra move
(``compensation.extra_moves``; each would have been a 402 without it).

    .venv/bin/python bench/bench_fault_sweep.py                      # 1000 parts, seeds 1-3
    .venv/bin/python bench/bench_fault_sweep.py --parts 100 --seeds 1

Runs go two at a time in separate processes. Every number is measured in this run.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from bench_calibration import DEFAULT, calibrate, config, run_cell  # noqa: E402
from cell import log  # noqa: E402
from cell.cycle.runner import VERIFY_NOTE  # noqa: E402
from cell.cyclelog import CycleLog, CycleStatus  # noqa: E402


def one_run(tmp: str, seed: int, calibrated: bool, parts: int) -> tuple:
    log.configure("console", "ERROR")
    tmp_path = Path(tmp)
    plant = dict(DEFAULT)                 # the plant file as shipped; --seed seeds the rest
    pf = tmp_path / f"plant-{seed}.yaml"
    pf.write_text(yaml.safe_dump(plant))
    label = "calibrated" if calibrated else "nominal"
    calf = tmp_path / f"robot-{seed}-{label}.json"
    db = tmp_path / f"cell-{seed}-{label}.sqlite"
    cfg = config(tmp_path, pf, calf, db)
    cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"seed": seed})})
    if calibrated:
        calibrate(config(tmp_path, pf, calf, tmp_path / f"cal-{seed}.sqlite"), [])
    r = run_cell(cfg, parts)
    cl = CycleLog(db, readonly=True)
    try:
        rows = cl.cycles(status=CycleStatus.DONE)
    finally:
        cl.close()
    extra = sum(any(str(s.get("note", "")).startswith(VERIFY_NOTE) for s in (rec.trace or [])) for rec in rows)
    return (seed, label, len(r["first"]), r["faults"], float(np.mean(r["moves"])), float(np.mean(r["first"])),
            float(np.mean(r["final"])), float(np.max(r["final"])), extra)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=1000, help="parts per run (default 1000)")
    ap.add_argument("--seeds", default="1,2,3", help="simulated cell seeds (default 1,2,3)")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s]
    tmp = tempfile.mkdtemp(prefix="bench-fault-sweep-")
    try:
        with ProcessPoolExecutor(max_workers=2) as pool:
            jobs = [pool.submit(one_run, tmp, s, cal, args.parts) for cal in (False, True) for s in seeds]
            rows = [j.result() for j in jobs]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"## Faults over {args.parts} parts of bracket-a per run, the default simulated cell\n")
    print(f"Reproduce: `.venv/bin/python bench/bench_fault_sweep.py --parts {args.parts} --seeds {args.seeds}`\n")
    print("| seed | model | parts done | faults | moves per part | first-move error mean mm | "
          "verified error mean mm | max mm | parts finished by an extra move |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for seed, label, done, faults, moves, first, final, worst, extra in rows:
        print(f"| {seed} | {label} | {done} | {faults} | {moves:.3f} | {first:.4f} | {final:.4f} | "
              f"{worst:.4f} | {extra} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
