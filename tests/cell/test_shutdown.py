"""StopRequest: a long-running command stops on SIGINT/SIGTERM wherever the signal lands.

A Python signal handler runs in the main thread between two bytecodes. The old handlers
(``threading.Event.set()``) deadlocked when the signal landed while the main thread held
that Event's lock inside ``Event.wait``: ``cellctl serve`` then ignored SIGTERM. Here the
handler is called at every line the waiting code runs, one line per try, as a signal could
land there."""
from __future__ import annotations

import os
import signal
import sys
import threading

from cell.shutdown import StopRequest


def _wait_with_signal_at(request: StopRequest, line: int, seconds: float):
    """``request.wait(seconds)`` in a thread whose ``line``-th traced line first runs the
    handler (as a signal landing there would); (ended, result, lines traced)."""
    seen, result = [0], []

    def tracer(frame, event, arg):
        if event == "line":
            seen[0] += 1
            if seen[0] == line:
                request.handler(signal.SIGTERM, None)
        return tracer

    def body():
        sys.settrace(tracer)
        try:
            result.append(request.wait(seconds))
        finally:
            sys.settrace(None)
    t = threading.Thread(target=body, daemon=True)
    t.start()
    t.join(60)                   # only a deadlock takes this long
    return not t.is_alive(), result, seen[0]


def test_a_signal_at_any_line_of_the_wait_ends_it():
    _, _, lines = _wait_with_signal_at(StopRequest(), 0, 3 * StopRequest.step_s)   # no signal
    assert lines >= 8            # several turns of the loop were traced
    for k in range(1, lines + 1):
        request = StopRequest()
        ended, result, _ = _wait_with_signal_at(request, k, 600.0)
        assert ended, f"the wait hung with the signal at its line {k}"
        assert result == [True] and request.why == ["SIGTERM received"], k


def test_no_signal_ends_the_wait_at_its_time_and_records_nothing():
    request = StopRequest()
    assert request.wait(0.0) is False
    assert request.wait(2 * request.step_s) is False
    assert request.why == [] and not request.signalled


def test_causes_keep_their_order():
    request = StopRequest()
    request.why.append("--seconds 5 elapsed")
    request.handler(signal.SIGINT, None)
    assert request.why == ["--seconds 5 elapsed", "SIGINT received"]
    assert request.signalled and request.wait(600.0) is True


def test_installed_handler_takes_a_real_sigterm():
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    try:
        request = StopRequest().install()
        os.kill(os.getpid(), signal.SIGTERM)
        assert request.wait(600.0) is True
        assert request.why == ["SIGTERM received"]
    finally:
        signal.signal(signal.SIGTERM, before[0])
        signal.signal(signal.SIGINT, before[1])
