"""CPU per part of the main job by thread and by side (controller / simulated devices),
beside the goals, and the main job's wall time as a user runs it.

    .venv/bin/python bench/bench_cycle_cpu.py           # 10 and 100 parts; 3 x cellctl run --sim --cycles 100
    .venv/bin/python bench/bench_cycle_cpu.py --quick   # 3 and 20 parts; 1 x cellctl run --sim --cycles 20
    .venv/bin/python bench/bench_cycle_cpu.py --parts 10,200 --runs 5 --skip-wall

Goals (the issue): controller <= 25 ms CPU per part, simulated devices <= 50 ms CPU per part,
``cellctl run --sim --cycles 100`` <= 15 s wall on 2 idle cores.

1. By thread. ``cell.commands.run.run_sim`` (= ``cellctl run --sim --cycles N --json``: recipe
   bracket-a, built-in sim config, ``--db`` a fresh log in a temp dir) runs in a fresh
   subprocess of this script (``--child N``, prints JSON), for N1 and for N2 parts (after an
   unshown 1-part run that byte-compiles modules edited since and fills caches). A sampler
   thread reads utime+stime of ``/proc/self/task/<tid>/stat`` (1/SC_CLK_TCK s resolution)
   before ``run_sim``, every 20 ms, and after it; a thread that ended counts with the last
   value seen. Tids are named by ``Thread.native_id``, else by ``/proc/.../comm`` in brackets
   (``[python]``: native threads, i.e. the OpenBLAS / OpenCV pools). Per part = marginal CPU,
   (CPU(N2) - CPU(N1)) / (N2 - N1) per thread name: start-up and shut-down cancel, imports are
   not counted. The sampler's own CPU is shown apart and counted nowhere.
2. Mixed threads. A thread's side is its name's: ``cell-*``, ``plc-*`` (the controller's Modbus
   server), ``stations-*``, ``camera-grab`` (the driver's grab task): controller; ``sim-*``
   (``sim-clock``; ``sim-plc-scan``, the simulated PLC's scan where it is a thread):
   simulated devices; others (MainThread: run_sim's loop, presenting parts and waiting on
   the simulated PLC; native threads): unattributed. But clock callbacks (the wire, the
   simulated stations, the simulated PLC's scan) run in ``sim-clock`` or, where the clock
   has a parking participant run the agenda itself, in whichever thread waits
   (``cell-cycle``, ``cell-scan``, ...), and the camera driver's
   task runs the simulated camera. So the child wraps (monkeypatch) the calls below, each
   counted for one side with its ``time.thread_time()`` *exclusive* of wrapped calls nested
   in it (a per-thread stack: nothing counts twice, and the controller's receive nested in the
   wire's delivery counts for the controller, which an outermost-only rule would not do), and
   moves that CPU from its thread's side to its own:
   * every clock callback, wrapped where it is scheduled (``VirtualClock.call_at``, which
     ``call_later`` uses), one row per ``__qualname__``: simulated devices
     (``VirtualWire._deliver``, ``SimStation._on_timer``, the stations' heartbeats, the
     simulated PLC's scan ``SimPlc._tick``) -- except three that are the controller's: a
     ``ClockCyclicTask._tick`` on the controller's bus, its heartbeat (``net.send_periodic``),
     ``HeartbeatWatchdog._tick``, the stations' watchdog checks, and ``CellController._tick``,
     its scan (each a task on a clock without ``call_at``). The controller schedules nothing
     else on the clock (its other tasks are threads);
   * ``VirtualCanBus._receive`` of the controller's bus (the one ``drivers.stations.driver.
     open_bus`` returns to ``JointStations.start``; that instance only): it hands each frame
     at once to the controller's canopen ``Network`` (TPDO, EMCY, SDO client) and
     ``BusMonitor``: controller. The stations' buses and networks stay simulated;
   * ``VirtualClock._park`` (if present), the clock's machinery in a waiting thread (agenda
     run, hand-offs): simulated devices, being no part of a real controller's wait;
   * ``SimCamera._grab``, the simulated camera (exposure wait, scene: drive positions and
     plant, render): simulated devices; ``CameraBase.grab`` around it stays controller. (It
     renders the calibration board once at start-up in MainThread too: cancels.)
   Not moved: ``VirtualCanBus.send`` / ``VirtualWire.reserve`` called by controller threads
   (it stands for the interface's send); work in the native pools (unseen by ``thread_time``).
   Shown apart but not moved, the controller's own parts of the cycle: its fiducial finds
   (``MeasuringCamera.find``), a move's plan (``Mover.plan``) and its delay-corrected
   velocities (``corrected_velocities``), a burst's frames (``JointStations._burst``) and
   the controller bus's ``send`` (the wire's slot reservation with it).
   The wrappers' own cost (calls per part x a wrapped no-op timed in the child) is printed
   and taken off: the part of it inside a call's own reading off the call's side, the rest off
   its caller's side (the wrapped call around it, else its thread's), each counted per call.
3. By side: thread CPU + moved in - moved out - the wrappers' own cost, beside the goals.
4. Wall time: ``.venv/bin/cellctl run --sim --cycles 100 --json --db <tmp>/x.sqlite`` (no
   wrappers), R runs one after another, wall s measured here (interpreter start-up included),
   1-min load average before each, median, and whether every run simulated the same ``sim_s``
   (and the in-process run of as many parts, wrappers on).

Every number is measured in this run; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import functools
import io
import json
import os
import platform
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from contextlib import redirect_stdout
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

CTL, SIM, OTHER = "controller", "simulated devices", "unattributed"
GOAL_MS = {CTL: 25.0, SIM: 50.0}
WALL_GOAL_S, WALL_GOAL_PARTS = 15.0, 100
TICK = os.sysconf("SC_CLK_TCK")
SAMPLE_S = 0.020


def thread_side(name: str) -> str:
    if name.startswith("sim-"):
        return SIM
    if name.startswith(("cell-", "plc-", "stations-", "camera-grab")):
        return CTL
    return OTHER


# ---------------------------------------------------------------------------- child
_tl = threading.local()
SPENT: dict = defaultdict(lambda: [0.0, 0])      # (thread, label, side) -> [CPU s exclusive, calls]
CALLERS: dict = defaultdict(int)                 # side the caller's time counts for -> wrapped calls


def call_accounted(label: str, side: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, its CPU (``time.thread_time``) added to SPENT[(thread, label,
    side)] *exclusive* of wrapped calls nested in it (a per-thread stack), so nothing counts
    twice and a controller call inside a simulated-device call counts for the controller."""
    stack = getattr(_tl, "stack", None)
    if stack is None:
        stack = _tl.stack = []
        _tl.name = threading.current_thread().name
        _tl.side = thread_side(_tl.name)
    now = time.thread_time()
    if stack:                                    # the caller's time so far is the caller's
        up = stack[-1]
        SPENT[(_tl.name, up[0], up[1])][0] += now - up[2]
        CALLERS[up[1]] += 1
    else:
        CALLERS[_tl.side] += 1
    me = [label, side, now]
    stack.append(me)
    try:
        return fn(*args, **kwargs)
    finally:
        now = time.thread_time()
        stack.pop()
        acc = SPENT[(_tl.name, label, side)]
        acc[0] += now - me[2]
        acc[1] += 1
        if stack:
            stack[-1][2] = now


def accounted(fn, label: str, side: str):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        return call_accounted(label, side, fn, *args, **kwargs)
    return wrapper


def install_wrappers() -> None:
    import weakref
    import drivers.stations.driver as driver
    from cell.sim.clock import VirtualClock
    from drivers.camera.sim import SimCamera
    from cell.controller import CellController
    from drivers.stations.faults import HeartbeatWatchdog
    from drivers.stations.sim_bus import ClockCyclicTask
    ctl_buses = weakref.WeakSet()
    open_bus = driver.open_bus

    def controller_open_bus(*args, **kwargs):
        bus = open_bus(*args, **kwargs)
        ctl_buses.add(bus)
        bus._receive = accounted(bus._receive, "`VirtualCanBus._receive`, the controller's bus "
                                 "(its canopen Network, BusMonitor)", CTL)   # this instance only
        bus.send = accounted(bus.send, "`VirtualCanBus.send`, the controller's bus (the wire's "
                             "slot reservation with it)", CTL)
        return bus
    driver.open_bus = controller_open_bus
    call_at = VirtualClock.call_at

    def accounted_call_at(clock, t, fn, *args):
        owner = getattr(fn, "__self__", None)
        if isinstance(owner, ClockCyclicTask) and owner.bus in ctl_buses:
            label, side = "clock callback `ClockCyclicTask._tick`, the controller's bus (heartbeat)", CTL
        elif isinstance(owner, HeartbeatWatchdog):
            label, side = "clock callback `HeartbeatWatchdog._tick` (the controller's watchdog checks)", CTL
        elif isinstance(owner, CellController):
            label, side = "clock callback `CellController._tick` (the controller's scan)", CTL
        else:
            label, side = f"clock callback `{getattr(fn, '__qualname__', repr(fn))}`", SIM
            if isinstance(owner, ClockCyclicTask):
                label += ", the stations' buses (their heartbeats)"
        return call_at(clock, t, call_accounted, label, side, fn, *args)
    VirtualClock.call_at = accounted_call_at
    if hasattr(VirtualClock, "_park"):
        VirtualClock._park = accounted(VirtualClock._park, "`VirtualClock._park` (the clock: "
                                       "agenda run by the waiting thread, hand-offs)", SIM)
    SimCamera._grab = accounted(SimCamera._grab, "`SimCamera._grab` (scene, plant, render)", SIM)
    from cell.motion.mover import Mover
    from cell.vision.measure import MeasuringCamera
    from drivers.stations.streaming import StreamingMixin
    for owner, name, label in (
            (MeasuringCamera, "find", "`MeasuringCamera.find` (a fiducial find: window, fit)"),
            (Mover, "plan", "`Mover.plan` (a move's way-points and segments)"),
            (StreamingMixin, "corrected_velocities", "`corrected_velocities` (a burst's delay-corrected velocities)"),
            (driver.JointStations, "_burst", "`JointStations._burst` (a burst's set-point frames)")):
        setattr(owner, name, accounted(getattr(owner, name), label, CTL))


def wrapper_cost_us(n: int = 200_000) -> tuple[float, float]:
    """CPU per call a wrapper adds, µs: (all of it: a wrapped no-op against a bare one, best
    of 3; the part inside the wrapped call's own reading, which counts for the call's side --
    the rest counts for its caller's)."""
    def noop():
        return None
    best = []
    callers = dict(CALLERS)
    key = (threading.current_thread().name, "check", OTHER)
    for f in (noop, accounted(noop, "check", OTHER)):
        t0 = [time.thread_time()]
        for _ in range(3):
            for _ in range(n):
                f()
            t0.append(time.thread_time())
        best.append(min(y - x for x, y in zip(t0, t0[1:])))
    inside, k = SPENT.pop(key)
    CALLERS.clear()
    CALLERS.update(callers)
    return (best[1] - best[0]) / n * 1e6, inside / k * 1e6


def child(n: int, db: str) -> int:
    import cell.app, cell.recipes.validation, cell.sim.assembly, cell.sim.plc  # noqa: F401,E401 -- run_sim imports them lazily
    from cell import log
    from cell.commands import run as runmod
    log.configure("console", "ERROR")
    install_wrappers()
    cpu: dict[int, float] = {}                   # tid -> utime + stime, s (last value seen)
    names: dict[int, str] = {}
    stop = threading.Event()

    def sample() -> None:
        for t in threading.enumerate():
            if t.native_id:
                names[t.native_id] = t.name
        for tid in map(int, os.listdir("/proc/self/task")):
            try:
                cpu[tid] = stat_cpu(f"/proc/self/task/{tid}")
                if tid not in names:
                    names[tid] = f"[{read(f'/proc/self/task/{tid}/comm').strip()}]"
            except OSError:
                pass                             # ended meanwhile: keep the last value

    def sampler() -> None:
        while not stop.wait(SAMPLE_S):
            sample()
    th = threading.Thread(target=sampler, name="bench-sampler", daemon=True)
    th.start()
    ns = argparse.Namespace(cycles=n, recipe="bracket-a", config=None, seed=None, db=db,
                            allow_examples=False, first_part=1, json=True, opcua=None)
    sample()
    base, proc0 = dict(cpu), stat_cpu("/proc/self")   # imports so far: not counted
    buf = io.StringIO()
    w0 = time.monotonic()
    with redirect_stdout(buf):
        rc = runmod.run_sim(ns)
    wall = time.monotonic() - w0
    stop.set()
    th.join()
    sample()
    proc1 = stat_cpu("/proc/self")
    by_name: dict[str, float] = defaultdict(float)
    for tid, c in cpu.items():
        if tid != th.native_id:
            by_name[names.get(tid, f"tid {tid}")] += c - base.get(tid, 0.0)
    out = json.loads(buf.getvalue())
    print(json.dumps({"n": n, "rc": rc, "sim_s": out["sim_s"], "wall_s": wall,
                      "done": sum(c["fault"] is None for c in out["cycles"]),
                      "threads": by_name, "sampler_s": cpu[th.native_id] - base.get(th.native_id, 0.0),
                      "process_s": proc1 - proc0,
                      "spent": [[*key, s, k] for key, (s, k) in SPENT.items()],
                      "callers": dict(CALLERS), "wrapper_us": wrapper_cost_us()}))
    return 0


def read(path: str) -> str:
    with open(path, "rb", buffering=0) as f:
        return f.read().decode()


def stat_cpu(task: str) -> float:
    """utime + stime of ``<task>/stat``, s."""
    f = read(task + "/stat").rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / TICK


# ---------------------------------------------------------------------------- parent
def machine() -> str:
    cpu = platform.processor() or platform.machine()
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    return (f"{cpu}, {os.cpu_count()} CPUs; {platform.system()} {platform.release()}; "
            f"Python {platform.python_version()}; load average (1 / 5 / 15 min) {load}")


def run_json(cmd: list[str]) -> tuple[dict, int, float]:
    """Run ``cmd`` in the repo; (its JSON on stdout, exit code, wall s measured here)."""
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True,
                          env={**os.environ, "CELL_PROGRESS": "0"})
    wall = time.monotonic() - t0
    try:
        return json.loads(proc.stdout), proc.returncode, wall
    except json.JSONDecodeError:
        raise RuntimeError(f"{shlex.join(cmd)} exited {proc.returncode} without JSON; stderr:\n"
                           f"{proc.stderr[-3000:]}") from None


def run_child(n: int, tmp: Path) -> dict:
    db = Path(tempfile.mkdtemp(dir=tmp)) / "x.sqlite"
    return run_json([sys.executable, str(Path(__file__).resolve()), "--child", str(n), "--db", str(db)])[0]


def cpu_per_part(a: dict, b: dict) -> None:
    dn = b["n"] - a["n"]
    per = lambda x, y: (y - x) / dn * 1e3  # noqa: E731 -- ms per part
    print(f"### 1. CPU per part by thread: `run_sim` in-process, {a['n']} and {b['n']} parts, "
          f"marginal ({b['n']} - {a['n']} parts)\n")
    for r in (a, b):
        print(f"- {r['n']} parts: {r['done']} done, exit {r['rc']}, simulated {r['sim_s']:.3f} s, "
              f"`run_sim` {r['wall_s']:.2f} s wall, process CPU {r['process_s']:.2f} s")
    print()
    print("| thread | side | CPU s, short run | CPU s, long run | ms / part |")
    print("|---|---|---:|---:|---:|")
    names = sorted(set(a["threads"]) | set(b["threads"]),
                   key=lambda t: -per(a["threads"].get(t, 0.0), b["threads"].get(t, 0.0)))
    side: dict = defaultdict(float)
    for t in names:
        x, y = a["threads"].get(t, 0.0), b["threads"].get(t, 0.0)
        side[thread_side(t)] += per(x, y)
        print(f"| {t} | {thread_side(t)} | {x:.2f} | {y:.2f} | {per(x, y):.1f} |")
    sa, sb = sum(a["threads"].values()), sum(b["threads"].values())
    print(f"| **all threads** | | {sa:.2f} | {sb:.2f} | **{per(sa, sb):.1f}** |")
    print(f"| bench sampler (excluded) | | {a['sampler_s']:.2f} | {b['sampler_s']:.2f} | "
          f"{per(a['sampler_s'], b['sampler_s']):.1f} |")
    print(f"| process (`/proc/self/stat`, sampler included) | | "
          f"{a['process_s']:.2f} | {b['process_s']:.2f} | {per(a['process_s'], b['process_s']):.1f} |")

    print("\n### 2. Attribution inside mixed threads (wrapped calls, `time.thread_time()`, "
          "exclusive of nested wrapped calls; marginal)\n")
    print("| wrapped call | counted for | calls / part | ms / part | ran in (ms / part) |")
    print("|---|---|---:|---:|---|")
    spent = defaultdict(lambda: defaultdict(lambda: [0.0, 0.0, 0, 0]))  # (label, side) -> thread -> ..
    for r, i in ((a, 0), (b, 1)):
        for t, lab, sd, sec, k in r["spent"]:
            spent[(lab, sd)][t][i] += sec
            spent[(lab, sd)][t][2 + i] += k
    move: dict = defaultdict(float)                     # (thread's side, call's side) -> ms / part
    calls = 0.0
    own_calls: dict = defaultdict(float)                # call's side -> wrapped calls / part
    for (lab, sd), by_thread in sorted(spent.items(), key=lambda kv: -sum(
            per(e[0], e[1]) for e in kv[1].values())):
        ms = {t: per(e[0], e[1]) for t, e in by_thread.items()}
        cpp = sum(e[3] - e[2] for e in by_thread.values()) / dn
        calls += cpp
        own_calls[sd] += cpp
        for t, x in ms.items():
            move[(thread_side(t), sd)] += x
        where = ", ".join(f"{t} {x:.1f}" for t, x in sorted(ms.items(), key=lambda kv: -kv[1])
                          if abs(x) >= 0.05)
        print(f"| {lab} | {sd} | {cpp:.0f} | {sum(ms.values()):.1f} | {where} |")
    for what in ("VirtualWire._deliver", "VirtualCanBus._receive", "SimCamera._grab"):
        if not any(what in lab and e[3] for (lab, _), bt in spent.items() for e in bt.values()):
            print(f"\n**No call of `{what}` counted: the code changed under this bench; CPU it "
                  f"stood for stays with its thread.**")
    moved_in, moved_out = defaultdict(float), defaultdict(float)
    for (frm, to), x in move.items():
        if frm != to:
            moved_out[frm] += x
            moved_in[to] += x
    us, inside = b["wrapper_us"]
    callers = {sd: (b["callers"].get(sd, 0) - a["callers"].get(sd, 0)) / dn for sd in (CTL, SIM, OTHER)}
    wrappers = {sd: (own_calls[sd] * inside + callers[sd] * (us - inside)) / 1e3 for sd in (CTL, SIM, OTHER)}
    print(f"\nWrapper cost: {calls:.0f} wrapped calls per part x {us:.2f} us (a wrapped no-op against "
          f"a bare one) = {calls * us / 1e3:.1f} ms / part the cell does not spend. Of each call's "
          f"{us:.2f} us, {inside:.2f} us fall inside the call's own reading and count for its side, "
          f"the rest for its caller's (the wrapped call around it, else its thread); per part the "
          f"wrapped calls are {', '.join(f'{own_calls[sd]:.0f} {sd}' for sd in (CTL, SIM) if own_calls[sd])}, "
          f"their callers {', '.join(f'{callers[sd]:.0f} {sd}' for sd in (CTL, SIM, OTHER) if callers[sd])}. "
          f"Section 3 takes that cost off each side.\n")

    print("### 3. CPU per part by side (thread CPU + moved in - moved out - the wrappers' own cost)\n")
    print("| side | threads, ms / part | moved in | moved out | wrappers | **ms / part** | goal | of goal |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    total = 0.0
    for sd in (CTL, SIM, OTHER):
        x = side[sd] + moved_in[sd] - moved_out[sd] - wrappers[sd]
        total += x
        goal = f"{GOAL_MS[sd]:g} | {x / GOAL_MS[sd] * 100:.0f} %" if sd in GOAL_MS else " | "
        name = sd if sd != OTHER else f"{OTHER} ({', '.join(t for t in names if thread_side(t) == OTHER)})"
        print(f"| {name} | {side[sd]:.1f} | {moved_in[sd]:.1f} | {moved_out[sd]:.1f} | {wrappers[sd]:.1f} | "
              f"**{x:.1f}** | {goal} |")
    print(f"| **total** | {sum(side.values()):.1f} | | | {sum(wrappers.values()):.1f} | **{total:.1f}** | "
          f"{sum(GOAL_MS.values()):g} | |\n")


def wall_time(n: int, runs: int, tmp: Path, in_process: dict | None) -> None:
    cellctl = REPO / ".venv/bin/cellctl"
    if not cellctl.exists():
        cellctl = Path(sys.executable).parent / "cellctl"
    shown = f".venv/bin/cellctl run --sim --cycles {n} --json --db <tmp>/x.sqlite"
    print(f"### 4. Wall time as a user runs it: `{shown}`, {runs} run(s) one after another\n")
    print("| run | parts done | wall s (measured) | simulated s (`sim_s`) | load 1 min before | exit |")
    print("|---|---:|---:|---:|---:|---:|")
    res = []
    for i in range(1, runs + 1):
        db = tmp / f"wall-{i}" / "x.sqlite"
        db.parent.mkdir()
        load = os.getloadavg()[0]
        out, rc, wall = run_json([str(cellctl), "run", "--sim", "--cycles", str(n), "--json", "--db", str(db)])
        res.append((wall, out["sim_s"]))
        print(f"| {i} | {sum(c['fault'] is None for c in out['cycles'])} | {wall:.2f} | "
              f"{out['sim_s']:.3f} | {load:.2f} | {rc} |", flush=True)
    med = statistics.median(w for w, _ in res)
    goal = (f"goal <= {WALL_GOAL_S:g} s: {med / WALL_GOAL_S * 100:.0f} % of it"
            if n == WALL_GOAL_PARTS else f"the goal, {WALL_GOAL_S:g} s, is for {WALL_GOAL_PARTS} parts")
    print(f"| **median** | | **{med:.2f}** | | | |\n\nMedian {med:.2f} s for {n} parts ({goal}).")
    sims = sorted({s for _, s in res})
    same = "yes" if len(sims) == 1 else "**NO**"
    extra = ""
    if in_process is not None:
        extra = (f"; the in-process run of {n} parts (section 1, wrappers on) simulated "
                 f"{in_process['sim_s']:g} s: {'same' if in_process['sim_s'] == sims[0] else '**different**'}")
    print(f"Every run simulated the same `sim_s`: {same} ({', '.join(f'{s:g}' for s in sims)} s){extra}.\n")


def parse_parts(p: argparse.ArgumentParser, text: str | None, default: tuple[int, int]) -> tuple[int, int]:
    """``--parts N1,N2`` (``default`` when not given), 1 <= N1 < N2; else ``p.error``."""
    if text is None:
        return default
    try:
        n1, n2 = (int(x) for x in text.split(","))
    except ValueError:
        p.error(f"--parts {text!r}: give N1,N2, e.g. {default[0]},{default[1]}")
    if not 1 <= n1 < n2:
        p.error(f"--parts {text}: need 1 <= N1 < N2")
    return n1, n2


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="3 and 20 parts; 1 wall run of 20 cycles")
    p.add_argument("--parts", help="N1,N2 parts of the two in-process runs (default 10,100)")
    p.add_argument("--runs", type=int, help="wall-time runs (default 3; 1 with --quick)")
    p.add_argument("--skip-wall", action="store_true", help="sections 1-3 only")
    p.add_argument("--child", type=int, help=argparse.SUPPRESS)
    p.add_argument("--db", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child is not None:
        return child(args.child, args.db)
    n1, n2 = parse_parts(p, args.parts, (3, 20) if args.quick else (10, 100))
    runs = args.runs or (1 if args.quick else 3)
    wall_n = 20 if args.quick else WALL_GOAL_PARTS

    argv_shown = sys.argv[1:] if argv is None else argv
    print("## CPU per part of `cellctl run --sim` by thread and side, and its wall time\n")
    print(f"Machine: {machine()}.\n")
    print(f"Reproduce: `{shlex.join(['.venv/bin/python', 'bench/bench_cycle_cpu.py', *argv_shown])}`\n",
          flush=True)
    tmp = Path(tempfile.mkdtemp(prefix="bench-cycle-cpu-"))
    t_all = time.monotonic()
    try:
        run_child(1, tmp)             # warm-up, not shown: byte-compiles edited modules, fills caches
        a, b = run_child(n1, tmp), run_child(n2, tmp)
        cpu_per_part(a, b)
        sys.stdout.flush()
        if not args.skip_wall:
            wall_time(wall_n, runs, tmp, next((r for r in (a, b) if r["n"] == wall_n), None))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"Whole bench: {time.monotonic() - t_all:.0f} s wall.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
