"""Background jobs: drift watch raises and clears recalibration_due; retention deletes old cycles."""
from types import SimpleNamespace

from cell.config import SchedulerSection
from cell.cyclelog import CycleLog, CycleRecord, utc_now
from cell.jobs import CellJobs, drift_due


def test_drift_due_needs_a_full_window_above_threshold():
    assert not drift_due([0.9] * 4, window=5, threshold_mm=0.5)
    assert drift_due([0.1] * 10 + [0.9] * 5, window=5, threshold_mm=0.5)
    assert not drift_due([0.9] * 10 + [0.1] * 5, window=5, threshold_mm=0.5)


def test_jobs_on_a_real_log(tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    controller = SimpleNamespace(log=log, recalibration_due=False)
    jobs = CellJobs(controller, SchedulerSection(drift_window=3, drift_threshold_mm=0.5), retention_days=30)

    def add(err, finished=None):
        log.add_cycle(CycleRecord(part_id=1, recipe="r", recipe_hash="h", started_at=utc_now(),
                                  finished_at=finished or utc_now(), status="done", cycle_time_s=1.0,
                                  initial_error_mm=err, final_error_mm=0.02, moves=2))
    for e in (0.2, 0.2, 0.2):
        add(e)
    assert jobs.drift() is False and controller.recalibration_due is False
    for e in (0.8, 0.9, 0.7):
        add(e)
    assert jobs.drift() is True and controller.recalibration_due is True
    add(0.1, finished="2001-01-01T00:00:00+00:00")
    assert jobs.retention() == 1 and log.count() == 6
