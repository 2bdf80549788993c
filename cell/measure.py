"""The cell's measuring camera: a camera driver, its plane calibration and the fiducial sizes.

:class:`MeasuringCamera` grabs a frame and returns where the part's or the tool's fiducial
lies on the work plane, in mm in the robot base frame. Fiducials are told apart by size: the
tool carries a disc of ``tool_radius_mm``, each part type one of the recipe's
``part.fiducial_radius_mm``; a search accepts radii within ±``radius_tolerance`` of the
expected one. Every failure raises :class:`~cell.faults.CellFault` with the PLC fault code
for what went wrong (no target, two targets, cut by the edge, saturated, ...).
"""
from __future__ import annotations

import numpy as np

from cell.faults import CellFault, Fault
from cell.vision import VisionError
from cell.vision.calibration import PlaneCalibration, locate

VISION_FAULTS = {
    "no_target": Fault.NO_TARGET, "multiple": Fault.MULTIPLE_TARGETS, "cut": Fault.TARGET_CUT,
    "saturated": Fault.SATURATED, "low_contrast": Fault.LOW_CONTRAST,
    "bad_image": Fault.CAMERA_FAILED, "other": Fault.VISION_FAILED,
}


class MeasuringCamera:
    """Camera + calibration. ``camera`` is any :class:`drivers.camera.base.Camera` (opened)."""

    def __init__(self, camera, calibration: PlaneCalibration, tool_radius_mm: float,
                 radius_tolerance: float = 0.3):
        self.camera = camera
        self.calibration = calibration
        self.tool_radius_mm = float(tool_radius_mm)
        self.radius_tolerance = float(radius_tolerance)
        self.frames = 0
        self.last_error: str | None = None           #: the last grab's failure (health job)

    def grab(self) -> np.ndarray:
        """One 8-bit grey frame. Raises CellFault(CAMERA_FAILED) if the camera gives none."""
        try:
            frame = self.camera.grab()
        except Exception as exc:                     # any driver failure is a camera fault
            self.last_error = str(exc)
            raise CellFault(Fault.CAMERA_FAILED, f"camera grab failed: {exc}") from exc
        self.frames += 1
        self.last_error = None
        return frame.image

    def find(self, image: np.ndarray, radius_mm: float, what: str) -> np.ndarray:
        """(x_mm, y_mm) of the single fiducial of ``radius_mm`` in ``image``."""
        cal = self.calibration
        r_px = radius_mm / cal.mm_per_px(cal.width / 2, cal.height / 2)
        try:
            fixes = locate(image, self.calibration, expected=1,
                           min_radius_px=r_px * (1 - self.radius_tolerance),
                           max_radius_px=r_px * (1 + self.radius_tolerance))
        except VisionError as exc:
            raise CellFault(VISION_FAULTS[exc.kind], f"{what}: {exc}") from exc
        return np.array([fixes[0].x_mm, fixes[0].y_mm])

    def tool(self) -> np.ndarray:
        """Grab and locate the tool's fiducial."""
        return self.find(self.grab(), self.tool_radius_mm, "tool fiducial")
