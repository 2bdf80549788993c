"""Injected clocks: every timed thing in the cell reads time and waits through one.

The controller, the drivers and the simulated devices never call ``time.monotonic()`` or
``time.sleep()`` for their own timing; they take a :class:`Clock` and use its ``now``,
``sleep``, events, queues and tasks. Which clock runs decides what "a second" is:

* :class:`MonotonicClock` — wall time, for the cell on real hardware. Its events, queues
  and tasks are the standard ``threading`` ones.
* ``cell.sim.clock.VirtualClock`` — simulated time for the simulated cell. Time advances
  only when every participant waits, so what happens never depends on when a thread gets
  the CPU. Its events, queues and tasks are aware of that.
* :class:`ManualClock` — moves only when a unit test says so (no threads).

A *task* is a thread started through the clock (:meth:`Clock.spawn`); a thread that is not
one joins the clock's time with :meth:`Clock.attach` before it waits on the clock. On a
wall clock both are plain threads and ``attach`` does nothing.
"""
from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from typing import Any, Callable, ContextManager, Protocol

from cell.errors import CellError


class ClockError(CellError, RuntimeError):
    """The clock cannot do what was asked: time asked to go back, a wait from a thread
    that is not part of a simulated clock, or a simulation in which everyone waits forever."""


class ClockEvent(Protocol):
    """A flag threads wait on (the interface of ``threading.Event``)."""

    def set(self) -> None: ...
    def clear(self) -> None: ...
    def is_set(self) -> bool: ...
    def wait(self, timeout: float | None = None) -> bool: ...


class ClockQueue(Protocol):
    """FIFO with the ``queue.Queue`` interface used here: ``get`` raises ``queue.Empty`` on
    time-out (clock seconds); ``clear`` drops what is queued."""

    def put(self, item: Any) -> None: ...
    def get(self, block: bool = True, timeout: float | None = None) -> Any: ...
    def empty(self) -> bool: ...
    def clear(self) -> None: ...


class Task(Protocol):
    """A thread started by :meth:`Clock.spawn`."""

    name: str

    @property
    def finished(self) -> bool:
        """True once the target has returned or raised (set before the thread lets go)."""
        ...

    def join(self, timeout: float | None = None) -> bool:
        """Wait (clock seconds) for the task to finish; True if it has."""
        ...


class Clock(Protocol):
    """What everything timed in the cell needs of a clock."""

    #: True when ``now()`` is wall time (libraries that read the wall clock can be used)
    wall: bool

    def now(self) -> float:
        """Seconds since an arbitrary, fixed origin (never decreases)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of this clock's time (≤ 0: let others run, return at once)."""
        ...

    def sleep_until(self, t: float) -> None:
        """Wait until ``now() >= t`` (returns at once if already past)."""
        ...

    def event(self) -> ClockEvent: ...
    def queue(self) -> ClockQueue: ...

    def spawn(self, target: Callable[..., Any], name: str, *args: Any) -> Task:
        """Start ``target(*args)`` in a new daemon thread that keeps this clock's time."""
        ...

    def attach(self, name: str | None = None) -> ContextManager:
        """``with clock.attach():`` the calling thread keeps this clock's time inside;
        ``name`` names it where a clock keeps a list of its threads."""
        ...


# ------------------------------------------------------------------------------ wall time
class _WallQueue(queue.Queue):
    def clear(self) -> None:
        with self.mutex:
            self.queue.clear()


class _ThreadTask:
    def __init__(self, target: Callable[..., Any], name: str, args: tuple):
        self.name = name
        self._finished = False

        def body() -> None:
            try:
                target(*args)
            finally:
                self._finished = True
        self._thread = threading.Thread(target=body, name=name, daemon=True)
        self._thread.start()

    @property
    def finished(self) -> bool:
        return self._finished

    def join(self, timeout: float | None = None) -> bool:
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)
        return self._finished


class MonotonicClock:
    """Wall time (``time.monotonic``) with standard threads, events and queues."""

    wall = True

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))

    def sleep_until(self, t: float) -> None:
        self.sleep(t - time.monotonic())

    def event(self) -> threading.Event:
        return threading.Event()

    def queue(self) -> _WallQueue:
        return _WallQueue()

    def spawn(self, target: Callable[..., Any], name: str, *args: Any) -> _ThreadTask:
        return _ThreadTask(target, name, args)

    def attach(self, name: str | None = None) -> ContextManager:
        return contextlib.nullcontext(self)


# ------------------------------------------------------------------------------ unit tests
class _ManualEvent:
    """Event on a :class:`ManualClock`: a wait that is not satisfied moves the clock by the
    whole time-out (there is nobody else to set it)."""

    def __init__(self, clock: "ManualClock"):
        self._clock = clock
        self._flag = False

    def set(self) -> None:
        self._flag = True

    def clear(self) -> None:
        self._flag = False

    def is_set(self) -> bool:
        return self._flag

    def wait(self, timeout: float | None = None) -> bool:
        if not self._flag:
            if timeout is None:
                raise ClockError("ManualClock: waiting forever on an event nobody can set")
            self._clock.sleep(timeout)
        return self._flag


class _ManualQueue(_WallQueue):
    def __init__(self, clock: "ManualClock"):
        super().__init__()
        self._clock = clock

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        try:
            return super().get(block=False)
        except queue.Empty:
            if block and timeout:
                self._clock.sleep(timeout)
            raise


class ManualClock:
    """A clock that moves only when told to (single-threaded unit tests).

    ``sleep`` and time-outs advance it at once. :raises ClockError: from :meth:`advance`
    with a negative or non-finite step, and for a non-finite start.
    """

    wall = False
    single_threaded = True      #: a worker runs its jobs at once, in the caller (cell.worker)

    def __init__(self, start: float = 0.0):
        if not math.isfinite(start):
            raise ClockError(f"ManualClock: start = {start!r} is not a finite time")
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ClockError(f"ManualClock: cannot advance by {seconds!r} s; "
                             "a clock never goes back (use a step ≥ 0)")
        with self._lock:
            self._t += seconds

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.advance(seconds)

    def sleep_until(self, t: float) -> None:
        self.sleep(t - self.now())

    def event(self) -> _ManualEvent:
        return _ManualEvent(self)

    def queue(self) -> _ManualQueue:
        return _ManualQueue(self)

    def spawn(self, target: Callable[..., Any], name: str, *args: Any) -> _ThreadTask:
        return _ThreadTask(target, name, args)

    def attach(self, name: str | None = None) -> ContextManager:
        return contextlib.nullcontext(self)
