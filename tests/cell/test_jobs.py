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


def test_retention_keeps_what_the_plant_has_not_received(tmp_path):
    # ids 1-4 old, 5 new: with the historian's watermark at 2, ids 3 and 4 are old but not yet
    # received, and stay (the outage is then bounded by the disk, and that is logged)
    from cell.jobs import retain
    log = CycleLog(tmp_path / "cell.sqlite")
    for k in range(5):
        log.add_cycle(CycleRecord(part_id=k + 1, recipe="r", recipe_hash="h", started_at=utc_now(),
                                  finished_at="2001-01-01T00:00:00+00:00" if k < 4 else utc_now(),
                                  status="done", cycle_time_s=1.0, moves=1))
    assert retain(log, 30, delivered=2) == 2
    assert sorted(c.id for c in log.cycles()) == [3, 4, 5]
    assert log.count_older_than("2002-01-01T00:00:00+00:00", above=2) == 2
    assert retain(log, 30, delivered=4) == 2 and sorted(c.id for c in log.cycles()) == [5]
    assert retain(log, 30, delivered=None) == 0 and log.count() == 1
