"""Background jobs of the controller: health checks, accuracy-drift watch, log retention.
They only read devices or the log; any finding reaches the PLC through the controller (a
fault or the recalibration_due bit).

On wall time (a real cell) apscheduler runs them in its own thread. apscheduler reads the
wall clock itself (``datetime.now``) and cannot be given another, so on the simulated clock
the same jobs run from one task of that clock, at the same intervals of simulated time.
"""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
from apscheduler.schedulers.background import BackgroundScheduler

from cell.clock import Clock, MonotonicClock
from cell.config import SchedulerSection
from cell.cyclelog import CycleStatus
from cell.log import get_logger

log = get_logger("jobs")


def retain(cyclelog, retention_days: int, delivered: int | None, now: datetime | None = None) -> int:
    """Delete the log's cycles that finished more than ``retention_days`` ago, except those
    the plant has not received: ids above ``delivered`` (the historian's watermark; None: the
    cell has no plant path). Those stay however old, and are logged as held
    (``retention_held``: how many, and that the disk now bounds the outage). Returns how
    many were deleted."""
    cutoff = ((now or datetime.now(timezone.utc)) - timedelta(days=retention_days)).isoformat()
    n = cyclelog.delete_older_than(cutoff, delivered)
    if n:
        log.info("retention_deleted", cycles=n, before=cutoff)
    held = 0 if delivered is None else cyclelog.count_older_than(cutoff, delivered)
    if held:
        log.warning("retention_held", cycles=held, before=cutoff, watermark=delivered,
                    why="the plant historian has not received them; they stay until it does, "
                        "bounded only by the disk")
    return n


def drift_due(initial_errors_mm: list[float], window: int, threshold_mm: float) -> bool:
    """True when the mean first-arrival error of the last ``window`` completed cycles exceeds
    ``threshold_mm``: the nominal model has drifted far enough that recalibration pays."""
    if len(initial_errors_mm) < window:
        return False
    return float(np.mean(initial_errors_mm[-window:])) > threshold_mm


class CellJobs:
    """Schedules the three jobs for one controller (see the module doc for the clock)."""

    def __init__(self, controller, settings: SchedulerSection, retention_days: int,
                 clock: Clock | None = None, outbox=None):
        self.c, self.s, self.retention_days = controller, settings, retention_days
        self.outbox = outbox                      # the plant outbox, whose backlog health reports
        self.clock = clock or MonotonicClock()
        self.jobs = [(self.health, settings.health_interval_s), (self.drift, settings.drift_interval_s),
                     (self.retention, settings.retention_interval_s)]
        self.scheduler: BackgroundScheduler | None = None
        self._task = None
        self._stop = self.clock.event()
        if self.clock.wall:
            self.scheduler = BackgroundScheduler(daemon=True, timezone="UTC")
            for job, every in self.jobs:
                self.scheduler.add_job(job, "interval", seconds=every, id=job.__name__,
                                       max_instances=1, coalesce=True)

    def start(self) -> None:
        if self.scheduler is not None:
            self.scheduler.start()
        else:
            self._task = self.clock.spawn(self._run, "cell-jobs")

    def stop(self) -> None:
        if self.scheduler is not None:
            self.scheduler.shutdown(wait=False)
        self._stop.set()
        if self._task is not None:
            self._task.join(timeout=5)

    def _run(self) -> None:
        due = [self.clock.now() + every for _, every in self.jobs]
        while True:
            k = min(range(len(due)), key=due.__getitem__)
            if self._stop.wait(max(0.0, due[k] - self.clock.now())):
                return
            job, every = self.jobs[k]
            due[k] += every
            try:
                job()
            except Exception as exc:               # noqa: BLE001 -- a job must not end the others
                log.error("job_failed", job=job.__name__, error=repr(exc))

    def health(self) -> dict:
        """Drive states and camera liveness, logged; a dead device shows up as a fault in the
        scan loop (stations) or at the next capture (camera)."""
        motion = self.c.motion
        states = {j: s.name for j, s in motion.drive_states().items()}
        fault = str(motion.fault) if motion.fault else None
        cam = self.c.runner.camera
        report = {"state": self.c.sm.state.name, "drives": states, "station_fault": fault,
                  "camera_frames": cam.frames, "camera_error": cam.last_error,
                  "camera_open": getattr(getattr(cam.camera, "state", None), "value", None) == "open",
                  "fault_code": self.c.fault_code}
        if self.outbox is not None:               # records the plant historian has not committed
            report["plant_backlog"] = self.outbox.backlog
        healthy = fault is None and cam.last_error is None and report["camera_open"]
        (log.info if healthy else log.warning)("health", healthy=healthy, **report)
        return report

    def drift(self) -> bool:
        cycles = self.c.log.cycles(limit=self.s.drift_window, status=CycleStatus.DONE)
        errors = [c.initial_error_mm for c in cycles if c.initial_error_mm is not None]
        due = drift_due(errors, self.s.drift_window, self.s.drift_threshold_mm)
        if due != self.c.recalibration_due:
            log.warning("recalibration_due" if due else "recalibration_cleared",
                        mean_initial_error_mm=float(np.mean(errors)) if errors else None)
        self.c.recalibration_due = due
        return due

    def retention(self) -> int:
        """:func:`retain` on the controller's log, with the plant outbox's watermark."""
        return retain(self.c.log, self.retention_days,
                      None if self.outbox is None else self.outbox.watermark)
