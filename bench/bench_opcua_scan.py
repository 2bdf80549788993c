"""The controller's scan period with the OPC UA server off and on, in the same run.

Runs the real :class:`~cell.controller.CellController` on the wall clock, as
bench/bench_scan.py does (its PLC link the real pymodbus server on loopback, driven by a
:class:`~cell.sim.plc.SimPlc` that keeps its heartbeat alive; recipes and log real), with
stations whose arm moves all the time, so the published status changes at its sampling
rate (ten messages a second) and the server has axes to write. Phases alternate, each
``--seconds`` long, ``--rounds`` times:

* ``off``: no OPC UA server;
* ``on``: the server (:class:`~cell.opcua.server.OpcuaServer`, in this process, as the
  cell runs it) with an MES stand-in in a process of its own, an asyncua client that
  browses the whole subset and reads every variable as fast as it can, subscribed to the
  axes' values and the result events.

The last column compares each phase's median period with the median of the ``off``
phases (goal: at most 1.05). The scan keeps its period by its schedule, so the period moves
only when a scan overruns or starts late; ``scan µs p50`` is the time one scan takes, the
first figure a busy neighbour thread (the server shares the interpreter) would raise.

    .venv/bin/python bench/bench_opcua_scan.py               # 10 s per phase, 2 rounds
    .venv/bin/python bench/bench_opcua_scan.py --seconds 2 --rounds 1   # quick look
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cell import log, progress  # noqa: E402
from cell.clock import MonotonicClock  # noqa: E402
from cell.controller import CellController, ControllerSettings  # noqa: E402
from cell.cycle.runner import CycleRunner  # noqa: E402
from cell.cyclelog import CycleLog  # noqa: E402
from cell.kinematics import Scara  # noqa: E402
from cell.opcua.config import OpcuaSection  # noqa: E402
from cell.opcua.server import OpcuaServer  # noqa: E402
from cell.recipes.store import RecipeStore  # noqa: E402
from cell.sim.plc import SimPlc  # noqa: E402
from drivers.plc.server import PlcLink  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SCAN_S = 0.01

#: the MES stand-in: browse everything, read every variable, count reads; prints the count
CLIENT = r"""
import asyncio, sys
from asyncua import Client, ua

async def main(url, seconds):
    reads, got = 0, []
    class H:
        def datachange_notification(self, node, val, data): got.append(val)
        def event_notification(self, event): got.append(event)
    async with Client(url, timeout=30) as c:
        idx = await c.get_namespace_index("urn:cell-controller:opcua")
        system = c.get_node(ua.NodeId("MotionDeviceSystem", idx))
        axes = [c.get_node(ua.NodeId(f"MotionDeviceSystem.MotionDevices.Robot.Axes.{j}.ParameterSet.ActualPosition",
                                     idx)) for j in ("j1", "j2", "j3", "j4")]
        sub = await c.create_subscription(50, H())
        await sub.subscribe_data_change(axes)
        await sub.subscribe_events(c.get_node(ua.NodeId("MotionDeviceSystem.Controllers.Controller.ResultManagement", idx)))
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while loop.time() < end:
            nodes = [system]
            for n in nodes:
                nodes.extend(await n.get_children())
                if (await n.read_node_class()) == ua.NodeClass.Variable:
                    await n.read_data_value(raise_on_bad_status=False)
                    reads += 1
    print(reads, len(got))

asyncio.run(main(sys.argv[1], float(sys.argv[2])))
"""


class MovingStations:
    """Stations as the scan sees them: no fault, the arm always moving (a slow sine)."""

    fault = None

    def actual_positions(self):
        t = time.monotonic()
        return np.array([30 * np.sin(t), 20 * np.cos(t), -10 + 5 * np.sin(t / 2), 45 * np.sin(t / 3)])


def measure(ctl: CellController, seconds: float) -> dict:
    stamps: list[float] = []
    work: list[float] = []
    orig = ctl.scan

    def scan():
        t0 = time.perf_counter()
        stamps.append(t0)
        orig()
        work.append(time.perf_counter() - t0)
    ctl.scan = scan
    time.sleep(seconds)
    ctl.scan = orig
    d = np.diff(stamps) * 1e3
    return {"scans": len(stamps), "p50": float(np.percentile(d, 50)), "p99": float(np.percentile(d, 99)),
            "max": float(d.max()), "late": int((d > 2 * SCAN_S * 1e3).sum()),
            "work": float(np.percentile(work, 50)) * 1e6}


def phase_on(ctl: CellController, seconds: float, pki: Path) -> dict:
    srv = OpcuaServer(OpcuaSection(port=0, pki=str(pki)), ctl.publisher, "bench", "SCARA seed000", insecure=True)
    srv.start()
    client = subprocess.Popen([sys.executable, "-c", CLIENT, srv.url, str(seconds + 2.0)],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        time.sleep(1.0)                      # the client connected and reading
        row = measure(ctl, seconds)
        out, _ = client.communicate(timeout=120)
    finally:
        if client.poll() is None:
            client.kill()
        srv.stop()
    reads, notes = (int(x) for x in out.split()) if out.strip() else (0, 0)
    row.update(reads=reads, notes=notes, dropped=srv.dropped)
    return row


def controller(tmp: Path, clock) -> tuple[CellController, PlcLink, CycleLog]:
    """The real controller on ``clock`` with the repo's recipes copied into ``tmp``, a log
    there, its PLC link (not started) and :class:`MovingStations`; not started."""
    rdir = tmp / "recipes"
    shutil.copytree(REPO / "recipes", rdir)
    cyclelog = CycleLog(tmp / "cell.sqlite")
    store = RecipeStore(rdir, commit=cyclelog.record_recipe_changes, clock=clock)
    link = PlcLink(clock=clock)
    stations = MovingStations()
    runner = CycleRunner(Scara.preset("seed000"), stations, None, cyclelog, clock=clock)
    ctl = CellController(link, stations, runner, cyclelog, store,
                         ControllerSettings(scan_s=SCAN_S, plc_heartbeat_timeout_s=1.0), clock=clock)
    return ctl, link, cyclelog


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each phase (default 10)")
    ap.add_argument("--rounds", type=int, default=2, help="off/on pairs (default 2)")
    args = ap.parse_args()
    log.configure("console", "ERROR")
    tmp = Path(tempfile.mkdtemp(prefix="bench-opcua-"))
    clock = MonotonicClock()
    ctl, link, cyclelog = controller(tmp, clock)
    ctl.start()
    port = link.start("127.0.0.1", 0)
    plc = SimPlc("127.0.0.1", port, clock=clock)
    plc.start()
    rows = []
    try:
        time.sleep(1.0)
        for _ in progress.each(range(args.rounds), "rounds", "round"):
            rows.append(("off", measure(ctl, args.seconds)))
            rows.append(("on", phase_on(ctl, args.seconds, tmp / "pki")))
    finally:
        plc.stop()
        link.stop()
        ctl.stop()
        cyclelog.close()
    print(f"scan period {SCAN_S * 1e3:.0f} ms, wall clock, {args.seconds:.0f} s per phase, {args.rounds} "
          f"round(s); load average (1 min) at the end {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs; "
          f"python {sys.version.split()[0]}")
    print()
    print("| OPC UA | scans | period p50 ms | p99 ms | max ms | periods > 20 ms | scan µs p50 | client reads/s "
          "| p50 / off p50 |")
    print("|---|---|---|---|---|---|---|---|---|")
    off = float(np.median([r["p50"] for name, r in rows if name == "off"]))
    for name, r in rows:
        rate = f"{r['reads'] / args.seconds:.0f}" if name == "on" else "-"
        print(f"| {name} | {r['scans']} | {r['p50']:.2f} | {r['p99']:.2f} | {r['max']:.2f} | {r['late']} "
              f"| {r['work']:.0f} | {rate} | {r['p50'] / off:.3f} |")
    on = [r for name, r in rows if name == "on"]
    print()
    print(f"median period on / off: {float(np.median([r['p50'] for r in on])) / off:.3f} (goal ≤ 1.05); "
          f"p99 on / off: {float(np.median([r['p99'] for r in on])) / float(np.median([r['p99'] for n, r in rows if n == 'off'])):.2f}; "
          f"messages the server dropped: {sum(r['dropped'] for r in on)}; "
          f"PLC heartbeat faults: {int(ctl.fault_code == 101)}")
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
