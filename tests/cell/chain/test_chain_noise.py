"""The chain noise estimates (:mod:`cell.diagnosis.chain.noise`): the rigid constellation recovers the
sensor σ whatever the arm does; revisits that disagree beyond it are caught; a bump in the
middle of a campaign is no longer taken for noise."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import f as f_dist

from cell.diagnosis.chain.noise import revisits_disagree, rigid_noise_mm
from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import read_campaign
from cell.truth import chain as truth
from cell.truth.chain_campaign import MARKERS, make


def test_rigid_constellation_recovers_the_sensor_noise():
    rng = np.random.default_rng(0)
    tip = np.array(MARKERS + [[10.0, 50.0, 20.0]])
    xyz, pose, marker = [], [], []
    for p in range(200):                      # any pose at all: the arm does not matter
        R, t = truth.random_rotation(rng), rng.uniform(-900, 900, 3)
        pts = tip @ R.T + t + rng.normal(0, 0.04, tip.shape)
        xyz.append(pts)
        pose += [p] * len(tip)
        marker += list(range(len(tip)))
    sigma, dof = rigid_noise_mm(np.vstack(xyz), np.array(pose), np.array(marker), tip, False)
    assert dof == 200 * (3 * 4 - 6)
    assert sigma == pytest.approx(0.04, rel=0.05)


@pytest.mark.parametrize("s1, d1, s2, d2", [(0.048, 54, 0.0362, 123), (0.06, 18, 0.04, 60),
                                            (0.05, 9, 0.03, 300), (0.036, 54, 0.036, 123)])
def test_the_revisit_test_is_the_f_test(s1, d1, s2, d2):
    # golden values: scipy.stats.f.sf, which the chain path does not import (start-up cost)
    assert revisits_disagree(s1, d1, s2, d2) == pytest.approx(f_dist.sf((s1 / s2) ** 2, d1, d2), rel=0.05)


def test_a_bump_mid_campaign_is_unexplained_not_noise(tmp_path):
    d = make(tmp_path / "c", {"bump": {"j3": 0.13}}, seed=1, noise_mm=0.03, repeats=6)
    rep = diagnose_chain(read_campaign(d))
    assert rep["unexplained"]
    assert rep["noise"]["source"].startswith("markers (rigid constellation")
    assert rep["noise"]["sigma_mm"] == pytest.approx(0.03, rel=0.25)
    assert any("did not come back" in r for r in rep["remainder"]["reasons"])


def test_consistent_revisits_are_the_noise_and_raise_nothing(tmp_path):
    d = make(tmp_path / "c", {"offset": {"j3": 0.08}}, seed=2, noise_mm=0.03, repeats=6)
    rep = diagnose_chain(read_campaign(d))
    assert rep["noise"]["source"] == "repeats (6 revisited poses)"
    assert not rep["unexplained"] and rep["cause"]["effect"] == "joint_offset"
