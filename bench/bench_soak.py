"""Soak of the simulated cell: does it stay flat (memory, threads, file descriptors) over a
long production run? Prints a Markdown table, one row per simulated hour, and the growth
after warm-up.

    .venv/bin/python bench/bench_soak.py                  # a week of production or 30 wall minutes
    .venv/bin/python bench/bench_soak.py --wall-min 3     # a short look
    .venv/bin/python bench/bench_soak.py --sim-hours 2 --every-min 10

The cell is the one ``cellctl run --sim`` runs (``cell.app.Cell(devices="sim")``, jobs on,
built-in simulated config, recipe bracket-a, a fresh cycle log in a temporary directory),
driven by the simulated PLC (``cell.sim.plc.SimPlc``, a Modbus TCP client on loopback), all
on one simulated clock, as fast as the host allows (not paced to wall time). Before every
cycle the conveyor presents a new part (``feeder.present``), as ``run --sim`` does; the PLC
then runs the cycle by the handshake (``SimPlc.run_cycle``). A cycle that ends in a fault
(or a PLC time-out) is counted; the PLC pulses ``reset`` (``SimPlc.reset``) and production
goes on. If the reset is refused the run stops there and says so.

The run stops at ``--sim-hours`` of simulated time or ``--wall-min`` of wall time,
whichever comes first. Every ``--sample-min`` simulated minutes (checked between cycles)
it samples, at no simulated time and without touching the garbage collector:

* resident memory: ``VmRSS`` of ``/proc/self/status``, MB;
* Python heap: ``sys.getallocatedblocks()`` (blocks the interpreter holds), in thousands;
* C heap in use: glibc ``mallinfo2()``, bytes in allocated chunks plus malloc's own mmaps
  (``uordblks + hblkhd``), MB. Unlike RSS it does not count freed memory malloc keeps for
  reuse, so a leak in C code (SQLite, numpy, OpenCV, the interpreter's objects over 512 B)
  shows here as a steady rise; "n/a" where the C library has no ``mallinfo2``;
* SQLite's own memory: ``sqlite3_memory_used()`` of the library the ``sqlite3`` module
  loaded, MB (page caches and statements; bounded by the connections' ``cache_size``);
* threads: ``threading.active_count()``; open file descriptors: entries of ``/proc/self/fd``;
* the cycle log's size on disk (log + WAL), MB: it grows by design, one row per cycle.

A table row every ``--every-min`` simulated minutes (and one at the end). The summary gives
least-squares slopes over the samples after warm-up (default: the first simulated hour, or
the first 10 % of the run when that is shorter; ``--warmup-min`` to choose): RSS in MB per
simulated hour and per 1000 cycles (also over each half of those samples, to tell a slow
plateau from a steady leak), the heap in blocks per hour, threads and fds per hour.
A flat cell shows slopes near zero: RSS wanders by allocator noise (a few tenths of a MB
either way), threads and fds do not move at all.

At the end, after the cell has stopped, it calls ``malloc_trim(0)`` once and prints RSS
before and after: what the trim gives back was free memory malloc had kept, not a leak.

Every number is measured in this run; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import platform
import shlex
import shutil
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from cell import log  # noqa: E402
from cell.app import Cell  # noqa: E402
from cell.config import CellConfig, SimSection  # noqa: E402
from cell.sim.plc import SimPlc, SimPlcError  # noqa: E402

RECIPE = "bracket-a"           # what `cellctl run --sim` runs by default


@dataclass
class Sample:
    sim_s: float          #: simulated seconds since the cell started
    wall_s: float         #: wall seconds since the cell started
    cycles: int
    faults: int
    rss_mb: float
    kblocks: float
    c_heap_mb: float
    sqlite_mb: float
    threads: int
    fds: int
    log_mb: float


def rss_mb() -> float:
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                 "uordblks", "fordblks", "keepcost")]


def _libc():
    try:
        libc = ctypes.CDLL(None)
        libc.mallinfo2.restype = _Mallinfo2
        libc.malloc_trim.argtypes = [ctypes.c_size_t]
        return libc
    except (OSError, AttributeError):
        return None


def _libsqlite():
    try:
        import _sqlite3
        lib = ctypes.CDLL(_sqlite3.__file__)      # resolves to the sqlite library it links
        lib.sqlite3_memory_used.restype = ctypes.c_int64
        return lib
    except (OSError, AttributeError, ImportError):
        return None


LIBC, LIBSQLITE = _libc(), _libsqlite()


def c_heap_mb() -> float:
    if LIBC is None:
        return float("nan")
    m = LIBC.mallinfo2()
    return (m.uordblks + m.hblkhd) / 1e6


def sqlite_mb() -> float:
    return LIBSQLITE.sqlite3_memory_used() / 1e6 if LIBSQLITE is not None else float("nan")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def file_mb(db: Path) -> float:
    return sum(p.stat().st_size for p in (db, Path(f"{db}-wal")) if p.exists()) / 1e6


def slope(xs: list[float], ys: list[float]) -> float | None:
    """Least-squares slope of ys over xs (None with fewer than 3 points or no spread)."""
    n = len(xs)
    if n < 3:
        return None
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    if sxx == 0:
        return None
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx


def hmm(seconds: float) -> str:
    m = int(seconds // 60)
    return f"{m // 60}:{m % 60:02d}"


def machine() -> str:
    try:
        load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        load = "n/a"
    return (f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
            f"load average {load}")


def config(db: Path, seed: int | None) -> CellConfig:
    """The built-in simulated cell of ``cellctl run --sim``, its log at ``db``."""
    cfg = CellConfig(sim=SimSection()).with_paths()     # the project's plant and recipes, from any folder
    sim = cfg.sim if seed is None else cfg.sim.model_copy(update={"seed": seed})
    return cfg.model_copy(update={"sim": sim, "plc": cfg.plc.model_copy(update={"host": "127.0.0.1"}),
                                  "log": cfg.log.model_copy(update={"path": str(db)})})


def one_cycle(cell: Cell, plc: SimPlc, active, part_id: int) -> str | None:
    """Present a part, let the PLC run its cycle; None when done, else what went wrong."""
    cell.devices.feeder.present(part_id, active.recipe)
    try:
        res = plc.run_cycle(active.recipe.number, part_id, timeout_s=30.0)
    except SimPlcError as exc:
        return f"PLC: {str(exc).split(';')[0]}"
    if res["done"]:
        return None
    return f"fault {res['fault_code']}" if res["fault_code"] else "aborted"


def print_header() -> None:
    print("| sim time h:mm | cycles | faults | RSS MB | C heap in use MB | SQLite MB | heap kblocks "
          "| threads | fds | log MB | wall min |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|", flush=True)


def print_row(s: Sample, note: str = "") -> None:
    print(f"| {hmm(s.sim_s)}{note} | {s.cycles} | {s.faults} | {s.rss_mb:.1f} | {s.c_heap_mb:.2f} | "
          f"{s.sqlite_mb:.2f} | {s.kblocks:.1f} | "
          f"{s.threads} | {s.fds} | {s.log_mb:.1f} | {s.wall_s / 60:.1f} |", flush=True)


def summary(samples: list[Sample], warmup_min: float | None) -> None:
    span = samples[-1].sim_s - samples[0].sim_s
    warm = min(3600.0, 0.1 * span) if warmup_min is None else 60.0 * warmup_min
    after = [s for s in samples if s.sim_s - samples[0].sim_s >= warm]
    print()
    if len(after) < 3:
        print(f"Too short for a slope: {len(after)} samples after the {warm / 60:.0f} min warm-up.")
        return
    hours = [s.sim_s / 3600.0 for s in after]
    kcyc = [s.cycles / 1000.0 for s in after]

    def per_h(attr: str) -> float:
        return slope(hours, [getattr(s, attr) for s in after]) or 0.0

    rss_k = slope(kcyc, [s.rss_mb for s in after])
    first, last = after[0], after[-1]
    print(f"After warm-up ({hmm(first.sim_s)} to {hmm(last.sim_s)} simulated, {len(after)} samples, "
          f"cycles {first.cycles}..{last.cycles}; the first {warm / 60:.0f} simulated min excluded), "
          f"least-squares growth:")
    print()
    print(f"- RSS: {per_h('rss_mb'):+.3f} MB per simulated hour"
          + (f", {rss_k:+.3f} MB per 1000 cycles" if rss_k is not None else "")
          + f" ({first.rss_mb:.1f} → {last.rss_mb:.1f} MB)")
    halves = [after[:len(after) // 2], after[len(after) // 2:]]

    def per_k_halves(attr: str, unit: str = "MB") -> None:
        ks = [slope([s.cycles / 1000.0 for s in h], [getattr(s, attr) for s in h]) for h in halves]
        if all(k is not None for k in ks):
            print(f"  - first half {ks[0]:+.3f}, second half {ks[1]:+.3f} {unit} per 1000 cycles "
                  f"(a plateau shows as a second half near zero)")

    per_k_halves("rss_mb")
    for attr, what in (("c_heap_mb", "C heap in use"), ("sqlite_mb", "of it SQLite's own")):
        k = slope(kcyc, [getattr(s, attr) for s in after])
        if k is not None and k == k:
            print(f"- {what}: {k:+.3f} MB per 1000 cycles "
                  f"({getattr(first, attr):.2f} → {getattr(last, attr):.2f} MB)")
            per_k_halves(attr)
    print(f"- Python heap: {per_h('kblocks') * 1000:+.0f} blocks per simulated hour "
          f"({first.kblocks:.1f} → {last.kblocks:.1f} kblocks)")
    print(f"- threads: {per_h('threads'):+.3f} per simulated hour ({first.threads} → {last.threads})")
    print(f"- open fds: {per_h('fds'):+.3f} per simulated hour ({first.fds} → {last.fds})")
    print(f"- cycle log on disk: {per_h('log_mb'):+.2f} MB per simulated hour (by design)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wall-min", type=float, default=30.0, help="wall-time budget, minutes (default 30)")
    parser.add_argument("--sim-hours", type=float, default=168.0,
                        help="simulated production to run, hours (default 168: a week)")
    parser.add_argument("--every-min", type=float, default=60.0,
                        help="a table row every this many simulated minutes (default 60)")
    parser.add_argument("--sample-min", type=float, default=1.0,
                        help="sample every this many simulated minutes, for the slopes (default 1)")
    parser.add_argument("--warmup-min", type=float, default=None,
                        help="simulated minutes left out of the slopes (default: 60, or 10 %% of the run "
                             "if shorter)")
    parser.add_argument("--recipe", default=RECIPE, help=f"recipe name (default {RECIPE})")
    parser.add_argument("--seed", type=int, default=None, help="seed of the simulated cell (default the config's, 0)")
    parser.add_argument("--log-level", default="ERROR", help="structlog level of the cell (default ERROR)")
    args = parser.parse_args(argv)
    for name in ("wall_min", "sim_hours", "every_min", "sample_min"):
        if not getattr(args, name) > 0:
            parser.error(f"--{name.replace('_', '-')} must be > 0")
    log.configure("console", args.log_level)

    argv_shown = sys.argv[1:] if argv is None else argv
    print(f"## Soak of the simulated cell: recipe {args.recipe}, up to {args.sim_hours:g} simulated hours "
          f"or {args.wall_min:g} wall minutes\n")
    print(f"Machine: {machine()}.\n")
    print(f"Reproduce: `{shlex.join(['.venv/bin/python', 'bench/bench_soak.py', *argv_shown])}`\n", flush=True)

    tmp = Path(tempfile.mkdtemp(prefix="bench-soak-"))
    db = tmp / "cell.sqlite"
    wall0 = time.monotonic()
    samples: list[Sample] = []
    kinds: Counter[str] = Counter()
    stopped = ""
    cell = Cell(config(db, args.seed), devices="sim", plc_port=0)
    clock = cell.clock
    try:
        # this thread keeps the simulated time for the whole run (as `cellctl run --sim`)
        with clock.attach("soak"):
            port = cell.start()
            try:
                active = cell.recipes.active.get(args.recipe)
                if active is None:
                    print(f"recipe {args.recipe!r} is not active (known: {sorted(cell.recipes.active)})")
                    return 2
                plc = SimPlc("127.0.0.1", port, clock=clock)
                plc.start()
                t0 = clock.now()
                cycles = faults = 0

                def sample() -> Sample:
                    s = Sample(clock.now() - t0, time.monotonic() - wall0, cycles, faults, rss_mb(),
                               sys.getallocatedblocks() / 1000.0, c_heap_mb(), sqlite_mb(),
                               threading.active_count(), open_fds(), file_mb(db))
                    samples.append(s)
                    return s

                print(f"Cell started in {time.monotonic() - wall0:.1f} s wall; a row every "
                      f"{args.every_min:g} simulated min, samples every {args.sample_min:g}.\n")
                print_header()
                print_row(sample())
                next_sample, next_row = 60.0 * args.sample_min, 60.0 * args.every_min
                part_id = 1
                try:
                    while True:
                        why = one_cycle(cell, plc, active, part_id)
                        part_id += 1
                        cycles += 1
                        if why is not None:
                            faults += 1
                            kinds[why] += 1
                            try:
                                plc.reset(timeout_s=30.0)
                            except SimPlcError as exc:
                                stopped = f"the reset after cycle {cycles} ({why}) was refused: {exc}"
                        sim_s, wall_s = clock.now() - t0, time.monotonic() - wall0
                        if sim_s >= next_sample:
                            s = sample()
                            next_sample = (sim_s // (60.0 * args.sample_min) + 1) * 60.0 * args.sample_min
                            if sim_s >= next_row:
                                print_row(s)
                                next_row = (sim_s // (60.0 * args.every_min) + 1) * 60.0 * args.every_min
                        if stopped:
                            break
                        if sim_s >= 3600.0 * args.sim_hours:
                            stopped = f"{args.sim_hours:g} simulated hours done"
                            break
                        if wall_s >= 60.0 * args.wall_min:
                            stopped = f"wall-time budget of {args.wall_min:g} min used"
                            break
                except KeyboardInterrupt:
                    stopped = "interrupted"
                print_row(sample(), " (end)")
                plc.stop()
            finally:
                cell.stop()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    last = samples[-1]
    print(f"\nStopped: {stopped}. {last.cycles} cycles, {last.faults} faulted"
          f"{' (' + ', '.join(f'{k}: {n}' for k, n in kinds.most_common()) + ')' if kinds else ''}; "
          f"{last.sim_s / 3600:.2f} simulated hours in {last.wall_s / 60:.1f} wall minutes "
          f"({last.sim_s / max(last.wall_s, 1e-9):.1f}x real time).")
    summary(samples, args.warmup_min)
    if LIBC is not None:
        before = rss_mb()
        LIBC.malloc_trim(0)
        print(f"- after the run, `malloc_trim(0)`: RSS {before:.1f} → {rss_mb():.1f} MB "
              f"(memory malloc had kept free for reuse)")
    return 1 if stopped.startswith("the reset") else 0


if __name__ == "__main__":
    sys.exit(main())
