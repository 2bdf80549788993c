"""``cellctl calibrate-camera`` holds its word: views that disagree (a board bumped between
views) leave a residual far above the measured noise, and such a calibration is refused,
naming the view that disagrees most; ``--accept-worse`` writes it with the warning in the
file and the audit trail; consistent views still pass and write."""
import dataclasses
import json

import cv2
import yaml

from cell.cli import main
from cell.cyclelog import CycleLog
from cell.vision.calibration import CircleGridBoard, PlaneCalibration
from cell.vision.camera_model import CameraModel
from drivers.camera.sim import SimCamera

# the board of tests/cell/test_cli_calibrate.py, seen by a nadir camera at 0.08 mm/px
BOARD = CircleGridBoard(cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0, origin_mm=(234.0, 920.0))
BUMP_MM = (0.6, -0.4)          # the board moved by 0.72 mm (9 px) before the third view


def _views(folder, bumped: bool):
    """Three views of BOARD (seeds 3, 4, 5); the third of the board bumped by BUMP_MM."""
    folder.mkdir()
    moved = dataclasses.replace(BOARD, origin_mm=(BOARD.origin_mm[0] + BUMP_MM[0],
                                                  BOARD.origin_mm[1] + BUMP_MM[1]))
    for k, seed in enumerate((3, 4, 5)):
        board = moved if bumped and k == 2 else BOARD
        cam = SimCamera(CameraModel.nadir(640, 512, 0.08, centre_mm=(250.0, 930.0)), lambda b=board: [b],
                        seed=seed)
        cam.open()
        cv2.imwrite(str(folder / f"view{k}.png"), cam.grab().image)
        cam.close()


def _args(tmp_path, *extra):
    (tmp_path / "board.yaml").write_text(yaml.safe_dump(dict(
        kind="circles", cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0, origin_mm=[234.0, 920.0], angle_deg=0.0)))
    return ["calibrate-camera", "--board", str(tmp_path / "board.yaml"), "--images", str(tmp_path / "imgs"),
            "--no-distortion", "--out", str(tmp_path / "cal.json"), *extra]


def test_a_bumped_board_is_refused_naming_the_view(tmp_path, capsys):
    _views(tmp_path / "imgs", bumped=True)
    assert main(_args(tmp_path)) == 2
    out, err = capsys.readouterr()
    assert "check: FAILED" in out and "refused, nothing written" in err
    assert "far above the noise" in err and "each view fitted alone" in err
    assert "disagree most: view 2 = " in err and "view2.png" in err.split("disagree most")[1].split(",")[0]
    assert not (tmp_path / "cal.json").exists()


def test_accept_worse_writes_it_with_the_warning_in_the_file_and_the_audit(tmp_path, capsys):
    _views(tmp_path / "imgs", bumped=True)
    db = tmp_path / "cell.sqlite"
    assert main(_args(tmp_path, "--accept-worse", "--db", str(db))) == 0
    out = capsys.readouterr().out
    assert "WARNING: written with --accept-worse" in out and "PASSED" not in out
    doc = json.loads((tmp_path / "cal.json").read_text())
    assert doc["accept_worse"] is True and "far above the noise" in doc["warning"]
    assert doc["check"]["passed"] is False and doc["check"]["views"][0]["view"] == 2
    PlaneCalibration.from_dict(doc)                  # the cell still loads it
    log = CycleLog(db, readonly=True)
    rows = log.audit_rows()
    log.close()
    assert len(rows) == 1 and rows[0]["action"] == "camera_calibration_write"
    assert rows[0]["target"] == str(tmp_path / "cal.json") and rows[0]["result"] == doc["warning"]


def test_consistent_views_pass_and_write(tmp_path, capsys):
    _views(tmp_path / "imgs", bumped=False)
    assert main(_args(tmp_path)) == 0
    out = capsys.readouterr().out
    assert "PASSED" in out and "written to" in out
    doc = json.loads((tmp_path / "cal.json").read_text())
    assert doc["accept_worse"] is False and doc["warning"] is None and doc["check"]["passed"]
    assert {n["source"] for n in doc["check"]["noise"]} == {"each view fitted alone",
                                                            "the detector's own centre uncertainty"}
    assert all(n["ratio"] < 2 for n in doc["check"]["noise"])
