"""CPU cost of the whole ``cellctl diagnose CAMPAIGN --json`` process, start-up included,
against bare Python and Python importing numpy, in the same run. Prints a Markdown table.

The issue's goal: ≤ 0.3 s CPU for a 300-point planar campaign and for a 100-pose ×
4-marker chain campaign. Campaigns, written to a temporary directory:

* **planar**: :func:`cell.sim.campaigns.make_campaign` (seed 000 robot, 300 static poses
  + 6 moves sampled at 2 ms), one per truth of :data:`PLANAR_TRUTHS`, seeded;
* **chain**: :func:`cell.truth.chain_campaign.make` (UR5 in DH, 100 poses, 4 markers at
  unknown places on the hand, a tracker at an unknown pose, σ 0.05 mm, a joint-2 offset of
  0.05° hidden).

Each campaign's command (``python -m cell.cli diagnose DIR --json``, what ``cellctl`` runs)
is a child process, in turn with ``python -c pass`` and ``python -c "import numpy"``
(A A' B C A A' B C …, after one warm-up round), so all see the same machine. CPU time is
the finished child's user + system time from the operating system
(``resource.getrusage(RUSAGE_CHILDREN)``). The children inherit
``OPENBLAS_NUM_THREADS=1`` (set by importing :mod:`cell`, as ``cellctl`` does), so the
numpy baseline loads numpy the way the command does. A case's median and max are over all
its runs (each planar campaign ``--runs`` times); "goal" compares the median of the
command with bytecode cached with 0.3 s.

Bytecode: an installed ``cellctl`` imports compiled bytecode (pip compiles it on install,
Python caches it in ``__pycache__``). A process started with ``PYTHONDONTWRITEBYTECODE=1``
(as some sandboxes and CI images set) and a checkout without ``__pycache__`` compiles
every module of the project from source at each start instead, about 0.1 s more for a
diagnose. So the command runs twice per round: **A**, bytecode cached (the children get
``PYTHONPYCACHEPREFIX`` in a temporary folder, written by the warm-up round, and
``PYTHONDONTWRITEBYTECODE`` unset; the baselines B and C run so too), and **A'**, in the
environment the benchmark was started in (the first line says whether it writes bytecode).

    .venv/bin/python bench/bench_diagnose_cpu.py [--runs 5]
"""
from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from cell import effects as fx
from cell import progress
from cell.sim.campaigns import Design, make_campaign
from cell.measurements import write_campaign
from cell.truth.chain_campaign import MARKER4, MARKERS, make

REPO = Path(__file__).resolve().parents[1]
GOAL_S = 0.3
PASS = [sys.executable, "-c", "pass"]
NUMPY = [sys.executable, "-c", "import numpy"]
PLANAR_TRUTHS = (
    ("none", []),
    ("offset j1", [fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.1})]),
    ("backlash j2", [fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.04})]),
)


def child_cpu(argv: list[str], env: dict | None = None) -> float:
    """User + system CPU seconds of one run of ``argv`` (its output thrown away), in
    ``env`` (default: this process's environment)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True,
                   env=env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def campaigns(tmp: Path) -> dict[str, list[Path]]:
    """{case: campaign directories} written below ``tmp``."""
    planar = []
    for k, (name, truth) in enumerate(PLANAR_TRUTHS):
        c = make_campaign(truth, 300_000 + k, Design(n_points=300))
        planar.append(write_campaign(c, tmp / f"planar-{k}"))
    chain = make(tmp / "chain", {"offset": {"j2": 0.05}}, poses=100, seed=1, markers=MARKERS + [MARKER4])
    return {f"planar, 300 points + 6 moves ({len(planar)} campaigns)": planar,
            "chain, 100 poses × 4 markers (UR5)": [chain]}


def cached_env(pycache: Path) -> dict:
    """This environment with bytecode written to and read from ``pycache``."""
    env = dict(os.environ, PYTHONPYCACHEPREFIX=str(pycache))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def rounds(dirs: list[Path], runs: int, cached: dict
           ) -> tuple[list[float], list[float], list[float], list[float]]:
    """(command CPU s with bytecode cached, command CPU s as run, pass CPU s, numpy CPU s)
    over ``runs`` rounds per campaign, in turn; ``cached`` the environment of the first."""
    argvs = [[sys.executable, "-m", "cell.cli", "diagnose", str(d), "--json"] for d in dirs]
    for argv in (argvs[0], PASS, NUMPY):                          # warm-up: not counted
        child_cpu(argv, cached), child_cpu(argv)
    a, a2, b, c = [], [], [], []
    for _ in range(runs):
        for argv in argvs:
            a.append(child_cpu(argv, cached))
            a2.append(child_cpu(argv))
            b.append(child_cpu(PASS, cached))
            c.append(child_cpu(NUMPY, cached))
    return a, a2, b, c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per campaign (default 5)")
    args = ap.parse_args()
    print(f"{platform.python_implementation()} {platform.python_version()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.2f}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
          f"PYTHONDONTWRITEBYTECODE={os.environ.get('PYTHONDONTWRITEBYTECODE')}; "
          f"{args.runs} runs per campaign\n")
    with tempfile.TemporaryDirectory() as tmp:
        cases = campaigns(Path(tmp))
        cached = cached_env(Path(tmp) / "pycache")
        print("| case | `cellctl diagnose DIR --json` CPU s median (max), bytecode cached "
              "| the same, environment as run | `python -c pass` CPU s median "
              "| `python -c \"import numpy\"` CPU s median | goal ≤ 0.3 s |")
        print("|---|---:|---:|---:|---:|---|")
        for name in progress.each(list(cases), "cases", "case"):
            a, a2, b, c = rounds(cases[name], args.runs, cached)
            m = statistics.median(a)
            print(f"| {name} | {m:.3f} ({max(a):.3f}) | {statistics.median(a2):.3f} ({max(a2):.3f}) "
                  f"| {statistics.median(b):.3f} | {statistics.median(c):.3f} "
                  f"| {'met' if m <= GOAL_S else 'not met'} |", flush=True)


if __name__ == "__main__":
    main()
