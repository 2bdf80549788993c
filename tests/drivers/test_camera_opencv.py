"""OpenCV VideoCapture backend: bad sources and arguments (the contract runs in test_camera_contract)."""
from __future__ import annotations

import pytest

from cell.errors import ConfigError
from drivers.camera import CameraError, CameraState, create


def test_missing_file_cannot_be_opened(tmp_path):
    cam = create("opencv", source=str(tmp_path / "missing.avi"))
    with pytest.raises(CameraError, match=r"opencv camera '.*missing\.avi': cannot open"):
        cam.open()
    assert cam.state is CameraState.CLOSED


def test_not_a_video_cannot_be_opened(tmp_path):
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"RIFF....AVI not really a video")
    cam = create("opencv", source=str(bad))
    with pytest.raises(CameraError, match="cannot open|no frame"):
        cam.open()
        cam.grab()


@pytest.mark.parametrize("kwargs, match", [
    (dict(source=None), "source"),
    (dict(source=True), "source"),
    (dict(source=""), "source"),
    (dict(source=0, width=-640), "width"),
    (dict(source=0, height=4.5), "height"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        create("opencv", **kwargs)
