"""Gross outliers of a chain campaign (cell/diagnosis/chain/robust.py): a tracker's glitch is set
aside and reported, a campaign with no error stays ``none``, and a residual that is
systematic rather than a few glitches is not trimmed away. Campaigns come from the
independent forward model (cell.truth.chain_campaign, the UR5 with 3 markers)."""
from __future__ import annotations

import numpy as np

from cell.diagnosis.chain import robust
from cell.diagnosis.chain.report import diagnose_chain
from cell.diagnosis.text import render
from cell.measurements import read_campaign
from cell.truth.chain_campaign import MARKERS, make


def _campaign(tmp_path, effects, outliers, seed=11, **kw):
    return read_campaign(make(tmp_path / "c", effects, poses=60, noise_mm=0.03, seed=seed,
                              markers=MARKERS, repeats=6, outliers=outliers, outlier_mm=(2.0, 4.0), **kw))


def test_a_glitch_in_a_campaign_with_no_error_is_set_aside_and_the_answer_is_none(tmp_path):
    cc = _campaign(tmp_path, {}, outliers=2)
    rep = diagnose_chain(cc)
    o = rep["outliers"]
    assert o["n"] == 2, o
    assert all(p["distance_mm"] > o["cut_mm"] for p in o["points"])
    assert {p["split"] for p in o["points"]} <= {"fit", "holdout"}
    assert rep["cause"]["effect"] == "none" and not rep["unexplained"], rep["remainder"]
    assert rep["holdout"]["inliers"]["n"] == rep["holdout"]["n"] - sum(p["split"] == "holdout"
                                                                       for p in o["points"])
    assert "outliers set aside: 2 point(s)" in render(rep)


def test_a_glitch_beside_a_true_cause_does_not_hide_it(tmp_path):
    rep = diagnose_chain(_campaign(tmp_path, {"offset": {"j2": 0.08}}, outliers=1))
    assert rep["outliers"]["n"] == 1
    assert rep["cause"]["label"] == "joint_offset" and rep["cause"]["joints"] == ["j2"], rep["cause"]
    assert not rep["unexplained"], rep["remainder"]


def test_no_glitch_no_outlier(tmp_path):
    rep = diagnose_chain(_campaign(tmp_path, {"offset": {"j2": 0.08}}, outliers=0))
    assert rep["outliers"]["n"] == 0 and rep["outliers"]["points"] == []


def test_more_far_points_than_the_allowed_share_are_not_set_aside_but_warned_about(tmp_path):
    """A fifth of the fit points pushed 1 mm off: not a few glitches but something
    systematic, so none is set aside and the flags carry a warning."""
    from cell.diagnosis.chain import fit as F
    cc = _campaign(tmp_path, {}, outliers=0)
    d = F.Data.of(cc)
    f0 = F.fit(d, [])
    far = np.arange(len(d.xyz)) % 5 == 0
    d.xyz = d.xyz + np.where(far[:, None], 1.0, 0.0)
    o = robust.flag(d, d.subset(np.zeros(d.n_poses, bool)), f0)
    assert o.set_aside[0] is False and not o.fit.any(), o
    assert any("none set aside" in w for w in o.warnings)
    assert far.mean() > robust.MAX_SHARE
