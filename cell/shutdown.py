"""Stopping a long-running command on SIGINT or SIGTERM without a lock in the handler.

A signal handler runs in the main thread between two bytecodes, wherever that thread is.
So it must take no lock the main thread may hold: a ``threading.Event.set()`` in the
handler waits for ever when the signal lands while the main thread is inside that Event's
``wait`` holding its lock, and the command never stops (for ``cellctl serve``: nor stops
its joints under control, until the service manager kills it). :class:`StopRequest`'s
handler only appends to lists, which takes no lock, and its :meth:`~StopRequest.wait`
sleeps in short steps and looks.
"""
from __future__ import annotations

import signal
import time

#: the signals a service stops on
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequest:
    """What ends a command: a signal (:meth:`handler`) or its time running out.

    ``why`` lists the causes in the order they came; the caller appends its own (a
    time-out, an error), so ``why[0]`` is the first."""

    step_s = 0.05     #: how often :meth:`wait` looks, s: the longest a signal waits to be seen

    def __init__(self) -> None:
        self.why: list[str] = []
        self._signals: list[int] = []

    def handler(self, signum: int, _frame) -> None:
        """The handler for ``signal.signal``: records the signal, nothing else."""
        self._signals.append(signum)
        self.why.append(f"{signal.Signals(signum).name} received")

    def install(self, signals=STOP_SIGNALS) -> StopRequest:
        """Make :meth:`handler` the handler of ``signals`` (main thread only); returns self."""
        for sig in signals:
            signal.signal(sig, self.handler)
        return self

    @property
    def signalled(self) -> bool:
        return bool(self._signals)

    def wait(self, seconds: float | None) -> bool:
        """Wait until a signal came (True) or ``seconds`` of wall time passed (False;
        None: no limit)."""
        deadline = None if seconds is None else time.monotonic() + seconds
        while not self._signals:
            left = self.step_s if deadline is None else min(self.step_s, deadline - time.monotonic())
            if left <= 0:
                return False
            time.sleep(left)
        return True
