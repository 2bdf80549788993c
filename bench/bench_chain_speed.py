"""CPU time of the chain diagnosis (``cellctl diagnose`` on a serial-arm campaign) against
the number of poses and of joints, and on the real TIAGo set. Prints Markdown tables.

Campaigns: :func:`cell.truth.chain_campaign.make` (UR5 DH rows, then two more wrist rows;
4 markers at unknown places on the hand, a tracker at an unknown pose, σ 0.05 mm, a
joint-2 offset of 0.05° hidden), written to a temporary directory. CPU time is
``time.process_time`` around reading the campaign and ``diagnose_chain`` (start-up
excluded; the whole command's figure is in the README), the median of ``--repeats`` runs
after one warm-up. Growth is shown as the ratio to the smallest case of the same table,
measured in the same run, so a loaded machine moves both alike. The issue's aim: ≤ 1 s CPU
for 100 poses, 7 joints, 4 markers.

The last table runs the whole command (``python -m cell.cli diagnose DIR --json``, start-up
included) as a child process with one BLAS thread (our default, ``cell/__init__.py``) and
with two, in turn (A B A B …), CPU from the operating system's accounting of the child.

    .venv/bin/python bench/bench_chain_speed.py [--repeats 3] [--quick]
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
import time
from pathlib import Path

import cell  # noqa: F401  (one BLAS thread, as cellctl runs: see cell/__init__.py)
from cell import progress
from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import read_campaign
from cell.truth.chain_campaign import MARKER4, MARKERS, arm, make

REPO = Path(__file__).resolve().parents[1]
TIAGO = REPO / "tests" / "data" / "real" / "tiago-mocap-train"
AIM_S = 1.0


def cpu(directory: Path, repeats: int) -> tuple[float, dict]:
    """(median CPU s of read + diagnose over ``repeats`` runs after a warm-up, the report)."""
    rep = diagnose_chain(read_campaign(directory))
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        rep = diagnose_chain(read_campaign(directory))
        times.append(time.process_time() - t0)
    return statistics.median(times), rep


def campaign(tmp: Path, poses: int, joints: int) -> Path:
    return make(tmp / f"p{poses}-j{joints}", {"offset": {"j2": 0.05}}, poses=poses, seed=1,
                rows=arm(joints), markers=MARKERS + [MARKER4])


def table(title: str, key: str, cases, repeats: int, tmp: Path) -> None:
    print(f"### {title}\n")
    print(f"| {key} | points | CPU s (median) | ms per pose | × smallest case | cause named |")
    print("|---:|---:|---:|---:|---:|---|")
    base = None
    for value, (poses, joints) in progress.each(cases, title, "case"):
        d = campaign(tmp, poses, joints)
        s, rep = cpu(d, repeats)
        base = base or s
        named = f"{rep['cause']['effect']} {','.join(rep['cause']['joints'])}".strip()
        mark = " (aim ≤ 1 s: met)" if (poses, joints) == (100, 7) and s <= AIM_S else \
            " (aim ≤ 1 s: MISSED)" if (poses, joints) == (100, 7) else ""
        print(f"| {value} | {rep['gap']['n'] + rep['holdout']['n']} | {s:.3f}{mark} "
              f"| {1000 * s / poses:.1f} | {s / base:.2f} | {named} |")
    print()


def child_cpu(argv: list[str], env: dict) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, cwd=REPO, env=env, stdout=subprocess.DEVNULL, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def whole_command(directory: Path, repeats: int) -> None:
    argv = [sys.executable, "-m", "cell.cli", "diagnose", str(directory), "--json"]
    runs = {1: [], 2: []}
    for n in (1, 2):                                   # warm-up
        child_cpu(argv, os.environ | {"OPENBLAS_NUM_THREADS": str(n)})
    for _ in range(repeats):
        for n in (1, 2):
            runs[n].append(child_cpu(argv, os.environ | {"OPENBLAS_NUM_THREADS": str(n)}))
    one, two = statistics.median(runs[1]), statistics.median(runs[2])
    print("### Whole command, 100 poses, 7 joints, 4 markers (start-up included)\n")
    print("| BLAS threads | CPU s (median) | × one thread |\n|---:|---:|---:|")
    print(f"| 1 (default) | {one:.3f} | 1.00 |\n| 2 | {two:.3f} | {two / one:.2f} |\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per case (default 3)")
    ap.add_argument("--quick", action="store_true", help="fewer cases (for a smoke run)")
    args = ap.parse_args()
    print(f"{platform.python_implementation()} {platform.python_version()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.2f}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}; "
          f"median of {args.repeats} runs\n")
    poses = (25, 50, 100) if args.quick else (25, 50, 100, 200, 400)
    joints = (3, 5, 7) if args.quick else (3, 4, 5, 6, 7, 8)
    with tempfile.TemporaryDirectory(prefix="bench-chain-") as t:
        tmp = Path(t)
        table("Poses (7 joints, 4 markers)", "poses", [(p, (p, 7)) for p in poses], args.repeats, tmp)
        table("Joints (100 poses, 4 markers)", "joints", [(j, (100, j)) for j in joints],
              args.repeats, tmp)
        whole_command(campaign(tmp, 100, 7), args.repeats)
    if TIAGO.is_dir():
        s, rep = cpu(TIAGO, args.repeats)
        print("### Real data: PAL TIAGo (8 joints, 37 poses × 4 markers)\n")
        print(f"| CPU s (median) | ms per pose | cause named | unexplained |\n|---:|---:|---|---|\n"
              f"| {s:.3f} | {1000 * s / 37:.1f} | {rep['cause']['effect']} | {rep['unexplained']} |")


if __name__ == "__main__":
    main()
