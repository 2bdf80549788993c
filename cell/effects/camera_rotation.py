"""camera_rotation: camera rotated about its centre (format: m = c + R(φ)·(p − c)). On a
chain the sensor turns its readings about the z axis through ``sensor_center_mm``."""
from __future__ import annotations

import math

import numpy as np

from cell.effects.base import Effect, OnChain, ParamSpec, planar_map
from cell.effects.camera_scale import CHECK_CAMERA, NO_CENTRE


def _rot(a_rad: float) -> np.ndarray:
    return np.array([[math.cos(a_rad), -math.sin(a_rad)], [math.sin(a_rad), math.cos(a_rad)]])


def camera_rotation(x, xy_mm, center_mm):
    """Camera rotation error φ (deg) about the camera centre c: m = c + R(φ)·(p − c)."""
    c = np.asarray(center_mm, dtype=float)
    return c + (xy_mm - c) @ _rot(math.radians(float(x[0]))).T


def d_camera_rotation(x):
    """M = R(φ), ∂M/∂φ = (π/180)·[[−sin φ, −cos φ], [cos φ, −sin φ]]."""
    a = math.radians(float(x[0]))
    return _rot(a), (math.pi / 180.0) * np.array([[-math.sin(a), -math.cos(a)],
                                                   [math.cos(a), -math.sin(a)]])


def chain_rotation(phi_deg: float):
    """The rotation about z in the measurement frame: M = R_z(φ), ∂M/∂φ (φ in deg)."""
    m, dm = d_camera_rotation([phi_deg])
    return planar_map(m, 1.0), planar_map(dm, 0.0)


TURN = ParamSpec("camera_rotation_deg", "deg", "rotation about the camera centre", (-5.0, 5.0),
                 (0.01, 0.1))

EFFECT = Effect(
    "camera_rotation", "vision", "vision", (), False, (TURN,),
    "position", "camera rotated about its centre", camera_rotation, d_camera_rotation,
    remedy=CHECK_CAMERA,
    chain=OnChain("sensor", "camera_rotation_deg", "deg", sensor_map=chain_rotation,
                  unseen=NO_CENTRE, remedy=CHECK_CAMERA, bounds=TURN.bounds))
