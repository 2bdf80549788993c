"""Modbus TCP request latency on loopback: our PlcLink server vs a bare pymodbus server.

Both servers run in this process, each on its own event-loop thread, serving the same
datastore generated from PLC_MAP (the bare one without our action hook and without the
conformance pre-decoder). One client socket per server sends a hand-built FC3 request for
20 registers (protocol addresses 0..19) and waits for the whole answer; requests alternate
between the two servers (A, B, A, B, ...) so drift in machine load hits both alike.

    .venv/bin/python bench/bench_modbus.py            # 20000 requests per server
    .venv/bin/python bench/bench_modbus.py --quick    # 2000
"""
from __future__ import annotations

import argparse
import platform
import socket
import statistics
import struct
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import pymodbus  # noqa: E402
from pymodbus.server import ModbusTcpServer  # noqa: E402

from bench_cycle_cpu import stat_cpu  # noqa: E402
from cell import log  # noqa: E402
from drivers.plc.conformance import ServerThread  # noqa: E402
from drivers.plc.register_map import PLC_MAP  # noqa: E402
from drivers.plc.server import PlcLink, build_datastore  # noqa: E402

COUNT = 20


def _recv_exact(s: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = s.recv(n - len(out))
        if not chunk:
            raise ConnectionError("server closed the connection")
        out += chunk
    return out


class RawClient:
    """Blocking FC3 client on a raw socket: the least client-side overhead we can get."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.tid = 0

    def read(self) -> float:
        """One FC3 read of COUNT registers; returns its latency in seconds."""
        self.tid = (self.tid + 1) & 0xFFFF
        frame = struct.pack(">HHHBBHH", self.tid, 0, 6, 1, 3, 0, COUNT)
        t0 = time.perf_counter()
        self.sock.sendall(frame)
        head = _recv_exact(self.sock, 6)
        body = _recv_exact(self.sock, int.from_bytes(head[4:6], "big"))
        dt = time.perf_counter() - t0
        if head[:2] != frame[:2] or body[1] != 3 or body[2] != 2 * COUNT:
            raise RuntimeError(f"unexpected answer {(head + body).hex(' ')}")
        return dt

    def close(self) -> None:
        self.sock.close()


def _thread_cpu_s(name: str) -> float:
    """utime + stime of this process's thread called ``name``, s (1/SC_CLK_TCK resolution)."""
    tid = next(t.native_id for t in threading.enumerate() if t.name == name)
    return stat_cpu(f"/proc/self/task/{tid}")


def _pct(samples: list[float], q: float) -> float:
    s = sorted(samples)
    return s[min(len(s) - 1, int(q * len(s)))]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2000 requests per server")
    parser.add_argument("-n", type=int, default=None, help="requests per server (default 20000)")
    args = parser.parse_args(argv)
    n = args.n or (2000 if args.quick else 20000)
    log.configure("console", "ERROR")

    ours = PlcLink()
    bare = ServerThread(lambda addr: ModbusTcpServer(build_datastore(PLC_MAP, None), address=addr),
                        name="bare-pymodbus")
    clients = {}
    try:
        clients["ours (PlcLink)"] = RawClient(ours.start())
        clients["bare pymodbus"] = RawClient(bare.start())
        for c in clients.values():          # warm-up, not measured
            for _ in range(min(500, n)):
                c.read()
        samples: dict[str, list[float]] = {k: [] for k in clients}
        for _ in range(n):
            for name, c in clients.items():
                samples[name].append(c.read())
        cpu_us: dict[str, float] = {}           # the server thread's CPU per request, back to back
        for (name, c), thread in zip(clients.items(), ("plc-modbus-server", "bare-pymodbus")):
            c0 = _thread_cpu_s(thread)
            for _ in range(n):
                c.read()
            cpu_us[name] = (_thread_cpu_s(thread) - c0) / n * 1e6
    finally:
        for c in clients.values():
            c.close()
        ours.stop()
        bare.stop()

    print(f"Modbus TCP FC3 read of {COUNT} registers on loopback, {n} requests per server, "
          f"interleaved; pymodbus {pymodbus.__version__}, Python {platform.python_version()}, "
          f"{platform.machine()}\n")
    print("| server | requests | p50 (us) | p99 (us) | mean (us) |")
    print("|---|---:|---:|---:|---:|")
    for name, s in samples.items():
        print(f"| {name} | {len(s)} | {_pct(s, 0.50) * 1e6:.1f} | {_pct(s, 0.99) * 1e6:.1f} | "
              f"{statistics.fmean(s) * 1e6:.1f} |")
    ours_s, bare_s = samples["ours (PlcLink)"], samples["bare pymodbus"]
    print(f"| **ratio ours / bare** | | **{_pct(ours_s, 0.5) / _pct(bare_s, 0.5):.2f}x** | "
          f"**{_pct(ours_s, 0.99) / _pct(bare_s, 0.99):.2f}x** | "
          f"**{statistics.fmean(ours_s) / statistics.fmean(bare_s):.2f}x** |")
    print(f"\nCPU of the server's thread per request, {n} more requests to each server back to back "
          f"(the client waiting for each answer):\n")
    print("| server | CPU per request (us) |")
    print("|---|---:|")
    for name, us in cpu_us.items():
        print(f"| {name} | {us:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
