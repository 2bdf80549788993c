"""``cellctl calibrate joint|kinematics`` on the simulated cell: what the process engineer
runs and reads. The plant is deploy/plants/default.yaml (truths named there)."""
import json

import pytest

from cell.calibration import calfile
from cell.cli import main
from cell.kinematics import Scara


def test_joint_calibration_prints_json_writes_the_plot_and_records_its_terms(tmp_path, capsys):
    png, cal = tmp_path / "plots" / "j2.png", tmp_path / "robot.json"
    assert main(["calibrate", "joint", "j2", "--sim", "--runs", "1", "--png", str(png), "--json",
                 "--out", str(cal)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["plan"]["joint"] == "j2" and out["plan"]["range_reason"].startswith("target in view")
    b = out["result"]["backlash_deg"]
    assert b["low"] <= 0.02 <= b["high"]                      # the plant's j2 backlash
    assert len(out["result"]["table"]) == out["plan"]["positions"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # no kinematic calibration yet: the terms are recorded, none but the backlash applied
    doc = calfile.load(cal, Scara.preset("seed000"), "cell-1")
    assert out["written"]["version"] == doc["version"] == 1 and out["written"]["applied"] == []
    assert "no kinematic calibration to weigh it against yet" in doc["joints"]["j2"]["why"]
    assert calfile.calibrated_robot(Scara.preset("seed000"), doc).backlash_deg[1] == pytest.approx(b["high"], rel=1e-7)


def test_joint_dry_run_writes_no_calibration(tmp_path, capsys):
    cal = tmp_path / "robot.json"
    assert main(["calibrate", "joint", "j2", "--sim", "--runs", "1", "--png", str(tmp_path / "j2.png"),
                 "--out", str(cal), "--dry-run"]) == 0
    assert "written: nothing (--dry-run)" in capsys.readouterr().out and not cal.exists()


@pytest.mark.slow
def test_kinematic_calibration_writes_a_file_the_cell_accepts(tmp_path, capsys):
    out = tmp_path / "robot.json"
    assert main(["calibrate", "kinematics", "--sim", "--poses", "8", "--holdout", "4",
                 "--out", str(out)]) == 0
    text, err = capsys.readouterr()
    assert "held-out poses (4): rms" in text and "PASSED" in text and f"written: {out}" in text
    assert "\r" not in err and "\x1b[" not in err and "pose" not in err   # not a terminal: no progress
    assert "base.rz" in text and "not observable" in text
    doc = calfile.load(out, Scara.preset("seed000"), "cell-1")
    assert doc["version"] == 1 and doc["report"]["holdout"]["passed"]


@pytest.mark.slow
def test_dry_run_writes_nothing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "robot.json"
    monkeypatch.setenv("CELL_PROGRESS", "1")          # as on a terminal: the bar goes to stderr only
    assert main(["calibrate", "kinematics", "--sim", "--poses", "8", "--holdout", "4", "--out",
                 str(out), "--dry-run", "--json"]) == 0
    text, err = capsys.readouterr()
    assert "calibrate kinematics" in err and "pose" in err and "\r" in err
    report = json.loads(text)
    assert report["written"] is None and report["holdout"]["passed"] and not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["calibrate", "joint", "j3", "--sim"], "j3 is prismatic"),
    (["calibrate", "joint", "j9", "--sim"], "'j9' is not a joint"),
    (["calibrate", "joint", "j1"], "--config is required without --sim"),
    (["calibrate", "joint", "j1", "--sim", "--plant", "nope.yaml"], "nope.yaml: plant file not found"),
    (["calibrate", "joint", "j1", "--plant", "nope.yaml", "--config", "x"], "--plant needs --sim"),
    (["calibrate", "joint", "j1", "--sim", "--step-deg", "5"], "choose a smaller --step-deg"),
    (["calibrate", "kinematics", "--sim", "--poses", "2", "--holdout", "3"], "cannot select 2 of"),
])
def test_bad_requests_get_a_clear_error_and_exit_2(argv, message, capsys, tmp_path):
    assert main([*argv[:2], *argv[2:]] + (["--png", str(tmp_path / "p.png")] if argv[1] == "joint" else [])) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("kind", [["joint", "j1"], ["kinematics", "--dry-run"]])
def test_hardware_calibration_beside_a_running_controller_is_refused(kind, tmp_path, capsys):
    """The drives take one master: while a controller holds the cell's log (as ``serve``
    does), a calibration on that cell's hardware stops before it opens any device."""
    import yaml

    from cell.config import CellConfig
    from cell.cyclelog import CycleLog
    from tests.system.conftest import REPO
    cfg = CellConfig.load(REPO / "deploy" / "cell.yaml")
    cfg = cfg.model_copy(update={"log": cfg.log.model_copy(update={"path": str(tmp_path / "cell.sqlite")})})
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
    controller = CycleLog(tmp_path / "cell.sqlite")             # the running controller's writer
    try:
        assert main(["calibrate", *kind, "--config", str(path)]) == 2
    finally:
        controller.close()
    err = capsys.readouterr().err
    assert "in use by another controller" in err and "stop the cell service first" in err
    assert "CAN" not in err and "stations" not in err          # no device was opened
