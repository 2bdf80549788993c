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
