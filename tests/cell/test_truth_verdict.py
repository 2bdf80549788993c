"""The verdict on one trial (cell/truth/verdict.py) on hand-written reports: every class,
rivals with and without components, joint order ignored, a truth outside the vocabulary."""
import pytest

from cell.truth.verdict import Expected, classify, counts, matches

OFFSET_J2 = Expected((("joint_offset", ("j2",)),))
TWO = Expected((("joint_offset", ("j2",)), ("gear_ratio", ("j1",))))
NONE = Expected(())
OUTSIDE = Expected((), True)


def report(effect="none", joints=(), confidence="high", rivals=None, unexplained=False,
           components=None):
    cause = {"effect": effect, "joints": list(joints), "confidence": confidence}
    if rivals is not None:
        cause["rivals"] = rivals
    if components is not None:
        cause["components"] = components
    return {"cause": cause, "unexplained": unexplained}


@pytest.mark.parametrize("truth, rep, want", [
    (OFFSET_J2, report("joint_offset", ["j2"]), "right"),
    (OFFSET_J2, report("joint_offset", ["j1"]), "wrong"),
    (OFFSET_J2, report("none"), "wrong"),
    (NONE, report("none"), "right"),
    (NONE, report("backlash", ["j1"]), "wrong"),
    (OFFSET_J2, report("joint_offset", ["j2"], unexplained=True), "unexplained"),
    (OFFSET_J2, report("gear_ratio", ["j2"], "ambiguous",
                       [{"label": "x", "effects": ["joint_offset"], "joints": ["j2"]}]), "ambiguous"),
    (OFFSET_J2, report("gear_ratio", ["j2"], "low"), "ambiguous_missing"),
    (OFFSET_J2, report("joint_offset", ["j2"], "low"), "ambiguous"),
    (OUTSIDE, report("camera_scale"), "wrong"),
    (OUTSIDE, report("camera_scale", confidence="low"), "ambiguous_missing"),
    (OUTSIDE, report("none"), "right"),
    (OUTSIDE, report("camera_scale", unexplained=True), "unexplained"),
    (TWO, report("joint_offset", ["j2"], components=[
        {"effect": "gear_ratio", "joints": ["j1"]}, {"effect": "joint_offset", "joints": ["j2"]}]),
     "right"),
    (TWO, report("joint_offset", ["j2"]), "wrong"),                 # half the truth, sure of it
    (TWO, report("joint_offset", ["j2"], "ambiguous", [{"label": "y", "components": [
        {"effect": "gear_ratio", "joints": ["j1"]}, {"effect": "joint_offset", "joints": ["j2"]}]}]),
     "ambiguous"),
])
def test_each_verdict(truth, rep, want):
    assert classify(truth, rep) == want


def test_no_confidence_given_counts_as_high_and_details_can_veto():
    rep = {"cause": {"effect": "joint_offset", "joints": ["j2"]}, "unexplained": False}
    assert classify(OFFSET_J2, rep) == "right"
    assert classify(OFFSET_J2, rep, lambda cause: False) == "wrong"


def test_matching_ignores_joint_order_and_reads_flat_rivals():
    t = Expected((("joint_offset", ("j2", "j3")),))
    assert matches(t, [("joint_offset", ("j3", "j2"))])
    assert matches(TWO, {"effects": ["joint_offset", "gear_ratio"], "joints": ["j1", "j2"]})
    assert not matches(TWO, {"effects": ["joint_offset", "gear_ratio"], "joints": ["j2"]})
    assert not matches(OUTSIDE, [])
    assert counts(["right", "wrong", "right"]) == {"right": 2, "ambiguous": 0, "ambiguous_missing": 0,
                                                   "unexplained": 0, "wrong": 1}
