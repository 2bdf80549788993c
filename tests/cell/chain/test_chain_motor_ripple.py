"""The motor-side ripple on chains (``motor_cyclic_error``): on the joints whose model states
a motor gear ratio N (``motor_gear_ratio``), a sine and a cosine coefficient of N cycles per
joint revolution; named when the poses sample that short period within each place, and
otherwise reported as untestable, never silently taken for ``none``."""
from __future__ import annotations

import math

from cell.diagnosis.chain import validate
from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import read_campaign
from tests.cell.chain import chainsim

NOISE = 0.03
RATIOS = {"motor_gear_ratio": {r["name"]: 100.0 for r in chainsim.UR5}}


def test_a_motor_ripple_is_named_with_its_coefficients(tmp_path):
    # 0.03° at N = 100 (a 3.6° period at the joint) on j3, poses spread over the workspace
    d = chainsim.make(tmp_path / "c", {"motor": {"j3": (0.03, 100.0, 60.0)}}, poses=60,
                      noise_mm=NOISE, seed=8, dirs=True, model_extra=RATIOS)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert not rep["unexplained"], rep["remainder"]["reasons"]
    cause = rep["cause"]
    assert cause["effect"] == "motor_cyclic_error" and cause["joints"] == ["j3"], cause["label"]
    assert cause["confidence"] == "high", cause["warnings"]
    for name, true in (("j3_motor_cyclic_sin_deg", 0.03 * math.cos(math.radians(60))),
                       ("j3_motor_cyclic_cos_deg", 0.03 * math.sin(math.radians(60)))):
        lo, hi = cause["ci95"][name]
        assert lo <= true <= hi, (name, cause["params"][name], (lo, hi))


def test_without_a_stated_ratio_the_effect_is_not_in_the_vocabulary(tmp_path):
    d = chainsim.make(tmp_path / "c", {"motor": {"j3": (0.03, 100.0, 60.0)}}, poses=60,
                      noise_mm=NOISE, seed=8, dirs=True)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert rep["cause"]["effect"] != "motor_cyclic_error"
    assert not any("motor" in n for n in rep["not_identifiable"])
    assert rep["unexplained"] or rep["cause"]["confidence"] != "high"


def test_stations_that_hardly_move_cannot_test_it_and_say_so(tmp_path):
    # 6 stations with ±0.3° of jitter: each station sees about one phase of the 3.6° period,
    # so a ripple there is an error that differs from station to station
    d = chainsim.make(tmp_path / "c", {"motor": {"j3": (0.03, 100.0, 60.0)}}, poses=60,
                      noise_mm=NOISE, seed=8, dirs=True, places=6, jitter_deg=0.3,
                      model_extra=RATIOS)
    rep = diagnose_chain(read_campaign(d), NOISE)
    why = rep["not_identifiable"]["j3_motor_cyclic_sin_deg"]
    assert "sample the 3.6° period too sparsely" in why, why
    assert rep["cause"]["effect"] != "motor_cyclic_error"
    assert rep["unexplained"] or rep["cause"]["confidence"] != "high", rep["cause"]


def test_a_gap_the_campaign_cannot_test_is_not_called_none_with_confidence():
    # seed 0's trial 71 (realistic layout): a 0.031° ripple on j2 whose stations cover the
    # period short of the requirement (phase spread 0.49 < 0.5). Its 0.285 mm gap lies within
    # twice what a noise measured on one revisited pose may be, but it is 3.2 times the
    # estimate: 'none' then says what the campaign could not test
    truth = validate.Truth("motor_cyclic_error", ("j2",),
                           {"motor": {"j2": (0.031101553425857034, 100.0, 273.95516115015744)}},
                           0.0, {})
    lay = {"places": 12, "jitter_deg": 3.0, "outliers": 1, "dirs": False, "temps": True}
    t = validate.judge_truth(71, 71, truth, 0.03904283187622916, lay)
    assert t.answer == "none" and t.confidence == "low", (t.answer, t.confidence)
    assert t.verdict != "wrong"
