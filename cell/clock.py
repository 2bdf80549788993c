"""Injected clocks (STYLE habit 5): the cell loop and every simulated device read time from one.

``MonotonicClock`` is wall time for production. ``SimClock`` runs simulated time: ``now()``
returns simulated seconds since start and ``sleep(s)`` waits ``s / time_scale`` real
seconds, so a plant whose motion takes 2 s of simulated time finishes in 0.02 s real time
at ``time_scale=100``. ``ManualClock`` only moves when ``advance`` is called (unit tests).
"""
from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Seconds since an arbitrary, fixed origin (monotonic)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` of this clock's time."""
        ...


class MonotonicClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class SimClock:
    """Simulated time running ``time_scale`` times faster than real time (thread-safe)."""

    def __init__(self, time_scale: float = 1.0):
        if not time_scale > 0:
            raise ValueError(f"time_scale = {time_scale} must be > 0")
        self.time_scale = float(time_scale)
        self._t0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.time_scale

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds / self.time_scale)


class ManualClock:
    """A clock that moves only when told to; ``sleep`` advances it immediately."""

    def __init__(self, start: float = 0.0):
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        with self._lock:
            self._t += seconds

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.advance(seconds)
