"""The simulated cell end to end: how much faster than real time it runs, where a cycle's
simulated time goes, and the Modbus latency an outside PLC sees while the paced cell works.

    .venv/bin/python bench/bench_cell.py            # 3 runs of 100 parts; 6 rounds of 3 s idle + 6 cycles
    .venv/bin/python bench/bench_cell.py --quick    # 1 run of 10 parts; 2 rounds of 1.5 s idle + 2 cycles
    .venv/bin/python bench/bench_cell.py --probe-process   # latency probe in its own process

The simulated cell runs on one simulated clock (``cell.sim.clock.VirtualClock``): drives on
the virtual CAN wire, the rendering camera, the plant, the simulated PLC and the controller
all take their time from it, and it moves only when all of them wait. Simulated results
therefore do not depend on the host; only wall times do.

1. Faster than real time. The main job exactly as a user runs it,
   ``.venv/bin/cellctl run --sim --cycles N --json --db <tmp>/x.sqlite`` (default recipe
   bracket-a, default built-in sim config), as R subprocesses one after another, each with a
   fresh log. Per run: parts done, simulated seconds (``sim_s``), wall seconds of the whole
   command measured here (interpreter start-up included) and as the command reports it
   (``wall_s``: cell construction to cell stop), simulated seconds per wall second, parts
   per wall minute, start-up = command wall - sum of the per-cycle ``wall_s``, and the CPU
   time the command used. The machine is shared, so its load average is shown too.
2. Where a cycle's simulated time goes. The same runs' cycle logs
   (``cell.cyclelog.CycleLog(path).cycles()``): mean simulated seconds per step
   (``step_times``), the PLC handshake around the cycle (``plc_round_trip_s`` of the JSON
   minus ``cycle_time_s``), moves and interpolation segments per cycle (``motion``), and the
   station delays lambda measured on the bus (``motion.delays_ms``).
3. Modbus latency while the paced cell works (what an outside PLC sees from
   ``cellctl serve --sim``). The cell is ``cell.app.Cell(devices="sim", pace=True)`` (its
   simulated clock kept to wall time, jobs on, as ``serve --sim``), with a fast recipe
   (joints 240 deg/s, 2 mm z stroke); its PLC is the simulated PLC (``SimPlc``, scan 10 ms)
   on the cell's clock, cycles run from a thread inside ``cell.clock.attach()``. A probe
   (pymodbus sync ``ModbusTcpClient``) reads holding registers 0..19 every 2 ms from the
   cell's PLC link and, alternately, from a bare pymodbus server (``bench_modbus.py``'s
   baseline) in the same process. Idle windows (SimPlc scanning, no cycle) and busy windows
   (back-to-back cycles) alternate, so machine drift hits both; a request counts for a
   window only if it starts and ends inside it. By default the probe is a thread of this
   process (it then also waits for the GIL on the client side, as any in-process client
   would); ``--probe-process`` runs it in a separate process (server side only).

Every number is measured in this run; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import platform
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import pymodbus  # noqa: E402
from pymodbus.client import ModbusTcpClient  # noqa: E402
from pymodbus.server import ModbusTcpServer  # noqa: E402

from cell import log, progress  # noqa: E402
from cell.app import Cell  # noqa: E402
from cell.config import CellConfig, SimSection  # noqa: E402
from cell.cyclelog import CycleLog  # noqa: E402
from cell.sim.plc import SimPlc  # noqa: E402
from drivers.plc.conformance import ServerThread  # noqa: E402
from drivers.plc.register_map import PLC_MAP  # noqa: E402
from drivers.plc.server import build_datastore  # noqa: E402

MAIN_RECIPE = "bracket-a"             # what `cellctl run --sim` and `python3 dev.py run` run
FAST_RECIPE_NAME = "fast-a"
FAST_RECIPE = f"""\
name: {FAST_RECIPE_NAME}
number: 7
description: bracket-a with a short z stroke and fast joints, for bench/bench_cell.py
part:
  nominal_xy_mm: [250.0, 930.0]
  fiducial_radius_mm: 1.5
  search_radius_mm: 3.0
approach:
  offset_mm: [-12.0, 0.0]
  z_mm: -20.0
  joint_speed_deg_s: 240.0
place:
  z_mm: -22.0
compensation:
  method: lattice
  max_moves: 4
motion:
  sync: corrected
  segment_ms: 10
  time_law: smooth
verify:
  tolerance_mm: 0.08
"""
HEARTBEAT_TIMEOUT_S = 0.4
PLC_SCAN_S = 0.010
PROBE_PERIOD_S = 0.002
PROBE_COUNT = 20                      # registers 0..19, one FC3
STEPS = ("approach", "capture", "locate", "compensate", "final_move", "verify")


# ---------------------------------------------------------------------------- statistics
def pct(samples: list[float], q: float) -> float:
    """Nearest-rank percentile."""
    s = sorted(samples)
    return s[max(0, math.ceil(q * len(s)) - 1)]


def med(xs: list[float]) -> float:
    return statistics.median(xs) if xs else float("nan")


def loadavg() -> str:
    try:
        return " / ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                mem = f", {int(line.split()[1]) / 1024 / 1024:.1f} GiB RAM"
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} CPUs{mem}; {platform.system()} {platform.release()}; "
            f"Python {platform.python_version()}, pymodbus {pymodbus.__version__}")


# ---------------------------------------------------------------------------- part 1
def cellctl() -> str:
    for cand in (REPO / ".venv/bin/cellctl", Path(sys.executable).parent / "cellctl"):
        if cand.exists():
            return str(cand)
    found = shutil.which("cellctl")
    if found is None:
        raise SystemExit("bench_cell: cellctl not found (pip install -e . in the venv)")
    return found


def main_job(n: int, db: Path, seed: int | None) -> dict:
    """One ``cellctl run --sim --cycles n --json --db db``; its JSON plus what we measured."""
    cmd = [cellctl(), "run", "--sim", "--cycles", str(n), "--json", "--db", str(db)]
    if seed is not None:
        cmd += ["--seed", str(seed)]
    load_before = os.getloadavg()[0]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    wall = time.monotonic() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    try:
        out = json.loads(proc.stdout)
    except json.JSONDecodeError:
        raise RuntimeError(f"{shlex.join(cmd)} exited {proc.returncode} without JSON; stderr:\n"
                           f"{proc.stderr[-3000:]}") from None
    cycles = out["cycles"]
    done = [c for c in cycles if c["fault"] is None]
    cyc_wall = sum(c["wall_s"] for c in cycles)
    return {"cmd": cmd, "rc": proc.returncode, "out": out, "cycles": cycles, "done": len(done),
            "sim_s": out["sim_s"], "wall": wall, "cmd_wall": out["wall_s"], "cyc_wall": cyc_wall,
            "startup": wall - cyc_wall, "cpu": cpu, "load": load_before,
            "faults": Counter(str(c["fault"]) for c in cycles if c["fault"] is not None),
            "records": CycleLog(db).cycles()}


def faster_than_real_time(n: int, runs: int, tmp: Path, seed: int | None) -> list[dict]:
    load0 = loadavg()
    res = []
    for i in progress.each(range(runs), "main-job runs", "run"):
        d = tmp / f"run{i + 1}"
        d.mkdir()
        res.append(main_job(n, d / "x.sqlite", seed))
    load1 = loadavg()
    shown = [".venv/bin/cellctl", "run", "--sim", "--cycles", str(n), "--json", "--db", "<tmp>/x.sqlite"]
    if seed is not None:
        shown += ["--seed", str(seed)]
    shown = " ".join(shown)
    print(f"### 1. Faster than real time: `{shown}`, "
          f"{f'{runs} runs one after another, each' if runs > 1 else '1 run'} with a fresh log\n")
    print(f"Recipe {MAIN_RECIPE}, the built-in simulated cell (seed "
          f"{seed if seed is not None else SimSection().seed}). Load average (1 / 5 / 15 min) "
          f"before: {load0}; after: {load1}.\n")
    print("| run | parts done | simulated s | wall s (measured) | wall s (cellctl `wall_s`) | "
          "sum of cycle `wall_s` | start-up s (measured - sum) | of which before the cell (measured - `wall_s`) | "
          "simulated s / wall s | "
          "parts / min (wall) | CPU s (user+sys) | load 1 min before | exit |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")

    def row(name, done, sim, wall, cmd_wall, cyc, start, cpu, load, rc):
        print(f"| {name} | {done} | {sim:.2f} | {wall:.2f} | {cmd_wall:.2f} | {cyc:.2f} | "
              f"{start:.2f} | {wall - cmd_wall:.2f} | {sim / wall:.2f} | {done / wall * 60:.1f} | {cpu:.1f} | {load} | {rc} |")

    for i, r in enumerate(res, 1):
        row(str(i), r["done"], r["sim_s"], r["wall"], r["cmd_wall"], r["cyc_wall"], r["startup"],
            r["cpu"], f"{r['load']:.2f}", r["rc"])
    if len(res) > 1:
        m = lambda k: med([r[k] for r in res])  # noqa: E731
        print(f"| **median** | {m('done'):g} | {m('sim_s'):.2f} | **{m('wall'):.2f}** | "
              f"{m('cmd_wall'):.2f} | {m('cyc_wall'):.2f} | {m('startup'):.2f} | "
              f"{med([r['wall'] - r['cmd_wall'] for r in res]):.2f} | "
              f"**{med([r['sim_s'] / r['wall'] for r in res]):.2f}** | "
              f"**{med([r['done'] / r['wall'] * 60 for r in res]):.1f}** | {m('cpu'):.1f} | "
              f"{m('load'):.2f} | |")
    cw = [c["wall_s"] for r in res for c in r["cycles"]]
    slow = max(res, key=lambda r: r["wall"])
    print(f"\nWall seconds per cycle (cycle `wall_s`, all runs, {len(cw)} cycles): mean "
          f"{statistics.fmean(cw):.3f}, p50 {pct(cw, 0.5):.3f}, p95 {pct(cw, 0.95):.3f}, max "
          f"{max(cw):.3f}. Slowest run: {slow['wall']:.2f} s wall for {slow['done']} parts done "
          f"({slow['done'] / slow['wall'] * 60:.1f} parts / min).")
    if len(res) > 1:
        print(same_simulation(res))
    faults = sum((r["faults"] for r in res), Counter())
    if faults:
        print(f"Faults: {dict(faults)}.")
    print()
    return res


def same_simulation(res: list[dict]) -> str:
    """Compare every run's simulated results (all but ``wall_s``) with the first run's."""
    sims = sorted({r["sim_s"] for r in res})
    diffs: Counter = Counter()
    example = ""
    ref = res[0]["cycles"]
    for i, r in enumerate(res[1:], 2):
        if len(r["cycles"]) != len(ref):
            diffs["number of cycles"] += 1
        for c0, c in zip(ref, r["cycles"]):
            for k in sorted(set(c0) | set(c)):
                if k != "wall_s" and c0.get(k) != c.get(k):
                    diffs[k] += 1
                    if not example:
                        example = (f"; first: run {i}, part {c.get('part_id')}, {k} "
                                   f"{json.dumps(c0.get(k))} in run 1, {json.dumps(c.get(k))} in run {i}")
    if len(sims) == 1 and not diffs:
        return (f"Every run simulated the same: yes (simulated s {sims[0]:g}; every cycle's results "
                f"identical apart from `wall_s`).")
    return (f"Every run simulated the same: **NO** (simulated s {', '.join(f'{x:g}' for x in sims)}; "
            f"cycles that differ from run 1, by field: "
            f"{', '.join(f'{k} {v}' for k, v in diffs.most_common()) or 'none'}{example}).")


# ---------------------------------------------------------------------------- part 2
def where_time_goes(res: list[dict]) -> None:
    recs = [rec for r in res for rec in r["records"]]
    done = [rec for rec in recs if rec.status == "done"]
    rt = {(i, c["part_id"]): c["plc_round_trip_s"] for i, r in enumerate(res) for c in r["cycles"]
          if c["fault"] is None}
    print(f"### 2. Where a cycle's simulated time goes ({len(done)} done cycles of {len(recs)} "
          f"logged, all runs of section 1; simulated seconds)\n")
    if not done:
        print("No cycle done.\n")
        return
    cyc = statistics.fmean(rec.cycle_time_s for rec in done)
    steps = list(STEPS) + sorted({k for rec in done for k in rec.step_times} - set(STEPS))
    print("| step (`step_times`) | mean s | p50 s | max s | share of cycle time |")
    print("|---|---:|---:|---:|---:|")
    for k in steps:
        xs = [rec.step_times.get(k, 0.0) for rec in done]
        print(f"| {k} | {statistics.fmean(xs):.4f} | {pct(xs, 0.5):.4f} | {max(xs):.4f} | "
              f"{statistics.fmean(xs) / cyc * 100:.1f} % |")
    cts = [rec.cycle_time_s for rec in done]
    print(f"| **cycle time** (`cycle_time_s`) | **{cyc:.4f}** | {pct(cts, 0.5):.4f} | {max(cts):.4f} "
          f"| 100 % |")
    hs = []
    for i, r in enumerate(res):
        by_part = {rec.part_id: rec for rec in r["records"] if rec.status == "done"}
        hs += [rt[(i, p)] - rec.cycle_time_s for p, rec in by_part.items() if (i, p) in rt]
    if hs:
        print(f"| PLC handshake around it (`plc_round_trip_s` - `cycle_time_s`) | "
              f"{statistics.fmean(hs):.4f} | {pct(hs, 0.5):.4f} | {max(hs):.4f} | "
              f"{statistics.fmean(hs) / cyc * 100:.1f} % |")
    rest = [(r["sim_s"] - sum(c["plc_round_trip_s"] for c in r["cycles"])) for r in res]
    print(f"\nPer run, simulated time outside the PLC round trips (start-up until the first "
          f"cycle, presenting parts, shut-down): {', '.join(f'{x:.3f} s' for x in rest)}.\n")

    def mean_of(key):
        xs = [rec.motion.get(key) for rec in done if rec.motion.get(key) is not None]
        return statistics.fmean(xs) if xs else float("nan")

    moves = [rec.moves or 0 for rec in done]
    print("| per cycle | mean | min | max |")
    print("|---|---:|---:|---:|")
    print(f"| compensation moves (`moves`) | {statistics.fmean(moves):.2f} | {min(moves)} | {max(moves)} |")
    for key, name in (("moves", "streamed moves (`motion.moves`)"),
                      ("segments", "interpolation segments (`motion.segments`)")):
        xs = [rec.motion[key] for rec in done if rec.motion.get(key) is not None]
        if xs:
            print(f"| {name} | {statistics.fmean(xs):.1f} | {min(xs)} | {max(xs)} |")
    seg_ms = mean_of("segment_ms")
    segs = mean_of("segments")
    if not math.isnan(seg_ms) and not math.isnan(segs):
        print(f"| segments x segment time (s) | {segs * seg_ms / 1e3:.3f} | | |")
    kinds = lambda key: ", ".join(f"{k} x{v}" for k, v in  # noqa: E731
                                  Counter(json.dumps(rec.motion.get(key)).strip('"')
                                          for rec in done).most_common())
    print(f"\nMotion: mode {kinds('mode')}; time law {kinds('time_law')}; segment ms "
          f"{kinds('segment_ms')}; paths {kinds('paths')}.\n")
    lam = [rec.motion["delays_ms"] for rec in done if rec.motion.get("delays_ms")]
    if lam:
        sigma_ms = SimSection().station_sigma_s * 1e3
        print("| station delay λ (`motion.delays_ms`) | mean ms | min ms | max ms | configured σ·i ms |")
        print("|---|---:|---:|---:|---:|")
        for j in range(len(lam[0])):
            xs = [v[j] for v in lam if len(v) > j]
            print(f"| j{j + 1} | {statistics.fmean(xs):.4f} | {min(xs):.4f} | {max(xs):.4f} | "
                  f"{sigma_ms * (j + 1):g} |")
        print()


# ---------------------------------------------------------------------------- part 3 set-up
def make_config(tmp: Path) -> CellConfig:
    """A sim cell config: the repo's recipes plus the fast one, log in ``tmp``, PLC on loopback
    (tests/system/conftest.py's ``make_config``)."""
    rdir = tmp / "recipes"
    shutil.copytree(REPO / "recipes", rdir)
    (rdir / f"{FAST_RECIPE_NAME}.yaml").write_text(FAST_RECIPE, encoding="utf-8")
    cfg = CellConfig(sim=SimSection(plant=str(REPO / "deploy/plants/default.yaml")))
    return cfg.model_copy(update={
        "plc": cfg.plc.model_copy(update={"host": "127.0.0.1",
                                          "heartbeat_timeout_s": HEARTBEAT_TIMEOUT_S}),
        "log": cfg.log.model_copy(update={"path": str(tmp / "cell.sqlite")}),
        "recipes": cfg.recipes.model_copy(update={"directory": str(rdir)}),
        "controller": cfg.controller.model_copy(update={"recipe_refresh_s": 0.05}),
    })


class PacedBench:
    """A started paced sim cell, its SimPlc on the cell's clock, and a bare pymodbus server."""

    def __init__(self, tmp: Path):
        self.config = make_config(tmp)
        self.cell = Cell(self.config, devices="sim", plc_port=0, jobs=True, pace=True)
        self.clock = self.cell.clock
        self.plc: SimPlc | None = None
        self.bare: ServerThread | None = None
        self.port = self.cell.start()
        self.plc = SimPlc("127.0.0.1", self.port, scan_s=PLC_SCAN_S, clock=self.clock)
        with self.clock.attach("bench-plc"):
            self.plc.start()
            self.plc.wait_until(lambda i: PLC_MAP.bits("status_word", i["status_word"])["ready"],
                                10.0, "cell ready")
        self.bare = ServerThread(lambda addr: ModbusTcpServer(build_datastore(PLC_MAP, None),
                                                              address=addr), name="bare-pymodbus")
        self.bare_port = self.bare.start()
        self.recipe = self.cell.recipes.active[FAST_RECIPE_NAME].recipe
        self.next_part = 1
        self.cycle_sim_s: list[float] = []

    def _cycle(self) -> None:
        """One cycle through the PLC handshake (caller keeps the clock's time)."""
        part_id = self.next_part
        self.next_part += 1
        self.cell.devices.feeder.present(part_id, self.recipe)
        t0 = self.clock.now()
        result = self.plc.run_cycle(self.recipe.number, part_id, timeout_s=20.0)
        if not result["done"]:
            c = self.cell.controller
            raise RuntimeError(f"cycle of part {part_id} did not end done: {result}, "
                               f"fault {c.fault_code} {c.fault_text!r}")
        self.cycle_sim_s.append(self.clock.now() - t0)

    def cycles(self, n: int) -> None:
        """``n`` back-to-back cycles from a thread inside ``cell.clock.attach()``; this
        (non-participant) thread waits in wall time."""
        err: list[BaseException] = []

        def body():
            try:
                with self.clock.attach("bench-plc-cycles"):
                    for _ in range(n):
                        self._cycle()
            except BaseException as exc:          # noqa: BLE001 -- re-raised below
                err.append(exc)

        th = threading.Thread(target=body, name="bench-plc-cycles", daemon=True)
        th.start()
        th.join()
        if err:
            raise err[0]

    def stop(self) -> None:
        def stop_plc():
            if self.plc is not None:
                with self.clock.attach("bench-plc"):
                    self.plc.stop()
        for step in (stop_plc, self.cell.stop, lambda: self.bare and self.bare.stop()):
            try:
                step()
            except Exception as exc:               # noqa: BLE001 -- take the rest down too
                print(f"stop failed: {exc!r}", file=sys.stderr)


# ---------------------------------------------------------------------------- part 3 probe
def probe_loop(ports: dict[str, int], period_s: float, stop, conn=None) -> list | None:
    """Read registers 0..PROBE_COUNT-1 from each port every ``period_s`` (fixed schedule, no
    catch-up; the order of the servers alternates) until ``stop`` is set. Returns (or sends on
    ``conn``) a list of (name, t_start, t_end, ok) with ``time.monotonic()`` stamps."""
    clients = {name: ModbusTcpClient("127.0.0.1", port=port, timeout=1.0, retries=0)
               for name, port in ports.items()}
    out = []
    try:
        for name, c in clients.items():
            if not c.connect():
                raise ConnectionError(f"probe: cannot connect to {name} on port {ports[name]}")
        order = list(clients.items())
        next_t = time.monotonic()
        while not stop.is_set():
            order.reverse()                        # A B, B A, ...: neither server always first
            for name, c in order:
                t0 = time.monotonic()
                try:
                    ok = not c.read_holding_registers(0, count=PROBE_COUNT, device_id=1).isError()
                except Exception:                  # noqa: BLE001 -- counted, not fatal
                    ok = False
                out.append((name, t0, time.monotonic(), ok))
            next_t += period_s
            delay = next_t - time.monotonic()
            if delay < -period_s:
                next_t = time.monotonic()
            elif delay > 0:
                stop.wait(delay)
    finally:
        for c in clients.values():
            c.close()
    if conn is not None:
        conn.send(out)
        conn.close()
        return None
    return out


class Probe:
    """:func:`probe_loop` in a thread of this process, or in a spawned process."""

    def __init__(self, ports: dict[str, int], in_process: bool):
        self.result: list = []
        self.error: BaseException | None = None
        if in_process:
            self.stop_ev = threading.Event()
            self.worker = threading.Thread(target=self._run_thread, args=(ports,),
                                           name="bench-probe", daemon=True)
            self.conn = None
        else:
            ctx = multiprocessing.get_context("spawn")
            self.stop_ev = ctx.Event()
            self.conn, child = ctx.Pipe(duplex=False)
            self.worker = ctx.Process(target=probe_loop, args=(ports, PROBE_PERIOD_S, self.stop_ev, child),
                                      name="bench-probe", daemon=True)
        self.worker.start()

    def _run_thread(self, ports):
        try:
            self.result = probe_loop(ports, PROBE_PERIOD_S, self.stop_ev)
        except BaseException as exc:               # noqa: BLE001 -- reported by finish()
            self.error = exc

    def finish(self) -> list:
        self.stop_ev.set()
        if self.conn is not None:
            if self.conn.poll(30):
                self.result = self.conn.recv()
            self.worker.join(timeout=10)
            if self.worker.exitcode != 0:
                raise RuntimeError(f"probe process ended with exit code {self.worker.exitcode}")
        else:
            self.worker.join(timeout=10)
            if self.error is not None:
                raise self.error
        return self.result


def latency(bench: PacedBench, rounds: int, idle_s: float, busy_cycles: int, in_process: bool) -> None:
    ports = {"ours (PlcLink)": bench.port, "bare pymodbus": bench.bare_port}
    probe = Probe(ports, in_process)
    windows: list[tuple[str, float, float]] = []
    pace: dict[str, list[tuple[int, float, float, float]]] = defaultdict(list)  # scans, sim s, wall s, CPU s
    load0 = loadavg()
    try:
        time.sleep(0.5)                               # probe connected and on its schedule
        for _ in range(rounds):
            for phase in ("idle", "busy"):
                s0, c0, t0, p0 = bench.plc.scans, bench.clock.now(), time.monotonic(), time.process_time()
                if phase == "idle":
                    time.sleep(idle_s)
                else:
                    bench.cycles(busy_cycles)
                t1 = time.monotonic()
                windows.append((phase, t0, t1))
                pace[phase].append((bench.plc.scans - s0, bench.clock.now() - c0, t1 - t0,
                                    time.process_time() - p0))
    finally:
        samples = probe.finish()
    load1 = loadavg()
    lat: dict[tuple[str, str], list[float]] = defaultdict(list)
    errors: dict[tuple[str, str], int] = defaultdict(int)
    for name, ts, te, ok in samples:
        for phase, w0, w1 in windows:
            if w0 <= ts and te <= w1:
                if ok:
                    lat[(name, phase)].append(te - ts)
                else:
                    errors[(name, phase)] += 1
                break
    where = "a thread of the cell's process" if in_process else "a separate process"
    cyc = bench.cycle_sim_s
    print(f"### 3. Modbus FC3 latency while the paced cell works: {PROBE_COUNT} registers every "
          f"{PROBE_PERIOD_S * 1e3:g} ms per server, probe in {where}\n")
    print(f"`Cell(devices=\"sim\", pace=True, jobs=True)`, recipe {FAST_RECIPE_NAME} (lattice, max 4 "
          f"moves, joints 240 deg/s, z -20 -> -22 mm), PLC heartbeat timeout {HEARTBEAT_TIMEOUT_S} s, "
          f"controller scan {bench.config.controller.scan_s * 1e3:g} ms, SimPlc scan "
          f"{PLC_SCAN_S * 1e3:g} ms on the cell's clock. {rounds} rounds of: idle {idle_s:g} s "
          f"(SimPlc scanning, no cycle), then {busy_cycles} back-to-back cycles (busy; "
          f"{len(cyc)} cycles, PLC round trip mean {statistics.fmean(cyc):.3f} s simulated). "
          f"Load average before: {load0}; after: {load1}.\n")
    print("| server | phase | requests | errors | p50 (us) | p99 (us) | mean (us) | max (us) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for name in ports:
        for phase in ("idle", "busy"):
            s = lat[(name, phase)]
            if not s:
                print(f"| {name} | {phase} | 0 | {errors[(name, phase)]} | | | | |")
                continue
            print(f"| {name} | {phase} | {len(s)} | {errors[(name, phase)]} | "
                  f"{pct(s, 0.50) * 1e6:.0f} | {pct(s, 0.99) * 1e6:.0f} | "
                  f"{statistics.fmean(s) * 1e6:.0f} | {max(s) * 1e6:.0f} |")
        i, b = lat[(name, "idle")], lat[(name, "busy")]
        if i and b:
            print(f"| **{name}: busy / idle** | | | | **{pct(b, 0.5) / pct(i, 0.5):.2f}x** | "
                  f"**{pct(b, 0.99) / pct(i, 0.99):.2f}x** | "
                  f"**{statistics.fmean(b) / statistics.fmean(i):.2f}x** | "
                  f"{max(b) / max(i):.2f}x |")
    o, r = "ours (PlcLink)", "bare pymodbus"
    for phase in ("idle", "busy"):
        a, b = lat[(o, phase)], lat[(r, phase)]
        if a and b:
            print(f"| ours / bare, {phase} | | | | {pct(a, 0.5) / pct(b, 0.5):.2f}x | "
                  f"{pct(a, 0.99) / pct(b, 0.99):.2f}x | "
                  f"{statistics.fmean(a) / statistics.fmean(b):.2f}x | {max(a) / max(b):.2f}x |")
    print("\nDid the paced clock keep to wall time? (1.000 = yes; below: simulated time "
          "stretched)\n")
    print("| phase | wall s | simulated s / wall s | SimPlc scans / wall s (nominal "
          f"{1 / PLC_SCAN_S:.0f}) | CPU s / wall s, this process (all threads) |")
    print("|---|---:|---:|---:|---:|")
    for phase in ("idle", "busy"):
        v = pace[phase]
        wall = sum(x[2] for x in v)
        print(f"| {phase} | {wall:.2f} | {sum(x[1] for x in v) / wall:.3f} | "
              f"{sum(x[0] for x in v) / wall:.1f} | {sum(x[3] for x in v) / wall:.2f} |")
    print()


# ---------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="1 run of 10 parts; 2 idle/busy rounds of 1.5 s / 2 cycles")
    parser.add_argument("-n", "--cycles", type=int, default=None,
                        help="parts per run in section 1 (default 100; 10 with --quick)")
    parser.add_argument("--runs", type=int, default=None, help="runs in section 1 (default 3; 1 with --quick)")
    parser.add_argument("--seed", type=int, default=None, help="pass --seed to cellctl run (default: none)")
    parser.add_argument("--rounds", type=int, default=None,
                        help="idle/busy rounds in section 3 (default 6; 2 with --quick)")
    parser.add_argument("--probe-process", action="store_true",
                        help="run the latency probe in a separate process instead of a thread")
    parser.add_argument("--skip-latency", action="store_true", help="sections 1 and 2 only")
    parser.add_argument("--log-level", default="ERROR",
                        help="structlog level of the in-process cell (default ERROR)")
    args = parser.parse_args(argv)
    n = args.cycles or (10 if args.quick else 100)
    runs = args.runs or (1 if args.quick else 3)
    rounds = args.rounds or (2 if args.quick else 6)
    idle_s, busy_cycles = (1.5, 2) if args.quick else (3.0, 6)
    log.configure("console", args.log_level)

    argv_shown = sys.argv[1:] if argv is None else argv
    print(f"## Simulated cell on one simulated clock: {runs} x `cellctl run --sim --cycles {n}` "
          f"(recipe {MAIN_RECIPE})"
          f"{'' if args.skip_latency else ', then the paced cell under a Modbus latency probe'}\n")
    print(f"Machine: {machine()}.\n")
    print(f"Reproduce: `{shlex.join(['.venv/bin/python', 'bench/bench_cell.py', *argv_shown])}`\n",
          flush=True)

    tmp = Path(tempfile.mkdtemp(prefix="bench-cell-"))
    t_all = time.monotonic()
    try:
        res = faster_than_real_time(n, runs, tmp, args.seed)
        sys.stdout.flush()
        where_time_goes(res)
        sys.stdout.flush()
        if not args.skip_latency:
            bench = None
            try:
                t_set_up = time.monotonic()
                bench = PacedBench(tmp / "paced")
                t_set_up = time.monotonic() - t_set_up
                latency(bench, rounds, idle_s, busy_cycles, in_process=not args.probe_process)
                print(f"(paced cell start-up {t_set_up:.1f} s wall)\n")
            finally:
                if bench is not None:
                    bench.stop()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"Whole bench: {time.monotonic() - t_all:.0f} s wall.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
