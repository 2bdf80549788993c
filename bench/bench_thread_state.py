"""C heap kept per short-lived thread: why the cell runs every cycle on one long-lived thread.

Some libraries keep state per thread that calls them and never give it back when the
thread ends. The cell once started a thread per cycle; this bench measures, for a few
kinds of work, the C heap in use (glibc ``mallinfo2``: allocated chunks, not free memory
malloc keeps) after N calls on ONE thread, and after N calls each on a FRESH thread that
then ends. Prints a Markdown table, MB per 1000 calls.

    .venv/bin/python bench/bench_thread_state.py            # 2000 calls per row
    .venv/bin/python bench/bench_thread_state.py --calls 500

Every number is measured in this run; nothing here is a pass/fail test.
"""
from __future__ import annotations

import argparse
import ctypes
import gc
import os
import platform
import sys
import threading

import cv2
import numpy as np


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                 "uordblks", "fordblks", "keepcost")]


def c_heap_mb(libc) -> float:
    m = libc.mallinfo2()
    return (m.uordblks + m.hblkhd) / 1e6


def works() -> dict:
    img = np.full((512, 640), 50, np.uint8)
    cv2.circle(img, (300, 250), 30, 200, -1)
    return {"nothing": lambda: None,
            "numpy (square, sum)": lambda: float(np.sum(img.astype(float) ** 2)),
            "cv2.GaussianBlur": lambda: cv2.GaussianBlur(img, (0, 0), 1.0),
            "cv2.threshold": lambda: cv2.threshold(img, 100, 255, cv2.THRESH_BINARY),
            "cv2.findContours": lambda: cv2.findContours((img > 100).astype(np.uint8), cv2.RETR_EXTERNAL,
                                                         cv2.CHAIN_APPROX_NONE)}


def growth(libc, work, calls: int, fresh_threads: bool) -> float:
    for _ in range(20):                      # warm up: first-call caches are not growth
        work()
    gc.collect()
    before = c_heap_mb(libc)
    for _ in range(calls):
        if fresh_threads:
            t = threading.Thread(target=work)
            t.start()
            t.join()
        else:
            work()
    gc.collect()
    return (c_heap_mb(libc) - before) * 1000.0 / calls


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000, help="calls per row (default 2000)")
    args = ap.parse_args(argv)
    try:
        libc = ctypes.CDLL(None)
        libc.mallinfo2.restype = _Mallinfo2
    except (OSError, AttributeError):
        print("this C library has no mallinfo2 (glibc ≥ 2.33 needed)")
        return 1
    print(f"## C heap kept per thread: {args.calls} calls per row\n")
    print(f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"OpenCV {cv2.__version__}, numpy {np.__version__}.\n")
    print(f"Reproduce: `.venv/bin/python bench/bench_thread_state.py --calls {args.calls}`\n")
    print("| work per call | one thread, MB per 1000 calls | a fresh thread per call, MB per 1000 calls |")
    print("|---|---:|---:|")
    for name, work in works().items():
        same = growth(libc, work, args.calls, False)
        fresh = growth(libc, work, args.calls, True)
        print(f"| {name} | {same:+.3f} | {fresh:+.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
