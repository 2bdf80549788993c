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


class Trimmer:
    """Trims at most once per ``period_s`` and only after ``min_connections`` opened
    connections; thread-safe (every server thread shares one). The process has one,
    behind :func:`maybe_trim` and :func:`stats`; a test makes its own to start from no trim.

    :param period_s: the shortest time between two trims, s of the ``now`` passed in
        (``time.monotonic`` by default).
    :param min_connections: connections opened since the last trim that make one worth it.
    """

    def __init__(self, period_s: float = PERIOD_S, min_connections: int = MIN_CONNECTIONS):
        self.period_s = float(period_s)
        self.min_connections = int(min_connections)
        self._lock = threading.Lock()
        self._last = float("-inf")
        self._trims, self._seconds, self._last_s = 0, 0.0, 0.0

    def maybe_trim(self, opened_since_last: int, now: float | None = None) -> bool:
        """Trim if ``opened_since_last`` connections justify it and none ran in the last
        ``period_s`` (any thread); returns whether it trimmed. Never on a C library without
        ``malloc_trim`` (:func:`available`)."""
        if _TRIM is None or opened_since_last < self.min_connections:
            return False
        now = time.monotonic() if now is None else now
        with self._lock:
            if now - self._last < self.period_s:
                return False
            self._last = now
            t0 = time.perf_counter()
            _TRIM(0)
            took = time.perf_counter() - t0
            self._trims += 1
            self._seconds += took
            self._last_s = took
        return True

    def stats(self) -> dict[str, float]:
        """Trims done, the time they took in all and the last one's (s)."""
        with self._lock:
            return {"trims": self._trims, "seconds": self._seconds, "last_s": self._last_s}


_PROCESS = Trimmer()


def available() -> bool:
    """Whether this C library has ``malloc_trim`` (glibc)."""
    return _TRIM is not None


def maybe_trim(opened_since_last: int, now: float | None = None) -> bool:
    """:meth:`Trimmer.maybe_trim` of the process's trimmer (one rate limit for every server
    thread)."""
    return _PROCESS.maybe_trim(opened_since_last, now)


def stats() -> dict[str, float]:
    """The process's trims: how many, the time they took in all and the last one's (s)."""
    return _PROCESS.stats()
