"""The recommended action at the top of the diagnosis page (:mod:`cell.diagnosis.action`):
one test per branch, on report dicts shaped like ``cell-diagnosis/1``."""
import pytest

from cell.diagnosis.action import recommend


def rep(effect="none", joints=(), subsystem="none", unexplained=False, confidence="high",
        chain=False, depends_on=None):
    r = {"source": "camp", "unexplained": unexplained,
         "cause": {"effect": effect, "joints": list(joints), "subsystem": subsystem,
                   "confidence": confidence},
         "remainder": {"reasons": [], "notes": [], "depends_on": depends_on}}
    if chain:
        r["chain"] = {"kinematics": "urdf"}
    return r


@pytest.mark.parametrize("effect", ["backlash", "gear_ratio", "cyclic_error"])
def test_joint_level_transmission_cause_calibrates_that_joint(effect):
    a = recommend(rep(effect, ["j2"], "transmission"))
    assert a.kind == "calibrate_joint" and a.commands == ("cellctl calibrate joint j2",)
    assert a.caveat == ""


@pytest.mark.parametrize("effect", ["joint_offset", "link_length"])
def test_geometric_cause_calibrates_the_kinematics(effect):
    a = recommend(rep(effect, ["j1"], "kinematics"))
    assert a.kind == "calibrate_kinematics" and a.commands == ("cellctl calibrate kinematics",)


def test_chain_geometry_and_gear_ratio_calibrate_the_kinematics_on_the_campaign():
    for effect in ("link_length", "gear_ratio"):
        a = recommend(rep(effect, ["j6"], "kinematics", chain=True))
        assert a.kind == "calibrate_kinematics" and a.commands == ("cellctl calibrate kinematics camp",)


def test_camera_cause_checks_the_camera_calibration():
    for effect in ("camera_scale", "camera_rotation"):
        a = recommend(rep(effect, [], "vision"))
        assert a.kind == "camera" and "camera calibration" in a.text
        assert a.commands[0].startswith("cellctl calibrate-camera")


def test_thermal_comms_and_compliance_causes():
    assert recommend(rep("thermal_drift", [], "thermal")).kind == "thermal"
    a = recommend(rep("comm_delay", [], "comms"))
    assert a.kind == "comms" and "motion.sync" in a.text
    a = recommend(rep("gravity_compliance", ["j3"], "transmission", chain=True))
    assert a.kind == "compliance" and "j3" in a.text and a.commands == ()


def test_none_is_no_action_within_noise():
    a = recommend(rep())
    assert a.kind == "none" and a.text == "No action: the gap is within noise." and a.commands == ()


def test_unexplained_wins_over_a_named_cause_and_says_where_to_look():
    a = recommend(rep("link_length", ["j2"], "kinematics", unexplained=True, depends_on="position"))
    assert a.kind == "investigate" and a.commands == ()
    assert "not explained by the vocabulary" in a.text and "See where it lies" in a.detail
    assert "link_length" in a.detail and "depends on position" in a.detail
    assert recommend(rep(unexplained=True)).kind == "investigate"


def test_low_confidence_keeps_the_action_with_a_caveat():
    a = recommend(rep("backlash", ["j1"], "transmission", confidence="low"))
    assert a.kind == "calibrate_joint" and "confirm on a second campaign" in a.caveat
