"""The simulated cell's clock (cell/sim/clock.py): discrete-event time, one runner at a time,
time moving only when every participant waits, pure or paced to wall time."""
from __future__ import annotations

import math
import queue
import threading
import time

import pytest

from cell.clock import ClockError, ManualClock, MonotonicClock
from cell.sim.clock import VirtualClock
from tests.waiting import wait_for


@pytest.fixture
def clock():
    c = VirtualClock()
    yield c
    c.close()


def trace_of_three_tasks(clock: VirtualClock) -> list:
    trace = []

    def worker(name, period, n):
        for _ in range(n):
            clock.sleep(period)
            trace.append((round(clock.now(), 9), name))
    with clock.attach():
        tasks = [clock.spawn(worker, n, n, p, k) for n, p, k in (("a", 0.01, 6), ("b", 0.015, 4), ("c", 0.03, 2))]
        for t in tasks:
            assert t.join()
    return trace


def test_tasks_run_in_time_order_and_the_same_way_every_time(clock):
    first = trace_of_three_tasks(clock)
    assert [t for t, _ in first] == sorted(t for t, _ in first)
    # ties at 0.03 and 0.06 go in the order the waits were scheduled, the same every run
    again = trace_of_three_tasks(VirtualClock())
    assert [(round(t - first[0][0], 9), n) for t, n in first] == \
        [(round(t - again[0][0], 9), n) for t, n in again]
    assert len(first) == 12


def test_time_moves_only_when_every_participant_waits(clock):
    seen = []

    def busy():
        t0 = clock.now()
        end = time.monotonic() + 0.05          # 50 ms of work on the host, no simulated time
        while time.monotonic() < end:
            pass
        seen.append(("busy done", clock.now() - t0))

    def sleeper():
        clock.sleep(0.001)
        seen.append(("slept", clock.now()))
    with clock.attach():
        a = clock.spawn(busy, "busy")
        b = clock.spawn(sleeper, "sleeper")
        a.join()
        b.join()
    assert seen[0] == ("busy done", 0.0)       # the sleeper's 1 ms did not pass meanwhile
    assert seen[1] == ("slept", pytest.approx(0.001))


def test_no_participant_no_time(clock):
    fired = []
    clock.call_at(0.5, fired.append, 1)
    time.sleep(0.05)
    assert clock.now() == 0.0 and fired == []  # nobody keeps the clock's time: it stands still
    with clock.attach():
        clock.sleep(1.0)
    assert fired == [1] and clock.now() == 1.0


def test_events_and_queues_time_out_in_clock_seconds(clock):
    with clock.attach():
        ev = clock.event()
        t0 = clock.now()
        assert ev.wait(0.25) is False and clock.now() - t0 == pytest.approx(0.25)
        clock.call_later(0.1, ev.set)
        assert ev.wait(5.0) is True and clock.now() - t0 == pytest.approx(0.35)
        q = clock.queue()
        clock.call_later(0.2, q.put, "x")
        assert q.get(timeout=1.0) == "x" and clock.now() - t0 == pytest.approx(0.55)
        with pytest.raises(queue.Empty):
            q.get(timeout=0.05)
        assert clock.now() - t0 == pytest.approx(0.6)
        q.put("y")
        q.clear()
        assert q.empty()


def test_a_participant_joins_a_task_in_clock_time(clock):
    with clock.attach():
        task = clock.spawn(clock.sleep, "sleeper", 2.0)
        assert task.join(timeout=0.5) is False and clock.now() == pytest.approx(0.5)
        assert task.join() is True and task.finished and clock.now() == pytest.approx(2.0)


def test_waiting_from_a_thread_that_does_not_keep_the_time_is_refused(clock):
    with pytest.raises(ClockError, match="does not keep this clock's time.*clock.attach"):
        clock.sleep(0.1)
    with pytest.raises(ClockError, match="MainThread"):
        clock.event().wait(0.1)


def test_the_clock_never_goes_back():
    c = VirtualClock(start=10.0)
    with c.attach():
        c.sleep(1.0)
        with pytest.raises(ClockError, match="cannot schedule at t = 5.0 s, the clock is at 11.0 s"):
            c.call_at(5.0, print)
        with pytest.raises(ClockError, match="must be ≥ 0"):
            c.call_later(-1.0, print)
        with pytest.raises(ClockError, match="nan"):
            c.sleep_until(math.nan)
        c.sleep_until(3.0)                    # a deadline already past: returns at once
        assert c.now() == 11.0
    c.close()
    with pytest.raises(ClockError, match="not a finite time"):
        VirtualClock(start=math.inf)
    m = ManualClock(5.0)
    with pytest.raises(ClockError, match="cannot advance by -1.0 s; a clock never goes back"):
        m.advance(-1.0)
    assert m.now() == 5.0


def test_a_simulation_where_everybody_waits_forever_is_named(clock):
    with clock.attach("tester"):
        never = clock.event()
        with pytest.raises(ClockError, match=r"simulation stuck at t = 0.000000 s.*tester"):
            never.wait()


def test_a_failing_callback_is_logged_and_time_goes_on(clock):
    done = []
    clock.call_at(0.1, lambda: 1 / 0)
    clock.call_at(0.2, done.append, "after")
    with clock.attach():
        clock.sleep(0.3)
    assert done == ["after"]


def test_paced_clock_never_runs_early_and_stretches_after_a_stall():
    """Entries never run before their wall time; after the host stalls, simulated time is
    stretched: it catches up at most ``max_lag_s``, never the whole stall.

    Only lower bounds on the (injected) wall time are asserted: the clock reads the wall,
    then runs the entry, which reads it again, so each holds whatever the host's load.
    How closely the clock keeps to wall time is measured by bench/bench_sim_clock.py."""
    offset = [0.0]
    lag = 0.005

    def wall():
        return time.monotonic() + offset[0]
    origin = wall()                                # the clock's origin is read after this
    c = VirtualClock(pace=True, max_lag_s=lag, wall=wall)
    runs, stall = [], []
    for k in range(1, 9):
        c.call_at(0.02 * k, lambda k=k: runs.append((c.now(), wall())))

    def freeze():                                  # the host "freezes" for 1 s of wall time
        offset[0] += 1.0
        stall.append(wall())
    c.call_at(0.085, freeze)
    wait_for(lambda: len(runs) == 8, 30, "the 8 entries")
    c.close()
    assert [round(t, 9) for t, _ in runs] == [round(0.02 * k, 9) for k in range(1, 9)]
    # before the stall: never earlier than the origin plus the entry's time
    assert all(w >= origin + t for t, w in runs[:4]), (origin, runs)
    # the entry after the stall runs after it ...
    assert runs[4][1] >= stall[0] >= runs[3][1] + 1.0
    # ... and the ones after keep their spacing from there: the stall is not caught up,
    # only max_lag_s of it (without stretching, entries 6-8 would all run at once)
    t5 = runs[4][0]
    assert all(w >= stall[0] + (t - t5) - lag for t, w in runs[4:]), (stall, runs)


def test_paced_clock_never_wakes_a_sleeper_early():
    """A task sleeping in short steps is never woken before the wall time of its wake-up,
    and simulated time adds up exactly. (That the clock keeps up with wall time, its wake-
    ups' lateness caught up, is a timing: bench/bench_sim_clock.py measures it.)"""
    origin = time.monotonic()
    c = VirtualClock(pace=True)
    wakes = []
    with c.attach():
        t0 = c.now()
        for _ in range(200):
            c.sleep(0.001)
            wakes.append((c.now(), time.monotonic()))
    c.close()
    assert c.now() - t0 == pytest.approx(0.2)
    assert [round(t - t0, 9) for t, _ in wakes] == [round(0.001 * k, 9) for k in range(1, 201)]
    assert all(w >= origin + t for t, w in wakes)


def test_wall_clock_primitives_are_the_standard_ones():
    c = MonotonicClock()
    assert c.wall and isinstance(c.event(), threading.Event)
    task = c.spawn(lambda: None, "noop")
    assert task.join(1.0) and task.finished
    with c.attach():
        t0 = c.now()
        c.sleep(0.001)
        assert c.now() > t0


# ------------------------------------------------------------------ who runs the agenda
def test_a_task_that_waits_runs_the_due_callbacks_itself_and_wakes_without_a_hand_off(clock):
    """Pure mode: the task that lets go of the baton runs what is due before its own wake-up
    in its own thread, in the agenda's order, and resumes without a thread switch."""
    seen = []
    with clock.attach("main"):
        for k in range(5):
            clock.call_later(0.001 * k, lambda k=k: seen.append((k, clock.now(), threading.current_thread().name)))
        before = clock.handoffs
        clock.sleep(0.01)
        assert clock.handoffs == before                       # its own wake-up: no switch
    assert [(k, t) for k, t, _ in seen] == [(k, pytest.approx(0.001 * k)) for k in range(5)]
    assert {name for _, _, name in seen} == {threading.current_thread().name}


def test_a_callback_may_not_wait_in_whichever_thread_it_runs(clock):
    errors = []

    def waits():
        try:
            clock.sleep(0.001)
        except ClockError as exc:
            errors.append(str(exc))

    with clock.attach("main"):
        clock.call_later(0.001, waits)
        clock.sleep(0.01)                                     # the callback runs in this thread
        assert clock.keeps_time()                             # back in the task: it may wait
    assert len(errors) == 1 and "inside a clock callback" in errors[0]
