"""Plant integration subscribes in one place (:mod:`cell.publish`): every settled cycle
exactly as the log holds it, and every status change, on the simulated cell."""
from __future__ import annotations

from cell.controller import JOINTS_SAMPLE_S
from cell.faults import Fault


def test_settled_cycles_and_status_changes_are_published_as_the_log_and_plc_see_them(harness):
    h = harness
    sub = h.cell.publisher.subscribe()
    results = [h.cycle() for _ in range(3)]
    h.wait(lambda: sum(m["topic"] == "cycle" for m in sub.pending()) == 3, what="three cycles published")
    # a faulted part too: the camera finds no target
    h.cell.devices.feeder.remove()
    h.plc.select_recipe(7)
    h.plc.set_part_id(999)
    h.wait(lambda: h.status()["ready"], what="ready")
    h.plc.set_command(execute=True)
    h.wait(lambda: h.status()["error"], timeout_s=20, what="error")
    h.plc.set_command(execute=False)
    h.wait(lambda: sum(m["topic"] == "cycle" for m in sub.pending()) == 4, what="the faulted cycle published")
    msgs = sub.drain()
    assert sub.dropped == 0
    assert [m["seq"] for m in msgs] == sorted(m["seq"] for m in msgs)
    assert all(a["clock_s"] <= b["clock_s"] for a, b in zip(msgs, msgs[1:]))
    cycles = [m["cycle"] for m in msgs if m["topic"] == "cycle"]
    logged = h.cell.cyclelog.cycles()
    assert [c["id"] for c in cycles] == [c.id for c in logged]
    for pub, row in zip(cycles, logged):
        assert (pub["part_id"], pub["status"], pub["fault_code"], pub["final_error_mm"]) == \
               (row.part_id, row.status, row.fault_code, row.final_error_mm)
        assert "trace" not in pub
    # what the PLC was told (µm registers) is what went out
    assert all(abs(c["final_error_mm"] * 1000 - r["final_error_um"]) <= 1 for c, r in zip(cycles, results))
    assert cycles[-1]["status"] == "aborted" and cycles[-1]["fault_code"] == Fault.NO_TARGET
    states = [m for m in msgs if m["topic"] == "status"]
    seen = [s["state"] for s in states]
    for step in ("approach", "capture", "compensate", "final_move", "verify", "done", "idle"):
        assert step in seen, (step, seen)
    assert states[-1]["fault_code"] == Fault.NO_TARGET and states[-1]["state"] == "fault"
    # a status message only when something changed
    keys = [tuple(sorted((k, v) for k, v in s.items() if k not in ("seq", "clock_s", "topic")))
            for s in states]
    assert all(a != b for a, b in zip(keys, keys[1:]))
    assert max(s["cycle_count"] for s in states) == 3


def test_scans_with_no_news_stay_quiet_yet_the_moving_joints_are_published_every_sample(harness):
    """Most scans of a cycle have no news and write only the heartbeat; the status still
    carries the joints as they move, sampled every JOINTS_SAMPLE_S of those scans too."""
    h = harness
    ctl = h.controller
    sub = h.cell.publisher.subscribe()
    scans0, quiet0 = ctl.scans, ctl.quiet_scans
    h.cycle()
    scans, quiet = ctl.scans - scans0, ctl.quiet_scans - quiet0
    assert quiet > scans / 2, (quiet, scans)                   # the core stepped on the rest
    status = [m for m in sub.drain() if m["topic"] == "status"]
    sampled = [b["clock_s"] for a, b in zip(status, status[1:]) if a["joints"] != b["joints"]]
    assert len(sampled) >= 5
    # the joints change at the sampling period, as often as they can while moving
    gaps = [round(b - a, 6) for a, b in zip(sampled, sampled[1:])]
    assert min(gaps) >= JOINTS_SAMPLE_S - 1e-9
    assert sum(g <= JOINTS_SAMPLE_S + 0.011 for g in gaps) >= len(gaps) // 2, gaps
