"""CPU cost of starting ``cellctl``: ``cellctl --help`` and ``cellctl COMMAND --help`` against
bare Python, in the same run. Prints a Markdown table.

Each command runs as its own process, in turn with the baseline ``python -c pass`` (A B A B
…), so the ratio is taken pair by pair and stays meaningful on a shared, drifting machine.
CPU time is the finished child's user + system time from the operating system
(``resource.getrusage(RUSAGE_CHILDREN)``); the median and the spread over ``--runs`` pairs
are printed, after one warm-up pair that is not counted.

    .venv/bin/python bench/bench_startup.py [--runs 10]
"""
from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
from pathlib import Path

from cell import progress

REPO = Path(__file__).resolve().parents[1]
BASELINE = [sys.executable, "-c", "pass"]
COMMANDS = ([], ["diagnose"], ["calibrate", "kinematics"], ["run"], ["plan", "line"])


def child_cpu(argv: list[str]) -> float:
    """User + system CPU seconds of one run of ``argv`` (its output thrown away)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def paired(argv: list[str], runs: int) -> tuple[list[float], list[float]]:
    """(command CPU s, baseline CPU s) over ``runs`` alternating pairs, after a warm-up pair."""
    child_cpu(argv), child_cpu(BASELINE)
    a, b = [], []
    for _ in range(runs):
        a.append(child_cpu(argv))
        b.append(child_cpu(BASELINE))
    return a, b


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10, help="pairs per command (default 10)")
    args = ap.parse_args()
    print(f"{platform.python_implementation()} {platform.python_version()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.2f}; {args.runs} pairs per command\n")
    print("| command | CPU s median (min–max) | `python -c pass` CPU s median | ratio median (min–max) |")
    print("|---|---:|---:|---:|")
    for words in progress.each(COMMANDS, "commands", "command"):
        argv = [sys.executable, "-m", "cell.cli", *words, "--help"]
        a, b = paired(argv, args.runs)
        ratios = [x / y for x, y in zip(a, b) if y > 0]
        print(f"| `cellctl {' '.join(words + ['--help'])}` | {statistics.median(a):.3f} "
              f"({min(a):.3f}–{max(a):.3f}) | {statistics.median(b):.3f} "
              f"| {statistics.median(ratios):.2f} ({min(ratios):.2f}–{max(ratios):.2f}) |")


if __name__ == "__main__":
    main()
