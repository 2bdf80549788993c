"""The CPU floor of a part: the cell's own events per part, each at the cost of the bare
primitive it cannot do without, beside what each costs in the cell, and what the CPU goals
leave for everything else.

    .venv/bin/python bench/bench_cpu_floor.py            # cell runs of 5 and 25 parts
    .venv/bin/python bench/bench_cpu_floor.py --parts 10,100

Goals (the issue): controller <= 25 ms CPU per part, simulated devices <= 50 ms.

1. Events per part and their cost in the cell: ``bench/bench_cycle_cpu.py``'s in-process
   run (``--child``: ``cellctl run --sim``, wrapped calls counted per thread with
   ``time.thread_time``), twice, marginal per part. The per-event cost is that bench's
   section 2 (exclusive of nested wrapped calls) divided by the calls; the Modbus server's
   and the noise thread's are their whole thread's CPU (section 1) per request / per frame.
   The wrappers' own cost (~2 us a call) is left in here: it is the same for every row and
   shown by that bench.
   Each event's bare primitive, timed here with ``time.thread_time`` (best of 3 rounds):
   * a Modbus request, server side: a do-nothing ``asyncio.Protocol`` on its own loop in a
     thread, answering each request with an answer as long as the PLC's read of the whole
     map (no decode, no register image, no checks); client side: a blocking socket's
     ``sendall`` + ``recv`` of the same bytes. Over loopback TCP, one request at a time;
   * a CAN frame sent: building python-can's ``Message`` (nothing sent anywhere);
   * a CAN frame received: canopen's ``Network.notify`` to one no-op subscriber;
   * a clock callback (the scan, a timer, a delivery, a heartbeat): a ``heapq`` push and pop
     of ``(t, seq, fn)`` and the call of a no-op;
   * a hand-off between two threads (the simulated clock's ``_park``): one thread sets a
     ``threading.Event`` the other waits on, per one-way hand-off, both threads' CPU;
   * a fiducial find: Otsu threshold, connected components and grey centroid on a 160 x 160
     window around the tool's disc in a rendered cell frame (no sub-pixel model, no checks);
   * a frame's render: a flat float32 frame plus its noise, rounded, clipped to 8 bits
     (no scene painted);
   * a frame's noise: the seeded float32 normal draw the camera makes (the stream the
     results depend on: this one *is* the cell's own cost).
   A row's floor is calls per part x the primitive; logic with no primitive (a move's plan,
   the delay-corrected velocities, a burst's set-points, the cycle's state machine, the
   log) counts 0, so the floor is a lower bound.
2. The bare Modbus exchange again, with 0.1-0.2 ms of other work (a few MB of Python
   objects and numpy data walked) before each request, as the cell's other events come
   between two of the PLC's requests: a thread that wakes to cold caches pays more.
3. By side: the floor's sum against the goal, and what the goal leaves per event for all
   the cell's own logic on top of the primitives.
4. The controller's cost above its floor, at least (its events' cost above their floor,
   plus its moves' plans, bursts and delay-corrected velocities), against what its goal
   leaves above the floor: the factor by which that cost would have to shrink.

Every number is measured in this run on this machine; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import asyncio
import heapq
import importlib.util
import shutil
import socket
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import can
import canopen
import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "bench" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


cycle = _load("bench_cycle_cpu")
CTL, SIM = cycle.CTL, cycle.SIM


def best_us(fn, n: int, rounds: int = 3) -> float:
    """CPU us per call of ``fn`` (``n`` calls a round), best of ``rounds``."""
    best = float("inf")
    for _ in range(rounds):
        t0 = time.thread_time()
        for _ in range(n):
            fn()
        best = min(best, time.thread_time() - t0)
    return best / n * 1e6


# ---------------------------------------------------------------------------- primitives
def _other_work():
    """Unrelated work (0.1-0.2 ms here) that walks a few MB of Python objects and numpy
    data, as the cell's other events do between two of the PLC's requests."""
    objects = [{"i": i, "s": str(i)} for i in range(60_000)]
    data = np.random.default_rng(0).random(1_000_000)
    k = [0]

    def work() -> None:
        i = k[0] = (k[0] + 1) % 20
        sum(o["i"] for o in objects[i * 3000:(i + 1) * 3000])
        data[i * 50_000:(i + 1) * 50_000].sum()
    return work


def modbus_us(answer_bytes: int, n: int = 5000, rounds: int = 3,
              between=None) -> tuple[float, float]:
    """(server, client) thread CPU us per request of a bare asyncio server on loopback, each
    the best of ``rounds`` rounds of ``n`` requests (after 200 unshown). The client's is
    timed around each request alone; ``between()``, if given, runs before each request
    (the server's thread sleeps meanwhile)."""
    answer = bytes(answer_bytes)
    marks = {200 + i * n for i in range(rounds + 1)}
    ready: list = []
    server_t: list = []
    stop = threading.Event()

    class Echo(asyncio.Protocol):
        count = 0

        def connection_made(self, transport):
            self.transport = transport

        def data_received(self, data):
            Echo.count += 1
            if Echo.count in marks:
                server_t.append(time.thread_time())
            self.transport.write(answer)

    async def serve():
        loop = asyncio.get_running_loop()
        server = await loop.create_server(Echo, "127.0.0.1", 0)
        ready.append(server.sockets[0].getsockname()[1])
        while not stop.is_set():
            await asyncio.sleep(0.05)
        server.close()

    th = threading.Thread(target=lambda: asyncio.run(serve()), name="floor-server")
    th.start()
    while not ready:
        time.sleep(0.01)
    sock = socket.create_connection(("127.0.0.1", ready[0]))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    request = bytes(21)                     # an FC23 writing one register: 7 + 14 bytes

    def ask(k: int) -> float:
        spent = 0.0
        for _ in range(k):
            if between is not None:
                between()
            t0 = time.thread_time()
            sock.sendall(request)
            got = sock.recv(4096)
            while len(got) < answer_bytes:
                got += sock.recv(4096)
            spent += time.thread_time() - t0
        return spent
    ask(200 - 1)
    client_t = [ask(n) for _ in range(rounds)]
    ask(1)                                  # the last round's end mark
    sock.close()
    stop.set()
    th.join()
    server = min(b - a for a, b in zip(server_t, server_t[1:]))
    return server / n * 1e6, min(client_t) / n * 1e6


def can_send_us() -> float:
    data = bytes(8)
    return best_us(lambda: can.Message(arbitration_id=0x201, data=data, is_extended_id=False,
                                       timestamp=1.0), 50_000)


def can_receive_us() -> float:
    network = canopen.Network()
    network.subscribe(0x181, lambda can_id, data, t: None)
    data = bytes(8)
    return best_us(lambda: network.notify(0x181, data, 1.0), 50_000)


def callback_us() -> float:
    agenda: list = []
    seq = [0]

    def noop():
        return None

    def one():
        seq[0] += 1
        heapq.heappush(agenda, (1.0, seq[0], noop))
        heapq.heappop(agenda)[2]()
    for i in range(64):                      # an agenda of the cell's size
        heapq.heappush(agenda, (2.0 + i, -i, noop))
    return best_us(one, 50_000)


def handoff_us(n: int = 5000) -> float:
    """Both threads' CPU per one-way hand-off of two threads taking turns on Events."""
    go, back = threading.Event(), threading.Event()
    spent: dict = {}

    def other():
        t0 = time.thread_time()
        for _ in range(n):
            go.wait()
            go.clear()
            back.set()
        spent["other"] = time.thread_time() - t0
    th = threading.Thread(target=other, name="floor-handoff")
    th.start()
    t0 = time.thread_time()
    for _ in range(n):
        go.set()
        back.wait()
        back.clear()
    mine = time.thread_time() - t0
    th.join()
    return (mine + spent["other"]) / (2 * n) * 1e6


def vision_us() -> tuple[float, float, float]:
    """(bare find on a window, bare render, noise draw) us, on the cell camera's frame."""
    from cell.sim.assembly import CAMERA_OPTICS
    from drivers.camera.sim import Fiducial, render
    vision = _load("bench_vision")                 # the cell's frame and tool disc, as there
    frame = render(vision.CELL, [Fiducial(*vision.TOOL_AT, vision.TOOL_MM, "tool")], CAMERA_OPTICS,
                   np.random.default_rng(1))
    u, v = (int(c) for c in vision.CELL.project([vision.TOOL_AT])[0])
    win = np.ascontiguousarray(frame[v - 80:v + 80, u - 80:u + 80])
    vv, uu = np.mgrid[0:160, 0:160]

    def find():
        _, mask = cv2.threshold(win, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        i = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        roi = win.astype(np.float64) * (labels == i)
        return (roi * uu).sum() / roi.sum(), (roi * vv).sum() / roi.sum()

    shape = frame.shape
    flat = np.full(shape, CAMERA_OPTICS.background, np.float32)
    noise = np.empty(shape, np.float32)
    tmp = np.empty(shape, np.float32)
    out = np.empty(shape, np.uint8)
    rng = np.random.default_rng(0)
    sigma = np.float32(CAMERA_OPTICS.noise_sigma)

    def draw():
        rng.standard_normal(noise.shape, dtype=np.float32, out=noise)
        np.multiply(noise, sigma, out=noise)

    def paint():
        np.add(flat, noise, out=tmp)
        np.rint(tmp, out=tmp)
        np.clip(tmp, 0, 255, out=tmp)
        out[...] = tmp
    draw()
    return best_us(find, 200), best_us(paint, 100), best_us(draw, 100)


# ---------------------------------------------------------------------------- the table
#: (event, side, label prefix in bench_cycle_cpu's section 2 or a thread name, primitive)
EVENTS = (
    ("Modbus request, server (thread `plc-modbus-server`)", CTL, "thread:plc-modbus-server", "server"),
    ("fiducial find (`MeasuringCamera.find`)", CTL, "`MeasuringCamera.find`", "find"),
    ("CAN frame sent (`VirtualCanBus.send`, controller)", CTL, "`VirtualCanBus.send`", "send"),
    ("CAN frame received (`VirtualCanBus._receive`, controller)", CTL, "`VirtualCanBus._receive`", "receive"),
    ("scan (`CellController._tick`)", CTL, "clock callback `CellController._tick`", "callback"),
    ("watchdog check (`HeartbeatWatchdog._tick`)", CTL, "clock callback `HeartbeatWatchdog._tick`", "callback"),
    ("heartbeat sent (controller's bus)", CTL, "clock callback `ClockCyclicTask._tick`, the controller",
     "callback+send"),
    ("Modbus request, client (`SimPlc._tick`)", SIM, "clock callback `SimPlc._tick`", "client+callback"),
    ("frame delivered (`VirtualWire._deliver`)", SIM, "clock callback `VirtualWire._deliver`", "callback"),
    ("drive timer (`SimStation._on_timer`)", SIM, "clock callback `SimStation._on_timer`", "callback"),
    ("clock hand-off (`VirtualClock._park`)", SIM, "`VirtualClock._park`", "handoff"),
    ("frame rendered (`SimCamera._grab`)", SIM, "`SimCamera._grab`", "render"),
    ("frame's noise (thread `sim-camera-noise`)", SIM, "thread:sim-camera-noise", "noise"),
    ("heartbeat sent (stations' buses)", SIM, "clock callback `ClockCyclicTask._tick`, the stations",
     "callback+send"),
)


#: the controller's wrapped calls with no bare primitive (bench_cycle_cpu's section 2 labels)
PLAIN_CTL = ("`Mover.plan`", "`corrected_velocities`", "`JointStations._burst`")


def per_part(a: dict, b: dict) -> dict:
    """label -> (calls per part, ms per part) of every wrapped call, and thread:<name> ->
    (None, ms per part) of every thread, marginal between the two runs."""
    dn = b["n"] - a["n"]
    out: dict = {}
    acc = defaultdict(lambda: [0.0, 0])
    for r, sign in ((a, -1), (b, 1)):
        for _t, lab, _sd, sec, k in r["spent"]:
            acc[lab][0] += sign * sec
            acc[lab][1] += sign * k
    for lab, (sec, k) in acc.items():
        out[lab] = (k / dn, sec / dn * 1e3)
    for t in set(a["threads"]) | set(b["threads"]):
        out[f"thread:{t}"] = (None, (b["threads"].get(t, 0.0) - a["threads"].get(t, 0.0)) / dn * 1e3)
    return out


def find_row(rows: dict, prefix: str):
    hits = [v for k, v in rows.items() if k.startswith(prefix)]
    if len(hits) != 1:
        raise RuntimeError(f"{len(hits)} rows of bench_cycle_cpu start with {prefix!r}: the code "
                           f"changed under this bench")
    return hits[0]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--parts", help="N1,N2 parts of the two cell runs (default 5,25)")
    args = p.parse_args(argv)
    n1, n2 = cycle.parse_parts(p, args.parts, (5, 25))
    from drivers.plc.register_map import PLC_MAP

    print("## The CPU floor of a part: the cell's events at the cost of their bare primitives\n")
    print(f"Machine: {cycle.machine()}.\n")
    print(f"Reproduce: `.venv/bin/python bench/bench_cpu_floor.py --parts {n1},{n2}`\n", flush=True)
    tmp = Path(tempfile.mkdtemp(prefix="bench-cpu-floor-"))
    t_all = time.monotonic()
    try:
        cycle.run_child(1, tmp)                   # warm-up, as bench_cycle_cpu
        rows = per_part(cycle.run_child(n1, tmp), cycle.run_child(n2, tmp))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    server, client = modbus_us(9 + 2 * PLC_MAP.size)
    other = _other_work()
    other_us = best_us(other, 2000)
    server_cold, client_cold = modbus_us(9 + 2 * PLC_MAP.size, n=2000, between=other)
    send, receive, callback, handoff = can_send_us(), can_receive_us(), callback_us(), handoff_us()
    find, render, noise = vision_us()
    prim = {"server": server, "find": find, "send": send, "receive": receive, "callback": callback,
            "callback+send": callback + send, "client+callback": client + callback,
            "handoff": handoff, "render": render, "noise": noise}
    requests = find_row(rows, "clock callback `SimPlc._tick`")[0]
    frames = find_row(rows, "`SimCamera._grab`")[0]

    print(f"### 1. Events per part, their cost in the cell and their bare primitive "
          f"(cell runs of {n1} and {n2} parts, marginal)\n")
    print("| event | side | per part | in the cell, us each | bare primitive, us each | "
          "floor, ms / part |")
    print("|---|---|---:|---:|---:|---:|")
    floor, ours, events = defaultdict(float), defaultdict(float), defaultdict(float)
    for name, side, key, what in EVENTS:
        calls, ms = find_row(rows, key)
        if calls is None:               # a whole thread: per request / per frame
            calls = requests if what == "server" else frames
        cost = prim[what]
        floor[side] += calls * cost / 1e3
        ours[side] += ms
        events[side] += calls
        print(f"| {name} | {side} | {calls:.0f} | {ms / calls * 1e3 if calls else 0:.1f} | "
              f"{cost:.1f} | {calls * cost / 1e3:.1f} |")

    print("\nThe simulated PLC's writes (a few per part) are not counted as requests; the "
          "controller's planning, bursts, cycle and log have no primitive and count 0 here.\n")
    print("### 2. The bare Modbus exchange back to back and with other work between requests\n")
    print("| requests | server thread, us each | client, us each (the exchange alone) |")
    print("|---|---:|---:|")
    print(f"| back to back (the floor above) | {server:.1f} | {client:.1f} |")
    print(f"| after {other_us:.0f} us of other work each (the server's thread asleep meanwhile) | "
          f"{server_cold:.1f} | {client_cold:.1f} |")
    print(f"\nIn the cell (section 1): server {find_row(rows, 'thread:plc-modbus-server')[1] / requests * 1e3:.1f}"
          f" us, client with its scan {find_row(rows, 'clock callback `SimPlc._tick`')[1] / requests * 1e3:.1f} us "
          f"per request.\n")
    print("### 3. By side: the floor against the goal\n")
    print("| side | these events in the cell, ms / part | their floor, ms / part | goal | "
          "goal - floor | events / part | left per event for the cell's own logic, us |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for side in (CTL, SIM):
        goal = cycle.GOAL_MS[side]
        left = goal - floor[side]
        print(f"| {side} | {ours[side]:.1f} | {floor[side]:.1f} | {goal:g} | {left:.1f} | "
              f"{events[side]:.0f} | {left / events[side] * 1e3:.1f} |")
    print("\n### 4. The controller: what its goal leaves above its floor\n")
    above = ours[CTL] - floor[CTL]
    plain = sum(find_row(rows, key)[1] for key in PLAIN_CTL)
    own, room = above + plain, cycle.GOAL_MS[CTL] - floor[CTL]
    print("| controller | ms / part |")
    print("|---|---:|")
    print(f"| its events of section 1, in the cell | {ours[CTL]:.1f} |")
    print(f"| their floor | {floor[CTL]:.1f} |")
    print(f"| their cost above the floor (the cell's logic, wake-ups, cold caches) | {above:.1f} |")
    print(f"| moves' plans, bursts and delay-corrected velocities (no primitive) | {plain:.1f} |")
    print(f"| the controller's cost above its floor, at least | {own:.1f} |")
    print(f"| what the goal ({cycle.GOAL_MS[CTL]:g}) leaves above the floor | {room:.1f} |")
    print(f"| **that cost would have to shrink by** | **{own / room:.1f} x** |")
    print("\nAt least: the scan's work beyond its callback, the camera driver's and the log's "
          "threads and the cycle's own steps are left out.")
    print(f"\nWhole bench: {time.monotonic() - t_all:.0f} s wall.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
