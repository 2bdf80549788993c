"""Load harness: the main job and the test suite on a loaded machine. Prints Markdown tables.

The simulated cell runs on a simulated clock, so host load may change how long a run takes
but never what happens in it (``cellctl run --sim``: "the same seed gives the same cycles,
whatever the load; only fields named ``wall_s`` depend on the host"). Build machines are
shared and often loaded (2 cores); this harness loads this machine the way a shared one is
loaded and checks that claim from the outside, through the product's own command line.

Phase 1, main job under load. R rounds (``--rounds``, default 5); each round starts at once
H CPU hogs (``--hogs``, default 4; separate processes ``python -c "while True: pass"``)
and C concurrent copies (``--copies``, default 4) of the main job
``.venv/bin/cellctl run --sim --cycles N --json --db <tmp>/p1-rR-cK.sqlite [--seed S]``,
each with its own cycle log in a fresh temp dir (a shared SQLite log would couple the copies).
Per copy: exit code, parts done (cycles of the JSON output whose ``fault`` is null), wall
time, simulated time (``sim_s``). The hogs are killed when every copy has ended; their CPU
seconds (``/proc/<pid>/stat``) and the 1-min load average at the end of the round show how
loaded the machine was. A round passes when every copy exits 0 with N of N parts done.
Determinism: every key named ``wall_s`` is stripped at any depth from each copy's
``cycles`` list, which is then compared with the first copy of round 1; the report says
whether all copies of all rounds printed identical per-cycle results (and whether ``sim_s``
agreed). Phase 1 fails if they do not, even when every round passed.

Phase 2, the test suite under load. T runs (``--test-runs``, default 3) of the whole suite,
``.venv/bin/python -m pytest -q -p no:cacheprovider [--pytest-args ...]``, while K copies
(``--test-copies``, default 2) of the main job run beside it continuously: a copy that ends
is recorded and replaced at once by a new one with its own ``--db``; copies still running
when pytest ends are killed and counted as "cut off", not as completed. Per run: pytest exit
code, passed / failed / skipped / errors from pytest's summary line, wall time, main-job
copies completed and how many of them exited 0 with N of N parts. A run passes when pytest
exits 0 (5, "no tests collected", is a failure); the copies are reported, not judged.

Processes: every child runs with the repo root as cwd, in its own session (so its own
process group), with stdout and stderr in files of the temp dir (no pipes to fill), and is
killed with its whole group (SIGTERM, then SIGKILL) when it exceeds ``--timeout`` (reported
as a failure), when the harness ends, on Ctrl-C, SIGTERM, SIGHUP and on exceptions; on Linux
each child also gets SIGKILL if the harness dies without cleaning up (PR_SET_PDEATHSIG).
Standard library only. Exit code 0 only if every round and every test run passed
(1 otherwise, 2 on bad options or a missing .venv, 130 when interrupted).

    .venv/bin/python bench/load_harness.py                          # both phases, defaults
    .venv/bin/python bench/load_harness.py --phase main --rounds 1 --copies 2 --hogs 2 --cycles 2
    .venv/bin/python bench/load_harness.py --phase tests --test-runs 1 --test-copies 1 \\
        --pytest-args "-k test_kinematics"
"""
from __future__ import annotations

import argparse
import atexit
import json
import os
import platform
import re
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CELLCTL = REPO / ".venv" / "bin" / "cellctl"
VENV_PY = REPO / ".venv" / "bin" / "python"
HOG_CODE = "while True: pass"
POLL_S = 0.05
TERM_GRACE_S = 3.0
TAIL_LINES = 20
MAX_FAILURE_DUMPS = 4
PYTEST_COUNTS = ("passed", "failed", "skipped", "errors", "xfailed", "xpassed", "deselected")

# ---------------------------------------------------------------------------- children
_LIVE: dict[int, "Child"] = {}          # pid -> child still to be reaped
_STATE = {"spawning": False, "pending": None, "cleaning": False}


def _pdeathsig():
    """A preexec_fn that asks Linux to SIGKILL the child if the harness dies, or None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        prctl = libc.prctl
    except (OSError, AttributeError):
        return None

    def set_it() -> None:
        prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    return set_it


_PREEXEC = _pdeathsig()


class Child:
    """One child process in its own session / process group, output in files."""

    def __init__(self, label: str, argv: list[str], out: Path, err: Path, timeout_s: float):
        self.label, self.argv, self.out_path, self.err_path = label, argv, out, err
        self._out, self._err = open(out, "wb"), open(err, "wb")
        self.t0 = time.monotonic()
        self.deadline = self.t0 + timeout_s
        self.rc: int | None = None
        self.wall_s: float | None = None
        self.timed_out = False
        self.killed = False                     # ended by us (timeout, cut off, hog, clean-up)
        self.reaped = False
        try:
            self.popen = subprocess.Popen(argv, cwd=REPO, stdin=subprocess.DEVNULL,
                                          stdout=self._out, stderr=self._err,
                                          start_new_session=True, preexec_fn=_PREEXEC)
        except BaseException:
            self._close()
            raise
        self.pid = self.popen.pid

    # -- state
    def _exited_unreaped(self) -> bool:
        """Has the child exited? Leaves it a zombie, so its pid / process group id cannot
        be reused before we have signalled the group."""
        try:
            return os.waitid(os.P_PID, self.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
        except (ChildProcessError, AttributeError, OSError):
            return self.popen.poll() is not None

    def check(self) -> bool:
        """True once the child has ended (reaped); kills it on its deadline."""
        if self.reaped:
            return True
        if self._exited_unreaped():
            self.wall_s = time.monotonic() - self.t0
            self._signal_group(signal.SIGKILL)   # stragglers left in its group
            self._reap(None)
            return True
        if time.monotonic() > self.deadline:
            self.timed_out = True
            self.kill()
            return True
        return False

    def cpu_s(self) -> float | None:
        """utime + stime of the (running or zombie) child from /proc, seconds."""
        try:
            raw = Path(f"/proc/{self.pid}/stat").read_text()
            f = raw[raw.rindex(")") + 2:].split()
            return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return None

    # -- ending
    def _signal_group(self, sig: int) -> None:
        if self.reaped:
            return
        try:
            os.killpg(self.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def _reap(self, timeout: float | None) -> bool:
        try:
            self.rc = self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return False
        if self.wall_s is None:
            self.wall_s = time.monotonic() - self.t0
        self.reaped = True
        _LIVE.pop(self.pid, None)
        self._close()
        return True

    def send_term(self) -> None:
        if not self.reaped:
            self.killed = True
            if self.wall_s is None:
                self.wall_s = time.monotonic() - self.t0
            self._signal_group(signal.SIGTERM)

    def finish_kill(self, grace_s: float) -> None:
        """After :meth:`send_term`: wait up to ``grace_s``, then SIGKILL the group."""
        if self.reaped:
            return
        self._wait_exit(grace_s)
        self._signal_group(signal.SIGKILL)       # the leader if still alive, and stragglers
        if not self._reap(10.0):
            print(f"load_harness: {self.label} (pid {self.pid}) did not die after SIGKILL",
                  file=sys.stderr)

    def _wait_exit(self, grace_s: float) -> bool:
        end = time.monotonic() + grace_s
        while time.monotonic() < end:
            if self._exited_unreaped():
                return True
            time.sleep(0.02)
        return False

    def kill(self, grace_s: float = TERM_GRACE_S) -> None:
        self.send_term()
        self.finish_kill(grace_s)

    def _close(self) -> None:
        for f in (self._out, self._err):
            try:
                f.close()
            except OSError:
                pass

    # -- output
    def stdout(self) -> str:
        return self.out_path.read_text(encoding="utf-8", errors="replace")

    def stderr(self) -> str:
        return self.err_path.read_text(encoding="utf-8", errors="replace")


def spawn(label: str, argv: list[str], tmp: Path, timeout_s: float) -> Child:
    """Start a child and register it for clean-up; a stop signal that arrives meanwhile is
    acted on only once the child is registered (so it cannot escape the clean-up)."""
    _STATE["spawning"] = True
    try:
        child = Child(label, argv, tmp / f"{label}.out", tmp / f"{label}.err", timeout_s)
        _LIVE[child.pid] = child
    finally:
        _STATE["spawning"] = False
    pending = _STATE["pending"]
    if pending is not None:
        _STATE["pending"] = None
        _raise_for(pending)
    return child


def kill_all() -> None:
    """Every child still alive: SIGTERM to each group, a common grace period, SIGKILL."""
    _STATE["cleaning"] = True
    try:
        live = list(_LIVE.values())
        for c in live:
            c.send_term()
        end = time.monotonic() + TERM_GRACE_S
        for c in live:
            c.finish_kill(max(0.0, end - time.monotonic()))
    finally:
        _STATE["cleaning"] = False


def _raise_for(signum: int) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise SystemExit(128 + signum)


def _on_signal(signum, _frame) -> None:
    if _STATE["cleaning"]:
        return                                  # finish killing the children first
    if _STATE["spawning"]:
        _STATE["pending"] = signum
        return
    _raise_for(signum)


def wait_all(children: list[Child]) -> None:
    while not all(c.check() for c in children):
        time.sleep(POLL_S)


# ---------------------------------------------------------------------------- main job
def main_job_argv(db: Path, cycles: int, seed: int | None) -> list[str]:
    argv = [str(CELLCTL), "run", "--sim", "--cycles", str(cycles), "--json", "--db", str(db)]
    return argv + (["--seed", str(seed)] if seed is not None else [])


def strip_wall(x):
    """``x`` without any key named ``wall_s``, at any depth."""
    if isinstance(x, dict):
        return {k: strip_wall(v) for k, v in x.items() if k != "wall_s"}
    if isinstance(x, list):
        return [strip_wall(v) for v in x]
    return x


class Copy:
    """The outcome of one main-job copy."""

    def __init__(self, child: Child, cycles: int):
        self.child, self.cycles = child, cycles
        self.doc = None
        self.key: str | None = None            # canonical per-cycle results, wall_s stripped
        self.sim_s = None
        self.parts_done: int | None = None
        self.n_rows: int | None = None
        try:
            doc = json.loads(child.stdout())
            rows = doc["cycles"]
            self.parts_done = sum(1 for r in rows if isinstance(r, dict) and "fault" in r
                                  and r["fault"] is None)
            self.n_rows = len(rows)
            self.sim_s = doc.get("sim_s")
            self.key = json.dumps(strip_wall(rows), sort_keys=True)
            self.doc = doc
        except (OSError, ValueError, KeyError, TypeError):
            pass

    @property
    def ok(self) -> bool:
        return (self.child.rc == 0 and not self.child.timed_out and not self.child.killed
                and self.parts_done == self.cycles and self.n_rows == self.cycles)

    def status(self) -> str:
        c = self.child
        if c.timed_out:
            return "timeout"
        if c.killed:
            return "killed"
        return str(c.rc)

    def parts(self) -> str:
        return "–" if self.parts_done is None else f"{self.parts_done}/{self.cycles}"


class Reference:
    """The first per-cycle result seen; every later copy is compared with it."""

    def __init__(self):
        self.key: str | None = None
        self.sim_s = None
        self.label = ""
        self.differ: list[str] = []            # labels of copies that differ or printed nothing
        self.sim_differ: list[str] = []
        self.compared = 0

    def same(self, cp: Copy) -> str:
        self.compared += 1
        if cp.key is None:
            self.differ.append(cp.child.label)
            return "– (no JSON)"
        if self.key is None:
            self.key, self.sim_s, self.label = cp.key, cp.sim_s, cp.child.label
            return "reference"
        if cp.sim_s != self.sim_s:
            self.sim_differ.append(cp.child.label)
        if cp.key == self.key:
            return "yes"
        self.differ.append(cp.child.label)
        return "**no**"


# ---------------------------------------------------------------------------- phase 1
def phase_main(args, tmp: Path, ref: Reference, failures: list) -> bool:
    ncpu = os.cpu_count()
    print(f"### Phase 1: main job under load, {args.rounds} round(s) of {args.copies} concurrent "
          f"copies + {args.hogs} CPU hog(s) on {ncpu} CPUs\n")
    print(f"Copy: `{_shown(main_job_argv(Path(_DB), args.cycles, args.seed), '<tmp>/p1-rR-cK.sqlite')}`; "
          f"hog: `{shlex.join([_rel_py(), '-c', HOG_CODE])}`. "
          f"Same: per-cycle results (`wall_s` stripped) equal to the reference copy's.\n", flush=True)
    rounds = []
    for r in range(1, args.rounds + 1):
        print(f"load_harness: phase 1 round {r}/{args.rounds} ...", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        # no deadline of their own: they live as long as the round, which the copies bound
        hogs = [spawn(f"p1-r{r}-hog{h}", [sys.executable, "-c", HOG_CODE], tmp, float("inf"))
                for h in range(1, args.hogs + 1)]
        kids = [spawn(f"p1-r{r}-c{k}", main_job_argv(tmp / f"p1-r{r}-c{k}.sqlite", args.cycles, args.seed),
                      tmp, args.timeout) for k in range(1, args.copies + 1)]
        wait_all(kids)
        wall = time.monotonic() - t0
        hog_cpu = [h.cpu_s() for h in hogs]
        hogs_alive = sum(1 for h in hogs if not h.check())
        for h in hogs:
            h.kill()
        load1 = os.getloadavg()[0]
        copies = [Copy(k, args.cycles) for k in kids]
        rounds.append({"copies": copies, "wall": wall, "load1": load1, "hogs_alive": hogs_alive,
                       "hog_cpu": None if None in hog_cpu else sum(hog_cpu)})
        passed = all(c.ok for c in copies)
        print(f"load_harness: phase 1 round {r}: {'pass' if passed else 'FAIL'} "
              f"({sum(c.ok for c in copies)}/{len(copies)} copies ok, {wall:.1f} s)",
              file=sys.stderr, flush=True)

    print("| round | copy | exit | parts done | wall (s) | sim (s) | same |")
    print("|---:|---:|---:|---:|---:|---:|---|")
    for r, rd in enumerate(rounds, 1):
        for k, cp in enumerate(rd["copies"], 1):
            same = ref.same(cp)
            if not cp.ok:
                failures.append(cp.child)
            sim = f"{cp.sim_s:.3f}" if isinstance(cp.sim_s, (int, float)) else "–"
            exit_s = cp.status() if cp.ok else f"**{cp.status()}**"
            parts = cp.parts() if cp.ok else f"**{cp.parts()}**"
            print(f"| {r} | {k} | {exit_s} | {parts} | {cp.child.wall_s:.1f} | {sim} | {same} |")

    print(f"\n| round | copies ok ({args.cycles}/{args.cycles}, exit 0) | copy wall min / median / max (s) "
          f"| round wall (s) | hog CPU (s) | hogs alive at end | load avg 1 min at end | result |")
    print("|---:|---:|---:|---:|---:|---:|---:|---|")
    all_ok = True
    for r, rd in enumerate(rounds, 1):
        cps = rd["copies"]
        ok = all(c.ok for c in cps)
        all_ok &= ok
        ws = [c.child.wall_s for c in cps]
        hog = "n/a" if rd["hog_cpu"] is None else f"{rd['hog_cpu']:.1f}"
        print(f"| {r} | {sum(c.ok for c in cps)}/{len(cps)} | {min(ws):.1f} / {statistics.median(ws):.1f} / "
              f"{max(ws):.1f} | {rd['wall']:.1f} | {hog} | {rd['hogs_alive']}/{args.hogs} | "
              f"{rd['load1']:.2f} | {'pass' if ok else '**FAIL**'} |")
    n = sum(len(rd["copies"]) for rd in rounds)
    identical = not ref.differ and ref.key is not None
    all_ok &= identical                      # the same seed must give the same cycles, whatever the load
    print(f"\nIdentical per-cycle results (`wall_s` stripped) across all {n} copies of all rounds: "
          f"{'**yes**' if identical else '**NO**'}"
          + ("" if identical else f" (differ or printed no JSON: {', '.join(ref.differ) or 'all'})")
          + (f"; `sim_s` equal in all: {'yes' if not ref.sim_differ else 'no (' + ', '.join(ref.sim_differ) + ')'}"
             if ref.key is not None else "")
          + f". Phase 1: **{'pass' if all_ok else 'FAIL'}**.\n", flush=True)
    return all_ok


# ---------------------------------------------------------------------------- phase 2
_COUNT_RE = re.compile(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed|deselected|warnings?)\b")
_SUMMARY_RE = re.compile(r"^(Interrupted: )?\d+ (passed|failed|skipped|errors?|xfailed|xpassed|deselected"
                         r"|warnings?)\b")


def pytest_summary(text: str) -> tuple[dict[str, int], str]:
    """Counts from pytest's summary line ("3 passed, 1 skipped in 2.1s", or "Interrupted:
    2 errors during collection"), and the line; only the last non-empty line is taken, so
    that nothing a test printed is mistaken for it. ({}, "") if there is none: at -qq (the
    project's addopts -q plus our -q) pytest prints no stats line."""
    lines = [ln.strip(" =!") for ln in text.splitlines() if ln.strip(" =!")]
    if not lines or not _SUMMARY_RE.match(lines[-1]):
        return {}, ""
    counts: dict[str, int] = {}
    for n, word in _COUNT_RE.findall(lines[-1]):
        word = {"error": "errors", "warning": "warnings"}.get(word, word)
        counts[word] = counts.get(word, 0) + int(n)
    return counts, lines[-1]


def junit_counts(path: Path) -> dict[str, int]:
    """passed / failed / skipped / errors from pytest's JUnit XML ({} if unreadable)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return {}
    suites = [root] if root.tag == "testsuite" else list(root.iter("testsuite"))
    tot = {k: sum(int(s.get(k, 0)) for s in suites) for k in ("tests", "failures", "errors", "skipped")}
    return {"passed": tot["tests"] - tot["failures"] - tot["errors"] - tot["skipped"],
            "failed": tot["failures"], "skipped": tot["skipped"], "errors": tot["errors"]}


def phase_tests(args, tmp: Path, ref: Reference, failures: list) -> bool:
    def pytest_argv(junit: str) -> list[str]:
        return [str(VENV_PY), "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={junit}",
                *args.pytest_extra]
    print(f"### Phase 2: the test suite under load, {args.test_runs} run(s) beside {args.test_copies} "
          f"continuously restarted main-job copies\n")
    print(f"Suite: `{_shown(pytest_argv(_DB), '<tmp>/p2-tT-junit.xml')}` (the JUnit XML only "
          f"for the counts when pytest prints no summary line); copy: "
          f"`{_shown(main_job_argv(Path(_DB), args.cycles, args.seed), '<tmp>/p2-tT-N.sqlite')}`, "
          f"restarted as soon as it ends; copies still running when pytest ends are cut off "
          f"(killed, not counted).\n", flush=True)
    runs = []
    for t in range(1, args.test_runs + 1):
        print(f"load_harness: phase 2 run {t}/{args.test_runs} ...", file=sys.stderr, flush=True)
        seq = [0]

        def new_copy() -> Child:
            seq[0] += 1
            label = f"p2-t{t}-{seq[0]}"
            return spawn(label, main_job_argv(tmp / f"{label}.sqlite", args.cycles, args.seed),
                         tmp, args.timeout)

        slots = [new_copy() for _ in range(args.test_copies)]
        junit = tmp / f"p2-t{t}-junit.xml"
        suite = spawn(f"p2-t{t}-pytest", pytest_argv(str(junit)), tmp, args.timeout)
        done: list[Copy] = []
        while not suite.check():
            for i, c in enumerate(slots):
                if c.check():
                    done.append(Copy(c, args.cycles))
                    slots[i] = new_copy()
            time.sleep(POLL_S)
        for c in slots:                          # may have ended since the last look
            if c.check():
                done.append(Copy(c, args.cycles))
        cut = [c for c in slots if not c.reaped]
        for c in cut:
            c.send_term()
        for c in cut:
            c.finish_kill(TERM_GRACE_S)
        counts, line = pytest_summary(suite.stdout())
        source = "summary line"
        if not counts:
            counts, source = junit_counts(junit), "JUnit XML"
        ok = suite.rc == 0 and not suite.timed_out
        runs.append({"suite": suite, "counts": counts, "source": source, "line": line, "copies": done,
                     "cut": len(cut), "ok": ok, "load1": os.getloadavg()[0]})
        if not ok:
            failures.append(suite)
        print(f"load_harness: phase 2 run {t}: {'pass' if ok else 'FAIL'} (pytest exit "
              f"{'timeout' if suite.timed_out else suite.rc}, {suite.wall_s:.1f} s)",
              file=sys.stderr, flush=True)

    print(f"| run | pytest exit | passed | failed | skipped | errors | wall (s) | copies completed "
          f"| of which {args.cycles}/{args.cycles}, exit 0 | copies cut off | copy wall median (s) "
          f"| copies same as reference | load avg 1 min at end | result |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    all_ok = True
    for t, run in enumerate(runs, 1):
        s, cnt, cps = run["suite"], run["counts"], run["copies"]
        all_ok &= run["ok"]
        for cp in cps:
            if not cp.ok:
                failures.append(cp.child)
        same = [ref.same(cp) for cp in cps]
        n_same = sum(1 for x in same if x in ("yes", "reference"))
        rc = "timeout" if s.timed_out else str(s.rc)
        if s.rc == 5 and not s.timed_out:
            rc += " (no tests)"
        c = (lambda k: str(cnt.get(k, 0)) if cnt else "?")
        med = f"{statistics.median(cp.child.wall_s for cp in cps):.1f}" if cps else "–"
        n_ok = sum(cp.ok for cp in cps)
        print(f"| {t} | {rc if run['ok'] else f'**{rc}**'} | {c('passed')} | {c('failed')} | {c('skipped')} "
              f"| {c('errors')} | {s.wall_s:.1f} | {len(cps)} | {n_ok if n_ok == len(cps) else f'**{n_ok}**'} "
              f"| {run['cut']} | {med} | {n_same}/{len(cps)} | {run['load1']:.2f} "
              f"| {'pass' if run['ok'] else '**FAIL**'} |")
    print()
    for t, run in enumerate(runs, 1):
        line = f"`{run['line']}`" if run["line"] else "none (at -qq pytest prints no stats line)"
        src = run["source"] if run["counts"] else "nowhere (no summary line, no JUnit XML)"
        print(f"Run {t}: pytest summary line {line}; counts from {src}.")
    print(f"\nPhase 2: **{'pass' if all_ok else 'FAIL'}**.\n", flush=True)
    return all_ok


# ---------------------------------------------------------------------------- report helpers
def _rel(argv: list[str]) -> list[str]:
    out = []
    for a in argv:
        try:
            out.append(str(Path(a).relative_to(REPO)) if os.path.isabs(a) else a)
        except ValueError:
            out.append(a)
    return out


_DB = "/DB-PLACEHOLDER"


def _shown(argv: list[str], db: str) -> str:
    """A command line for the report, repo paths relative, the temp db as a placeholder."""
    return shlex.join(_rel(argv)).replace(_DB, db)


def _rel_py() -> str:
    return _rel([sys.executable])[0]


def _tail(text: str, n: int) -> str:
    lines = text.rstrip("\n").splitlines()
    return "\n".join(lines[-n:]) if lines else "(empty)"


def dump_failures(failures: list[Child]) -> None:
    if not failures:
        return
    print(f"### Failure output ({min(len(failures), MAX_FAILURE_DUMPS)} of {len(failures)} failed "
          f"processes, last {TAIL_LINES} lines)\n")
    for c in failures[:MAX_FAILURE_DUMPS]:
        why = "timeout" if c.timed_out else ("killed" if c.killed else f"exit {c.rc}")
        print(f"`{c.label}` ({why}, {c.wall_s:.1f} s): `{shlex.join(_rel(c.argv))}`\n")
        is_pytest = c.label.endswith("-pytest")
        for name, text in (("stdout", c.stdout()) if is_pytest else ("stderr", c.stderr()),
                           ("stderr", c.stderr()) if is_pytest else ("stdout", c.stdout())):
            if text.strip():
                print(f"{name}:\n```text\n{_tail(text, TAIL_LINES)}\n```")
        if not (c.stdout().strip() or c.stderr().strip()):
            print("(no output)")
        print()


def reproduce_cmd(args) -> str:
    argv = [_rel_py(), "bench/load_harness.py", "--phase", args.phase]
    if args.phase in ("main", "both"):
        argv += ["--rounds", str(args.rounds), "--copies", str(args.copies), "--hogs", str(args.hogs)]
    if args.phase in ("tests", "both"):
        argv += ["--test-runs", str(args.test_runs), "--test-copies", str(args.test_copies)]
    argv += ["--cycles", str(args.cycles), "--timeout", f"{args.timeout:g}"]
    if args.seed is not None:
        argv += ["--seed", str(args.seed)]
    cmd = shlex.join(argv)
    if args.pytest_args and args.phase in ("tests", "both"):
        cmd += " --pytest-args=" + shlex.quote(args.pytest_args)
    return cmd


def _load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


# ---------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--phase", choices=("main", "tests", "both"), default="both",
                   help="main job under load, the test suite under load, or both (default)")
    p.add_argument("--rounds", type=int, default=5, help="phase 1 rounds (default 5)")
    p.add_argument("--copies", type=int, default=4, help="phase 1 concurrent main-job copies (default 4)")
    p.add_argument("--hogs", type=int, default=4, help="phase 1 CPU hog processes (default 4)")
    p.add_argument("--cycles", type=int, default=10, help="parts per main-job copy (default 10)")
    p.add_argument("--test-runs", type=int, default=3, help="phase 2 runs of the test suite (default 3)")
    p.add_argument("--test-copies", type=int, default=2,
                   help="phase 2 main-job copies running beside pytest (default 2)")
    p.add_argument("--pytest-args", default="",
                   help='extra pytest arguments, one shell-quoted string (e.g. "-k test_kinematics"; '
                        'use --pytest-args=-x for a single dash option)')
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the simulated cell, passed as cellctl run --seed (default: the config's)")
    p.add_argument("--timeout", type=float, default=1800.0,
                   help="seconds per child process before it is killed and reported failed (default 1800)")
    args = p.parse_args(argv)
    for name, lo in (("rounds", 1), ("copies", 1), ("hogs", 0), ("cycles", 1), ("test_runs", 1),
                     ("test_copies", 0)):
        if getattr(args, name) < lo:
            p.error(f"--{name.replace('_', '-')} must be >= {lo}")
    if args.timeout <= 0:
        p.error("--timeout must be > 0")
    try:
        args.pytest_extra = shlex.split(args.pytest_args)
    except ValueError as exc:
        p.error(f"--pytest-args: {exc}")
    need = [CELLCTL] if args.phase in ("main", "both") else []
    need += [CELLCTL, VENV_PY] if args.phase in ("tests", "both") else []
    missing = [str(x) for x in need if not x.exists()]
    if missing:
        print(f"load_harness: missing {', '.join(missing)}; build the venv first (python3 dev.py run)",
              file=sys.stderr)
        return 2

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _on_signal)
    atexit.register(kill_all)
    load0 = _load()
    t0 = time.monotonic()
    tmp = Path(tempfile.mkdtemp(prefix="load-harness-"))
    results: dict[str, bool] = {}
    failures: list[Child] = []
    ref = Reference()
    seed = "the config's (0)" if args.seed is None else str(args.seed)
    try:
        print(f"## Load harness: the simulated cell ({args.cycles} parts per copy, seed {seed}) "
              f"and the test suite on a loaded machine\n", flush=True)
        if args.phase in ("main", "both"):
            results["phase 1"] = phase_main(args, tmp, ref, failures)
        if args.phase in ("tests", "both"):
            results["phase 2"] = phase_tests(args, tmp, ref, failures)
        kill_all()
        dump_failures(failures)                 # reads the output files: before the rmtree
    except KeyboardInterrupt:
        print("\nload_harness: interrupted; killing child processes", file=sys.stderr)
        return 130
    finally:
        kill_all()
        shutil.rmtree(tmp, ignore_errors=True)
    ok = all(results.values())
    print(f"Machine: Python {platform.python_version()} ({platform.python_implementation()}), "
          f"{platform.machine()}, {platform.system()} {platform.release()}, {os.cpu_count()} CPUs; "
          f"load average 1/5/15 min at start {load0}, at end {_load()}; "
          f"harness wall time {time.monotonic() - t0:.0f} s.\n")
    print(f"Reproduce (from the repo root): `{reproduce_cmd(args)}`\n")
    verdicts = ", ".join(f"{k} {'pass' if v else 'FAIL'}" for k, v in results.items())
    print(f"**Result: {'PASS' if ok else 'FAIL'}** ({verdicts})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
