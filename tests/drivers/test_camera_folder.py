"""Folder replay: name order, colour to grey, and bad files named in the error."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from cell.errors import ConfigError
from drivers.camera import CameraError, create
from drivers.camera.folder import FolderCamera


def _write(path, value, shape=(32, 48)):
    cv2.imwrite(str(path), np.full(shape, value, np.uint8))


def test_natural_name_order_and_other_files_ignored(tmp_path):
    for name, value in (("img10.png", 3), ("img2.png", 2), ("img1.bmp", 1)):
        _write(tmp_path / name, value)
    (tmp_path / "notes.txt").write_text("not an image")
    with FolderCamera(tmp_path) as cam:
        assert [p.name for p in cam.files] == ["img1.bmp", "img2.png", "img10.png"]
        frames = [cam.grab() for _ in range(3)]
    assert [int(f.image[0, 0]) for f in frames] == [1, 2, 3]
    assert frames[1].metadata["file"].endswith("img2.png")


def test_loop_starts_again(tmp_path):
    _write(tmp_path / "a.png", 7)
    _write(tmp_path / "b.png", 9)
    with FolderCamera(tmp_path, loop=True) as cam:
        assert [int(cam.grab().image[0, 0]) for _ in range(5)] == [7, 9, 7, 9, 7]


def test_colour_image_becomes_grey(tmp_path):
    img = np.zeros((20, 30, 3), np.uint8)
    img[..., 1] = 200                                      # pure green
    cv2.imwrite(str(tmp_path / "c.png"), img)
    with FolderCamera(tmp_path) as cam:
        frame = cam.grab()
    assert frame.image.shape == (20, 30)
    assert int(frame.image[0, 0]) == round(0.587 * 200)


def test_unreadable_image_is_named_and_replay_stays_put(tmp_path):
    _write(tmp_path / "a.png", 1)
    (tmp_path / "b.png").write_bytes(b"\x89PNG garbage, not really")
    _write(tmp_path / "c.png", 3)
    with FolderCamera(tmp_path) as cam:
        assert cam.grab().index == 0
        for _ in range(2):                                 # no skipping past the bad file
            with pytest.raises(CameraError, match=r"'.*b\.png' is not a readable image \(24 bytes\)"):
                cam.grab()
        # the failed grabs changed nothing: frame counter and position are where they were
        (tmp_path / "b.png").unlink()
        _write(tmp_path / "b.png", 2)
        frame = cam.grab()
    assert frame.index == 1 and int(frame.image[0, 0]) == 2


def test_empty_file_is_named(tmp_path):
    (tmp_path / "zero.png").write_bytes(b"")
    with FolderCamera(tmp_path) as cam:
        with pytest.raises(CameraError, match=r"zero\.png' is not a readable image \(0 bytes\)"):
            cam.grab()


def test_16_bit_image_is_refused_by_name(tmp_path):
    cv2.imwrite(str(tmp_path / "deep.png"), np.full((8, 8), 4000, np.uint16))
    with FolderCamera(tmp_path) as cam:
        with pytest.raises(CameraError, match=r"deep\.png' is uint16, only 8-bit"):
            cam.grab()


def test_missing_and_empty_folders(tmp_path):
    cam = FolderCamera(tmp_path / "nope")
    with pytest.raises(CameraError, match=r"folder camera '.*nope': no such folder"):
        cam.open()
    assert cam.state.value == "closed"
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraError, match="no image files"):
        FolderCamera(tmp_path / "empty").open()


def test_bad_path_argument():
    with pytest.raises(ConfigError, match="path must be a folder name"):
        create("folder", path=42)
