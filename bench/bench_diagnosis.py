"""Sim-to-real diagnosis validation. Prints Markdown tables.

Runs ``cellctl diagnose validate`` three times: single hidden effects (the vocabulary plus
``none``, uniform), a main effect plus a smaller second one (combos), then effects from
outside the vocabulary only (``--out-of-vocabulary 1``: radial lens distortion, reach sag,
an offset bump halfway through, joint coupling), which should come back unexplained. The
truth is the independent forward model :mod:`cell.truth` (not :mod:`cell.effects`, which
the diagnosis fits with); campaign design: :class:`cell.sim.campaigns.Design` (seed 000
robot, 300 static poses over an hour of warm-up, 6 straight moves sampled at 2 ms, 70/30
fit/holdout). Scores: :mod:`cell.diagnosis.validate`. Run time per campaign is the
diagnosis only (campaign generation and the format round trip excluded), on this machine.

    .venv/bin/python bench/bench_diagnosis.py [--quick] [--trials N] [--seed S]
"""
from __future__ import annotations

import argparse
import platform
import time

from cell import progress
from cell.diagnosis import validate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="30 trials each instead of 200")
    ap.add_argument("--trials", type=int, help="trials per table (default 200, --quick 30)")
    ap.add_argument("--seed", type=int, default=0, help="validation seed (default 0)")
    ap.add_argument("--points", type=int, default=300, help="static poses per campaign")
    args = ap.parse_args()
    n = args.trials or (30 if args.quick else 200)
    print(f"Python {platform.python_version()} on {platform.machine()}, one process.\n")
    runs = ((False, 0.0, "single effect"), (True, 0.0, "main effect + smaller second"),
            (False, 1.0, "outside the vocabulary"))
    for combos, share, kind in runs:
        t0 = time.perf_counter()
        with progress.bar(kind, total=n, unit="campaign") as bar:
            ts = validate.run(n, args.seed, combos, args.points, outside_share=share,
                              progress=lambda i, t: bar.update(1))
        wall = time.perf_counter() - t0
        cmd = (f"cellctl diagnose validate --trials {n} --seed {args.seed} --points {args.points}"
               + (" --combos" if combos else "")
               + (f" --out-of-vocabulary {share:g}" if share else ""))
        print(validate.markdown(ts, f"{kind}: {n} campaigns (`{cmd}`)"))
        print(f"\n(wall time incl. campaign generation: {wall:.0f} s)\n")


if __name__ == "__main__":
    main()
