"""camera_scale: camera scale error about its centre (format: m = c + (1 + s)·(p − c)). On a
chain the sensor scales every axis it sees about its centre ``sensor_center_mm``."""
from __future__ import annotations

import numpy as np

from cell.effects.base import Effect, OnChain, ParamSpec, Remedy, planar_map

NO_CENTRE = "model.yaml gives no sensor_center_mm"
CHECK_CAMERA = Remedy("camera", "Check the camera calibration ({what}).",
                      ("cellctl calibrate-camera --board board.yaml --images DIR --out cal.json",))


def camera_scale(x, xy_mm, center_mm):
    """Camera scale error s (relative) about the camera centre c: m = c + (1 + s)·(p − c)."""
    c = np.asarray(center_mm, dtype=float)
    return c + (1.0 + float(x[0])) * (xy_mm - c)


def d_camera_scale(x):
    """M = (1 + s)·I, ∂M/∂s = I."""
    return (1.0 + float(x[0])) * np.eye(2), np.eye(2)


def chain_scale(s: float):
    """The scale in the measurement frame: M = (1 + s)·I₃, ∂M/∂s = I₃."""
    m, dm = d_camera_scale([s])
    return planar_map(m, 1.0 + s), planar_map(dm, 1.0)


SCALE = ParamSpec("camera_scale_rel", "1", "scale about the camera centre", (-0.05, 0.05),
                  (2e-4, 2e-3))

EFFECT = Effect(
    "camera_scale", "vision", "vision", (), False, (SCALE,),
    "position", "camera scale error about its centre", camera_scale, d_camera_scale,
    remedy=CHECK_CAMERA,
    chain=OnChain("sensor", "camera_scale_rel", "1", sensor_map=chain_scale, unseen=NO_CENTRE,
                  bounds=SCALE.bounds))
