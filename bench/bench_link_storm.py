"""The PLC link under attack: fuzz and connection storms against ``cellctl serve --sim``.

One run, four phases on one served cell (a ``serve --sim`` child, clock paced to wall time,
product defaults for the link: heartbeat time-out 1 s, 8 connections, 4 per client host,
60 s idle, 5 s half frame):

1. **quiet**: the control. The simulated PLC (``cell.sim.plc.SimPlc``, a real Modbus
   client in a thread here) runs cycles back to back and beats every scan; a legitimate
   reader (a raw socket, FC3 of 20 registers) measures its round trips.
2. **fuzz**: ``--attackers`` processes send mutated frames as fast as they can (random
   bytes; valid MBAP headers with random PDUs; bad lengths; writes from a client that does
   not own the link), reconnecting whenever the server closes them.
3. **connections**: the same processes open ``--sockets`` idle connections each, leave
   half frames (slowloris) and reconnect as they are shed.
4. **tls**: the same processes storm the Modbus/TCP Security listener (served on its own
   port with certificates made for the run): full TLS handshakes without a client
   certificate (refused in the handshake), garbage instead of a ClientHello, and silent
   connections left half-open (up to ``--sockets`` each) until shed or timed out.
During every storm, each second a *new* legitimate client connects (plain TCP; during the
TLS storm over TLS with an Operator certificate) and reads once; it counts as served if
answered within 2 s.

Hosts. As in a plant, each attacker connects from a host of its own (127.0.0.2, .3, ...:
Linux routes all of 127/8 to lo), and the PLC, the reader and the new clients from
127.0.0.1. The allow-list lists them all: allowed-but-hostile clients are the worst case,
since a host outside it is closed at connect. ``--same-host`` puts the attackers on
127.0.0.1 too, a case a per-host quota cannot tell apart (reported as what it is).

Phases 2 to 4 are repeated ``--rounds`` times (default 2). Memory: each round's high-water
is the largest RSS after its storms. The verdict is on the least-squares slope of the
high-water over the second half of the rounds (the first half is warm-up): *flat* when at
most ``--flat-mb`` (0.5) MB per round. A leak keeps its slope round after round; a level
being reached does not. With fewer than 8 rounds no verdict is given. ``--control`` then
runs the same schedule on a fresh cell with no attack, so the cell's own warm-up is
measured in the same run.

5. **settle**: 5 s with no attack, then the server's memory is read again.

Printed, as Markdown tables: the reader's p50/p99 per phase and its ratio to the quiet
control of the same run; false watchdog trips (fault 101 or ``plc_link_ok`` low while the
PLC beats: the aim is 0) and the PLC's cycles per phase; the server's resident memory
(VmRSS) before, after each storm and after settling; new clients served during each storm.
Attackers run in their own processes so this process's GIL does not colour the latencies.

    .venv/bin/python bench/bench_link_storm.py               # 20 s per phase
    .venv/bin/python bench/bench_link_storm.py --quick       # 6 s per phase
    .venv/bin/python bench/bench_link_storm.py --quick --rounds 16 --control  # the memory verdict
"""
from __future__ import annotations

import argparse
import os
import platform
import random
import re
import resource
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cell import progress  # noqa: E402
from cell.clock import MonotonicClock  # noqa: E402
from cell.sim.plc import SimPlc, SimPlcError  # noqa: E402
from drivers.plc.register_map import PLC_MAP  # noqa: E402

FC3 = struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 0, 20)
LEGIT_HOST = "127.0.0.1"     # the PLC, the reader and the new clients connect from here
PHASES = ("fuzz", "connections", "tls")      # the storms, in the order of one round

ATTACKER = r'''
import os, random, resource, socket, ssl, struct, sys, time
mode, port, seconds, nsock, seed, src = (sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]),
                                         int(sys.argv[5]), sys.argv[6])
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
rnd = random.Random(seed)
end = time.monotonic() + seconds
sent = conns = 0

def frame():
    k = rnd.randrange(5)
    if k == 0:
        return os.urandom(rnd.randrange(1, 300))                      # noise
    pdu = bytes([rnd.choice([3, 6, 16, 5, 15, 1, 23, 0x41, 0x90, rnd.randrange(256)])]) + os.urandom(rnd.randrange(0, 40))
    if k == 1:
        return struct.pack(">HHHB", rnd.randrange(65536), 0, len(pdu) + 1, 1) + pdu   # well framed, random PDU
    if k == 2:
        return struct.pack(">HHHB", rnd.randrange(65536), rnd.randrange(65536), rnd.randrange(65536), 1) + pdu  # bad header
    if k == 3:                                                        # a write: this client owns nothing
        return struct.pack(">HHHBBHH", rnd.randrange(65536), 0, 6, 1, 6, rnd.choice([1, 11, 20, 24]), rnd.randrange(65536))
    return struct.pack(">HHHB", 1, 0, 200, 1) + pdu[:3]              # a frame that never completes

def connect():
    global conns
    s = socket.socket()
    s.settimeout(2)
    s.bind((src, 0))                                                  # this attacker's host
    s.connect(("127.0.0.1", port))
    s.setblocking(False)
    conns += 1
    return s

def reap(socks):
    """Let go of the sockets the server closed (non-blocking peeks)."""
    for s in list(socks):
        try:
            if s.recv(1) == b"":
                raise OSError("closed")
        except BlockingIOError:
            pass
        except OSError:
            socks.remove(s)
            s.close()

if mode == "fuzz":
    socks = []
    while time.monotonic() < end:
        try:
            while len(socks) < 4:
                socks.append(connect())
            for s in list(socks):
                try:
                    s.send(frame())
                    sent += 1
                    try:
                        s.recv(65536)
                    except BlockingIOError:
                        pass
                except OSError:
                    socks.remove(s)
                    s.close()
        except OSError:
            time.sleep(0.01)
elif mode == "tls":                                                   # Modbus/TCP Security storm
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    socks, n = [], 0
    while time.monotonic() < end:
        k = rnd.randrange(3)
        try:
            if k == 0:                                                # a handshake without a client certificate
                with socket.create_connection(("127.0.0.1", port), timeout=2, source_address=(src, 0)) as raw:
                    conns += 1
                    try:
                        with ctx.wrap_socket(raw) as t:
                            t.send(frame())
                            t.recv(1)                                 # TLS 1.3: the refusal comes here
                    except OSError:
                        pass
                    sent += 1
            elif k == 1:                                              # garbage instead of a ClientHello
                s = connect()
                s.send(os.urandom(rnd.randrange(1, 600)))
                sent += 1
                socks.append(s)
            else:                                                     # connect, say nothing
                socks.append(connect())
        except OSError:
            time.sleep(0.01)
        while len(socks) > nsock:
            socks.pop(0).close()
        n += 1
        if n % 20 == 0:                                               # let go of those the server closed
            reap(socks)
else:                                                                 # connection storm
    socks = []
    while time.monotonic() < end:
        try:
            while len(socks) < nsock:
                s = connect()
                if rnd.random() < 0.3:
                    s.send(struct.pack(">HHHB", 1, 0, 200, 1))        # slowloris: a header, then nothing
                    sent += 1
                socks.append(s)
        except OSError:
            time.sleep(0.05)
        reap(socks)
        time.sleep(0.05)
print(sent, conns)
'''


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _recv_exact(s: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = s.recv(n - len(out))
        if not chunk:
            raise ConnectionError("closed")
        out += chunk
    return out


def _read_once(s: socket.socket) -> None:
    s.sendall(FC3)
    head = _recv_exact(s, 7)
    _recv_exact(s, struct.unpack(">H", head[4:6])[0] - 1)


class Reader(threading.Thread):
    """The legitimate reader: FC3 round trips, one at a time, ~every 5 ms; reconnects if shed
    (an idle reader would be: it is not the owner)."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        self.port, self.samples, self.errors, self.phase = port, {}, {}, "quiet"
        self.stop = threading.Event()

    def run(self) -> None:
        s = None
        while not self.stop.is_set():
            try:
                if s is None:
                    s = socket.create_connection(("127.0.0.1", self.port), timeout=5,
                                                 source_address=(LEGIT_HOST, 0))
                t0 = time.perf_counter()
                _read_once(s)
                self.samples.setdefault(self.phase, []).append(time.perf_counter() - t0)
            except OSError:
                self.errors[self.phase] = self.errors.get(self.phase, 0) + 1
                if s is not None:
                    s.close()
                s = None
            time.sleep(0.005)
        if s is not None:
            s.close()


class Plc(threading.Thread):
    """The simulated PLC running cycles back to back, counting done, faulted and the false
    trips: fault 101 or plc_link_ok low, seen while it beats."""

    def __init__(self, port: int, recipe: int):
        super().__init__(daemon=True)
        self.plc = SimPlc("127.0.0.1", port, clock=MonotonicClock(), timeout_s=5.0)
        self.recipe, self.phase = recipe, "quiet"
        self.done, self.faulted, self.trips = {}, {}, {}
        self.stop = threading.Event()

    def _count(self, table: dict) -> None:
        table[self.phase] = table.get(self.phase, 0) + 1

    def run(self) -> None:
        self.plc.start()
        part = 1
        while not self.stop.is_set():
            try:
                res = self.plc.run_cycle(self.recipe, part, timeout_s=15.0)
                self._count(self.done if res["done"] else self.faulted)
            except SimPlcError:
                self._count(self.faulted)
            img = self.plc.inputs()
            if img["fault_code"] == 101 or not PLC_MAP.bits("status_word", img["status_word"])["plc_link_ok"]:
                self._count(self.trips)
            if img["fault_code"]:
                try:
                    self.plc.reset(timeout_s=10.0)
                except SimPlcError:
                    pass
            part += 1
        self.plc.stop()


def _watch_trips(plc: Plc, stop: threading.Event) -> None:
    """Between cycles too: poll the PLC's image every 50 ms for a tripped watchdog."""
    seen = False
    while not stop.is_set():
        try:
            img = plc.plc.inputs()
        except Exception:  # noqa: BLE001 -- not started yet
            time.sleep(0.05)
            continue
        tripped = img["fault_code"] == 101
        if tripped and not seen:
            plc._count(plc.trips)
        seen = tripped
        time.sleep(0.05)


FAILED: dict[str, int] = {}      # why new clients were not served, over the run


def _new_clients(port: int, seconds: float, sslctx=None) -> tuple[int, int, float]:
    """Every second a new client connects (over TLS with ``sslctx``) and reads once."""
    served = tried = 0
    worst = 0.0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        tried += 1
        t0 = time.monotonic()
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2,
                                          source_address=(LEGIT_HOST, 0)) as raw:
                raw.settimeout(2)
                s = sslctx.wrap_socket(raw) if sslctx is not None else raw
                _read_once(s)
            served += 1
            worst = max(worst, time.monotonic() - t0)
        except OSError as exc:
            why = type(exc).__name__
            FAILED[why] = FAILED.get(why, 0) + 1
        time.sleep(max(0.0, 1.0 - (time.monotonic() - t0)))
    return served, tried, worst


def attacker_hosts(n: int, same_host: bool) -> list[str]:
    """Where attacker ``i`` connects from: 127.0.0.(2+i), a host of its own (Linux routes all
    of 127/8 to lo), or with ``same_host`` the legitimate clients' 127.0.0.1."""
    return [LEGIT_HOST if same_host else f"127.0.0.{2 + i}" for i in range(n)]


def _attack(mode: str, port: int, seconds: float, hosts: list[str], sockets: int, seed: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", ATTACKER, mode, str(port), str(seconds), str(sockets),
                              str(seed + i), src], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            for i, src in enumerate(hosts)]


def _collect(procs: list[subprocess.Popen]) -> tuple[int, int]:
    sent = conns = 0
    for p in procs:
        out, _ = p.communicate(timeout=120)
        a, b = (out.split() + ["0", "0"])[:2]
        sent, conns = sent + int(a), conns + int(b)
    return sent, conns


def _pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))] * 1000 if xs else float("nan")


def run_cell(args, seconds: float, hosts: list[str], tmp: Path, label: str) -> dict:
    """One served cell through quiet, ``args.rounds`` rounds of the storms from ``hosts`` (none:
    the same schedule with no attack, the control) and settle; what was measured."""
    port, tls_port = _free_port(), _free_port()
    cfg = tmp / f"cell-{label}.yaml"
    from tests.drivers.tlscerts import Authority, client_context   # certificates for this run only
    (tmp / f"pki-{label}").mkdir()
    ca = Authority(tmp / f"pki-{label}")
    me, plc_cert = ca.issue("controller", server=True), ca.issue("plc-operator", role="Operator")
    tls_client = client_context(ca, plc_cert)
    # the attackers' hosts are allowed: allowed-but-hostile clients are the worst case (a
    # host outside the allow-list is closed at connect, before it costs a handshake)
    allow = sorted({LEGIT_HOST, *attacker_hosts(max(args.attackers, 1), args.same_host)})
    cfg.write_text(f"sim:\n  plant: {ROOT / 'deploy/plants/default.yaml'}\nplc:\n  host: 127.0.0.1\n"
                   f"  allow: [{', '.join(allow)}]\n"
                   f"  tls:\n    enabled: true\n    port: {tls_port}\n    cert: {me.cert}\n    key: {me.key}\n"
                   f"    ca: {ca.path}\n"
                   f"log:\n  path: {tmp / f'cell-{label}.sqlite'}\n  format: json\n"
                   f"recipes:\n  directory: {tmp / 'recipes'}\n")
    log_path = tmp / f"serve-{label}.log"
    server = subprocess.Popen([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(cfg),
                               "--port", str(port)], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=open(log_path, "w"), text=True)
    attackers: list[subprocess.Popen] = []
    plc = reader = None
    stop_watch = threading.Event()
    try:
        if "serving" not in server.stdout.readline():
            raise SystemExit(f"serve did not start; see {log_path}")
        plc, reader = Plc(port, recipe=1), Reader(port)
        plc.start()
        time.sleep(2.0)                                   # the PLC owns the link, first cycle runs
        reader.start()
        threading.Thread(target=_watch_trips, args=(plc, stop_watch), daemon=True).start()
        rss = {"before": _rss_mb(server.pid)}
        time.sleep(seconds)                               # 1. quiet
        rss["after quiet"] = _rss_mb(server.pid)
        traffic, served = {}, {phase: [0, 0, 0.0] for phase in PHASES}
        for rnd in progress.each(range(1, args.rounds + 1), f"storm rounds ({label})", "round"):
            for phase in PHASES:
                plc.phase = reader.phase = phase
                mode = {"fuzz": "fuzz", "connections": "conn", "tls": "tls"}[phase]
                attackers = _attack(mode, tls_port if phase == "tls" else port, seconds, hosts,
                                    args.sockets, args.seed + 100 * rnd)
                ok, tried, worst = (_new_clients(tls_port, seconds, tls_client) if phase == "tls"
                                    else _new_clients(port, seconds))
                was = served[phase]
                served[phase] = [was[0] + ok, was[1] + tried, max(was[2], worst)]
                sent, conns = _collect(attackers)
                before = traffic.get(phase, (0, 0))
                traffic[phase] = (before[0] + sent, before[1] + conns)
                attackers = []
                rss[f"after {phase}, round {rnd}"] = _rss_mb(server.pid)
        plc.phase = reader.phase = "settle"
        time.sleep(5.0)
        rss["after 5 s settle"] = _rss_mb(server.pid)
    finally:
        stop_watch.set()
        for t in (reader, plc):
            if t is not None:
                t.stop.set()
                t.join(timeout=30)
        for p in attackers:
            p.kill()
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
    return {"reader": reader, "plc": plc, "rss": rss, "traffic": traffic, "served": served,
            "log": log_path.read_text()}


def high_water(rss: dict[str, float], rounds: int) -> list[float]:
    """Each round's high-water: the largest RSS after its storms."""
    return [max(rss[f"after {p}, round {r}"] for p in PHASES) for r in range(1, rounds + 1)]


#: rounds needed for a memory verdict: its second half (4 rounds or more) must lie past the
#: warm-up (in 16-round runs the high-water levelled by about round 7)
MIN_VERDICT_ROUNDS = 8


def late_slope(highs: list[float]) -> tuple[float, int]:
    """Least-squares slope (MB per round) of the high-water over the second half of the
    rounds (rounds floor(n/2)+1 .. n: the first half is the warm-up) and the first round
    of that half. A leak keeps a slope; a level being reached does not."""
    first = len(highs) // 2                       # index of the half's first round
    ys = highs[first:]
    xs = list(range(first + 1, len(highs) + 1))
    if len(ys) < 2:
        return float("nan"), first + 1
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs), first + 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="length of each phase (default 20)")
    ap.add_argument("--quick", action="store_true", help="6 s phases")
    ap.add_argument("--attackers", type=int, default=3,
                    help="attacking processes (default 3), each from a host of its own (127.0.0.2, .3, ...)")
    ap.add_argument("--same-host", action="store_true",
                    help="the attackers connect from 127.0.0.1, the legitimate clients' host: what a "
                         "per-host quota cannot tell apart")
    ap.add_argument("--sockets", type=int, default=100, help="idle connections per attacker (default 100)")
    ap.add_argument("--rounds", type=int, default=2,
                    help="fuzz + connection + TLS storms, one after the other, this often (default 2)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--flat-mb", type=float, default=0.5,
                    help="memory is flat if the round high-water's slope over the second half of the "
                         "rounds is at most this many MB per round (default 0.5)")
    ap.add_argument("--control", action="store_true",
                    help="then run the same schedule on a fresh cell with no attack (the cell's own "
                         "warm-up) and compare")
    args = ap.parse_args()
    seconds = 6.0 if args.quick else args.seconds
    tmp = Path(tempfile.mkdtemp(prefix="link-storm-"))
    shutil.copytree(ROOT / "recipes", tmp / "recipes")
    hosts = attacker_hosts(args.attackers, args.same_host)
    print(f"`{' '.join([Path(sys.executable).name] + sys.argv)}`  \n"
          f"{platform.python_implementation()} {platform.python_version()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f} at start; phases of {seconds:.0f} s; "
          f"{args.attackers} attacking processes from {', '.join(sorted(set(hosts))) or 'nowhere'}; "
          f"legitimate clients from {LEGIT_HOST}\n")
    run = run_cell(args, seconds, hosts, tmp, "storm")
    control = run_cell(args, seconds, [], tmp, "control") if args.control else None
    reader, plc, rss, traffic, served = run["reader"], run["plc"], run["rss"], run["traffic"], run["served"]
    quiet = reader.samples.get("quiet", [])
    print("#### The legitimate reader's FC3 round trip (20 registers)\n")
    print("| phase | requests | errors | p50 ms | p99 ms | p99 / quiet p99 |")
    print("|---|---|---|---|---|---|")
    for phase in ("quiet", *PHASES, "settle"):
        xs = reader.samples.get(phase, [])
        print(f"| {phase} | {len(xs)} | {reader.errors.get(phase, 0)} | {_pct(xs, 0.5):.2f} | {_pct(xs, 0.99):.2f} | "
              f"{_pct(xs, 0.99) / _pct(quiet, 0.99):.2f} |")
    print("\n#### The simulated PLC: cycles and false watchdog trips (aim 0)\n")
    print("| phase | cycles done | cycles faulted | watchdog trips (fault 101 / link not ok) |")
    print("|---|---|---|---|")
    for phase in ("quiet", *PHASES, "settle"):
        print(f"| {phase} | {plc.done.get(phase, 0)} | {plc.faulted.get(phase, 0)} | {plc.trips.get(phase, 0)} |")
    print("\n#### Server resident memory (VmRSS, MB)\n")
    ctl = control["rss"] if control else None
    print("| when | MB | change from after quiet |" + (" no attack (control) MB | control's change |" if ctl else ""))
    print("|---|---|---|" + ("---|---|" if ctl else ""))
    for when, mb in rss.items():
        extra = f" {ctl[when]:.1f} | {ctl[when] - ctl['after quiet']:+.1f} |" if ctl else ""
        print(f"| {when} | {mb:.1f} | {mb - rss['after quiet']:+.1f} |{extra}")
    highs = high_water(rss, args.rounds)
    slope, from_round = late_slope(highs)
    print(f"\nRound high-water (largest RSS after a round's storms), MB: "
          f"{', '.join(f'{h:.1f}' for h in highs)}; round {args.rounds} against round 1: "
          f"{highs[-1] - highs[0]:+.1f} MB.")
    if ctl:
        chighs = high_water(ctl, args.rounds)
        cslope, _ = late_slope(chighs)
        print(f"No attack (control, same schedule, fresh cell): {', '.join(f'{h:.1f}' for h in chighs)}; "
              f"round {args.rounds} against round 1: {chighs[-1] - chighs[0]:+.1f} MB; "
              f"slope over rounds {from_round}-{args.rounds}: {cslope:+.2f} MB/round.")
    if args.rounds < MIN_VERDICT_ROUNDS:
        print(f"\nMemory verdict: none: {args.rounds} rounds are too few (the cell and the storms warm up "
              f"over several rounds; use --rounds {MIN_VERDICT_ROUNDS} or more). Slope over rounds "
              f"{from_round}-{args.rounds}: {slope:+.2f} MB/round.")
    else:
        verdict = "flat" if slope <= args.flat_mb else "NOT flat"
        print(f"\nMemory verdict: **{verdict}**: the round high-water's slope over rounds {from_round}-"
              f"{args.rounds} is {slope:+.2f} MB/round (flat: at most {args.flat_mb:g}); after settling "
              f"{rss['after 5 s settle'] - rss['after quiet']:+.1f} MB against the quiet control.")
    print("\n#### Attack traffic, and new legitimate clients during each storm\n")
    print("| phase | frames sent | connections opened | new clients served (answered within 2 s) | slowest ms |")
    print("|---|---|---|---|---|")
    for phase, (sent, conns) in traffic.items():
        ok, tried, worst = served[phase]
        what = "TLS (Operator)" if phase == "tls" else "plain TCP"
        print(f"| {phase} | {sent} | {conns} | {ok}/{tried} {what} | {worst * 1000:.0f} |")
    if FAILED:
        print(f"\nNew clients not served, by error: "
              f"{', '.join(f'{k} {v}' for k, v in sorted(FAILED.items()))} (both runs).")
    log = run["log"]
    print(f"\nServer log lines over the whole run: {log.count(chr(10))} (warnings are rate-limited).")
    trims = [float(m.group(1)) for line in log.splitlines() if "plc_memory_trimmed" in line
             for m in [re.search(r'"ms": ([0-9.]+)', line)] if m]
    if trims:
        print(f"malloc_trim after connection churn (drivers/plc/memory.py): {len(trims)} times, "
              f"{sum(trims):.1f} ms in all, the longest {max(trims):.1f} ms.")
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    resource.setrlimit(resource.RLIMIT_NOFILE, (resource.getrlimit(resource.RLIMIT_NOFILE)[1],) * 2)
    random.seed(0)
    sys.exit(main())
