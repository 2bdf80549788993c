"""Check that every table of the README and of ``docs/`` is still what its command prints.

    .venv/bin/python bench/check_readme_tables.py            # every table (some commands take minutes)
    .venv/bin/python bench/check_readme_tables.py --fast     # only the commands under a minute
    .venv/bin/python bench/check_readme_tables.py --only cell vision
    .venv/bin/python bench/check_readme_tables.py --update   # re-print the tables that differ into README.md
    .venv/bin/python bench/check_readme_tables.py --list     # which README tables each command covers

Each table is printed by a command written above it (a heading, or "`COMMAND` printed:"),
in the README or in a page of ``docs/`` (a source's page is the first of ``docs/*.md``, then
the README, that writes its command). :data:`SOURCES` lists them: the command, where its
tables start (the command as written there, in backticks) and how many follow, and for each table which
columns are wall time (measured on whatever machine runs it, so never compared). Each
command is run from the repository root, its output's Markdown tables are matched to the
README's by their header row, and every cell not in a wall-time column must be equal. A
difference is printed as a unified diff of the table (wall-time cells shown as in the
README), so what changed is plain; exit 1.

* **Deterministic tables** (simulated time, counts, accuracy of seeded runs): every cell
  outside the wall-time columns is compared.
* **Wall-time tables** (benchmarks of speed, latency, memory): only the columns are
  compared, from a short run of the command (``probe``) where a full run would take long.

``--fast`` (what ``tests/system/test_readme_tables.py`` runs in the test suite) leaves out
the ``slow`` commands: those that take more than a minute (bench_cell, bench_calibration,
the storm) and the two diagnosis validations that repeat the plain one's code path with
other options (``--combos``, ``--out-of-vocabulary``, 25 s each), to keep the suite short;
without it they run too (about 6 minutes more). Two wall-time sources have no
short run and are checked only with ``--full``: the soak (60 minutes) and the load
harness's second phase (the whole test suite three times).
``--update`` rewrites only the README tables whose compared cells differ, with the cells
this run printed; wall-time cells keep the README's measured values, which the text around
the table quotes (re-measure those by hand, text and table together). The text around the
tables is left alone: read the diff and fix any sentence that quotes a changed figure.
When a command changes what it prints on purpose, re-run with ``--update`` and commit the
README with the change.
"""
from __future__ import annotations

import argparse
import difflib
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = REPO / "docs"
ALL = "*"          #: a table whose every value is wall time: only its columns are compared


@dataclass(frozen=True)
class Source:
    """One command and the README tables it prints.

    ``marker``: the command as the README writes it, in backticks, above its tables; the
    ``count`` tables after its first occurrence (after skipping ``skip``) are this source's.
    ``argv``: what to run (``cellctl`` and ``.venv/bin/python`` are this interpreter).
    ``wall``: per table, the columns that are wall time (:data:`ALL`: every one).
    ``probe``: a shorter argv printing the same columns, for wall-time-only sources.
    ``slow``: left out by ``--fast`` and the test suite (module doc).
    """

    name: str
    marker: str
    argv: tuple[str, ...]
    count: int
    wall: tuple = ()
    skip: int = 0
    probe: tuple[str, ...] | None = None
    slow: bool = False
    note: str = ""

    def wall_columns(self, k: int):
        return self.wall[k] if k < len(self.wall) else frozenset()

    @property
    def deterministic(self) -> bool:
        return any(self.wall_columns(k) != ALL for k in range(self.count))


def cols(*names: str) -> frozenset:
    return frozenset(names)


CELL_WALL = cols("wall s (measured)", "wall s (cellctl `wall_s`)", "sum of cycle `wall_s`",
                 "start-up s (measured - sum)", "of which before the cell (measured - `wall_s`)",
                 "simulated s / wall s", "parts / min (wall)", "CPU s (user+sys)", "load 1 min before")
VALIDATE_WALL = (cols(), cols("CPU s/campaign median (max)"), cols("median CPU s"), cols())
CHAIN_WALL = VALIDATE_WALL

SOURCES: tuple[Source, ...] = (
    Source("startup", ".venv/bin/python bench/bench_startup.py --runs 8",
           ("bench/bench_startup.py", "--runs", "8"), 1, (ALL,), probe=("bench/bench_startup.py", "--runs", "1")),
    Source("registers", "cellctl registers --format md", ("cellctl", "registers", "--format", "md"), 3),
    Source("storm", ".venv/bin/python bench/bench_link_storm.py --quick --rounds 3",
           ("bench/bench_link_storm.py", "--quick", "--rounds", "3"), 1, (ALL,),
           probe=("bench/bench_link_storm.py", "--quick", "--rounds", "1"), slow=True),
    Source("compensation", ".venv/bin/python bench/bench_compensation.py",
           ("bench/bench_compensation.py",), 2, (cols(), cols("ms per target"))),
    Source("full-plant", ".venv/bin/python bench/bench_full_plant.py", ("bench/bench_full_plant.py",), 1,
           (cols(),), slow=True),
    Source("fault-sweep", ".venv/bin/python bench/bench_fault_sweep.py", ("bench/bench_fault_sweep.py",), 1,
           (cols(),), slow=True),
    Source("line-delay", ".venv/bin/python bench/bench_line_delay.py", ("bench/bench_line_delay.py",), 1),
    Source("timelaws", ".venv/bin/python bench/bench_timelaws.py", ("bench/bench_timelaws.py",), 2,
           (cols("fit µs"), cols())),
    Source("plant", ".venv/bin/python bench/bench_plant.py", ("bench/bench_plant.py",), 1, (ALL,),
           probe=("bench/bench_plant.py", "--quick")),
    Source("modbus", ".venv/bin/python bench/bench_modbus.py", ("bench/bench_modbus.py",), 2, (ALL, ALL),
           probe=("bench/bench_modbus.py", "-n", "200")),
    Source("vision", ".venv/bin/python bench/bench_vision.py", ("bench/bench_vision.py",), 4,
           (cols(), ALL, cols(), ALL)),
    Source("can", ".venv/bin/python bench/bench_can.py", ("bench/bench_can.py",), 1),
    Source("cell", ".venv/bin/python bench/bench_cell.py", ("bench/bench_cell.py", "--skip-latency"), 4,
           (CELL_WALL,), slow=True, note="sections 1 and 2 (the same runs as the whole bench)"),
    Source("cell-latency", ".venv/bin/python bench/bench_cell.py", ("bench/bench_cell.py",), 2, (ALL, ALL),
           skip=4, probe=("bench/bench_cell.py", "--quick", "--runs", "1", "--cycles", "1", "--rounds", "1"),
           note="section 3"),
    Source("cycle-cpu", ".venv/bin/python bench/bench_cycle_cpu.py", ("bench/bench_cycle_cpu.py",), 4,
           (ALL, ALL, ALL, ALL), slow=True, probe=("bench/bench_cycle_cpu.py", "--quick")),
    Source("cpu-floor", ".venv/bin/python bench/bench_cpu_floor.py", ("bench/bench_cpu_floor.py",), 4,
           (ALL, ALL, ALL, ALL), slow=True, probe=("bench/bench_cpu_floor.py", "--parts", "1,2")),
    Source("load-main", ".venv/bin/python bench/load_harness.py", ("bench/load_harness.py",), 1, (ALL,),
           probe=("bench/load_harness.py", "--phase", "main", "--rounds", "1", "--copies", "1", "--hogs", "1"),
           note="phase 1 (its header names --cycles: 10/10)"),
    Source("load-tests", ".venv/bin/python bench/load_harness.py", ("bench/load_harness.py",), 1, (ALL,),
           skip=1, slow=True, note="phase 2: the whole test suite three times"),
    Source("scan", ".venv/bin/python bench/bench_scan.py", ("bench/bench_scan.py",), 1, (ALL,),
           probe=("bench/bench_scan.py", "--seconds", "1")),
    Source("opcua-scan", ".venv/bin/python bench/bench_opcua_scan.py", ("bench/bench_opcua_scan.py",), 1, (ALL,),
           probe=("bench/bench_opcua_scan.py", "--seconds", "1", "--rounds", "1")),
    Source("plant-scan", ".venv/bin/python bench/bench_plant_scan.py", ("bench/bench_plant_scan.py",), 1, (ALL,),
           probe=("bench/bench_plant_scan.py", "--seconds", "1", "--rounds", "1")),
    Source("soak", ".venv/bin/python bench/bench_soak.py --wall-min 60 --every-min 60",
           ("bench/bench_soak.py", "--wall-min", "60", "--every-min", "60"), 2, (ALL, ALL), slow=True),
    Source("thread-state", ".venv/bin/python bench/bench_thread_state.py", ("bench/bench_thread_state.py",),
           1, (ALL,), probe=("bench/bench_thread_state.py", "--calls", "20")),
    Source("calibration", ".venv/bin/python bench/bench_calibration.py", ("bench/bench_calibration.py",),
           4, (cols(), cols("wall s"), cols(), cols()), slow=True),
    Source("validate", "cellctl diagnose validate --trials 200 --seed 0 --points 300",
           ("cellctl", "diagnose", "validate", "--trials", "200", "--seed", "0", "--points", "300"),
           4, VALIDATE_WALL),
    Source("validate-combos", "cellctl diagnose validate --trials 200 --seed 0 --points 300 --combos",
           ("cellctl", "diagnose", "validate", "--trials", "200", "--seed", "0", "--points", "300", "--combos"),
           4, VALIDATE_WALL, slow=True),
    Source("validate-oov", "cellctl diagnose validate --trials 200 --seed 0 --points 300 --out-of-vocabulary 1",
           ("cellctl", "diagnose", "validate", "--trials", "200", "--seed", "0", "--points", "300",
            "--out-of-vocabulary", "1"), 4, VALIDATE_WALL, slow=True),
    Source("diagnose-cpu", ".venv/bin/python bench/bench_diagnose_cpu.py", ("bench/bench_diagnose_cpu.py",), 1,
           (ALL,), probe=("bench/bench_diagnose_cpu.py", "--runs", "1")),
    Source("chain", "cellctl diagnose validate --chain --trials 100 --seed 0",
           ("cellctl", "diagnose", "validate", "--chain", "--trials", "100", "--seed", "0"), 4, CHAIN_WALL),
    Source("chain-oov", "cellctl diagnose validate --chain --trials 60 --seed 0 --out-of-vocabulary 1",
           ("cellctl", "diagnose", "validate", "--chain", "--trials", "60", "--seed", "0",
            "--out-of-vocabulary", "1"), 4, CHAIN_WALL),
    Source("tiago", "cellctl diagnose tests/data/real/tiago-mocap-train",
           ("cellctl", "diagnose", "tests/data/real/tiago-mocap-train"), 1),
    Source("chain-speed", ".venv/bin/python bench/bench_chain_speed.py --repeats 3",
           ("bench/bench_chain_speed.py", "--repeats", "3"), 4, (ALL, ALL, ALL, ALL),
           probe=("bench/bench_chain_speed.py", "--quick", "--repeats", "1")),
)


#: README tables no command prints, by their header line: written by hand (commands, faults,
#: start-up messages, TLS rights), or compiled from the printed lines of several runs at
#: different commits (the storm's 16-round memory table)
HANDWRITTEN = ("| command | for | what it does |", "| code | meaning |",
               "| message says | cause | what to do |", "| right | lets the role change |",
               "| run | round high-water, MB (rounds 1–16) | slope, rounds 9–16 | verdict |",
               "| page | for | what it holds |",
               # docs/: guides, written by hand
               "| # | place | what goes there | written from |",
               "| field | what to give | example (`motor_cyclic_error`) |",
               "| module | what it decides |", "| | planar (`cell/diagnosis/`) | chain (`cell/diagnosis/chain/`) |",
               "| seed | what it is | where it lives here | how you meet it |",
               "| Attack | Defence | Code | Test |", "| What | Value | Where |", "| file | what |")


# ---------------------------------------------------------------------------- Markdown tables
@dataclass
class Table:
    start: int                       #: index of the header line in its text
    lines: list[str] = field(default_factory=list)

    @property
    def header(self) -> list[str]:
        return cells(self.lines[0])

    @property
    def rows(self) -> list[list[str]]:
        return [cells(line) for line in self.lines[2:]]


_RULE = re.compile(r"^\|(\s*:?-+:?\s*\|)+\s*$")


def cells(line: str) -> list[str]:
    """The cells of a table line (``\\|`` is a literal bar, as in the README)."""
    inner = line.strip()[1:-1] if line.strip().endswith("|") else line.strip()[1:]
    return [c.strip().replace("\x00", "\\|") for c in inner.replace("\\|", "\x00").split("|")]


def tables_in(lines: list[str]) -> list[Table]:
    """Every Markdown table (header, rule, rows) in ``lines``, in order."""
    out, i = [], 0
    while i < len(lines) - 1:
        if lines[i].lstrip().startswith("|") and _RULE.match(lines[i + 1].strip()):
            t = Table(i)
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                t.lines.append(lines[i].rstrip("\n"))
                i += 1
            out.append(t)
        else:
            i += 1
    return out


def pages() -> list[Path]:
    """The documents whose tables are checked: ``docs/*.md``, then the README."""
    return [*sorted(DOCS.glob("*.md")), README]


def read_pages() -> dict[Path, list[str]]:
    return {p: p.read_text().splitlines() for p in pages()}


def home(source: Source, texts: dict[Path, list[str]]) -> Path:
    """The page that writes ``source``'s command above its tables: the first (``docs/``,
    then the README) where the command is followed by as many tables (ValueError: none;
    a page that only names the command in passing is not its home)."""
    for path, lines in texts.items():
        try:
            readme_tables(source, lines)
        except ValueError:
            continue
        return path
    raise ValueError(f"no page (README.md, docs/*.md) writes `{source.marker}` above its "
                     f"{source.count} table(s)")


def shown(path: Path) -> str:
    return str(path.relative_to(REPO))


def uncovered(lines: list[str], sources=None) -> list[Table]:
    """Tables of a page (``lines``) that none of ``sources`` (default: every source, as the
    README's tables were checked) covers and that are not :data:`HANDWRITTEN`."""
    sources = SOURCES if sources is None else sources
    covered = {t.start for s in sources for t in readme_tables(s, lines)}
    return [t for t in tables_in(lines) if t.start not in covered and t.lines[0].strip() not in HANDWRITTEN]


def readme_tables(source: Source, lines: list[str]) -> list[Table]:
    """The README tables of ``source`` (see :class:`Source`); ValueError if not found."""
    needle = f"`{source.marker}`"
    at = next((i for i, line in enumerate(lines) if needle in line), None)
    if at is None:
        raise ValueError(f"the page no longer writes {needle} above a table")
    found = [t for t in tables_in(lines[at:])][source.skip:source.skip + source.count]
    for t in found:
        t.start += at
    if len(found) < source.count:
        raise ValueError(f"the page has {len(found)} tables after {needle}, expected {source.count}")
    return found


# ---------------------------------------------------------------------------- running and comparing
def command(argv: tuple[str, ...]) -> list[str]:
    if argv[0] == "cellctl":
        return [sys.executable, "-m", "cell.cli", *argv[1:]]
    return [sys.executable, *argv]


def run(argv: tuple[str, ...], timeout: float) -> tuple[list[str], float]:
    """The command's stdout lines and its wall seconds; RuntimeError if it fails."""
    env = dict(os.environ, CELL_PROGRESS="0", PYTHONPATH=str(REPO))
    t0 = time.monotonic()
    out = subprocess.run(command(argv), cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=timeout)
    if out.returncode != 0:
        raise RuntimeError(f"`{' '.join(argv)}` exited {out.returncode}:\n{out.stderr[-3000:]}")
    return out.stdout.splitlines(), time.monotonic() - t0


@dataclass
class Finding:
    source: str
    readme_line: int                 #: 1-based line of the README table's header
    problem: str                     #: "" when the table matches
    diff: str = ""
    new_lines: list[str] | None = None   #: the table this run printed (for --update)
    page: Path = README              #: the document the table is in


def row_line(values: list[str]) -> str:
    """A table line from cell values, as the README writes them (``| a | b |``, ``| |`` if empty)."""
    return "|" + "|".join(f" {v} " if v else " " for v in values) + "|"


def masked(table: Table, wall, like: Table | None = None) -> list[str]:
    """``table``'s lines with its wall-time cells replaced by ``like``'s (same row and
    column; blank if ``like`` has none), so that only compared cells can differ."""
    if not wall:
        return list(table.lines)
    head = table.header
    out = table.lines[:2]
    for r, row in enumerate(table.rows):
        other = like.rows[r] if like is not None and r < len(like.rows) else None
        new = [(other[c] if other is not None and c < len(other) else "") if (wall == ALL or name in wall)
               else v for c, (name, v) in enumerate(zip(head, row))]
        out.append(row_line(new))
    return out


def normal(line: str) -> list[str]:
    """A table line's cells as compared: a number under 1e-9 in size is floating-point noise
    (a residual printed as 5.7e-14 on one machine and 0.0e+00 on another) and equals 0."""
    out = []
    for c in cells(line):
        try:
            out.append("0" if abs(float(c)) < 1e-9 else c)
        except ValueError:
            out.append(c)
    return out


def compare(source: Source, printed: list[str], lines: list[str], full: bool) -> list[Finding]:
    """Findings for each README table of ``source`` against the command's output ``printed``
    (``full``: the command was run as the README says, not a probe)."""
    ours = readme_tables(source, lines)
    theirs = tables_in(printed)
    used: set[int] = set()
    findings = []
    for k, t in enumerate(ours):
        wall = source.wall_columns(k)
        match = next((j for j, o in enumerate(theirs) if j not in used and o.header == t.header), None)
        where = t.start + 1
        if match is None:
            near = [o for j, o in enumerate(theirs) if j not in used]
            diff = "\n".join(difflib.unified_diff(t.lines[:1], near[0].lines[:1] if near else [],
                                                  "README.md", "printed", lineterm=""))
            findings.append(Finding(source.name, where, "the command prints no table with these columns", diff))
            continue
        used.add(match)
        o = theirs[match]
        if wall == ALL or not full:
            findings.append(Finding(source.name, where, ""))
            continue
        a = [line.strip() for line in masked(t, wall, t)]
        b = [line.strip() for line in masked(o, wall, t)]
        if [normal(line) for line in a] == [normal(line) for line in b]:
            findings.append(Finding(source.name, where, ""))
            continue
        diff = "\n".join(difflib.unified_diff(a, b, f"README.md:{where}", f"`{' '.join(source.argv)}`",
                                              lineterm=""))
        findings.append(Finding(source.name, where, "figures differ", diff, masked(o, wall, t)))
    return findings


def check(source: Source, lines: list[str], use_probe: bool, timeout: float = 7200.0):
    """(findings, wall s, argv run) for ``source``."""
    argv = source.probe if (use_probe and source.probe) else source.argv
    full = argv == source.argv
    if not full and source.deterministic:
        raise ValueError(f"{source.name}: a deterministic source has no probe")
    printed, took = run(argv, timeout)
    return compare(source, printed, lines, full), took, argv


def update(findings: list[Finding]) -> int:
    """Write the changed tables into their pages (re-read now: others may have edited them)."""
    done = 0
    for path in {f.page for f in findings if f.new_lines}:
        lines = path.read_text().splitlines(keepends=True)
        plain = [line.rstrip("\n") for line in lines]
        for f in sorted((f for f in findings if f.new_lines and f.page == path), key=lambda f: -f.readme_line):
            source = next(s for s in SOURCES if s.name == f.source)
            table = next((t for t in readme_tables(source, plain) if t.start + 1 == f.readme_line), None)
            if table is None:
                print(f"{f.source}: {shown(path)} table at line {f.readme_line} moved; run again",
                      file=sys.stderr)
                continue
            lines[table.start:table.start + len(table.lines)] = [line + "\n" for line in f.new_lines]
            plain = [line.rstrip("\n") for line in lines]
            done += 1
        path.write_text("".join(lines))
    return done


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fast", action="store_true", help="leave out the commands that take over a minute")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="these sources only (see --list)")
    ap.add_argument("--full", action="store_true",
                    help="run wall-time sources as the README does, not their short probe; this adds "
                         "the soak (60 min) and the load harness's test phase (the suite 3 times)")
    ap.add_argument("--update", action="store_true", help="write the tables that differ into README.md")
    ap.add_argument("--list", action="store_true", help="list the sources and their README tables")
    args = ap.parse_args(argv)
    texts = read_pages()
    chosen = [s for s in SOURCES if (not args.only or s.name in args.only) and not (args.fast and s.slow)
              and (args.full or s.deterministic or s.probe)]
    if args.only and (unknown := set(args.only) - {s.name for s in SOURCES}):
        ap.error(f"unknown source(s) {sorted(unknown)}; known: {[s.name for s in SOURCES]}")
    if args.list:
        homes = {s.name: home(s, texts) for s in SOURCES}
        for path, lines in texts.items():
            for t in uncovered(lines, [s for s in SOURCES if homes[s.name] == path]):
                print(f"{shown(path)}:{t.start + 1}: no source prints this table: {t.lines[0][:90]}")
        for s in SOURCES:
            kind = "deterministic" if s.deterministic else "wall time: columns only"
            print(f"{s.name}: `{' '.join(s.argv)}` ({kind}{', slow' if s.slow else ''}"
                  f"{'; ' + s.note if s.note else ''})")
            for k, t in enumerate(readme_tables(s, texts[homes[s.name]])):
                wall = s.wall_columns(k)
                ign = " (every value is wall time)" if wall == ALL else \
                    f" (wall time, not compared: {', '.join(sorted(wall))})" if wall else ""
                print(f"    {shown(homes[s.name])}:{t.start + 1}: {t.lines[0][:90]}{ign}")
        return 0
    findings, bad = [], 0
    for s in chosen:
        try:
            page = home(s, texts)
            got, took, ran = check(s, texts[page], use_probe=not args.full)
        except (ValueError, RuntimeError, subprocess.TimeoutExpired) as exc:
            print(f"FAIL {s.name}: {exc}")
            bad += 1
            continue
        for f in got:
            f.page = page
            status = "ok  " if not f.problem else "DIFF"
            print(f"{status} {s.name}: {shown(page)}:{f.readme_line} ({took:.0f} s, `{' '.join(ran)}`)"
                  f"{': ' + f.problem if f.problem else ''}", flush=True)
            if f.problem:
                bad += 1
                print(f.diff, flush=True)
        findings += got
    if args.update:
        print(f"updated {update(findings)} table(s)")
    for s in SOURCES:
        if s not in chosen and (not args.only or s.name in args.only):
            why = "slow: run without --fast" if args.fast and s.slow else "needs --full (no short run)"
            print(f"not run: {s.name} ({why})")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
