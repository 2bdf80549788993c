"""The cell's measuring camera: a camera driver, its plane calibration and the fiducial sizes.

:class:`MeasuringCamera` grabs a frame and returns where the part's or the tool's fiducial
lies on the work plane, in mm in the robot base frame. Fiducials are told apart by size: the
tool carries a disc of ``tool_radius_mm``, each part type one of the recipe's
``part.fiducial_radius_mm``; a search accepts radii within ±``radius_tolerance`` of the
expected one. Every failure raises :class:`~cell.faults.CellFault` with the PLC fault code
for what went wrong (no target, two targets, cut by the edge, saturated, ...).

**Where to look.** A search told where its fiducial should be (``near_mm``) looks first in
a window around it: ``within_mm`` (how far off it may lie, default ``window_mm``) plus the
largest accepted radius. The window holds a few per cent of the frame, so the search costs
that much less. When the window gives no single fiducial, the whole frame is searched
instead; each such fall-back is counted in :attr:`MeasuringCamera.window_misses` and
logged (``vision_window_missed``, with the reason), so a model that predicts badly shows.

A grab runs in the ``camera-grab`` worker task, and the cycle waits for it at most
``grab_timeout_s`` of the injected clock — or until the cycle is cancelled, which ends the
wait at once. A grab that does not return in time is fault 301; while it still hangs,
the next grab waits for it once more and is then refused with 301 too, so hung grabs never
pile up.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from cell.clock import Clock, MonotonicClock
from cell.faults import CellFault, Fault
from cell.log import get_logger
from cell.vision import VisionError
from cell.vision.calibration import PlaneCalibration, PlaneFix, locate
from cell.worker import Job, Worker

VISION_FAULTS = {
    "no_target": Fault.NO_TARGET, "multiple": Fault.MULTIPLE_TARGETS, "cut": Fault.TARGET_CUT,
    "saturated": Fault.SATURATED, "low_contrast": Fault.LOW_CONTRAST,
    "bad_image": Fault.CAMERA_FAILED, "other": Fault.VISION_FAILED,
}


#: the fiducial search: (image, calibration, **find_kwargs) -> fixes in mm on the work plane;
#: raises :class:`~cell.vision.VisionError` with its ``kind``
Locate = Callable[..., list[PlaneFix]]

log = get_logger("vision")


class MeasuringCamera:
    """Camera + calibration. ``camera`` is any :class:`drivers.camera.base.Camera` (opened).

    :param locate: the fiducial search (default :func:`cell.vision.calibration.locate`);
        another one lets a test make the search fail in each of its ways
        (:data:`VISION_FAULTS`) without an image that does so.
    """

    def __init__(self, camera, calibration: PlaneCalibration, tool_radius_mm: float,
                 radius_tolerance: float = 0.3, grab_timeout_s: float = 2.0, clock: Clock | None = None,
                 locate: Locate = locate, window_mm: float = 5.0):
        self.camera = camera
        self.window_mm = float(window_mm)
        self.window_misses = 0                       #: window searches that fell back to the frame
        self.calibration = calibration
        self.tool_radius_mm = float(tool_radius_mm)
        self.radius_tolerance = float(radius_tolerance)
        self.grab_timeout_s = float(grab_timeout_s)
        self.clock = clock or MonotonicClock()
        self._locate = locate
        self.frames = 0
        self.last_error: str | None = None           #: the last grab's failure (health job)
        self._worker = Worker(self.clock, "camera-grab")
        self._unfinished: Job | None = None          # a grab the cycle stopped waiting for
        self._centre_scale: tuple[PlaneCalibration, float] | None = None   # see _centre_mm_per_px

    def grab(self, cancel=None) -> np.ndarray:
        """One 8-bit grey frame.

        :param cancel: the cycle's :class:`~cell.cycle.runner.CancelToken`: a cancel ends the wait
            at once (raises its ``CycleCancelled``).
        :raises CellFault: CAMERA_FAILED if the camera gives no frame, fails, or takes longer
            than ``grab_timeout_s``.
        """
        if self._unfinished is not None:             # the last grab was left hanging
            if not self._wait(self._unfinished, cancel):
                self.last_error = f"camera still hung in a grab after {self.grab_timeout_s} s more"
                raise CellFault(Fault.CAMERA_FAILED, self.last_error)
            self._unfinished = None
        self._worker.start()
        job = self._worker.submit(self.camera.grab)
        if not self._wait(job, cancel):
            self._unfinished = job
            self.last_error = f"camera gave no frame within {self.grab_timeout_s} s (grab_timeout_s)"
            raise CellFault(Fault.CAMERA_FAILED, self.last_error)
        try:
            frame = job.outcome()
        except Exception as exc:                     # any driver failure is a camera fault
            self.last_error = str(exc)
            raise CellFault(Fault.CAMERA_FAILED, f"camera grab failed: {exc}") from exc
        self.frames += 1
        self.last_error = None
        return frame.image

    def _wait(self, job: Job, cancel) -> bool:
        """Wait for ``job`` up to the time-out; True if it finished. A cancel raises."""
        if cancel is not None:
            cancel.wake_on_cancel(job.finished)
        job.finished.wait(self.grab_timeout_s)
        if job.done:
            return True
        if cancel is not None:
            if cancel.cancelled:
                self._unfinished = job
            cancel.check()
        return False

    def close(self) -> None:
        """End the grab worker (a grab that hangs is left behind in its daemon task)."""
        self._worker.stop(timeout_s=self.grab_timeout_s)

    def find(self, image: np.ndarray, radius_mm: float, what: str, near_mm=None,
             within_mm: float | None = None) -> np.ndarray:
        """(x_mm, y_mm) of the single fiducial of ``radius_mm`` in ``image``. With
        ``near_mm`` (x, y), first in the window ``within_mm`` (default :attr:`window_mm`)
        around it (see the module doc); CellFault names ``what`` and the search's failure."""
        r_px = radius_mm / self._centre_mm_per_px()
        sizes = dict(min_radius_px=r_px * (1 - self.radius_tolerance),
                     max_radius_px=r_px * (1 + self.radius_tolerance))
        roi = None if near_mm is None else self._window(near_mm, radius_mm, within_mm)
        if roi is not None:
            try:
                return self._search(image, what, sizes, roi)
            except CellFault as exc:
                self.window_misses += 1
                log.warning("vision_window_missed", what=what, near_mm=[round(float(v), 3) for v in near_mm],
                            window_px=list(roi), reason=exc.detail, misses=self.window_misses)
        return self._search(image, what, sizes, None)

    def _search(self, image, what: str, sizes: dict, roi) -> np.ndarray:
        try:
            fixes = self._locate(image, self.calibration, expected=1, roi=roi, **sizes)
        except VisionError as exc:
            raise CellFault(VISION_FAULTS[exc.kind], f"{what}: {exc}") from exc
        return np.array([fixes[0].x_mm, fixes[0].y_mm])

    def _window(self, near_mm, radius_mm: float, within_mm: float | None):
        """(u0, v0, u1, v1) px around ``near_mm``, clipped to the frame; None when the point
        is not finite or the window would not hold the disc whole."""
        cal = self.calibration
        near = np.asarray(near_mm, dtype=float)
        if near.shape != (2,) or not np.all(np.isfinite(near)):
            return None
        u, v = cal.base_to_pixel(float(near[0]), float(near[1]))
        reach_mm = (self.window_mm if within_mm is None else within_mm) \
            + radius_mm * (1 + self.radius_tolerance) + 0.5
        half = reach_mm / cal.mm_per_px(u, v) if 0 <= u < cal.width and 0 <= v < cal.height \
            else reach_mm / self._centre_mm_per_px()
        u0, v0 = max(0, int(u - half)), max(0, int(v - half))
        u1, v1 = min(cal.width - 1, int(math.ceil(u + half))), min(cal.height - 1, int(math.ceil(v + half)))
        r_px = radius_mm * (1 + self.radius_tolerance) / self._centre_mm_per_px()
        if u1 - u0 < 2 * r_px or v1 - v0 < 2 * r_px:
            return None
        return (u0, v0, u1, v1)

    def _centre_mm_per_px(self) -> float:
        """The calibration's scale at the frame centre (mm per px), which sizes every search;
        worked out once per calibration (a frozen :class:`PlaneCalibration`), not per find."""
        cal = self.calibration
        if self._centre_scale is None or self._centre_scale[0] is not cal:
            self._centre_scale = (cal, cal.mm_per_px(cal.width / 2, cal.height / 2))
        return self._centre_scale[1]

    def tool(self, cancel=None, near_mm=None) -> np.ndarray:
        """Grab and locate the tool's fiducial (``cancel`` as for :meth:`grab`; ``near_mm``
        where it should be, as for :meth:`find`)."""
        return self.find(self.grab(cancel), self.tool_radius_mm, "tool fiducial", near_mm)
