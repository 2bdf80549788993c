"""The measuring camera looks where the model says first, and falls back to the whole frame.

Set-up as the simulated cell's: 640 × 512 px at 0.08 mm per px over (250, 930) mm, the
plane calibration taken from a rendered circle-grid board (cell/sim/assembly.py)."""
import numpy as np
import pytest

from cell.vision import CameraModel
from cell.vision.calibration import CircleGridBoard, calibrate
from cell.vision.measure import MeasuringCamera
from drivers.camera.sim import Fiducial, Optics, render

CENTRE = (250.0, 930.0)
MODEL = CameraModel.nadir(640, 512, 0.08, centre_mm=CENTRE)
OPTICS = Optics(supersample=2)
TOOL, PART = (250.4, 930.3), (262.0, 931.0)


class Frames:
    """A camera driver that grabs the rendered frames it was given, in turn."""

    def __init__(self, *images):
        self.images = list(images)

    def grab(self):
        from types import SimpleNamespace
        return SimpleNamespace(image=self.images.pop(0))


@pytest.fixture(scope="module")
def cal():
    board = CircleGridBoard(cols=11, rows=7, pitch_mm=4.0, radius_mm=1.0,
                            origin_mm=(CENTRE[0] - 20.0, CENTRE[1] - 12.0), angle_deg=0.0)
    image = render(MODEL, [board], OPTICS, np.random.default_rng(0))
    return calibrate([(image, board)], distortion=False, u_axis_deg=0.0)


def frame(seed=1):
    return render(MODEL, [Fiducial(*PART, 1.5, "part"), Fiducial(*TOOL, 3.0, "tool")], OPTICS,
                  np.random.default_rng(seed))


def test_a_window_search_finds_what_the_frame_search_finds(cal):
    cam = MeasuringCamera(Frames(frame(), frame()), cal, tool_radius_mm=3.0)
    near = cam.tool(near_mm=(251.0, 929.0))                 # the model 1.2 mm off
    full = cam.tool()
    assert np.hypot(*(near - TOOL)) < 0.01 and np.hypot(*(near - full)) < 0.01
    assert cam.window_misses == 0
    assert cam._window((251.0, 929.0), 3.0, None) is not None


def test_a_window_that_misses_falls_back_to_the_frame_and_is_counted(cal):
    """The model 9 mm off (a first part on an uncalibrated robot, say): the window holds no
    tool disc, the frame does; the cell measures the tool and the miss is counted."""
    cam = MeasuringCamera(Frames(frame()), cal, tool_radius_mm=3.0)
    got = cam.tool(near_mm=(241.0, 930.0))
    assert np.hypot(*(got - TOOL)) < 0.01
    assert cam.window_misses == 1


def test_the_part_window_leaves_out_the_tool_beside_it(cal):
    cam = MeasuringCamera(Frames(frame()), cal, tool_radius_mm=3.0)
    got = cam.find(cam.grab(), 1.5, "part fiducial", near_mm=(261.0, 930.0), within_mm=4.0)
    assert np.hypot(*(got - PART)) < 0.01 and cam.window_misses == 0


@pytest.mark.parametrize("near", [(np.nan, 930.0), (1e6, 1e6), (1.0,)])
def test_a_useless_expected_place_searches_the_frame(cal, near):
    cam = MeasuringCamera(Frames(frame()), cal, tool_radius_mm=3.0)
    assert np.hypot(*(cam.tool(near_mm=near) - TOOL)) < 0.01


def test_search_sizes_follow_the_calibration_the_camera_holds(cal):
    """The scale at the frame centre sizes every search; it is worked out once per
    calibration, and a camera given another calibration sizes its searches by that one."""
    import dataclasses
    from cell.vision.calibration import PlaneFix
    asked = []

    def locate(image, calibration, **kw):
        asked.append((calibration, kw["min_radius_px"], kw["max_radius_px"]))
        return [PlaneFix(*TOOL, 0.0, 0.0, None)]
    cam = MeasuringCamera(Frames(frame(), frame(), frame()), cal, tool_radius_mm=3.0, locate=locate)
    cam.tool()
    cam.tool()
    coarser = dataclasses.replace(cal, homography=cal.homography * [[1, 1, 1], [1, 1, 1], [2, 2, 1]])
    cam.calibration = coarser
    cam.tool()
    for calibration, lo, hi in asked:
        r_px = 3.0 / calibration.mm_per_px(calibration.width / 2, calibration.height / 2)
        assert (lo, hi) == (r_px * 0.7, r_px * 1.3)
    assert [a[0] is coarser for a in asked] == [False, False, True] and asked[2][1] != asked[0][1]
