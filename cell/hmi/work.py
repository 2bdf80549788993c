"""Blocking work of the HMI, bounded: :class:`WorkPool` and :class:`SingleFlight`.

Everything the HMI does that blocks (a recipe check, reading the cycle log, a Modbus read,
a password hash, drawing the trend) runs off the event loop through a :class:`WorkPool`:
at most ``slots`` calls of a pool at once, each on a daemon thread of its own. A call that
finds every slot taken is refused at once with :class:`Busy` (the page answers 503 and asks
to retry), so a flood of expensive requests costs ``slots`` threads, not one per request,
and the pools cannot starve each other (the status page keeps working while the recipe
checks are saturated).

A request cancelled while its call runs (the client went away, or the server stops and
its graceful time is up) stops waiting at once; the thread finishes on its own and only
then frees its slot, so the threads alive never outnumber the slots. The threads are
daemons: a process told to stop does not wait for them.

:class:`SingleFlight` lets concurrent requests share one run of the same async work (the
trend's key and its drawing).
"""
from __future__ import annotations

import asyncio
import threading
from typing import Any, Awaitable, Callable

from cell.errors import CellError


class Busy(CellError):
    """Every slot of a pool is taken: nothing was run; try again shortly."""


class WorkPool:
    """At most ``slots`` blocking calls at once (see the module doc).

    :param name: what the work is, for the :class:`Busy` message and the threads' names.
    """

    def __init__(self, name: str, slots: int):
        if slots < 1:
            raise ValueError("a work pool needs at least one slot")
        self.name, self.slots = name, int(slots)
        self._running = 0
        self._lock = threading.Lock()

    @property
    def running(self) -> int:
        """Calls running now (threads alive, including ones nobody waits for any more)."""
        return self._running

    def full(self) -> bool:
        """Whether a call now would be refused :class:`Busy` (looked at and acted on in one
        step of the event loop, it is exact)."""
        return self._running >= self.slots

    async def run(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` on a thread of its own; its result, or its exception raised here.

        :raises Busy: all ``slots`` are running (``fn`` not called).
        """
        with self._lock:
            if self._running >= self.slots:
                raise Busy(f"the HMI is busy ({self.slots} {self.name} running): try again in a moment")
            self._running += 1
        loop = asyncio.get_running_loop()
        done = loop.create_future()

        def settle(ok: bool, value: Any) -> None:
            if not done.done():
                (done.set_result if ok else done.set_exception)(value)

        def work() -> None:
            try:
                ok, value = True, fn(*args)
            except BaseException as exc:        # noqa: BLE001 -- handed to the awaiting request
                ok, value = False, exc
            finally:
                with self._lock:
                    self._running -= 1
            try:
                loop.call_soon_threadsafe(settle, ok, value)
            except RuntimeError:                # the loop is closed: nobody waits any more
                pass

        threading.Thread(target=work, name=f"hmi-{self.name}", daemon=True).start()
        return await done


class SingleFlight:
    """``await flight(make)``: the result of ``make()``, shared by every caller that comes
    while one run is in progress (one run at a time; a caller that comes after it ended
    starts the next). A caller cancelled while waiting does not cancel the run."""

    def __init__(self) -> None:
        self._task: asyncio.Future | None = None

    async def __call__(self, make: Callable[[], Awaitable[Any]]) -> Any:
        if self._task is None or self._task.done():
            self._task = asyncio.ensure_future(make())
            self._task.add_done_callback(lambda t: t.cancelled() or t.exception())   # always retrieved
        return await asyncio.shield(self._task)
