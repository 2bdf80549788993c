"""How closely the paced simulated clock keeps to wall time, and how fast the pure one runs.

    .venv/bin/python bench/bench_sim_clock.py [--sim-s 1.0] [--repeats 3]

The tests (tests/cell/test_sim_clock.py) check what the clock guarantees whatever the host
does: a paced entry never runs before its wall time, a stall stretches simulated time by
all but ``max_lag_s`` of it. What they cannot check is a timing, so it is measured here:

1. Paced (``VirtualClock(pace=True)``, as ``cellctl serve --sim``): one task sleeps
   ``--sim-s`` of simulated time in steps of 0.5, 1, 5 and 10 ms. Simulated seconds per wall
   second (1.000: the clock keeps to wall time; below: it fell behind, each wake-up's
   lateness not caught up), and the wake-ups' lateness (wall time of the wake-up minus the
   wall time it was due at; median and max).
2. A stall: a 1 ms-step sleeper whose host stalls for 0.2 s of wall time half-way (a busy
   loop inside one step); how much of the stall simulated time lost (stretched) and how much
   it caught up (at most ``max_lag_s``, 0.02 s by default).
3. Pure (``pace=False``, as ``cellctl run --sim`` and the tests): two tasks taking turns
   (sleep 1 ms each); simulated seconds per wall second and hand-overs per wall second.

Every figure is a wall-time measurement on whatever machine runs this: nothing here is a
pass/fail test. Median over ``--repeats`` runs.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cell.sim.clock import VirtualClock  # noqa: E402

STEPS_MS = (0.5, 1.0, 5.0, 10.0)


def paced(step_s: float, sim_s: float) -> tuple[float, float, float]:
    """(simulated s per wall s, median lateness ms, max lateness ms) of one paced sleeper."""
    w0 = time.monotonic()                    # just before the clock reads its origin
    c = VirtualClock(pace=True)
    late = []
    with c.attach():
        for _ in range(round(sim_s / step_s)):
            c.sleep(step_s)
            late.append(time.monotonic() - (w0 + c.now()))
        ratio = c.now() / (time.monotonic() - w0)
    c.close()
    return ratio, 1e3 * statistics.median(late), 1e3 * max(late)


def stall(stall_s: float, sim_s: float) -> tuple[float, float, float]:
    """(wall s, simulated s, stretch s) of a 1 ms-step sleeper whose host stalls for
    ``stall_s`` half-way; stretch = wall − simulated: how much of the stall was kept."""
    c = VirtualClock(pace=True)
    with c.attach():
        w0, t0 = time.monotonic(), c.now()
        n = round(sim_s / 0.001)
        for i in range(n):
            if i == n // 2:
                end = time.monotonic() + stall_s
                while time.monotonic() < end:        # the host is busy elsewhere
                    pass
            c.sleep(0.001)
        wall, sim = time.monotonic() - w0, c.now() - t0
    c.close()
    return wall, sim, wall - sim


def pure(sim_s: float) -> tuple[float, float]:
    """(simulated s per wall s, hand-overs per wall s) of two tasks taking turns."""
    c = VirtualClock()

    def worker():
        for _ in range(round(sim_s / 0.001)):
            c.sleep(0.001)
    with c.attach():
        w0, t0, h0 = time.monotonic(), c.now(), c.handoffs
        tasks = [c.spawn(worker, f"w{i}") for i in range(2)]
        for t in tasks:
            t.join()
        wall = time.monotonic() - w0
        out = ((c.now() - t0) / wall, (c.handoffs - h0) / wall)
    c.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sim-s", type=float, default=1.0, help="simulated seconds per run (default 1)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per row (default 3)")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"Python {platform.python_version()}, {os.cpu_count()} CPUs, load average {load:.2f}; "
          f"median of {args.repeats} runs of {args.sim_s:g} simulated s\n")

    print("#### 1. Paced clock, one task sleeping in steps\n")
    print("| step ms | simulated s / wall s | wake-up lateness median ms | max ms |")
    print("|---:|---:|---:|---:|")
    for step in STEPS_MS:
        runs = [paced(step / 1e3, args.sim_s) for _ in range(args.repeats)]
        ratio, med, mx = (statistics.median(r[k] for r in runs) for k in range(3))
        print(f"| {step:g} | {ratio:.3f} | {med:.3f} | {mx:.3f} |")

    print("\n#### 2. Paced clock, a 0.2 s stall of the host half-way (1 ms steps, max_lag_s 0.02)\n")
    print("| stall s | wall s | simulated s | stretched s (kept of the stall) | caught up s |")
    print("|---:|---:|---:|---:|---:|")
    runs = [stall(0.2, args.sim_s) for _ in range(args.repeats)]
    wall, sim, stretch = (statistics.median(r[k] for r in runs) for k in range(3))
    print(f"| 0.2 | {wall:.3f} | {sim:.3f} | {stretch:.3f} | {0.2 - stretch:.3f} |")

    print("\n#### 3. Pure clock, two tasks taking turns (1 ms steps)\n")
    print("| simulated s / wall s | hand-overs / wall s |")
    print("|---:|---:|")
    runs = [pure(args.sim_s) for _ in range(args.repeats)]
    ratio, handoffs = (statistics.median(r[k] for r in runs) for k in range(2))
    print(f"| {ratio:.1f} | {handoffs:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
