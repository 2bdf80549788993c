"""The chain noise estimates (:mod:`cell.diagnosis.chain.noise`): the rigid constellation recovers the
sensor σ whatever the arm does; revisits that disagree beyond it are caught; a bump in the
middle of a campaign is no longer taken for noise."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import f as f_dist

from cell.diagnosis.chain.noise import revisits_disagree, rigid_noise_mm
from cell.diagnosis.chain.rank import NOISE_FACTOR
from cell.diagnosis.chain.report import diagnose_chain
from cell.diagnosis.noise import upper95
from cell.measurements import read_campaign
from cell.numerics.stats import chi2_ppf
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


def test_a_noise_from_one_revisited_pose_is_judged_by_its_upper_bound(tmp_path):
    # seed 7: the one revisited pose happens to agree to 0.0021 mm per axis where the
    # sensor's noise is 0.005 mm; judged by that estimate, the right cause's fit error
    # (0.0065 mm 2-D) looked like 3× the noise and the gap "unexplained". Two degrees of
    # freedom say σ may be up to 4.4× the estimate (95 %): the tests use that bound
    rows = [{"name": f"j{k}", "type": "revolute", "a_mm": a, "alpha_deg": 0.0, "d_mm": 0.0,
             "theta_deg": 0.0} for k, a in ((1, 325.0), (2, 275.0))]
    d = make(tmp_path / "c", {"offset": {"j2": 0.05}}, poses=60, noise_mm=0.005, seed=7,
             sensor=False, rows=rows, markers=[[0.0, 0.0, 0.0]], repeats=1,
             model_extra={"sensor_axes": ["x", "y"], "markers": {1: [0.0, 0.0, 0.0]}})
    rep = diagnose_chain(read_campaign(d))
    n = rep["noise"]
    assert n["source"] == "repeats (1 revisited poses)" and n["dof"] == 2
    assert n["upper95_mm"] == pytest.approx(n["sigma_mm"] * math.sqrt(2 / chi2_ppf(0.05, 2)), abs=1e-6)
    # a σ that is given has no uncertainty of its own; one from nothing has no bound
    assert upper95(0.005, math.inf) == 0.005 and upper95(0.005, 0) == math.inf
    assert n["fit_rms_mm"] > NOISE_FACTOR * n["sigma_mm"] * math.sqrt(2)   # the old rule's doubt
    assert rep["cause"]["label"] == "joint_offset" and not rep["unexplained"], rep["remainder"]


def _rigid_one_pose_at_a_time(xyz, obs_pose, obs_marker, markers_tip, free_markers):
    # the pose-by-pose Kabsch the stacked one replaced, the reference for its bits
    ss, dof = 0.0, 0
    order = np.argsort(obs_pose, kind="stable")
    for rows in np.split(order, np.flatnonzero(np.diff(obs_pose[order])) + 1):
        if len(rows) < 3:
            continue
        a, b = markers_tip[obs_marker[rows]], xyz[rows]
        a0, b0 = a - a.mean(0), b - b.mean(0)
        u, _, vt = np.linalg.svd(a0.T @ b0)
        s = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
        rot = (u @ s @ vt).T
        ss += float(np.sum((b0 - a0 @ rot.T) ** 2))
        dof += 3 * len(rows) - 6
    if free_markers:
        dof -= 3 * len(markers_tip) - 6
    return (math.sqrt(ss / dof), dof) if dof > 0 and ss > 0 else (None, 0)


@pytest.mark.parametrize("free", [False, True])
def test_the_stacked_rigid_fit_gives_the_bits_of_one_pose_at_a_time(free):
    # poses of 2 to 5 markers (a pose of 2 counts for nothing), shuffled rows, some
    # poses turned by a reflection (QR's Q): the same sigma and dof, bit for bit
    from cell.diagnosis.chain.noise import rigid_noise_mm
    rng = np.random.default_rng(3)
    tip = rng.normal(0, 40, (5, 3))
    pose, marker, pts = [], [], []
    for p in range(60):
        ks = rng.choice(5, size=rng.integers(2, 6), replace=False)
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        for k in ks:
            pose.append(p)
            marker.append(k)
            pts.append(R @ tip[k] + [p, 2 * p, 500] + rng.normal(0, 0.05, 3))
    order = rng.permutation(len(pose))
    xyz, obs_pose, obs_marker = np.array(pts)[order], np.array(pose)[order], np.array(marker)[order]
    got = rigid_noise_mm(xyz, obs_pose, obs_marker, tip, free)
    assert got == _rigid_one_pose_at_a_time(xyz, obs_pose, obs_marker, tip, free)
    assert got[0] is not None
