"""``cellctl calibrate-camera``: board images in a folder → the calibration file the cell loads."""
import json

import cv2
import numpy as np
import yaml

from cell.cli import main
from cell.vision.calibration import CircleGridBoard, PlaneCalibration
from cell.vision.camera_model import CameraModel
from drivers.camera.sim import Fiducial, SimCamera

BOARD = dict(kind="circles", cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0,
             origin_mm=[234.0, 920.0], angle_deg=0.0)


def render(tmp_path, scene):
    model = CameraModel.nadir(640, 512, 0.08, centre_mm=(250.0, 930.0))
    cam = SimCamera(model, lambda: scene, seed=3)
    cam.open()
    image = cam.grab().image
    cam.close()
    return model, image


def test_calibration_from_a_folder(tmp_path, capsys):
    board = CircleGridBoard(cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0, origin_mm=(234.0, 920.0))
    model, image = render(tmp_path, [board])
    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "board1.png"), image)
    (tmp_path / "board.yaml").write_text(yaml.safe_dump(BOARD))
    out = tmp_path / "cal.json"
    assert main(["calibrate-camera", "--board", str(tmp_path / "board.yaml"), "--images",
                 str(tmp_path / "imgs"), "--no-distortion", "--out", str(out)]) == 0
    assert "reprojection rms" in capsys.readouterr().out
    cal = PlaneCalibration.from_dict(json.loads(out.read_text()))
    # a fiducial rendered through the same camera maps back to where it lies
    _, img = render(tmp_path, [Fiducial(251.3, 928.2, 2.0)])
    u, v = model.project(np.array([[251.3, 928.2]]))[0]
    np.testing.assert_allclose(cal.pixel_to_base(u, v), (251.3, 928.2), atol=0.01)


def test_bad_inputs_name_what_and_where(tmp_path, capsys):
    (tmp_path / "imgs").mkdir()
    _, blank = render(tmp_path, [])
    cv2.imwrite(str(tmp_path / "imgs" / "empty.png"), blank)
    (tmp_path / "board.yaml").write_text(yaml.safe_dump(BOARD))
    args = ["calibrate-camera", "--board", str(tmp_path / "board.yaml"), "--images", str(tmp_path / "imgs"),
            "--out", str(tmp_path / "cal.json")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "calibration failed" in err and "empty.png" in err and not (tmp_path / "cal.json").exists()
    (tmp_path / "board.yaml").write_text(yaml.safe_dump({**BOARD, "kind": "hexagons"}))
    assert main(args) == 2
    assert "board.yaml" in capsys.readouterr().err
    (tmp_path / "imgs" / "junk.png").write_bytes(b"not an image")
    (tmp_path / "board.yaml").write_text(yaml.safe_dump(BOARD))
    assert main(args) == 2
    assert "junk.png" in capsys.readouterr().err


def test_help_documents_the_board_format_and_its_examples_parse(capsys):
    """``--board`` used to point to ``cellctl calibrate-camera -h``, which did not describe it."""
    import re

    import pytest
    import yaml

    from cell.cli import main
    from cell.vision.calibration import ChessBoard, CircleGridBoard, board_from_dict
    with pytest.raises(SystemExit):
        main(["calibrate-camera", "--help"])
    out = capsys.readouterr().out
    for word in ("kind: circles", "kind: chessboard", "pitch_mm", "radius_mm", "square_mm",
                 "origin_mm", "angle_deg"):
        assert word in out
    blocks = re.findall(r"\n((?:    \w+: .*\n)+)", out)
    boards = [board_from_dict(yaml.safe_load(b)) for b in blocks]
    assert [type(b) for b in boards] == [CircleGridBoard, ChessBoard]
