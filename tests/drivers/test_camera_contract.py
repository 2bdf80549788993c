"""The camera contract, written once and run against every backend.

sim, folder (PNG files), opencv on a video file (MJPG/.avi from cv2.VideoWriter) and on an
image-sequence pattern; a real device runs the same contract when ``--hw`` is given.
"""
from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from cell.clock import ManualClock
from drivers.camera import Camera, CameraError, CameraState, Frame, create
from drivers.camera.sim import Fiducial

W, H, N = 96, 64, 4


def _frames():
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (H, W), dtype=np.uint8) for _ in range(N)]


def _sim(tmp_path, clock):
    from cell.vision import CameraModel
    return create("sim", model=CameraModel.nadir(W, H, 1.0), clock=clock,
                  scene=lambda: [Fiducial(0.0, 0.0, 8.0, "tool")])


def _folder(tmp_path, clock):
    for i, img in enumerate(_frames()):
        cv2.imwrite(str(tmp_path / f"frame{i}.png"), img)
    return create("folder", path=tmp_path, clock=clock)


def _opencv_video(tmp_path, clock):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (W, H), isColor=False)
    assert writer.isOpened(), "this OpenCV build cannot write MJPG/.avi"
    for img in _frames():
        writer.write(img)
    writer.release()
    return create("opencv", source=str(path), clock=clock)


def _opencv_sequence(tmp_path, clock):
    for i, img in enumerate(_frames()):
        cv2.imwrite(str(tmp_path / f"img_{i:03d}.png"), img)
    return create("opencv", source=str(tmp_path / "img_%03d.png"), api=cv2.CAP_IMAGES, clock=clock)


BACKENDS = {"sim": _sim, "folder": _folder, "opencv-avi": _opencv_video,
            "opencv-sequence": _opencv_sequence}


@pytest.fixture(params=list(BACKENDS))
def camera(request, tmp_path):
    """(camera, the ManualClock it stamps frames with)."""
    clock = ManualClock(10.0)
    return BACKENDS[request.param](tmp_path, clock), clock


@pytest.fixture
def hw_camera(request):
    if not request.config.getoption("--hw", default=False):
        pytest.skip("needs a real camera: run with --hw (CELL_CAMERA_SOURCE=index or URL)")
    src = os.environ.get("CELL_CAMERA_SOURCE", "0")
    clock = ManualClock(10.0)
    return create("opencv", source=int(src) if src.isdigit() else src, clock=clock), clock


def check_frames_are_grey_stamped_and_counted(cam, clock):
    assert isinstance(cam, Camera) and cam.state is CameraState.CLOSED
    with cam:
        assert cam.state is CameraState.OPEN
        frames = []
        for i in range(3):
            clock.advance(0.5)
            frames.append(cam.grab())
    assert cam.state is CameraState.CLOSED
    shapes = {f.image.shape for f in frames}
    assert len(shapes) == 1
    for i, f in enumerate(frames):
        assert isinstance(f, Frame)
        assert f.image.dtype == np.uint8 and f.image.ndim == 2 and f.image.size > 0
        assert not f.image.flags.writeable
        assert f.index == i
        assert f.timestamp_s == pytest.approx(10.5 + 0.5 * i)
        assert f.metadata["backend"] == cam.backend and "source" in f.metadata


def check_lifecycle_is_enforced(cam):
    with pytest.raises(CameraError, match="cannot grab while closed"):
        cam.grab()
    with pytest.raises(CameraError, match="cannot close while closed"):
        cam.close()
    cam.open()
    with pytest.raises(CameraError, match="cannot open while open"):
        cam.open()
    cam.grab()
    cam.close()
    with pytest.raises(CameraError, match="cannot grab while closed"):
        cam.grab()


def test_contract_frames(camera):
    check_frames_are_grey_stamped_and_counted(*camera)


def test_contract_lifecycle(camera):
    check_lifecycle_is_enforced(camera[0])


# replay backends whose frames are the files' pixels exactly (the sim renders, MJPG is lossy)
LOSSLESS_REPLAY = ("folder", "opencv-sequence")
# backends with a last frame (the sim renders for ever)
FINITE = ("folder", "opencv-avi", "opencv-sequence")


@pytest.mark.parametrize("backend", LOSSLESS_REPLAY)
def test_replayed_frames_match_what_was_written(backend, tmp_path):
    camera = BACKENDS[backend](tmp_path, ManualClock(10.0))
    with camera:
        got = [camera.grab().image for _ in range(N)]
    assert all(np.array_equal(g, e) for g, e in zip(got, _frames()))


@pytest.mark.parametrize("backend", FINITE)
def test_end_of_stream_is_an_error_not_a_frame(backend, tmp_path):
    camera = BACKENDS[backend](tmp_path, ManualClock(10.0))
    with camera:
        for _ in range(N):
            camera.grab()
        with pytest.raises(CameraError, match="end of"):
            camera.grab()


@pytest.mark.hw
def test_hw_contract_frames(hw_camera):
    check_frames_are_grey_stamped_and_counted(*hw_camera)


@pytest.mark.hw
def test_hw_contract_lifecycle(hw_camera):
    check_lifecycle_is_enforced(hw_camera[0])
