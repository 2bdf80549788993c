"""Background jobs of the controller (apscheduler): health checks, accuracy-drift watch, log
retention. They run in the scheduler's own thread and only read devices or the log; any
finding reaches the PLC through the controller (a fault or the recalibration_due bit).
"""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
from apscheduler.schedulers.background import BackgroundScheduler

from cell.config import SchedulerSection
from cell.log import get_logger

log = get_logger("jobs")


def drift_due(initial_errors_mm: list[float], window: int, threshold_mm: float) -> bool:
    """True when the mean first-arrival error of the last ``window`` completed cycles exceeds
    ``threshold_mm``: the nominal model has drifted far enough that recalibration pays."""
    if len(initial_errors_mm) < window:
        return False
    return float(np.mean(initial_errors_mm[-window:])) > threshold_mm


class CellJobs:
    """Schedules the three jobs for one controller."""

    def __init__(self, controller, settings: SchedulerSection, retention_days: int):
        self.c, self.s, self.retention_days = controller, settings, retention_days
        self.scheduler = BackgroundScheduler(daemon=True, timezone="UTC")
        self.scheduler.add_job(self.health, "interval", seconds=settings.health_interval_s,
                               id="health", max_instances=1, coalesce=True)
        self.scheduler.add_job(self.drift, "interval", seconds=settings.drift_interval_s,
                               id="drift", max_instances=1, coalesce=True)
        self.scheduler.add_job(self.retention, "interval", seconds=settings.retention_interval_s,
                               id="retention", max_instances=1, coalesce=True)

    def start(self) -> None:
        self.scheduler.start()

    def stop(self) -> None:
        self.scheduler.shutdown(wait=False)

    def health(self) -> dict:
        """Drive states and camera liveness, logged; a dead device shows up as a fault in the
        scan loop (stations) or at the next capture (camera)."""
        motion = self.c.motion
        states = {j: s.name for j, s in motion.drive_states().items()} if hasattr(motion, "drive_states") else {}
        fault = str(motion.fault) if getattr(motion, "fault", None) else None
        cam = self.c.runner.camera
        report = {"state": self.c.sm.state.name, "drives": states, "station_fault": fault,
                  "camera_frames": cam.frames, "camera_error": cam.last_error,
                  "camera_open": getattr(getattr(cam.camera, "state", None), "value", None) == "open",
                  "fault_code": self.c.fault_code}
        healthy = fault is None and cam.last_error is None and report["camera_open"]
        (log.info if healthy else log.warning)("health", healthy=healthy, **report)
        return report

    def drift(self) -> bool:
        cycles = self.c.log.cycles(limit=self.s.drift_window, status="done")
        errors = [c.initial_error_mm for c in cycles if c.initial_error_mm is not None]
        due = drift_due(errors, self.s.drift_window, self.s.drift_threshold_mm)
        if due != self.c.recalibration_due:
            log.warning("recalibration_due" if due else "recalibration_cleared",
                        mean_initial_error_mm=float(np.mean(errors)) if errors else None)
        self.c.recalibration_due = due
        return due

    def retention(self) -> int:
        cutoff = (datetime.now(timezone.utc) - timedelta(days=self.retention_days)).isoformat()
        n = self.c.log.delete_older_than(cutoff)
        if n:
            log.info("retention_deleted", cycles=n, before=cutoff)
        return n
