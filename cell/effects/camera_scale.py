"""camera_scale: camera scale error about its centre (format: m = c + (1 + s)·(p − c))."""
from __future__ import annotations

import numpy as np

from cell.effects.base import CameraCentre, Effect, ParamSpec, Remedy

CHECK_CAMERA = Remedy("camera", "Check the camera calibration ({what}).",
                      ("cellctl calibrate-camera --board board.yaml --images DIR --out cal.json",))


def camera_scale(x, xy_mm, center_mm):
    """Camera scale error s (relative) about the camera centre c: m = c + (1 + s)·(p − c)."""
    c = np.asarray(center_mm, dtype=float)
    return c + (1.0 + float(x[0])) * (xy_mm - c)


def d_camera_scale(x):
    """M = (1 + s)·I, ∂M/∂s = I."""
    return (1.0 + float(x[0])) * np.eye(2), np.eye(2)


EFFECT = Effect(
    "camera_scale", "vision", "vision", (), False,
    (ParamSpec("camera_scale_rel", "1", "scale about the camera centre", (-0.05, 0.05),
               (2e-4, 2e-3)),),
    "position", "camera scale error about its centre", camera_scale, d_camera_scale,
    needs=(CameraCentre(),), remedy=CHECK_CAMERA)
