"""Vision maths for the cell: camera model, sub-pixel fiducials, work-plane calibration.

Pure numerics on arrays (no I/O): images come from :mod:`drivers.camera`, calibrations are
stored by whoever owns the files. Pixel convention everywhere: OpenCV's, the centre of the
top-left pixel is (0, 0). Every failure is a :class:`VisionError` (a
:class:`~cell.errors.MeasurementError`) naming what went wrong and where.
"""
from cell.vision.camera_model import (CameraModel, Distortion, Intrinsics, Pose, VisionError,
                                      distort, undistort)
from cell.vision.fiducial import (FiducialFix, check_image, find_fiducial, find_fiducials,
                                  refine_fiducial)
from cell.vision.calibration import (ChessBoard, CircleGridBoard, PlaneCalibration, PlaneFix,
                                     board_from_dict, calibrate, detect_board, locate)

__all__ = ["CameraModel", "ChessBoard", "CircleGridBoard", "Distortion", "FiducialFix",
           "Intrinsics", "PlaneCalibration", "PlaneFix", "Pose", "VisionError", "board_from_dict",
           "calibrate", "check_image", "detect_board", "distort", "find_fiducial",
           "find_fiducials", "locate", "refine_fiducial", "undistort"]
