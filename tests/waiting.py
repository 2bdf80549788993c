"""Waiting on state, not on time: poll a condition with a generous bound.

A fixed ``time.sleep`` in a test guesses how long something takes and checks nothing about
it; :func:`wait_for` returns as soon as the state is there and fails, naming what it waited
for, only when the bound passes (a bound, not a timing: a loaded machine makes the test
slower, never wrong). For waits in simulated time see ``tests/drivers/conftest.py``
(``clock_wait_for``) and the system harness (``tests/system/conftest.py``).
"""
from __future__ import annotations

import time
from typing import Callable, TypeVar

T = TypeVar("T")


def wait_for(probe: Callable[[], T], timeout: float = 30.0, what: str = "condition",
             every: float = 0.01) -> T:
    """Call ``probe`` every ``every`` wall seconds until it returns something true; return that.

    :raises AssertionError: naming ``what`` (and the last value seen) after ``timeout`` s.
    """
    deadline = time.monotonic() + timeout
    while True:
        value = probe()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what} (last: {value!r})")
        time.sleep(every)


def unchanged_over(read: Callable[[], object], sleep: Callable[[float], None], dt: float) -> bool:
    """True when ``read()`` gives the same value before and after ``sleep(dt)`` (numpy
    arrays compared whole): a probe for :func:`wait_for`, or the harness's ``wait`` in
    simulated time, that holds once something has come to rest."""
    import numpy as np
    before = read()
    sleep(dt)
    return bool(np.array_equal(read(), before))
