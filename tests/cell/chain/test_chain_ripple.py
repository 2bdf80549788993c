"""Transmission ripples on chains: one of 1–4 cycles per revolution is the vocabulary's
``cyclic_error`` (a sine and a cosine coefficient of one order per joint), one of more cycles
is outside it and found in the remainder (:mod:`cell.diagnosis.chain.ripple`)."""
from __future__ import annotations

import math

import pytest

from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import read_campaign
from tests.cell.chain import chainsim

NOISE = 0.03


def test_a_two_cycle_ripple_is_named_with_its_order_and_coefficients(tmp_path):
    # a 0.04° 2-cycle ripple at phase 30° on j2, which over j2's 140° also looks like an offset
    # and a gear ratio: the fit must find a·cos φ and a·sin φ of order 2 (format, chain effects)
    d = chainsim.make(tmp_path / "c", {"cyclic": {"j2": (0.04, 2, 30.0)}}, poses=60,
                      noise_mm=NOISE, seed=8)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert not rep["unexplained"], rep["remainder"]["reasons"]
    assert rep["cause"]["effect"] == "cyclic_error" and rep["cause"]["joints"] == ["j2"]
    params, ci = rep["cause"]["params"], rep["cause"]["ci95"]
    assert set(params) == {"j2_cyclic2_sin_deg", "j2_cyclic2_cos_deg"}
    for name, true in (("j2_cyclic2_sin_deg", 0.04 * math.cos(math.radians(30))),
                       ("j2_cyclic2_cos_deg", 0.04 * math.sin(math.radians(30)))):
        assert ci[name][0] <= true <= ci[name][1], (name, params[name], ci[name])
    # the better rivals are only those the campaign cannot test (no jK_dir: backlash)
    assert all(r.get("testable") is False for r in rep["cause"].get("rivals", [])), \
        rep["cause"]["rivals"]


def test_a_ripple_the_campaign_can_test_is_named_with_confidence(tmp_path):
    # with the approach directions recorded no backlash can stand behind it; and the orders
    # the search left out are no yardstick for the one it kept (no 'hard to tell apart'
    # warning for its coefficients, nor for the orders not kept)
    d = chainsim.make(tmp_path / "c", {"cyclic": {"j2": (0.04, 2, 30.0)}}, poses=60,
                      noise_mm=NOISE, seed=8, dirs=True)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert rep["cause"]["label"] == "cyclic_error" and rep["cause"]["confidence"] == "high", \
        rep["cause"]["warnings"]
    assert not any("cyclic" in w for w in rep["registration"]["warnings"]), rep["registration"]["warnings"]


@pytest.mark.parametrize("cycles", [6, 7])
def test_a_ripple_beyond_the_vocabularys_orders_is_not_passed_off_as_the_named_cause(tmp_path, cycles):
    # a j3 offset the vocabulary holds, and a ripple of more cycles than cyclic_error's on j2
    d = chainsim.make(tmp_path / "c", {"offset": {"j3": 0.1}, "cyclic": {"j2": (0.03, cycles, 30.0)}},
                      poses=60, noise_mm=NOISE, seed=8)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert rep["unexplained"], rep["cause"]
    assert rep["cause"]["confidence"] != "high"
    assert any("varies periodically with j2" in r and "5–8 cycles" in r
               for r in rep["remainder"]["reasons"]), rep["remainder"]["reasons"]


def test_a_vocabulary_cause_leaves_no_ripple_behind(tmp_path):
    d = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.1}, "ratio": {"j3": 1e-3}}, poses=60,
                      noise_mm=NOISE, seed=9)
    rep = diagnose_chain(read_campaign(d), NOISE)
    assert not rep["unexplained"], rep["remainder"]["reasons"]
    assert not any("periodically" in r for r in rep["remainder"]["reasons"])
