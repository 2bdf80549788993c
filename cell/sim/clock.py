"""The simulated cell's clock: discrete-event time shared by every simulated device and
by the controller running against them.

Rules (what makes a run independent of host load):

* **One runner at a time.** Threads that keep this clock's time (*participants*: tasks
  from :meth:`VirtualClock.spawn`, or a thread inside :meth:`VirtualClock.attach`) run
  one at a time, handing over a baton whenever they wait on the clock (``sleep``, an
  :meth:`event`, a :meth:`queue`). Timed callbacks (:meth:`call_at`: CAN frames ending
  their slot on the wire, a drive's timers) also run holding the baton. In pure mode the
  participant that lets go of the baton runs the agenda itself, callbacks included, up to
  the next wake-up: its own costs no thread switch, another participant's one (through
  the clock's own thread it took two, and the switches cost more than the callbacks). In
  paced mode, and whenever no participant holds the baton, the clock's own thread runs it.
  Either way the agenda's order alone decides what happens, never which thread runs it;
  a callback may not wait on the clock, in whichever thread it runs.
* **Time moves only when everybody waits.** The next thing to happen is the earliest
  entry of one agenda (callbacks and wake-ups), ties broken by the order in which they
  were scheduled. Work in flight — a frame on the virtual wire, a Modbus request a
  participant is blocked on — is either on the agenda or keeps its participant running,
  so it is always delivered before time passes it.
* **Pure or paced.** ``pace=False`` (``cellctl run --sim``, the tests): time jumps to the
  next entry at once, as fast as the host allows. ``pace=True`` (``cellctl serve --sim``,
  for an outside PLC): an entry at clock time ``t`` runs no earlier than wall time
  ``origin + t``. A wake-up a little late (a thread's usual lateness) is caught up; when
  the host stalls for longer than ``max_lag_s``, ``origin`` moves forward, so simulated time
  stretches and never jumps by more than that: every device still sees its own deadlines
  in order.
* **No participant, no time** (pure mode): with nobody to wait for, the clock stands still.

Threads that are not participants (the Modbus server's event loop, a test's main thread)
may read :meth:`now`, set events, put to queues and schedule callbacks; waiting on the
clock from such a thread is a :class:`~cell.clock.ClockError`, as is scheduling a
callback in the past. If every participant waits with nothing on the agenda the run is
stuck for good: every waiter gets a ``ClockError`` naming them.
"""
from __future__ import annotations

import contextlib
import contextvars
import heapq
import itertools
import math
import queue
import sys
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

from cell.clock import ClockError
from cell.log import get_logger

log = get_logger("sim.clock")

_SCHEDULER = object()     # the baton holder while a callback runs
_INF, _heappush = math.inf, heapq.heappush


class _Gate:
    """A participant's go signal: ``threading.Event``'s meaning on one bare lock (an Event
    is a Condition written in Python, whose notify and wait every hand-off paid). ``set``
    and ``clear`` are called with the clock's lock held; only the participant itself waits
    on (and clears) its gate."""

    __slots__ = ("_lock", "_open")

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._lock.acquire()
        self._open = False

    def set(self) -> None:
        if not self._open:
            self._open = True
            self._lock.release()

    def clear(self) -> None:
        if self._open:
            self._open = False
            self._lock.acquire()

    def wait(self) -> None:
        self._lock.acquire()
        self._lock.release()


@dataclass(eq=False)
class _Actor:
    name: str
    go: _Gate = field(default_factory=_Gate)
    token: int = 0            # id of the current wait; stale wake-ups carry an older one
    woke_by: str = ""         # "event", "timeout", "start" or "stuck"


@dataclass(eq=False)
class _Resume:
    actor: _Actor
    token: int
    why: str


class Timer:
    """A scheduled callback; :meth:`cancel` stops it if it has not run yet."""

    __slots__ = ("fn", "args", "cancelled")

    def __init__(self, fn: Callable[..., Any], args: tuple, cancelled: bool = False):
        self.fn, self.args, self.cancelled = fn, args, cancelled

    def __repr__(self) -> str:
        return f"Timer(fn={self.fn!r}, args={self.args!r}, cancelled={self.cancelled!r})"

    def cancel(self) -> None:
        self.cancelled = True


class VirtualClock:
    """Discrete-event clock (see the module doc).

    :param start: clock time at creation, s.
    :param pace: run no faster than wall time (for an outside PLC).
    :param max_lag_s: pacing: how far simulated time may run behind wall time and catch up;
        a longer stall stretches simulated time instead.
    :param wall: wall-time source for pacing (injectable for tests).
    :param stall_warn_s: log the baton holder's stack if it runs longer than this (wall s);
        a diagnostic only, it changes nothing.
    """

    wall = False

    def __init__(self, start: float = 0.0, *, pace: bool = False, max_lag_s: float = 0.02,
                 wall: Callable[[], float] = time.monotonic, stall_warn_s: float = 120.0):
        if not math.isfinite(start):
            raise ClockError(f"VirtualClock: start = {start!r} is not a finite time")
        self.pace = pace
        self.max_lag_s = max_lag_s
        self._wall = wall
        self._stall_warn_s = stall_warn_s
        self._mu = threading.Lock()
        self._cv = threading.Condition(self._mu)
        self._now = float(start)
        self._agenda: list[tuple[float, int, Any]] = []
        self._seq = itertools.count()
        self._actors: dict[threading.Thread, _Actor] = {}
        self._holder: Any = None
        self._origin = wall() - self._now
        self._last_wall = wall()
        self._closed = False
        self._thread: threading.Thread | None = None
        self._waiting = ""                    # what the clock's thread waits for on _cv, if it waits
        self._context = contextvars.Context()  # callbacks run in it, in whichever thread
        self.callbacks_run = 0
        self.handoffs = 0

    # ------------------------------------------------------------------ reading time
    def now(self) -> float:
        return self._now

    def __repr__(self) -> str:
        return f"VirtualClock(t={self._now:.6f}, pace={self.pace}, participants={len(self._actors)})"

    # ------------------------------------------------------------------ scheduling
    def call_at(self, t: float, fn: Callable[..., Any], *args: Any) -> Timer:
        """Run ``fn(*args)`` in the clock's thread at clock time ``t`` (any thread may call).

        :raises ClockError: ``t`` is not finite or lies in the past (the clock never goes back).
        """
        t = float(t)
        with self._mu:
            now = self._now
            if not t >= now - 1e-9 or t == _INF:          # NaN and -inf fail the comparison
                raise ClockError(f"VirtualClock: cannot schedule at t = {t!r} s, the clock is at "
                                 f"{now!r} s and never goes back")
            timer = Timer(fn, args)
            _heappush(self._agenda, (t if t > now else now, next(self._seq), timer))
            if self._thread is None:
                self._ensure_thread()
            if self._waiting and self._waiting != "holder":   # as _push
                self._cv.notify()
            return timer

    def call_later(self, delay: float, fn: Callable[..., Any], *args: Any) -> Timer:
        """:meth:`call_at` ``now() + delay`` (``delay`` ≥ 0)."""
        if not delay >= 0:
            raise ClockError(f"VirtualClock: delay = {delay!r} s must be ≥ 0")
        return self.call_at(self._now + delay, fn, *args)

    def _push(self, t: float, entry: Any) -> None:
        # caller holds _mu
        heapq.heappush(self._agenda, (t, next(self._seq), entry))
        self._ensure_thread()
        if self._waiting and self._waiting != "holder":  # it waits for the agenda, not the baton
            self._cv.notify()

    # ------------------------------------------------------------------ participants
    def _me(self, what: str) -> _Actor:
        a = self._actors.get(threading.current_thread())
        if a is None:
            raise ClockError(f"VirtualClock: {what} from thread {threading.current_thread().name!r}, "
                             "which does not keep this clock's time; start it with clock.spawn() "
                             "or wrap the code in 'with clock.attach():'")
        if self._holder is _SCHEDULER:
            raise ClockError(f"VirtualClock: {what} inside a clock callback (a callback never waits)")
        return a

    def keeps_time(self) -> bool:
        """The calling thread is a participant that may wait on the clock now (not a
        callback, which may run in a participant's thread)."""
        return threading.current_thread() in self._actors and self._holder is not _SCHEDULER

    def _park(self, a: _Actor, deadline: float | None) -> str:
        """Caller holds _mu and the baton: let go, wait to be resumed; returns why.

        In pure mode the parking thread runs the agenda itself (:meth:`_dispatch`) until
        the baton's next holder is known: its own wake-up costs no thread switch at all,
        another participant's one switch, where the clock's thread took two."""
        a.token += 1
        if deadline is not None:
            self._push(max(deadline, self._now), _Resume(a, a.token, "timeout"))
        a.go.clear()
        if self.pace:
            self._holder = None
            self._signal()
        elif self._dispatch(a):
            return a.woke_by
        self._mu.release()
        try:
            a.go.wait()
        finally:
            self._mu.acquire()
        if a.woke_by == "stuck":
            raise ClockError(f"VirtualClock: simulation stuck at t = {self._now:.6f} s: every "
                             f"participant waits with nothing scheduled ({self._names()})")
        return a.woke_by

    def _wake(self, a: _Actor, token: int, why: str) -> None:
        # caller holds _mu: resume ``a`` after everything already due now
        self._push(self._now, _Resume(a, token, why))

    def _names(self) -> str:
        return ", ".join(sorted(a.name for a in self._actors.values()))

    @contextlib.contextmanager
    def attach(self, name: str | None = None) -> Iterator["VirtualClock"]:
        """Make the calling thread a participant for the ``with`` block (re-entrant)."""
        me = threading.current_thread()
        if me in self._actors:
            yield self
            return
        a = _Actor(name or me.name)
        with self._mu:
            self._actors[me] = a
            self._wake(a, a.token, "start")
            self._mu.release()
            try:
                a.go.wait()
            finally:
                self._mu.acquire()
        try:
            yield self
        finally:
            with self._mu:
                del self._actors[me]
                if self._holder is a:
                    self._holder = None
                self._signal()

    def spawn(self, target: Callable[..., Any], name: str, *args: Any) -> "VirtualTask":
        """Start ``target(*args)`` in a participant thread; it first runs once the caller
        lets go of the baton, after everything already due now."""
        task = VirtualTask(self, name)
        a = _Actor(name)

        def body() -> None:
            a.go.wait()
            try:
                target(*args)
            except ClockError as exc:
                log.error("task_stopped_by_clock", task=name, error=str(exc))
            except BaseException:          # noqa: BLE001 -- a task must never die silently
                log.exception("task_failed", task=name)
            finally:
                with self._mu:
                    task._finished = True
                    task._done._set_locked()
                    del self._actors[th]
                    if self._holder is a:
                        self._holder = None
                    self._signal()

        th = threading.Thread(target=body, name=name, daemon=True)
        with self._mu:
            self._actors[th] = a
            self._wake(a, a.token, "start")
        th.start()
        task._thread = th
        return task

    # ------------------------------------------------------------------ waiting
    def sleep_until(self, t: float) -> None:
        t = float(t)
        if math.isnan(t):
            raise ClockError("VirtualClock: cannot sleep until t = nan")
        a = self._me("sleep")
        with self._mu:
            self._park(a, max(t, self._now))

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of simulated time; ≤ 0 lets everything due now run first."""
        self.sleep_until(self._now + max(0.0, seconds))

    def event(self) -> "VirtualEvent":
        return VirtualEvent(self)

    def queue(self) -> "VirtualQueue":
        return VirtualQueue(self)

    # ------------------------------------------------------------------ the agenda loop
    def _ensure_thread(self) -> None:
        if self._thread is None and not self._closed:
            self._thread = threading.Thread(target=self._run, name="sim-clock", daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop the clock's thread (pending entries are dropped). Idempotent."""
        with self._mu:
            self._closed = True
            self._signal()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    def _run(self) -> None:
        with self._mu:
            while not self._closed:
                if self._holder is not None:
                    if not self._wait(self._stall_warn_s, "holder") and self._holder is not None:
                        self._warn_stall()
                    continue
                if not self._agenda:
                    if self._actors and not self.pace:
                        self._stuck()
                    self._wait(None, "agenda")
                    continue
                if not self._actors and not self.pace:
                    self._wait(None, "actors")           # nobody to wait for: time stands still
                    continue
                t, _, entry = self._agenda[0]
                if self._stale(entry):
                    heapq.heappop(self._agenda)
                    continue
                if self.pace and not self._paced(t):
                    continue
                heapq.heappop(self._agenda)
                self._now = max(self._now, t)
                self._run_entry(entry)
                if self._holder is _SCHEDULER:
                    self._holder = None

    def _dispatch(self, me: _Actor) -> bool:
        """Pure mode, lock held, called by participant ``me`` as it parks: run due agenda
        entries in this thread, in the agenda's order (callbacks with the lock released and
        the baton marked as the scheduler's, so the clock's thread keeps out), until one
        hands the baton on. True if it came back to ``me`` (no wait needed)."""
        self._holder = _SCHEDULER
        agenda, pop, run, mu = self._agenda, heapq.heappop, self._context.run, self._mu
        while not self._closed:
            if not agenda:
                self._stuck()                            # every participant waits: nothing can come
                return False
            t, _, entry = pop(agenda)
            if type(entry) is Timer:                    # a callback, as _run_entry runs it
                if entry.cancelled:
                    continue
                if t > self._now:
                    self._now = t
                mu.release()
                try:
                    run(entry.fn, *entry.args)
                except Exception:                        # noqa: BLE001 -- keep the world turning
                    log.exception("sim_callback_failed",
                                  callback=getattr(entry.fn, "__qualname__", repr(entry.fn)))
                finally:
                    mu.acquire()
                    self.callbacks_run += 1
                if self._holder is not _SCHEDULER:      # a callback never takes the baton; kept as a guard
                    return False
                continue
            if entry.token != entry.actor.token:         # a stale wake-up
                continue
            if t > self._now:
                self._now = t
            if entry.actor is me:
                me.woke_by = entry.why
                me.token += 1
                self._holder = me
                return True
            self._run_entry(entry)                       # hands the baton on
            return False
        self._holder = None
        return False

    def _run_entry(self, entry: Any) -> None:
        """One due agenda entry (lock held): a wake-up hands the baton to its participant;
        a callback runs with the lock released, in the clock's own context (the callback's
        log lines never carry a participant's bound context, whichever thread runs it)."""
        if isinstance(entry, _Resume):
            entry.actor.woke_by = entry.why
            entry.actor.token += 1               # later wake-ups of this wait are stale
            self._holder = entry.actor
            self.handoffs += 1
            entry.actor.go.set()
            return
        self._holder = _SCHEDULER
        self._mu.release()
        try:
            self._context.run(entry.fn, *entry.args)
        except Exception:                        # noqa: BLE001 -- keep the world turning
            log.exception("sim_callback_failed", callback=getattr(entry.fn, "__qualname__", repr(entry.fn)))
        finally:
            self._mu.acquire()
            self.callbacks_run += 1

    def _wait(self, timeout: float | None, what: str) -> bool:
        """The clock's thread waits (lock held) for ``what``: ``"holder"`` (the baton to be
        let go), ``"agenda"`` (an entry, or an earlier one) or ``"actors"`` (a participant)."""
        self._waiting = what
        try:
            return self._cv.wait(timeout)
        finally:
            self._waiting = ""

    def _signal(self) -> None:
        """The baton was let go or the clock closes (lock held): wake the clock's thread if it
        waits. Only it waits on ``_cv``. A new agenda entry wakes it only if it waits for one
        (:meth:`_push`): while a participant holds the baton, each wake-up would be for
        nothing, and the participants schedule thousands of entries per simulated second."""
        if self._waiting:
            self._cv.notify()

    @staticmethod
    def _stale(entry: Any) -> bool:
        if isinstance(entry, _Resume):
            return entry.token != entry.actor.token
        return entry.cancelled

    def _paced(self, t: float) -> bool:
        """Pacing (lock held): True when ``t`` may run now; otherwise waits and returns False."""
        wall = self._wall()
        if wall < self._last_wall:           # a broken wall source: never let it move us back
            log.error("wall_clock_went_back", was=self._last_wall, now=wall)
            self._origin -= self._last_wall - wall
        self._last_wall = wall
        due = self._origin + t
        if due > wall:
            self._wait(due - wall, "agenda")
            return False
        # a little late: catch up; stalled: stretch, never jump by more than max_lag_s
        self._origin = max(self._origin, wall - t - self.max_lag_s)
        return True

    def _stuck(self) -> None:
        for a in self._actors.values():
            a.woke_by = "stuck"
            a.token += 1
            a.go.set()
        self._holder = None

    def _warn_stall(self) -> None:
        holder = self._holder
        th = next((t for t, a in self._actors.items() if a is holder), None)
        frame = sys._current_frames().get(th.ident) if th is not None and th.ident else None
        stack = "".join(traceback.format_stack(frame)) if frame is not None else "(callback)"
        log.warning("sim_clock_stalled", holder=getattr(holder, "name", "callback"),
                    wall_s=self._stall_warn_s, at=self._now, stack=stack)


class VirtualTask:
    """A participant thread started by :meth:`VirtualClock.spawn`."""

    def __init__(self, clock: VirtualClock, name: str):
        self.name = name
        self._clock = clock
        self._finished = False
        self._done = VirtualEvent(clock)
        self._thread: threading.Thread | None = None

    @property
    def finished(self) -> bool:
        return self._finished

    def join(self, timeout: float | None = None) -> bool:
        """A participant waits in clock time; any other thread waits in wall time."""
        if self._clock.keeps_time():
            return self._done.wait(timeout)
        if self._thread is not None:
            self._thread.join(timeout)
        return self._finished


class VirtualEvent:
    """``threading.Event`` on a :class:`VirtualClock` (time-outs in clock seconds)."""

    def __init__(self, clock: VirtualClock):
        self._clock = clock
        self._flag = False
        self._waiters: list[tuple[_Actor, int]] = []

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        with self._clock._mu:
            self._set_locked()

    def _set_locked(self) -> None:
        self._flag = True
        for a, token in self._waiters:
            if token == a.token:
                self._clock._wake(a, token, "event")
        self._waiters.clear()

    def clear(self) -> None:
        self._flag = False

    def wait(self, timeout: float | None = None) -> bool:
        c = self._clock
        a = c._me("event wait")
        with c._mu:
            if self._flag:
                return True
            if timeout is not None and timeout <= 0:
                return False
            self._waiters.append((a, a.token + 1))   # the token _park is about to take
            c._park(a, None if timeout is None else c._now + timeout)
            self._waiters = [(w, t) for w, t in self._waiters if w is not a]
            return self._flag


class VirtualQueue:
    """FIFO on a :class:`VirtualClock`: ``get`` waits in clock time and raises
    ``queue.Empty`` on time-out, as ``queue.Queue.get`` does."""

    def __init__(self, clock: VirtualClock):
        self._clock = clock
        self._items: deque = deque()
        self._waiters: list[tuple[_Actor, int]] = []

    def put(self, item: Any, block: bool = True, timeout: float | None = None) -> None:
        c = self._clock
        with c._mu:
            self._items.append(item)
            for a, token in self._waiters:
                if token == a.token:
                    c._wake(a, token, "event")
            self._waiters.clear()

    def put_nowait(self, item: Any) -> None:
        self.put(item)

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        c = self._clock
        with c._mu:
            if self._items:
                return self._items.popleft()
            if not block or (timeout is not None and timeout <= 0):
                raise queue.Empty
        a = c._me("queue get")
        with c._mu:
            deadline = None if timeout is None else c._now + timeout
            while not self._items:
                if deadline is not None and c._now >= deadline:
                    raise queue.Empty
                self._waiters.append((a, a.token + 1))
                c._park(a, deadline)
                self._waiters = [(w, t) for w, t in self._waiters if w is not a]
            return self._items.popleft()

    def get_nowait(self) -> Any:
        return self.get(block=False)

    def empty(self) -> bool:
        return not self._items

    def qsize(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        with self._clock._mu:
            self._items.clear()
