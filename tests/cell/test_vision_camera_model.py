"""Projection maths against OpenCV's own projectPoints, and its round trips."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from cell.errors import ConfigError
from cell.vision import CameraModel, Distortion, Intrinsics, Pose, VisionError, distort, undistort

MODEL = CameraModel(Intrinsics(1400.0, 1402.0, 645.0, 508.0, 1280, 1024),
                    Pose(600.0, (320.0, 140.0), yaw_deg=35.0, tilt_x_deg=3.0, tilt_y_deg=-2.0),
                    Distortion(-0.12, 0.05, 0.001, -0.0007))


def _plane_points(n=50, seed=0):
    return np.random.default_rng(seed).uniform([200, 40], [440, 240], (n, 2))


def test_project_matches_opencv_projectpoints():
    pts = _plane_points()
    r, t = MODEL.extrinsics()
    rvec, _ = cv2.Rodrigues(r)
    obj = np.column_stack([pts, np.zeros(len(pts))])
    ref, _ = cv2.projectPoints(obj, rvec, t, MODEL.intrinsics.matrix(), MODEL.distortion.coeffs())
    assert np.allclose(MODEL.project(pts), ref.reshape(-1, 2), atol=1e-6)


def test_unproject_inverts_project():
    pts = _plane_points()
    assert np.allclose(MODEL.unproject(MODEL.project(pts)), pts, atol=1e-8)


def test_pose_conventions():
    nadir = CameraModel.nadir(640, 480, 0.5, centre_mm=(100.0, 50.0), yaw_deg=90.0)
    # the optical axis meets the plane at the image centre
    assert np.allclose(nadir.project([(100.0, 50.0)]), [[319.5, 239.5]])
    # yaw 90: image +u runs along base +y; image +v along base +x (seen from above)
    assert np.allclose(nadir.project([(100.0, 51.0)]), [[321.5, 239.5]])
    assert np.allclose(nadir.project([(101.0, 50.0)]), [[319.5, 241.5]])
    assert nadir.px_per_mm((100.0, 50.0)) == pytest.approx(2.0)
    assert MODEL.pose.centre_mm()[2] == pytest.approx(600.0)
    assert np.allclose(MODEL.project([MODEL.pose.axis_point_mm]), [[645.0, 508.0]])


def test_homography_is_the_undistorted_projection():
    pts = _plane_points(10)
    q = np.column_stack([pts, np.ones(len(pts))]) @ MODEL.homography().T
    undist = CameraModel(MODEL.intrinsics, MODEL.pose)
    assert np.allclose(q[:, :2] / q[:, 2:], undist.project(pts), atol=1e-9)


def test_undistort_inverts_distort():
    d = Distortion(-0.2, 0.08, 0.002, -0.001)
    x, y = np.meshgrid(np.linspace(-0.5, 0.5, 11), np.linspace(-0.4, 0.4, 9))
    xu, yu = undistort(*distort(x, y, d), d)
    assert np.allclose(xu, x, atol=1e-12) and np.allclose(yu, y, atol=1e-12)


def test_undistort_outside_invertible_region_raises():
    with pytest.raises(VisionError, match="did not converge"):
        undistort(np.array([5.0]), np.array([5.0]), Distortion(k1=-0.5))


def test_dict_round_trip_through_json():
    again = CameraModel.from_dict(json.loads(json.dumps(MODEL.as_dict())))
    assert again == MODEL


@pytest.mark.parametrize("build, match", [
    (lambda: Intrinsics(0.0, 800, 320, 240, 640, 480), "intrinsics.fx"),
    (lambda: Intrinsics(800, 800, 320, 240, 640.5, 480), "intrinsics.width"),
    (lambda: Intrinsics(800, 800, float("nan"), 240, 640, 480), "intrinsics.cx"),
    (lambda: Pose(-5.0), "pose.height_mm"),
    (lambda: Pose(500.0, tilt_x_deg=60.0), "pose.tilt_x_deg"),
    (lambda: Pose(500.0, axis_point_mm=(1.0,)), "pose.axis_point_mm"),
    (lambda: Distortion(k1="a lot"), "distortion.k1"),
    (lambda: CameraModel.from_dict({"intrinsics": {}, "pose": {"height_mm": 1}}), "intrinsics"),
    (lambda: CameraModel.from_dict({**MODEL.as_dict(), "lens": 1}), "unknown keys"),
    (lambda: CameraModel.from_dict([1, 2]), "mapping"),
])
def test_bad_parameters_name_the_field(build, match):
    with pytest.raises(ConfigError, match=match):
        build()


@pytest.mark.parametrize("bad", [np.zeros((3, 3)), [[1.0, float("nan")]], "x"])
def test_bad_points(bad):
    with pytest.raises((VisionError, ValueError)):
        MODEL.project(bad)


def test_pixel_above_horizon_raises():
    steep = CameraModel(Intrinsics(100.0, 100.0, 320, 240, 640, 480), Pose(500.0, tilt_x_deg=45.0))
    with pytest.raises(VisionError, match="above the horizon"):
        steep.unproject([[320.0, -400.0]])
