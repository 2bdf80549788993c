"""Publisher messages folded into what the OPC UA server shows (pure, no server)."""
import math

from cell.cyclelog import CycleRecord
from cell.opcua.model import RESULT_FIELDS, CellStatus, Fold, Result
from cell.publish import Publisher


def _record(**kw) -> CycleRecord:
    base = dict(id=3, part_id=12, recipe="bracket-a", recipe_hash="h", started_at="t0",
                finished_at="2026-01-01T00:00:01Z", status="done", cycle_time_s=2.5, final_error_mm=0.021,
                verify_error_mm=0.019, moves=2)
    return CycleRecord(**{**base, **kw})


def test_status_and_results_are_folded_from_what_the_publisher_sends():
    p = Publisher()
    sub = p.subscribe()
    p.status(0.0, {"state": "idle", "fault_code": 0, "fault_text": "", "cycle_count": 0, "recipe_number": 1,
                   "recipe_name": "bracket-a", "recalibration_due": False, "plc_owner": None, "joints": None})
    p.status(0.1, {"state": "approach", "cycle_count": 0, "recipe_number": 1, "joints": [1, 2.5, -20, 0]})
    p.cycle(0.2, _record())
    p.cycle(0.3, _record(id=4, part_id=13, status="aborted", fault_code=301, fault_text="no frame",
                         final_error_mm=None, verify_error_mm=None, moves=None))
    fold = Fold()
    status, results = fold.take(sub.drain())
    assert status == fold.status and status.state == "approach" and status.joints == (1.0, 2.5, -20.0, 0.0)
    assert [r.part_id for r in results] == [12, 13] and fold.latest is results[-1]
    done, faulted = results
    assert (done.result_id, done.status, done.final_error_mm, done.moves, done.recipe) == (3, "done", 0.021, 2,
                                                                                          "bracket-a")
    assert faulted.fault_code == 301 and faulted.fault_text == "no frame" and faulted.moves == 0
    assert math.isnan(faulted.final_error_mm) and math.isnan(faulted.verify_error_mm)
    assert len(done.values()) == len(RESULT_FIELDS)


def test_no_message_changes_nothing_and_a_status_without_joints_waits_for_them():
    fold = Fold()
    assert fold.take([]) == (None, []) and fold.status is None and fold.latest is None
    st = CellStatus.from_message({"topic": "status", "state": "fault", "fault_code": 101})
    assert st.joints is None and st.fault_code == 101 and st.recipe_name == ""


def test_a_cycle_message_missing_its_part_is_refused_loudly():
    import pytest
    with pytest.raises(KeyError):
        Result.from_message({"topic": "cycle", "cycle": {"status": "done"}})
