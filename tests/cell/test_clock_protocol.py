"""Every clock takes the same calls: code written for the simulated clock (which names the
threads that keep its time) runs on wall time too, as ``calibrate`` does on hardware."""
from __future__ import annotations

import pytest

from cell.clock import ManualClock, MonotonicClock
from cell.sim.clock import VirtualClock


@pytest.mark.parametrize("make", [MonotonicClock, lambda: ManualClock(0.0), VirtualClock])
def test_attach_takes_a_thread_name_on_every_clock(make):
    clock = make()
    try:
        with clock.attach("calibrate") as attached:
            assert attached is clock
            t0 = clock.now()
            clock.sleep(0.001)
            assert clock.now() >= t0
    finally:
        close = getattr(clock, "close", None)
        if close is not None:
            close()
