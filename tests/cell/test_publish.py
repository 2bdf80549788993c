"""The publisher's contract: bounded per-subscriber queues that never block the controller."""
import threading

import pytest

from cell.cyclelog import CycleRecord
from cell.publish import Publisher


def test_a_slow_subscriber_loses_its_oldest_messages_never_blocks_and_counts_them():
    p = Publisher()
    slow, fast = p.subscribe(maxlen=3), p.subscribe(("status",), maxlen=100)
    for i in range(10):
        p.status(float(i), {"state": "idle", "cycle_count": i})
    assert [m["cycle_count"] for m in slow.drain()] == [7, 8, 9] and slow.dropped == 7
    assert len(fast.drain()) == 10 and fast.dropped == 0


def test_status_is_sent_only_when_it_changes():
    p = Publisher()
    s = p.subscribe(("status",))
    assert p.status(0.0, {"state": "idle"}) and not p.status(1.0, {"state": "idle"})
    assert p.status(2.0, {"state": "running"})
    assert [m["state"] for m in s.drain()] == ["idle", "running"]


def test_cycles_go_only_to_their_subscribers_without_the_trace():
    p = Publisher()
    status_only, cycles = p.subscribe(("status",)), p.subscribe(("cycle",))
    rec = CycleRecord(id=1, part_id=5, recipe="a", recipe_hash="h", started_at="t0", finished_at="t1",
                      status="done", method="lattice", target_mm=(1.0, 2.0), initial_error_mm=0.2,
                      final_error_mm=0.01, verify_error_mm=0.01, moves=2, cycle_time_s=1.0,
                      step_times={}, fault_code=0, fault_text="", temp_c=None, trace=[{"big": 1}])
    p.cycle(3.0, rec)
    assert status_only.drain() == []
    [m] = cycles.drain()
    assert m["cycle"]["part_id"] == 5 and m["cycle"]["target_mm"] == [1.0, 2.0] and "trace" not in m["cycle"]


def test_a_consumer_thread_gets_messages_as_they_come_and_can_leave():
    p = Publisher()
    s = p.subscribe()
    got = []
    t = threading.Thread(target=lambda: got.append(s.get(timeout=30)))
    t.start()
    p.status(0.0, {"state": "idle"})
    t.join(30)
    assert got and got[0]["state"] == "idle"
    assert s.get(timeout=0) is None
    s.close()
    p.status(1.0, {"state": "fault"})
    assert s.drain() == []


@pytest.mark.parametrize("topics, maxlen, words", [(("cycles",), 10, "unknown topic"),
                                                   ((), 10, "unknown topic"), (("cycle",), 0, "maxlen 0")])
def test_a_bad_subscription_is_refused_by_name(topics, maxlen, words):
    with pytest.raises(ValueError, match=words):
        Publisher().subscribe(topics, maxlen)


def test_events_go_only_to_their_subscribers():
    p = Publisher()
    status_only, events = p.subscribe(("status",)), p.subscribe(("event",))
    p.event(4.0, "calibration_applied", {"calibration": "cal-0002"})
    assert status_only.drain() == []
    [m] = events.drain()
    assert (m["topic"], m["kind"], m["data"], m["clock_s"]) == ("event", "calibration_applied",
                                                                {"calibration": "cal-0002"}, 4.0)


def test_the_last_status_is_there_for_a_late_subscriber():
    p = Publisher()
    assert p.last_status() is None
    p.status(1.0, {"state": "idle"})
    p.status(2.0, {"state": "fault", "fault_code": 3})
    assert p.last_status() == {"state": "fault", "fault_code": 3}
