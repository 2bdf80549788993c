"""The simulated cell end to end: controller overhead per cycle, and Modbus latency under load.

    .venv/bin/python bench/bench_cell.py             # 30 cycles; 6 rounds of 3 s idle + 6 cycles
    .venv/bin/python bench/bench_cell.py --quick     # 8 cycles; 2 rounds of 1.5 s idle + 2 cycles
    .venv/bin/python bench/bench_cell.py --probe-process   # latency probe in its own process

The cell is the product's ``cell.app.Cell(sim=True)``, its PLC the simulated PLC
(``cell.sim.plc.SimPlc``, a real Modbus TCP client, scan 10 ms) doing the full
handshake of ``SimPlc.run_cycle``. Sizes are the system tests' (a 640x512 camera at 0.08
mm/px, the same field as the default 1280x1024 at 0.04; ``--full-frame`` for the latter) and
the recipe is a fast one (joints at 240 deg/s, 2 mm z stroke), written by this script.

1. Controller overhead. Timing wrappers are set on the *instances* of the cell's motion
   object (``move_to``, ``wait_reached``), its camera (``grab``: the sim renders the frame)
   and its cycle log (``add_cycle``) before ``Cell.start()``; they count only calls made in
   the cycle worker thread. Per cycle: ``CycleRecord.cycle_time_s`` (the runner's own clock,
   APPROACH to VERIFY; it ends *before* the cycle log row is written), time in motion, time in
   camera grabs, and the remainder = controller overhead (vision maths, compensation, state
   machine, step bookkeeping). The log write (SQLite WAL, synchronous=FULL) is outside
   ``cycle_time_s`` and shown on its own; the PLC round trip is the wall time of
   ``SimPlc.run_cycle`` (recipe ack, ready, execute, done, acknowledge).
2. Modbus latency. A probe (pymodbus sync ``ModbusTcpClient``) reads holding registers 0..19
   every 2 ms from the cell's PLC link and, alternately, from a bare pymodbus server
   (``bench_modbus.py``'s baseline) in the same process as the cell. Idle windows (PLC
   scanning, no cycle) and busy windows (back-to-back cycles) alternate, so machine drift
   hits both; a request counts for a window only if it starts and ends inside it.
   By default the probe is a thread of this process (it then also waits for the GIL on the
   client side, as any in-process client would); ``--probe-process`` runs it in a separate
   process, which measures the server side only.

Every number is measured in this run; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import platform
import shutil
import statistics
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import pymodbus  # noqa: E402
from pymodbus.client import ModbusTcpClient  # noqa: E402
from pymodbus.server import ModbusTcpServer  # noqa: E402

from cell import log  # noqa: E402
from cell.app import Cell  # noqa: E402
from cell.config import CellConfig, SimSection  # noqa: E402
from drivers.plc.conformance import ServerThread  # noqa: E402
from drivers.plc.register_map import PLC_MAP  # noqa: E402
from drivers.plc.server import build_datastore  # noqa: E402
from cell.sim.plc import SimPlc  # noqa: E402

RECIPE_NAME, RECIPE_NUMBER = "bench-fast", 7
RECIPE = f"""\
name: {RECIPE_NAME}
number: {RECIPE_NUMBER}
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
verify:
  tolerance_mm: 0.08
"""
HEARTBEAT_TIMEOUT_S = 0.4
PLC_SCAN_S = 0.010
PROBE_PERIOD_S = 0.002
PROBE_COUNT = 20                      # registers 0..19, one FC3
CYCLE_THREAD = "cell-cycle"           # the worker thread's name (cell/controller.py)


# ---------------------------------------------------------------------------- set-up
def make_config(tmp: Path, camera_px: tuple[int, int], mm_per_px: float) -> CellConfig:
    """A sim cell config: the repo's recipes plus ours, log in ``tmp``, PLC on loopback."""
    rdir = tmp / "recipes"
    shutil.copytree(REPO / "recipes", rdir)
    (rdir / f"{RECIPE_NAME}.yaml").write_text(RECIPE, encoding="utf-8")
    cfg = CellConfig(sim=SimSection(plant=str(REPO / "deploy/plants/default.yaml"),
                                    camera_px=camera_px, camera_mm_per_px=mm_per_px))
    return cfg.model_copy(update={
        "plc": cfg.plc.model_copy(update={"host": "127.0.0.1",
                                          "heartbeat_timeout_s": HEARTBEAT_TIMEOUT_S}),
        "log": cfg.log.model_copy(update={"path": str(tmp / "cell.sqlite")}),
        "recipes": cfg.recipes.model_copy(update={"directory": str(rdir)}),
    })


class Meter:
    """Wall time spent in wrapped methods, counted only in the cycle worker thread."""

    def __init__(self):
        self._lock = threading.Lock()
        self._t: dict[str, float] = defaultdict(float)
        self._n: dict[str, int] = defaultdict(int)

    def wrap(self, obj, method: str, key: str) -> None:
        """Shadow ``obj.method`` by a timing wrapper (an instance attribute; the class and
        every other instance stay untouched)."""
        orig = getattr(obj, method)

        def timed(*args, **kwargs):
            if threading.current_thread().name != CYCLE_THREAD:
                return orig(*args, **kwargs)
            t0 = time.monotonic()
            try:
                return orig(*args, **kwargs)
            finally:
                dt = time.monotonic() - t0
                with self._lock:
                    self._t[key] += dt
                    self._n[key] += 1

        setattr(obj, method, timed)

    def take(self) -> tuple[dict[str, float], dict[str, int]]:
        """Totals since the last take (seconds, calls), then reset."""
        with self._lock:
            t, n = dict(self._t), dict(self._n)
            self._t.clear()
            self._n.clear()
        return t, n


class Bench:
    """A started sim cell with wrapped devices, its SimPlc, and a bare pymodbus server."""

    def __init__(self, tmp: Path, camera_px: tuple[int, int], mm_per_px: float):
        self.config = make_config(tmp, camera_px, mm_per_px)
        self.cell = Cell(self.config, sim=True, plc_port=0, jobs=False)
        self.meter = Meter()
        # before start(): the cycle runner and the MeasuringCamera get these same objects
        self.meter.wrap(self.cell.motion, "move_to", "move_to")
        self.meter.wrap(self.cell.motion, "wait_reached", "wait_reached")
        self.meter.wrap(self.cell.camera, "grab", "grab")
        self.meter.wrap(self.cell.cyclelog, "add_cycle", "log_write")
        self.plc: SimPlc | None = None
        self.bare: ServerThread | None = None
        self.port = self.cell.start()
        self.plc = SimPlc("127.0.0.1", self.port, scan_s=PLC_SCAN_S)
        self.plc.start()
        self.bare = ServerThread(lambda addr: ModbusTcpServer(build_datastore(PLC_MAP, None),
                                                              address=addr), name="bare-pymodbus")
        self.bare_port = self.bare.start()
        self.next_part = 1
        self.plc.wait_until(lambda i: PLC_MAP.bits("status_word", i["status_word"])["ready"],
                            10.0, "cell ready")

    def cycle(self) -> dict:
        """One cycle through the PLC handshake; the record and the metered times."""
        part_id = self.next_part
        self.next_part += 1
        recipe = self.cell.recipes.active[RECIPE_NAME].recipe
        self.cell.sim.feeder.present(part_id, recipe)
        self.meter.take()
        t0 = time.monotonic()
        result = self.plc.run_cycle(recipe.number, part_id, timeout_s=20.0)
        round_trip = time.monotonic() - t0
        t, n = self.meter.take()
        out = self.cell.controller.last_outcome
        rec = out.record if out is not None else None
        if not result["done"] or rec is None or rec.part_id != part_id or rec.status != "done":
            raise RuntimeError(f"cycle of part {part_id} did not end done: {result}, "
                               f"fault {self.cell.controller.fault_code} "
                               f"{self.cell.controller.fault_text!r}")
        return {"record": rec, "round_trip": round_trip, "t": t, "n": n}

    def stop(self) -> None:
        for step in (lambda: self.plc and self.plc.stop(), self.cell.stop,
                     lambda: self.bare and self.bare.stop()):
            try:
                step()
            except Exception as exc:               # noqa: BLE001 -- take the rest down too
                print(f"stop failed: {exc!r}", file=sys.stderr)


# ---------------------------------------------------------------------------- statistics
def pct(samples: list[float], q: float) -> float:
    """Nearest-rank percentile (with n < 20, p95 is the maximum)."""
    s = sorted(samples)
    return s[max(0, math.ceil(q * len(s)) - 1)]


def ms_row(name: str, xs: list[float]) -> str:
    return (f"| {name} | {statistics.fmean(xs) * 1e3:.1f} | {pct(xs, 0.50) * 1e3:.1f} | "
            f"{pct(xs, 0.95) * 1e3:.1f} |")


# ---------------------------------------------------------------------------- part 1
def overhead(bench: Bench, n: int, warmup: int) -> None:
    for _ in range(warmup):
        bench.cycle()
    rows = [bench.cycle() for _ in range(n)]
    cols: dict[str, list[float]] = defaultdict(list)
    steps: dict[str, list[float]] = defaultdict(list)
    calls: dict[str, list[int]] = defaultdict(list)
    for r in rows:
        rec, t = r["record"], r["t"]
        motion = t.get("move_to", 0.0) + t.get("wait_reached", 0.0)
        grab = t.get("grab", 0.0)
        over = rec.cycle_time_s - motion - grab
        cols["cycle time (CycleRecord.cycle_time_s)"].append(rec.cycle_time_s)
        cols["motion: move_to + wait_reached"].append(motion)
        cols["of which move_to (set-points sent)"].append(t.get("move_to", 0.0))
        cols["camera grab (sim rendering)"].append(grab)
        cols["**controller overhead** = cycle - motion - grab"].append(over)
        cols["cycle log write (SQLite FULL; after cycle time)"].append(t.get("log_write", 0.0))
        cols["PLC round trip (SimPlc.run_cycle)"].append(r["round_trip"])
        cols["round trip - cycle time - log write"].append(
            r["round_trip"] - rec.cycle_time_s - t.get("log_write", 0.0))
        for k, v in rec.step_times.items():
            steps[k].append(v)
        for k, v in r["n"].items():
            calls[k + " calls"].append(v)
        calls["compensation moves (CycleRecord.moves)"].append(rec.moves or 0)
    print(f"### 1. Controller overhead per cycle ({n} cycles after {warmup} warm-up, "
          f"no latency probe)\n")
    print("| per cycle | mean (ms) | p50 (ms) | p95 (ms) |")
    print("|---|---:|---:|---:|")
    for name, xs in cols.items():
        print(ms_row(name, xs))
    cyc = cols["cycle time (CycleRecord.cycle_time_s)"]
    over = cols["**controller overhead** = cycle - motion - grab"]
    rt = cols["PLC round trip (SimPlc.run_cycle)"]
    dev = [m + g for m, g in zip(cols["motion: move_to + wait_reached"],
                                 cols["camera grab (sim rendering)"])]
    share = [o / c for o, c in zip(over, cyc)]
    share_rt = [(r - d) / r for r, d in zip(rt, dev)]
    print(f"| overhead share of cycle time (per cycle, %) | {statistics.fmean(share) * 100:.1f} | "
          f"{pct(share, 0.5) * 100:.1f} | {pct(share, 0.95) * 100:.1f} |")
    print(f"| (round trip - motion - grab) / round trip (%) | {statistics.fmean(share_rt) * 100:.1f} | "
          f"{pct(share_rt, 0.5) * 100:.1f} | {pct(share_rt, 0.95) * 100:.1f} |")
    print("\n| step (CycleRecord.step_times) | mean (ms) |")
    print("|---|---:|")
    for k, v in steps.items():
        print(f"| {k} | {statistics.fmean(v) * 1e3:.1f} |")
    print("| logging (the row's own write; in the PLC's cycle_time_ms, not in the row) | "
          f"{statistics.fmean(cols['cycle log write (SQLite FULL; after cycle time)']) * 1e3:.1f} |")
    print("\n| per cycle, in the cycle thread | mean count |")
    print("|---|---:|")
    for k in sorted(calls):
        print(f"| {k} | {statistics.fmean(calls[k]):.1f} |")
    print()


# ---------------------------------------------------------------------------- part 2
def probe_loop(ports: dict[str, int], period_s: float, stop, conn=None) -> list | None:
    """Read registers 0..PROBE_COUNT-1 from each port every ``period_s`` (fixed schedule, no
    catch-up; the order of the servers alternates) until ``stop`` is set. Returns (or sends on ``conn``) a list of
    (name, t_start, t_end, ok) with ``time.monotonic()`` stamps."""
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


def latency(bench: Bench, rounds: int, idle_s: float, busy_cycles: int, in_process: bool) -> None:
    ports = {"ours (PlcLink)": bench.port, "bare pymodbus": bench.bare_port}
    probe = Probe(ports, in_process)
    windows: list[tuple[str, float, float]] = []
    scans: dict[str, list[tuple[int, float]]] = defaultdict(list)
    try:
        time.sleep(0.5)                               # probe connected and on its schedule
        for _ in range(rounds):
            s0, t0 = bench.plc.scans, time.monotonic()
            time.sleep(idle_s)
            t1 = time.monotonic()
            windows.append(("idle", t0, t1))
            scans["idle"].append((bench.plc.scans - s0, t1 - t0))
            s0, t0 = bench.plc.scans, time.monotonic()
            for _ in range(busy_cycles):
                bench.cycle()
            t1 = time.monotonic()
            windows.append(("busy", t0, t1))
            scans["busy"].append((bench.plc.scans - s0, t1 - t0))
    finally:
        samples = probe.finish()
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
    print(f"### 2. Modbus FC3 latency, {PROBE_COUNT} registers every {PROBE_PERIOD_S * 1e3:g} ms "
          f"per server, probe in {where}\n")
    print(f"{rounds} rounds of: idle {idle_s:g} s (SimPlc scanning, no cycle), then "
          f"{busy_cycles} back-to-back cycles (busy).\n")
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
                  f"**{statistics.fmean(b) / statistics.fmean(i):.2f}x** | |")
    o, r = "ours (PlcLink)", "bare pymodbus"
    for phase in ("idle", "busy"):
        a, b = lat[(o, phase)], lat[(r, phase)]
        if a and b:
            print(f"| ours / bare, {phase} | | | | {pct(a, 0.5) / pct(b, 0.5):.2f}x | "
                  f"{pct(a, 0.99) / pct(b, 0.99):.2f}x | "
                  f"{statistics.fmean(a) / statistics.fmean(b):.2f}x | |")
    rate = {p: sum(n for n, _ in v) / sum(d for _, d in v) for p, v in scans.items()}
    print(f"\nSimPlc scans completed per second (nominal {1 / PLC_SCAN_S:.0f}): "
          f"idle {rate['idle']:.1f}, busy {rate['busy']:.1f}.\n")


# ---------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8 cycles, 2 idle/busy rounds")
    parser.add_argument("-n", type=int, default=None, help="measured cycles in part 1 (default 30)")
    parser.add_argument("--rounds", type=int, default=None, help="idle/busy rounds in part 2 (default 6)")
    parser.add_argument("--full-frame", action="store_true",
                        help="the product's default camera: 1280x1024 at 0.04 mm/px")
    parser.add_argument("--probe-process", action="store_true",
                        help="run the latency probe in a separate process instead of a thread")
    parser.add_argument("--log-level", default="ERROR",
                        help="structlog level of the cell (default ERROR; INFO logs to stderr)")
    args = parser.parse_args(argv)
    n = args.n or (8 if args.quick else 30)
    rounds = args.rounds or (2 if args.quick else 6)
    idle_s, busy_cycles = (1.5, 2) if args.quick else (3.0, 6)
    camera_px, mm_per_px = ((1280, 1024), 0.04) if args.full_frame else ((640, 512), 0.08)
    log.configure("console", args.log_level)

    tmp = Path(tempfile.mkdtemp(prefix="bench-cell-"))
    bench = None
    try:
        t_set_up = time.monotonic()
        bench = Bench(tmp, camera_px, mm_per_px)
        t_set_up = time.monotonic() - t_set_up
        c = bench.config
        print(f"## Simulated cell: camera {camera_px[0]}x{camera_px[1]} px at {mm_per_px} mm/px, "
              f"recipe {RECIPE_NAME} (lattice, max 4 moves, joints 240 deg/s, z -20 -> -22 mm), "
              f"PLC heartbeat timeout {c.plc.heartbeat_timeout_s} s, controller scan "
              f"{c.controller.scan_s * 1e3:g} ms, SimPlc scan {PLC_SCAN_S * 1e3:g} ms, recipe refresh "
              f"{c.controller.recipe_refresh_s:g} s, cell log level {args.log_level}; "
              f"Python {platform.python_version()}, pymodbus {pymodbus.__version__}, "
              f"{platform.machine()}, {os.cpu_count()} CPUs (cell start-up {t_set_up:.1f} s)\n")
        overhead(bench, n, warmup=1)
        latency(bench, rounds, idle_s, busy_cycles, in_process=not args.probe_process)
    finally:
        if bench is not None:
            bench.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
