"""Bad chain campaigns get a clear error naming the file, line, column or joint."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import CampaignFormatError, read_campaign
from tests.cell.chain import chainsim

TIAGO = Path(__file__).resolve().parents[2] / "data" / "real" / "tiago-mocap-train"  # copy of shared/data/real
needs_tiago = pytest.mark.skipif(not TIAGO.is_dir(), reason="real data not present")


def _tiago(tmp_path) -> Path:
    d = tmp_path / "t"
    shutil.copytree(TIAGO, d)
    return d


def _edit_model(d: Path, **kw) -> None:
    m = yaml.safe_load((d / "model.yaml").read_text())
    m.update(kw)
    (d / "model.yaml").write_text(yaml.safe_dump(m))


@needs_tiago
def test_a_urdf_that_does_not_parse(tmp_path):
    d = _tiago(tmp_path)
    (d / "tiago_arm_chain.urdf").write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(CampaignFormatError, match=r"tiago_arm_chain\.urdf.*not a valid URDF"):
        read_campaign(d)


@needs_tiago
def test_a_urdf_without_a_path_from_base_to_tip(tmp_path):
    d = _tiago(tmp_path)
    _edit_model(d, base_link="arm_4_link", tip_link="arm_2_link")
    with pytest.raises(CampaignFormatError, match=r"no path from base_link 'arm_4_link' to tip_link 'arm_2_link'"):
        read_campaign(d)


@needs_tiago
def test_a_missing_urdf_file(tmp_path):
    d = _tiago(tmp_path)
    _edit_model(d, urdf="nope.urdf")
    with pytest.raises(CampaignFormatError, match=r"urdf .*nope\.urdf: cannot read"):
        read_campaign(d)


@needs_tiago
def test_joint_columns_that_do_not_match_joints(tmp_path):
    d = _tiago(tmp_path)
    _edit_model(d, joints=["torso_lift_joint", "arm_1_joint"])
    with pytest.raises(CampaignFormatError, match=r"moving joint\(s\) .*arm_2_joint.* not in joints"):
        read_campaign(d)
    d2 = chainsim.make(tmp_path / "c", {}, poses=10)
    text = (d2 / "points.csv").read_text().replace("j6,", "j7,", 1)
    (d2 / "points.csv").write_text(text)
    with pytest.raises(CampaignFormatError, match=r"points\.csv, line 1, column 'j7'.*6 joints"):
        read_campaign(d2)


@needs_tiago
def test_a_prismatic_value_in_degrees_is_out_of_its_limits(tmp_path):
    d = _tiago(tmp_path)
    lines = (d / "points.csv").read_text().splitlines()
    cells = lines[5].split(",")
    cells[2] = "-45.0"                        # torso_lift_joint, mm, limits 0 … 350
    lines[5] = ",".join(cells)
    # the other rows of that sample keep their value: fix them too so the limit check speaks
    sample = cells[0]
    for i in range(1, len(lines)):
        c = lines[i].split(",")
        if c[0] == sample:
            c[2] = "-45.0"
            lines[i] = ",".join(c)
    (d / "points.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(CampaignFormatError, match=r"line \d+, column 'j1'.*torso_lift_joint, prismatic.*"
                                                  r"outside its limits 0 … 350 mm.*in mm"):
        read_campaign(d)


def test_a_marker_seen_in_too_few_poses(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=10)
    lines = (d / "points.csv").read_text().splitlines()
    lines = [ln for ln in lines if not (ln.split(",")[7] == "3" and int(ln.split(",")[0]) > 1)]
    (d / "points.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(CampaignFormatError, match=r"column 'marker': marker 3 is seen in 2 fit pose\(s\)"):
        read_campaign(d)


def test_a_sensor_frame_with_too_few_non_collinear_points(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=12, markers=[[0.0, 0.0, 0.0]])
    lines = (d / "points.csv").read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:                      # poses differ in j6 only, the marker on its axis: one point
        c = ln.split(",")
        c[1:7] = ["0.0", "-90.0", "0.0", "0.0", "0.0", f"{10.0 * int(c[0]):.1f}"]
        c[8:11] = ["1.0", "2.0", "3.0"]
        out.append(",".join(c))
    (d / "points.csv").write_text("\n".join(out) + "\n")
    with pytest.raises(CampaignFormatError, match=r"measurement_frame sensor: .*registering the sensor "
                                                  r"frame needs at least 3 non-collinear points"):
        diagnose_chain(read_campaign(d))


def test_rows_of_one_pose_that_disagree_and_a_bad_coupling(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=10)
    lines = (d / "points.csv").read_text().splitlines()
    c = lines[2].split(",")
    c[1] = "12.5"
    lines[2] = ",".join(c)
    (d / "points.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(CampaignFormatError, match=r"line 3, column 'sample': rows of sample 0 disagree"):
        read_campaign(d)
    d = chainsim.make(tmp_path / "c2", {}, poses=10, model_extra={"coupling": [{"joint": "j3", "from": "j9",
                                                                               "factor": 1.0}]})
    with pytest.raises(CampaignFormatError, match=r"coupling\[0\]\.from 'j9' is not one of the joints"):
        read_campaign(d)


def test_a_bad_campaign_changes_nothing_on_disk(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=10)
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    (d / "model.yaml").write_text((d / "model.yaml").read_text().replace("kinematics: dh", "kinematics: dh\nbogus: 1"))
    before["model.yaml"] = (d / "model.yaml").read_bytes()
    with pytest.raises(CampaignFormatError, match=r"model\.yaml.*bogus"):
        read_campaign(d)
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before


@needs_tiago
@pytest.mark.parametrize("gravity, direction", [([1e308, 1e308, 0], [0.7071068, 0.7071068, 0.0]),
                                                ([0, 0, -1e-310], [0.0, 0.0, -1.0])])
def test_a_gravity_of_huge_or_tiny_numbers_keeps_its_direction(tmp_path, gravity, direction):
    d = _tiago(tmp_path)
    _edit_model(d, gravity=gravity)
    assert read_campaign(d).chain.gravity == pytest.approx(direction, abs=1e-7)


@needs_tiago
def test_a_zero_gravity_is_refused(tmp_path):
    d = _tiago(tmp_path)
    _edit_model(d, gravity=[0, 0, 0])
    with pytest.raises(CampaignFormatError, match="gravity must be a non-zero direction"):
        read_campaign(d)


@pytest.mark.parametrize("centre, where", [([400.0, 0.0], "sensor_center_mm.2"),
                                           ([400.0, float("nan"), 0.0], "sensor_center_mm.1"),
                                           ("middle", "sensor_center_mm")])
def test_a_sensor_centre_that_is_not_three_finite_numbers_is_refused(tmp_path, centre, where):
    d = chainsim.make(tmp_path / "c", {}, poses=10)
    _edit_model(d, sensor_center_mm=centre)
    before = (d / "model.yaml").read_bytes()
    with pytest.raises(CampaignFormatError) as exc:
        read_campaign(d)
    assert exc.value.file.endswith("model.yaml") and exc.value.column == where, str(exc.value)
    assert exc.value.line and (d / "model.yaml").read_bytes() == before


@pytest.mark.parametrize("ratios, where, says", [
    ({"j9": 50.0}, "motor_gear_ratio.j9", "not one of the joints"),
    ({"j2": 0.0}, "motor_gear_ratio", "positive number of motor turns per joint turn, not j2: 0"),
    ({"j2": "fifty"}, "motor_gear_ratio.j2", "must be a valid number"),
    ([50.0, 50.0], "motor_gear_ratio", "must be a mapping")])
def test_a_motor_gear_ratio_that_is_not_a_joints_positive_number_is_refused(tmp_path, ratios, where,
                                                                              says):
    d = chainsim.make(tmp_path / "c", {}, poses=10)
    _edit_model(d, motor_gear_ratio=ratios)
    before = (d / "model.yaml").read_bytes()
    with pytest.raises(CampaignFormatError, match=says) as exc:
        read_campaign(d)
    assert exc.value.file.endswith("model.yaml") and exc.value.column == where, str(exc.value)
    assert (d / "model.yaml").read_bytes() == before


def test_a_motor_gear_ratio_on_a_prismatic_joint_is_refused(tmp_path):
    rows = [dict(r) for r in chainsim.UR5]
    rows[2]["type"] = "prismatic"
    d = chainsim.make(tmp_path / "c", {}, poses=10, rows=rows)
    _edit_model(d, motor_gear_ratio={"j3": 50.0})
    with pytest.raises(CampaignFormatError, match="j3 is prismatic") as exc:
        read_campaign(d)
    assert exc.value.column == "motor_gear_ratio.j3"
