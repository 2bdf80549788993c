"""Thermal growth on chains: the pose temperatures (``temp_c``) read from the format, the
effect named from a campaign of the independent forward model (:mod:`cell.truth.chain`,
which grows every DH length and marker offset rather than the point), and the campaigns
that cannot show it said so."""
from __future__ import annotations

import numpy as np
import pytest

from cell.diagnosis.chain import fit as F
from cell.diagnosis.chain.noise import repeat_noise_mm
from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import CampaignFormatError, read_campaign
from cell.measurements.chain import write_chain_campaign
from cell.truth import chain as truth
from tests.cell.chain import chainsim

NOISE = 0.03
ALPHA = 2.5e-5      # 1/K: aluminium, the upper end of the format's typical size


@pytest.mark.parametrize("modified", [False, True])
def test_thermal_growth_agrees_with_the_independent_forward_model(tmp_path, modified):
    eff = {"grow": 3e-4, "offset": {"j2": 0.2}, "a": {"j3": 1.0}}   # large, to see any slip
    d = chainsim.make(tmp_path / "c", None, poses=8, noise_mm=0.0, sensor=False,
                      modified=modified, temps=True)
    cc = read_campaign(d)
    voc = {p.name: p for p in F.vocabulary(cc.chain)}
    params = [voc["thermal_expansion_per_k"], voc["j2_offset_deg"], voc["j3_a_mm"]]
    reg = F.Registration(np.eye(3), np.zeros(3), np.array(chainsim.MARKERS))
    got, _ = F.model(F.Data.of(cc), reg, params, np.array([3e-4, 0.2, 1.0]))
    temps = cc.pose_temps()
    want = np.vstack([truth.tool_points(chainsim.UR5, q, modified, (0, 0, 0), chainsim.MARKERS,
                                        eff, p, 8, temp_c=temps[p])
                      for p, q in enumerate(cc.readings)])
    assert np.ptp(temps) > 5.0
    assert np.max(np.abs(got - want)) < 1e-9


def test_thermal_growth_on_a_chain_is_named_from_the_temperatures(tmp_path):
    d = chainsim.make(tmp_path / "c", {"grow": ALPHA}, poses=80, noise_mm=NOISE, seed=3,
                      temps=True)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert rep["cause"]["label"] == "thermal_drift", rep["cause"]
    assert rep["cause"]["joints"] == []
    lo, hi = rep["cause"]["ci95"]["thermal_expansion_per_k"]
    assert lo < ALPHA < hi
    assert rep["holdout"]["shrink"] > 0.5


def test_without_temperatures_thermal_growth_is_not_identifiable_and_says_why(tmp_path):
    d = chainsim.make(tmp_path / "c", {"grow": ALPHA}, poses=40, noise_mm=NOISE, seed=5)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert "no temp_c column" in rep["not_identifiable"]["thermal_expansion_per_k"]
    assert rep["cause"]["label"] == "none"


def _set_temps(d, temps) -> None:
    lines = (d / "points.csv").read_text().splitlines()
    k = lines[0].split(",").index("temp_c")
    for i in range(1, len(lines)):
        cells = lines[i].split(",")
        cells[k] = repr(float(temps(int(cells[0]))))
        lines[i] = ",".join(cells)
    (d / "points.csv").write_text("\n".join(lines) + "\n")


def test_a_temperature_that_hardly_changes_cannot_be_told_from_link_lengths(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=40, noise_mm=NOISE, seed=5, temps=True)
    _set_temps(d, lambda pose: 24.0 + 0.002 * pose)          # 0.08 °C over the campaign
    rep = diagnose_chain(read_campaign(d), NOISE)
    why = rep["not_identifiable"]["thermal_expansion_per_k"]
    assert "temperature spread under 0.2 °C" in why


def test_revisits_at_another_temperature_are_not_the_same_pose(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=40, noise_mm=NOISE, seed=5, temps=True,
                      repeats=6)
    _set_temps(d, lambda pose: 20.0)
    same = repeat_noise_mm(read_campaign(d))
    _set_temps(d, lambda pose: 20.0 + (5.0 if pose >= 34 else 0.0))   # the revisits, warmer
    warmer = repeat_noise_mm(read_campaign(d))
    assert same[1] == 6 and same[0] is not None
    assert warmer == (None, 0, 0)


def test_a_written_chain_campaign_keeps_its_temperatures(tmp_path):
    cc = read_campaign(chainsim.make(tmp_path / "c", {"grow": ALPHA}, poses=10, temps=True))
    back = read_campaign(write_chain_campaign(cc, tmp_path / "copy"))
    assert np.array_equal(back.extra["temp_c"], cc.extra["temp_c"])
    assert np.array_equal(back.pose_temps(), cc.pose_temps())


def test_a_temperature_no_arm_is_measured_at_is_refused_where_it_is(tmp_path):
    d = chainsim.make(tmp_path / "c", {}, poses=10, temps=True)
    lines = (d / "points.csv").read_text().splitlines()
    k = lines[0].split(",").index("temp_c")
    cells = lines[5].split(",")
    cells[k] = "2150.0"                                       # 21.50 with the point slipped
    lines[5] = ",".join(cells)
    (d / "points.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(CampaignFormatError, match=r"line 6, column 'temp_c'.*temperature 2150.0 °C"):
        read_campaign(d)
