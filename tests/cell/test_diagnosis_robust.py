"""The diagnosis where blind campaigns found it weak: cyclic errors of 2–4 cycles per
revolution, no noise reference (no paths, no --noise-mm), camera misdetections, clustered
poses and close rivals. Campaigns from :func:`cell.sim.campaigns.make_campaign` (the
plant) and :func:`cell.truth.campaign.make_campaign` (the independent forward model), seeded.
"""
import numpy as np
import pytest

from cell import effects as fx
from cell.diagnosis import noise
from cell.diagnosis.answer import diagnose_campaign as diagnose
from cell.measurements import read_campaign
from cell.sim.campaigns import Design, make_campaign
from cell.robots import PRESETS
from cell.truth import campaign as truth_campaign
from cell.truth import parts

POINT_NOISE = float(np.hypot(0.01, 0.005))   # plant: repeatability 0.01 + camera 0.005 mm
NO_PATHS = Design(n_points=200, n_moves=0)


def _cyclic(joint: str, order: int, amp=0.03, phase=40.0) -> fx.EffectInstance:
    return fx.make_effect("cyclic_error", (joint,), {f"{joint}_cyclic_amp_deg": amp,
                                                     f"{joint}_cyclic_phase_deg": phase,
                                                     f"{joint}_cyclic_period_deg": 360.0 / order})


# ------------------------------------------------------------------ 1. harmonic order
@pytest.mark.parametrize("joint,order", [("j1", 2), ("j2", 3), ("j1", 4)])
def test_harmonic_order_is_chosen_by_the_data(joint, order):
    truth = _cyclic(joint, order)
    rep = diagnose(make_campaign([truth], 60 + order, NO_PATHS)).report
    c = rep["cause"]
    assert (c["effect"], c["joints"]) == ("cyclic_error", [joint])
    assert rep["unexplained"] is False and c["confidence"] == "high"
    assert c["params"][f"{joint}_cyclic_order"] == order
    assert c["params"][f"{joint}_cyclic_period_deg"] == pytest.approx(360.0 / order)
    assert c["ci95"][f"{joint}_cyclic_order"] == [order, order]
    # the old parameter names keep their meaning, with intervals that cover the truth
    lo, hi = c["ci95"][f"{joint}_cyclic_amp_deg"]
    assert lo < 0.03 < hi
    lo, hi = c["ci95"][f"{joint}_cyclic_phase_deg"]
    assert lo < 40.0 < hi
    assert {f"{joint}_cyclic{order}_sin_deg", f"{joint}_cyclic{order}_cos_deg"} & set(c["params"])
    assert not any(f"_cyclic{k}_" in p for p in c["params"] for k in range(1, 5) if k != order)
    assert rep["holdout"]["shrink"] > 0.8


def test_harmonic_order_from_the_independent_truth(tmp_path):
    # a three-cycle ripple drawn by cell/truth (its own parametrisation: cos/sin parts)
    p = parts.Part("cyclic_error", 2, {"cycles": 3, "cos_deg": 0.02, "sin_deg": -0.015})
    rep = diagnose(read_campaign(truth_campaign.write_campaign(tmp_path / "c", [p], 5, NO_PATHS))).report
    c = rep["cause"]
    assert (c["effect"], c["joints"], c["params"]["j2_cyclic_order"]) == ("cyclic_error", ["j2"], 3)
    want = parts.answer(p).params
    lo, hi = c["ci95"]["j2_cyclic_amp_deg"]
    assert lo < want["j2_cyclic_amp_deg"] < hi
    assert rep["unexplained"] is False


def test_order_not_identifiable_from_a_narrow_layout():
    # j1 only over ±15°: sin 2θ and sin θ (with their cosines) span nearly the same curves
    rep = diagnose(make_campaign([_cyclic("j1", 2, amp=0.05)], 4,
                                 Design(n_points=150, n_moves=0, theta1_deg=(-15.0, 15.0)))).report
    why = {k: v for k, v in rep["not_identifiable"].items() if k.startswith("j1_cyclic")}
    assert why and all("seen only as a sum with" in v for v in why.values()), why
    assert rep["cause"]["confidence"] != "high" or rep["cause"]["effect"] != "cyclic_error"


# ------------------------------------------------------------------ 2. noise from the data
def test_gap_far_above_the_noise_is_not_called_noise_without_paths(tmp_path):
    # joint 2 coupled to joint 1 (outside the vocabulary), no paths, no --noise-mm: the
    # remainder's own structure gives the noise, and the gap is many times that
    p = parts.Part("joint_coupling", None, {"coupling_21": 8e-4})
    rep = diagnose(read_campaign(truth_campaign.write_campaign(
        tmp_path / "c", [p], 2, Design(n_points=300, n_moves=0)))).report
    assert rep["unexplained"] is True and rep["remainder"]["reasons"]
    nz = rep["noise"]
    # the local planes take a little of the coupling's curvature for noise: still far below it
    assert nz["source"].startswith("residual") and POINT_NOISE * 0.7 < nz["sigma_mm"] < 3 * POINT_NOISE
    assert rep["gap"]["rms_mm"] > 10 * nz["sigma_mm"]


def test_noise_of_a_none_campaign_without_paths():
    rep = diagnose(make_campaign([], 12, Design(n_points=200, n_moves=0))).report
    assert rep["cause"]["effect"] == "none" and rep["unexplained"] is False
    assert rep["noise"]["source"].startswith("residual")
    assert rep["noise"]["sigma_mm"] == pytest.approx(POINT_NOISE, rel=0.2)
    assert rep["noise"]["upper95_mm"] > rep["noise"]["sigma_mm"]


def _revisited(truth, seed, visits=3, n_poses=60):
    """A campaign that visits each of ``n_poses`` poses ``visits`` times, same approach."""
    c = make_campaign(truth, seed, Design(n_points=n_poses * visits, n_moves=0))
    idx = np.repeat(np.arange(n_poses), visits)
    for k in ("j1_deg", "j2_deg", "j1_dir", "j2_dir"):
        c.points[k] = c.points[k][idx]
    rng = np.random.default_rng(seed)
    q = np.column_stack([c.points["j1_deg"], c.points["j2_deg"]])
    dirs = np.column_stack([c.points["j1_dir"], c.points["j2_dir"]])
    xy = fx.simulate_points(PRESETS["seed000"], truth, q, dirs, None, c.points["temp_c"],
                            (250.0, 930.0)) + rng.normal(0.0, POINT_NOISE, q.shape)
    c.points["x_mm"], c.points["y_mm"] = xy[:, 0], xy[:, 1]
    return c


def test_noise_from_revisited_poses():
    rep = diagnose(_revisited([fx.make_effect("joint_offset", ("j2",), {"j2_offset_deg": 0.05})],
                              14)).report
    nz = rep["noise"]
    assert nz["estimates"]["repeats"]["dof"] == 2 * (180 - 60)
    assert nz["estimates"]["repeats"]["sigma_mm"] == pytest.approx(POINT_NOISE, rel=0.15)
    assert "revisited" in nz["estimates"]["repeats"]["method"]
    assert rep["cause"]["effect"] == "joint_offset"


def test_given_noise_wins_and_estimates_are_reported():
    rep = diagnose(make_campaign([], 15, Design(n_points=100, n_moves=2)), noise_mm=0.02).report
    nz = rep["noise"]
    assert (nz["source"], nz["sigma_mm"], nz["upper95_mm"]) == ("given", 0.02, 0.02)
    assert {"given", "residual", "paths"} <= set(nz["estimates"])


def test_too_few_points_give_no_residual_estimate():
    rng = np.random.default_rng(0)
    cmd = np.column_stack([rng.uniform(-90, 90, 12), rng.uniform(30, 120, 12)])
    r = rng.normal(0, 0.01, (12, 2))
    assert noise.residual(cmd, np.arange(12.0), r, (500.0, 500.0)) is None
    assert noise.repeats(cmd, None, r) is None                   # nothing revisited
    assert noise.best(None, None) is None


# ------------------------------------------------------------------ 3. outliers, spread, margin
def _misdetect(c, seed, share):
    """Move ``share`` of the points and path samples by 0.1–0.3 mm in a random direction;
    returns the sample ids of the points moved."""
    rng = np.random.default_rng(seed)
    moved = None
    for tab in (c.points, c.paths):
        if tab is None:
            continue
        n = len(tab["x_mm"])
        m = rng.random(n) < share
        a, r = rng.uniform(0, 2 * np.pi, m.sum()), rng.uniform(0.1, 0.3, m.sum())
        tab["x_mm"], tab["y_mm"] = tab["x_mm"].copy(), tab["y_mm"].copy()
        tab["x_mm"][m] += r * np.cos(a)
        tab["y_mm"][m] += r * np.sin(a)
        if moved is None:
            moved = set(tab["sample"][m].tolist())
    return moved


def test_misdetections_are_set_aside_on_a_none_campaign():
    c = make_campaign([], 20, Design(n_points=200, n_moves=3))
    moved = _misdetect(c, 20, 0.03)
    rep = diagnose(c).report
    assert rep["cause"]["effect"] == "none" and rep["unexplained"] is False
    found = set(rep["outliers"]["points"]["samples"])
    assert found == moved                                # 0.1–0.3 mm ≫ 5 σ of 0.011 mm
    assert rep["outliers"]["paths"]["n"] > 0 and rep["outliers"]["points"]["set_aside"]
    assert rep["holdout"]["inliers"]["n"] < rep["holdout"]["n"]


def test_more_misdetections_than_a_few_are_no_confident_none():
    # 8 %: beyond the share set aside as glitches (robust.MAX_SHARE), so not "within noise"
    c = make_campaign([], 20, Design(n_points=200, n_moves=3))
    _misdetect(c, 20, 0.08)
    rep = diagnose(c).report
    assert rep["unexplained"] or rep["cause"]["confidence"] != "high", rep["cause"]


def test_misdetections_do_not_hide_an_effect():
    truth = fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.03})
    c = make_campaign([truth], 23, Design(n_points=200, n_moves=3))
    assert len(_misdetect(c, 23, 0.03)) == 7                     # 3.5 % of the points: a few
    rep = diagnose(c).report
    cause = rep["cause"]
    assert (cause["effect"], cause["joints"]) == ("backlash", ["j2"])
    assert rep["unexplained"] is False and cause["confidence"] == "high"
    lo, hi = cause["ci95"]["j2_backlash_deg"]
    assert lo < 0.03 < hi
    assert rep["outliers"]["n"] > 0
    assert rep["holdout"]["inliers"]["shrink"] > rep["holdout"]["shrink"]


def test_a_heavy_tailed_remainder_is_not_set_aside():
    # a quarter and more of the points far off is not "a few misdetections"
    c = make_campaign([], 22, Design(n_points=120, n_moves=0))
    _misdetect(c, 22, 0.45)
    rep = diagnose(c).report
    o = rep["outliers"]
    assert o["points"]["set_aside"] is False and o["points"]["n"] == 0
    assert "none set aside" in o["notes"][0]
    assert rep["cause"]["confidence"] == "low"


def _clustered(truth, seed, n=120, jitter_deg=1.0):
    """Poses around two places only (±jitter), measured through the vocabulary."""
    c = make_campaign(truth, seed, Design(n_points=n, n_moves=0))
    rng = np.random.default_rng(seed)
    q = np.array([[30.0, 60.0], [-40.0, -90.0]])[rng.integers(0, 2, n)] \
        + rng.normal(0.0, jitter_deg, (n, 2))
    dirs = np.column_stack([c.points["j1_dir"], c.points["j2_dir"]])
    xy = fx.simulate_points(PRESETS["seed000"], truth, q, dirs, None, c.points["temp_c"],
                            (250.0, 930.0)) + rng.normal(0.0, POINT_NOISE, q.shape)
    c.points.update(j1_deg=q[:, 0], j2_deg=q[:, 1], x_mm=xy[:, 0], y_mm=xy[:, 1])
    return c


def test_clustered_poses_lower_the_confidence():
    truth = [fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.05})]
    rep = diagnose(_clustered(truth, 1)).report
    sp = rep["spread"]
    assert sp["few"] is True and sp["places"] < 10 and sp["distinct_poses"] > 50
    assert rep["cause"]["confidence"] != "high"
    assert any("place" in w for w in rep["cause"]["warnings"])
    # the same effect on well spread poses: a confident answer
    rep = diagnose(make_campaign(truth, 1, Design(n_points=120, n_moves=0))).report
    assert rep["spread"]["few"] is False and rep["cause"]["confidence"] == "high"
