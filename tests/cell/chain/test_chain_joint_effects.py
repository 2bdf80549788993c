"""Backlash on chains: the approach directions (``jK_dir``) read from the format, the
effect named from a campaign of the independent forward model (:mod:`cell.truth.chain`),
and bad direction columns refused where they are."""
from __future__ import annotations

import pytest

from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import CampaignFormatError, read_campaign
from tests.cell.chain import chainsim

NOISE = 0.03


def test_backlash_on_a_chain_is_named_from_the_approach_directions(tmp_path):
    d = chainsim.make(tmp_path / "c", {"backlash": {"j2": 0.08}}, poses=80, noise_mm=NOISE,
                      seed=4, dirs=True)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert rep["cause"]["label"] == "backlash", rep["cause"]["warnings"]
    assert rep["cause"]["joints"] == ["j2"]
    lo, hi = rep["cause"]["ci95"]["j2_backlash_deg"]
    assert lo < 0.08 < hi
    assert rep["holdout"]["shrink"] > 0.6


def test_without_directions_backlash_is_not_identifiable_and_says_why(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=40, noise_mm=NOISE, seed=5)
    rep = diagnose_chain(read_campaign(d), NOISE)
    why = rep["not_identifiable"]["j2_backlash_deg"]
    assert "no jK_dir column" in why


def _edit(d, row: int, column: str, value: str) -> None:
    lines = (d / "points.csv").read_text().splitlines()
    k = lines[0].split(",").index(column)
    cells = lines[row].split(",")
    cells[k] = value
    lines[row] = ",".join(cells)
    (d / "points.csv").write_text("\n".join(lines) + "\n")


def test_a_direction_that_is_not_plus_or_minus_one_is_refused_where_it_is(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=10, dirs=True)
    _edit(d, 4, "j3_dir", "2")
    with pytest.raises(CampaignFormatError, match=r"line 5, column 'j3_dir'"):
        read_campaign(d)


def test_markers_of_one_pose_that_disagree_on_the_approach_are_refused(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=10, dirs=True)
    lines = (d / "points.csv").read_text().splitlines()
    k = lines[0].split(",").index("j2_dir")
    flipped = str(-int(lines[2].split(",")[k]))
    _edit(d, 2, "j2_dir", flipped)
    with pytest.raises(CampaignFormatError,
                       match=r"line 3, column 'j2_dir': rows of sample 0 disagree on j2_dir"):
        read_campaign(d)


def test_a_joint_whose_axis_runs_through_the_tool_point_has_no_gravity_lever(tmp_path):
    # UR5: the tool point (tool_mm 0) lies on j6's axis, so j6's lever is rounding noise
    # (~1e-13 m); scaled to unit length it looked like a direction of its own, and on the real
    # TIAGo set a candidate gave arm_7's twin a compliance of 6e12 deg/m
    d = chainsim.make(tmp_path / "c", {"sag": {"j2": 0.3}}, poses=40, noise_mm=NOISE, seed=5)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert rep["not_identifiable"]["j6_compliance_deg_per_m"] == "has no effect on the measured points"
    assert rep["cause"]["label"] == "gravity_compliance"


def test_a_fit_that_wants_a_negative_give_or_width_leaves_that_parameter_out(tmp_path):
    # a joint pushed against gravity (an over-set balancer): the format's compliance is a
    # give (≥ 0), so no candidate may carry a negative one, and none names it
    d = chainsim.make(tmp_path / "c", {"sag": {"j2": -0.4}}, poses=60, noise_mm=NOISE, seed=6,
                      dirs=True)
    rep = diagnose_chain(read_campaign(d), NOISE)
    values = [(r["label"], n, v) for r in rep["ranking"] for n, v in r["params"].items()
              if "compliance" in n or "backlash" in n]
    assert all(v >= 0 for _, _, v in values), values
    assert "gravity_compliance" not in rep["cause"]["label"]


def test_a_fit_that_wants_a_gear_ratio_beyond_its_hard_limit_leaves_it_out(tmp_path):
    # a 9 % ratio error is no gear's (gear_ratio's ParamSpec allows ±5 %: a wrong
    # transmission or a wrong unit, not a calibration): no candidate carries one beyond it
    d = chainsim.make(tmp_path / "c", {"ratio": {"j2": 0.09}}, poses=60, noise_mm=NOISE, seed=6,
                      dirs=True, temps=True)
    rep = diagnose_chain(read_campaign(d), NOISE)
    ratios = [(r["label"], n, v) for r in rep["ranking"] for n, v in r["params"].items()
              if "gear_ratio" in n]
    assert all(abs(v) <= 0.05 for _, _, v in ratios), ratios
    assert "gear_ratio" not in rep["cause"]["label"] or rep["unexplained"], rep["cause"]
    assert any(n.startswith("j2_gear_ratio_rel fitted to 0.09, beyond what its effect can "
                            "physically be (-0.05 … 0.05)") for n in rep["remainder"]["notes"])


@pytest.mark.parametrize("row,column,value,message", [
    (6, "marker", None, r"line 7, column 'marker': sample 1 has marker \d twice"),
    (8, "j4", "12.5", r"line 9, column 'sample': rows of sample 2 disagree on the joints"),
    (3, "split", "holdout", r"line 4, column 'split': rows of sample 0 disagree on the split"),
])
def test_rows_of_one_pose_that_disagree_are_refused_at_the_first_such_row(tmp_path, row, column,
                                                                          value, message):
    # the rows are checked all at once; when one fails, the error names the first row
    # that does, as checking them one by one would (a later bad row changes nothing)
    d = chainsim.make(tmp_path / "c", {}, poses=10)
    lines = (d / "points.csv").read_text().splitlines()
    if column == "split":
        (d / "points.csv").write_text("\n".join(
            [lines[0] + ",split"] + [ln + ",fit" for ln in lines[1:]]) + "\n")
    if value is None:                      # the marker of the row before, on the same pose
        k = lines[0].split(",").index("marker")
        value = lines[row - 1].split(",")[k]
    _edit(d, row, column, value)
    _edit(d, row + 9, "j2", "7.25")        # a later row that disagrees too
    with pytest.raises(CampaignFormatError, match=message):
        read_campaign(d)
