"""``cellctl calibrate kinematics CAMPAIGN`` holds its word: the TIAGo campaign's calibration
makes the held-out max worse (6.38 → 9.61 mm) and leaves a residual far above the markers'
noise, so it is refused (dry run included) and never says PASSED; ``--accept-worse`` writes
it with the warning in calibration.json, in model.yaml and in the audit trail; a campaign
whose effects the model holds still passes and writes."""
import json
from pathlib import Path

import pytest
import yaml

from cell.cli import main
from cell.cyclelog import CycleLog
from tests.cell.chain import chainsim

TIAGO = Path(__file__).resolve().parents[1] / "data" / "real" / "tiago-mocap-train"
needs_tiago = pytest.mark.skipif(not TIAGO.is_dir(), reason="real data not present")


@needs_tiago
def test_tiago_dry_run_says_what_got_worse_and_fails(capsys):
    assert main(["calibrate", "kinematics", str(TIAGO), "--dry-run"]) == 2
    out, err = capsys.readouterr()
    assert "PASSED" not in out and "check: FAILED" in out
    assert "held-out max 6.379 → 9.61 mm (+3.23 mm, +50.6%) got worse" in out
    assert "far above the noise" in out and "markers (rigid constellation within each pose" in out
    assert "nothing written" in err and "--accept-worse" in err


@needs_tiago
def test_tiago_is_refused_and_nothing_is_written(tmp_path, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate", "kinematics", str(TIAGO), "--out", str(out), "--json"]) == 2
    report = json.loads(capsys.readouterr().out)
    check = report["check"]
    assert check["passed"] is False and [w["figure"] for w in check["worse"]] == ["max"]
    assert check["noise"][0]["far"] and check["noise"][0]["ratio"] > 100
    assert report["written"] is None and not out.exists()


@needs_tiago
def test_tiago_accept_worse_writes_with_the_warning_in_the_files_and_the_audit(tmp_path, capsys):
    out, db = tmp_path / "cal", tmp_path / "cell.sqlite"
    assert main(["calibrate", "kinematics", str(TIAGO), "--out", str(out), "--accept-worse",
                 "--db", str(db)]) == 0
    text, err = capsys.readouterr()
    assert "PASSED" not in text and "check: FAILED" in text and "WARNING: written with --accept-worse" in text
    assert "warning" in err
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["format"] == "cell-chain-calibration/1"
    assert doc["accept_worse"] is True and "held-out max 6.379 → 9.61 mm" in doc["warning"]
    assert "WARNING: " + doc["warning"] in yaml.safe_load((out / "model.yaml").read_text())["source"]
    log = CycleLog(db, readonly=True)
    rows = log.audit_rows()
    log.close()
    assert [r["action"] for r in rows] == ["chain_calibration_write"]
    assert rows[0]["target"] == str(out / "calibration.json") and rows[0]["result"] == doc["warning"]


def test_a_campaign_the_model_holds_passes_and_writes(tmp_path, capsys):
    c = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.2}, "a": {"j3": 1.0}}, seed=6)
    out = tmp_path / "cal"
    assert main(["calibrate", "kinematics", str(c), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "PASSED" in text and "FAILED" not in text
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["check"]["passed"] and doc["accept_worse"] is False and doc["warning"] is None
    assert not doc["check"]["worse"] and doc["check"]["noise"][0]["ratio"] < 2
