"""CPU time of the planar diagnosis per campaign against the number of points. Prints a
Markdown table.

Two ways, in the same run, on the same campaigns:

* **before-style**: ``diagnose(..., method="exhaustive", jac="2-point")`` — every single
  candidate fitted in full (a cyclic error once per harmonic order), pairs of the best
  three, finite-difference Jacobians: the search as it was before the screening;
* **after**: the defaults — linearised screening of every single and pair, full fits (exact
  Jacobians) of the few the decision needs.

Campaigns: :func:`cell.sim.campaigns.make_campaign` (seed 000 robot, ``n`` static poses +
6 moves sampled at 2 ms), one per truth of :data:`TRUTHS`, seeded. CPU time is
``time.process_time`` around ``diagnose`` only (campaign drawing excluded), the median and
the largest over the truths; a warm-up diagnosis runs first. ``same`` counts the campaigns
where both ways name the same cause (effect and joints) and the same unexplained flag.

    .venv/bin/python bench/bench_diagnosis_speed.py [--points 100,300,1000,3000] [--seed S]
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

from cell import effects as fx
from cell import progress
from cell.diagnosis import diagnose
from cell.sim.campaigns import Design, make_campaign

TRUTHS = (
    ("none", []),
    ("backlash j2", [fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.04})]),
    ("cyclic j1 ×2", [fx.make_effect("cyclic_error", ("j1",), {
        "j1_cyclic_amp_deg": 0.03, "j1_cyclic_phase_deg": 40.0, "j1_cyclic_period_deg": 180.0})]),
    ("thermal", [fx.make_effect("thermal_drift", (), {"thermal_expansion_per_k": 2e-5})]),
    ("comm delay", [fx.make_effect("comm_delay", (), {"comm_delay_sigma_ms": 2.0})]),
    ("offset j1 + camera scale", [
        fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.1}),
        fx.make_effect("camera_scale", (), {"camera_scale_rel": 3e-4})]),
)
WAYS = (("before-style", {"method": "exhaustive", "jac": "2-point"}), ("after", {}))


def cpu(c, **kw) -> tuple[float, dict]:
    t0 = time.process_time()
    rep = diagnose(c, **kw).report
    return time.process_time() - t0, rep


def answer(rep: dict) -> tuple:
    return rep["cause"]["effect"], tuple(rep["cause"]["joints"]), rep["unexplained"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="100,300,1000,3000",
                    help="comma-separated numbers of static poses (default 100,300,1000,3000)")
    ap.add_argument("--seed", type=int, default=0, help="campaign seed offset (default 0)")
    args = ap.parse_args()
    sizes = [int(v) for v in args.points.split(",") if v.strip()]
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    print(f"Python {platform.python_version()} on {platform.machine()}, one process, "
          f"OPENBLAS_NUM_THREADS={threads}; {len(TRUTHS)} campaigns per size "
          f"({', '.join(n for n, _ in TRUTHS)}), 6 moves each.\n")
    cpu(make_campaign([], 1, Design(n_points=100)))            # warm-up (imports, caches)
    print("| points | rows | before-style CPU s median (max) | after CPU s median (max) "
          "| ratio of medians | same answer |")
    print("|---:|---:|---:|---:|---:|---:|")
    for n in progress.each(sizes, "sizes", "size"):
        times = {w: [] for w, _ in WAYS}
        same = 0
        rows = 0
        for k, (_, truth) in enumerate(TRUTHS):
            c = make_campaign(truth, args.seed + 1000 * n + k, Design(n_points=n))
            rows = len(c.points["sample"]) + len(c.paths["move"])
            answers = []
            for w, kw in WAYS:
                t, rep = cpu(c, **kw)
                times[w].append(t)
                answers.append(answer(rep))
            same += answers[0] == answers[1]
        b, a = times["before-style"], times["after"]
        mb, ma = statistics.median(b), statistics.median(a)
        print(f"| {n} | {rows} | {mb:.2f} ({max(b):.2f}) | {ma:.3f} ({max(a):.3f}) "
              f"| {mb / ma:.1f}× | {same}/{len(TRUTHS)} |", flush=True)


if __name__ == "__main__":
    main()
