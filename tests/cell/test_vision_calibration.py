"""Calibration round trip: render boards through a known camera, calibrate, measure fiducials in mm."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml

from cell.errors import ConfigError
from cell.vision import (CameraModel, ChessBoard, CircleGridBoard, Distortion, Intrinsics,
                         PlaneCalibration, Pose, VisionError, board_from_dict, calibrate,
                         detect_board, find_fiducial, locate)
from drivers.camera.sim import Fiducial, Optics, render
from tests.cell.test_vision_fiducial import crb_centre_px

# A tilted, rotated camera with barrel distortion and an off-centre principal point;
# ~0.5 mm per pixel over a 320 x 240 mm field centred on (300, 150) mm.
MODEL = CameraModel(Intrinsics(800.0, 800.0, 322.0, 236.0, 640, 480),
                    Pose(400.0, (300.0, 150.0), yaw_deg=30.0, tilt_x_deg=2.0, tilt_y_deg=-1.5),
                    Distortion(-0.08, 0.02, 0.0005, -0.0003))
CHESS = ChessBoard(9, 6, origin_mm=(230.0, 100.0), angle_deg=30.0, square_mm=18.0)
CIRCLES = CircleGridBoard(9, 7, origin_mm=(240.0, 95.0), angle_deg=28.0, pitch_mm=16.0, radius_mm=4.0)


@pytest.fixture(scope="module")
def images():
    rng = np.random.default_rng(7)
    return {b.kind: render(MODEL, [b], Optics(noise_sigma=2.0), rng) for b in (CHESS, CIRCLES)}


@pytest.fixture(scope="module")
def fiducial_shots():
    """20 rendered fiducials at known positions (mm) across the board area."""
    rng = np.random.default_rng(3)
    pts = rng.uniform([220.0, 90.0], [380.0, 210.0], (20, 2))
    shots = [render(MODEL, [Fiducial(x, y, 3.0)], Optics(noise_sigma=2.0), rng) for x, y in pts]
    return pts, [find_fiducial(img).uv for img in shots]


@pytest.mark.parametrize("kind, tol_mm", [("circles", 0.012), ("chessboard", 0.03)])
def test_round_trip_maps_fiducials_to_mm(images, fiducial_shots, kind, tol_mm):
    board = CIRCLES if kind == "circles" else CHESS
    cal = calibrate([(images[kind], board)], u_axis_deg=30.0)
    pts, uvs = fiducial_shots
    err = np.linalg.norm(cal.pixels_to_base(uvs) - pts, axis=1)
    assert err.max() < tol_mm                       # 0.5 mm/px: that is 0.024 / 0.06 px
    assert cal.rms_px < 0.03 and cal.rms_mm < 0.015
    assert cal.n_points == board.cols * board.rows
    # and back: base_to_pixel inverts pixel_to_base
    u, v = cal.base_to_pixel(*pts[0])
    assert np.allclose(cal.pixel_to_base(u, v), pts[0], atol=1e-9)
    assert cal.mm_per_px(320.0, 240.0) == pytest.approx(0.5, abs=0.02)


def test_plain_homography_leaves_the_lens_distortion(images):
    cal = calibrate([(images["circles"], CIRCLES)], distortion=False, u_axis_deg=30.0)
    assert cal.distortion.is_zero
    assert cal.rms_px > 0.05                        # barrel distortion it cannot model


def test_serialises_to_json_and_yaml(circle_cal):
    cal = circle_cal
    for text in (json.dumps(cal.as_dict()), yaml.safe_dump(cal.as_dict())):
        again = PlaneCalibration.from_dict(yaml.safe_load(text))
        assert again.rms_px == cal.rms_px and again.n_points == cal.n_points
        q = np.array([[100.0, 80.0], [500.0, 400.0]])
        assert np.allclose(again.pixels_to_base(q), cal.pixels_to_base(q), atol=1e-9)
    assert board_from_dict(cal.boards[0]) == CIRCLES


def test_detected_points_follow_the_board_order(images):
    pts = detect_board(images["chessboard"], CHESS, u_axis_deg=30.0)
    assert np.allclose(pts, MODEL.project(CHESS.points_mm()), atol=0.1)


# -- failures ----------------------------------------------------------------------------

def test_board_not_in_view():
    blank = render(MODEL, [], Optics())
    with pytest.raises(VisionError, match=r"view 0 \(640x480\): chessboard board with 9x6 points not found"):
        calibrate([(blank, CHESS)], u_axis_deg=30.0)


@pytest.mark.parametrize("kind, cols, rows, match", [
    ("chessboard", 8, 6, "not found"),
    ("chessboard", 10, 6, "not found"),
    ("circles", 8, 7, "63 circles seen but the board is 8x7"),
    ("circles", 10, 7, "not found"),
    ("circles", 7, 9, "cols and rows swapped"),
])
def test_wrong_board_size(images, kind, cols, rows, match):
    board = dataclasses.replace(CIRCLES if kind == "circles" else CHESS, cols=cols, rows=rows)
    with pytest.raises(VisionError, match=match):
        detect_board(images[kind], board, u_axis_deg=30.0)


def test_orientation_hint_must_be_unambiguous(images):
    with pytest.raises(VisionError, match="ambiguous|swapped"):
        detect_board(images["circles"], CIRCLES, u_axis_deg=120.0)


def test_bad_views():
    with pytest.raises(VisionError, match="no views"):
        calibrate([])
    with pytest.raises(VisionError, match=r"view 0: expected \(image, board\)"):
        calibrate([np.zeros((480, 640), np.uint8)])
    with pytest.raises(VisionError, match="view 0 must be 8-bit grey"):
        calibrate([(np.zeros((480, 640)), CHESS)])


def test_views_of_different_size(images):
    small = np.zeros((240, 320), np.uint8)
    with pytest.raises(VisionError, match=r"view 1: image shape \(240, 320\) differs"):
        calibrate([(images["circles"], CIRCLES), (small, CIRCLES)], u_axis_deg=30.0)


@pytest.mark.parametrize("build, match", [
    (lambda: ChessBoard(2, 6), "cols = 2"),
    (lambda: ChessBoard(9, 6, square_mm=-1.0), "square_mm"),
    (lambda: CircleGridBoard(5, 4, pitch_mm=10.0, radius_mm=6.0), "radius_mm"),
    (lambda: CircleGridBoard(5, 4, origin_mm=(float("nan"), 0.0)), "finite"),
])
def test_bad_boards(build, match):
    with pytest.raises(VisionError, match=match):
        build()


@pytest.fixture(scope="module")
def circle_cal(images):
    return calibrate([(images["circles"], CIRCLES)], u_axis_deg=30.0)


@pytest.mark.parametrize("change, match", [
    (lambda d: d.update(format="other/1"), "format"),
    (lambda d: d.pop("homography"), "missing field 'homography'"),
    (lambda d: d.update(width=0), "width"),
    (lambda d: d.update(homography=[[1, 0], [0, 1]]), "invertible 3x3"),
    (lambda d: d.update(focal_px="wide"), "numbers"),
    (lambda d: d.update(distortion={"k3": 0.1}), "distortion"),
])
def test_bad_calibration_dicts(circle_cal, change, match):
    d = circle_cal.as_dict()
    change(d)
    with pytest.raises(ConfigError, match=match):
        PlaneCalibration.from_dict(d)


def test_bad_board_dict():
    with pytest.raises(ConfigError, match="kind"):
        board_from_dict({"kind": "aruco"})
    with pytest.raises(ConfigError, match="board"):
        board_from_dict({"kind": "chessboard", "cols": 9, "rows": 6, "colour": "red"})


def test_bad_points_to_map(circle_cal):
    cal = circle_cal
    with pytest.raises(VisionError, match=r"finite \(N, 2\)"):
        cal.pixels_to_base([[1.0, float("inf")]])
    with pytest.raises(VisionError, match=r"finite \(N, 2\)"):
        cal.base_to_pixels([1.0, 2.0, 3.0])


def test_locate_gives_mm_with_uncertainty(circle_cal):
    truth = [(260.0, 120.0), (340.0, 190.0)]
    img = render(MODEL, [Fiducial(*truth[0], 3.0, "tool"), Fiducial(*truth[1], 3.0, "part")],
                 Optics(noise_sigma=2.0), np.random.default_rng(11))
    fixes = locate(img, circle_cal, expected=2)
    got = sorted((f.x_mm, f.y_mm) for f in fixes)
    assert np.allclose(got, truth, atol=0.015)
    for f in fixes:
        # the image's Cramér-Rao bound on the centre (tests/cell/test_vision_fiducial.py's
        # hand calculation): a 3 mm disc is R = 3 / s px at s mm per px here (~0.5), so
        # σ ≈ 0.0051 px, 0.0026 mm; the reported σ within a window of 2× around it
        s = circle_cal.mm_per_px(*circle_cal.base_to_pixel(f.x_mm, f.y_mm))
        crb_mm = s * crb_centre_px(2.0, Optics().contrast, 3.0 / s, Optics().blur_sigma_px)
        assert 0.7 * crb_mm < f.sigma_x_mm < 1.4 * crb_mm and 0.7 * crb_mm < f.sigma_y_mm < 1.4 * crb_mm


def test_locate_refuses_an_image_of_another_size(circle_cal):
    with pytest.raises(VisionError, match="image is 320x240 but the calibration is for 640x480"):
        locate(np.zeros((240, 320), np.uint8), circle_cal)
