"""Giving memory back after a connection storm: ``malloc_trim(0)``, at a low rate, only after
connection churn, from the PLC servers' event loops (never the scan thread).

Why. Under the storm bench (bench/bench_link_storm.py) the serve process's RSS rose a few
MB every storm round while ``tracemalloc`` saw no Python object left behind (0.06-0.08 MB).
The biggest cause, asyncio's fresh 256 KiB block per socket read, is fixed at the source
(:class:`drivers.plc.conformance.ConformantRequestHandler` reads into one buffer). What
remains is per-connection objects (transports, handlers, TLS objects, including
asyncio's 256 KiB TLS read buffer per connection, which we cannot size) freed between
longer-lived ones: glibc keeps such freed pages inside its heaps (one per thread that
allocates, so the server threads have their own) and gives back only the free top of a heap.
``malloc_trim(0)`` releases every whole free page in every heap (``madvise``), which is
exactly the creep. It changes no object and costs well under a millisecond here.

When. At most once per :data:`PERIOD_S`, and only when at least :data:`MIN_CONNECTIONS`
connections were opened since the last trim: a PLC that stays connected never causes one.
Not glibc (musl, macOS): nothing is done.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import threading
import time

PERIOD_S = 5.0          # at most one trim this often, process-wide
MIN_CONNECTIONS = 100   # connections opened since the last trim that make one worth it


def _load_trim():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


_TRIM = _load_trim()
_LOCK = threading.Lock()
_state = {"last": float("-inf"), "trims": 0, "seconds": 0.0, "last_s": 0.0}


def available() -> bool:
    """Whether this C library has ``malloc_trim`` (glibc)."""
    return _TRIM is not None


def maybe_trim(opened_since_last: int, now: float | None = None) -> bool:
    """Trim if ``opened_since_last`` connections justify it and none ran in the last
    :data:`PERIOD_S` (any server thread); returns whether it trimmed."""
    if _TRIM is None or opened_since_last < MIN_CONNECTIONS:
        return False
    now = time.monotonic() if now is None else now
    with _LOCK:
        if now - _state["last"] < PERIOD_S:
            return False
        _state["last"] = now
        t0 = time.perf_counter()
        _TRIM(0)
        took = time.perf_counter() - t0
        _state["trims"] += 1
        _state["seconds"] += took
        _state["last_s"] = took
    return True


def stats() -> dict[str, float]:
    """Trims done in this process, the time they took in all and the last one's (s)."""
    with _LOCK:
        return {"trims": _state["trims"], "seconds": _state["seconds"], "last_s": _state["last_s"]}
