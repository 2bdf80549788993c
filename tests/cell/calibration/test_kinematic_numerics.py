"""Seed 001 numerics: the DH chain, its differential error model, identifiability,
iterated least squares, pose selection and the held-out check.

Golden values: the nominal chain against the independent scalar SCARA
(cell.kinematics.Scara, seed 000 eq. 4 / seed 002 z chain); the differential Jacobian
against central finite differences of fk → planar_pose; the merge coefficients from the
closed forms (α1 acts like (−h/l1)·(Δθ1 − Δθ2), h = d3 + tool_z the tool's height over
link 1). Synthetic robot: nominal + the known errors TRUE, noise 5 µm and 0.001°.
"""
import json

import numpy as np
import pytest

from cell.calibration import dh
from cell.calibration import kinematic as km
from cell.errors import CalibrationError
from cell.kinematics import Scara
from cell.robots import PRESETS

CHAIN = dh.scara_chain(PRESETS["seed000"])           # seed 000: l1 = l2 = 500 mm
CHAIN2 = dh.scara_chain(PRESETS["seed002"])          # seed 002: l1 = l2 = 200, tool_z −50
D3 = -100.0                                          # camera height: d3 constant over a pose set
TRUE = {"j1.theta": 0.05, "j2.theta": -0.04, "j1.a": 0.3, "j2.a": -0.25, "j4.theta": 0.03,
        "j4.a": 0.1, "j2.d": 0.2, "base.x": 3.0, "base.y": -2.0, "base.rz": 0.1}
P_TRUE = CHAIN.errors(TRUE)
SIGMA_XY, SIGMA_PHI = 0.005, 0.001
KEPT = ("j1.theta", "j2.theta", "j4.theta", "j1.a", "j2.a", "j4.a", "base.x", "base.y")


def poses(rng, n, d3=D3):
    """θ1 in [−120, 120]°, θ2 in ±[20, 140]° (away from the singularity), θ4 anywhere."""
    return np.column_stack([rng.uniform(-120, 120, n), rng.choice([-1.0, 1.0], n) * rng.uniform(20, 140, n),
                            np.full(n, d3), rng.uniform(-180, 180, n)])


def measure(rng, q, p=P_TRUE, chain=CHAIN):
    m = chain.predict(q, p)
    m[:, :2] += rng.normal(0.0, SIGMA_XY, (len(q), 2))
    m[:, 2] += rng.normal(0.0, SIGMA_PHI, len(q))
    return m


def data(seed, n, p=P_TRUE):
    rng = np.random.default_rng(seed)
    q = poses(rng, n)
    return q, measure(rng, q, p)


def fd_jacobian(chain, q, p, h=1e-5):
    cols = []
    for k in range(chain.n_params):
        e = np.zeros(chain.n_params)
        e[k] = h
        d = chain.predict(q, p + e) - chain.predict(q, p - e)
        d[:, 2] = dh.wrap_deg(d[:, 2])
        cols.append((d / (2 * h)).reshape(-1))
    return np.column_stack(cols)


# ------------------------------------------------------------------ the DH chain
@pytest.mark.parametrize("preset, d3", [("seed000", -100.0), ("seed002", 40.0)])
def test_nominal_chain_is_the_scara_of_cell_kinematics(preset, d3):
    chain, robot = dh.scara_chain(PRESETS[preset]), Scara(PRESETS[preset])
    q = poses(np.random.default_rng(1), 30, d3)
    T = dh.fk(chain, q, None)
    ref = np.array([robot.fk(row) for row in q])
    np.testing.assert_allclose(T[:, 0, 3], ref[:, 0], atol=1e-9)
    np.testing.assert_allclose(T[:, 1, 3], ref[:, 1], atol=1e-9)
    np.testing.assert_allclose(T[:, 2, 3], ref[:, 2], atol=1e-9)       # base_z + d3 + tool_z
    np.testing.assert_allclose(dh.wrap_deg(dh.planar_pose(T)[:, 2] - ref[:, 3]), 0.0, atol=1e-9)
    assert len(chain.param_names) == 19 and chain.param_names[-3:] == ("base.x", "base.y", "base.rz")


def test_base_nuisance_is_the_base_pose_in_the_board_frame():
    q = np.array([[30.0, 45.0, D3, 10.0]])
    p = CHAIN.errors({"base.x": 10.0, "base.y": -5.0, "base.rz": 90.0})
    x, y = Scara(PRESETS["seed000"]).fk_planar(30.0, 45.0)
    # p_board = Rz(90°)·p_base + (10, −5): (x, y) → (−y + 10, x − 5); φ turns by 90°
    np.testing.assert_allclose(CHAIN.predict(q, p)[0], [-y + 10.0, x - 5.0, 175.0], atol=1e-9)
    shifted = dh.scara_chain(PRESETS["seed000"], base_nominal=(10.0, -5.0, 90.0))
    np.testing.assert_allclose(shifted.predict(q), CHAIN.predict(q, p), atol=1e-12)


def test_planar_measurement_is_blind_to_d_errors():
    q = poses(np.random.default_rng(2), 10)
    p = CHAIN.errors({"j1.d": 5.0, "j2.d": -3.0, "j3.d": 1.0, "j4.d": 2.0})
    np.testing.assert_allclose(CHAIN.predict(q, p), CHAIN.predict(q), atol=1e-12)
    assert dh.fk(CHAIN, q, p)[0, 2, 3] == pytest.approx(dh.fk(CHAIN, q)[0, 2, 3] + 5.0)


@pytest.mark.parametrize("chain", [CHAIN, CHAIN2], ids=["seed000", "seed002"])
def test_differential_jacobian_matches_finite_differences(chain):
    rng = np.random.default_rng(11)
    q = poses(rng, 25, d3=-100.0 if chain is CHAIN else 40.0)
    p = rng.normal(0.0, 0.5, chain.n_params)         # non-nominal: tilted axes, offsets
    p[-3:-1] = rng.normal(0.0, 5.0, 2)
    J, Jfd = dh.error_jacobian(chain, q, p), fd_jacobian(chain, q, p)
    assert J.shape == (25 * 3, 19)
    np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-6 * np.abs(J).max())


def test_jacobian_columns_at_nominal():
    J = dh.error_jacobian(CHAIN, poses(np.random.default_rng(3), 12))
    col = {n: J[:, k] for k, n in enumerate(CHAIN.param_names)}
    np.testing.assert_array_equal(col["base.rz"], col["j1.theta"])
    for name in ("j1.d", "j2.d", "j3.d", "j4.d", "j4.alpha"):
        assert not col[name].any(), name
    np.testing.assert_allclose(col["j4.theta"][2::3], 1.0)       # 1°/° of φ, no xy


def test_chain_input_errors_name_the_cause():
    q = poses(np.random.default_rng(4), 5)
    q[3, 1] = np.nan
    with pytest.raises(CalibrationError, match="joints of pose 3"):
        dh.fk(CHAIN, q)
    with pytest.raises(CalibrationError, match=r"shape \(N >= 1, 4\)"):
        dh.fk(CHAIN, np.zeros((5, 3)))
    with pytest.raises(CalibrationError, match=r"shape \(19,\)"):
        dh.fk(CHAIN, np.zeros((5, 4)), np.zeros(18))
    with pytest.raises(CalibrationError, match="unknown DH parameter 'j5.a'"):
        CHAIN.errors({"j5.a": 1.0})


# ------------------------------------------------------------------ identifiability
def report_for(chain, d3, n=40):
    J = km.design_matrix(chain, poses(np.random.default_rng(5), n, d3))
    return km.identifiability(J, chain.param_names, priority=km.default_priority(chain))


def test_identifiability_of_the_500_500_scara():
    rep = report_for(CHAIN, D3)
    assert rep.rank == 8 and rep.kept == KEPT
    assert rep.condition_number < 20
    assert set(rep.unobservable) == {"j1.d", "j2.d", "j3.d", "j4.d", "j3.alpha", "j4.alpha"}
    m = rep.merged
    assert set(m) == {"base.rz", "j3.theta", "j3.a", "j1.alpha", "j2.alpha"}
    assert m["base.rz"] == {"j1.theta": pytest.approx(1.0)}              # only the sum is seen
    assert m["j3.theta"] == {"j4.theta": pytest.approx(1.0)}
    assert m["j3.a"] == {"j2.a": pytest.approx(1.0)}
    h = D3 + 0.0                                                          # d3 + tool_z
    assert m["j1.alpha"] == {"j1.theta": pytest.approx(-h / 500), "j2.theta": pytest.approx(h / 500)}
    assert all(f["fit_residual"] < 1e-9 for f in rep.fixed if f["reason"] == "merged")
    assert len(rep.singular_values) == 13 and rep.rank_threshold == pytest.approx(1e-4 * rep.singular_values[0])
    json.dumps(rep.as_dict())


def test_identifiability_of_the_seed002_scara():
    rep = report_for(CHAIN2, 40.0)                   # h = 40 − 50 = −10 mm
    assert set(rep.kept) >= {"j1.theta", "j2.theta", "j1.a", "j2.a", "base.x", "base.y", "j4.theta"}
    assert {"j1.d", "j2.d", "j3.d", "j4.d"} <= set(rep.unobservable)
    assert rep.merged["base.rz"] == {"j1.theta": pytest.approx(1.0)}
    # α3 tilts the 50 mm tool: acts like (−tool_z/l2)·(Δθ2 − Δθ4)
    assert rep.merged["j3.alpha"] == {"j2.theta": pytest.approx(0.25), "j4.theta": pytest.approx(-0.25)}


def test_priority_decides_which_of_a_merged_pair_is_kept():
    J = km.design_matrix(CHAIN, poses(np.random.default_rng(5), 40))
    rep = km.identifiability(J, CHAIN.param_names, priority=["base.rz"] + km.default_priority(CHAIN))
    assert "base.rz" in rep.kept and rep.merged["j1.theta"] == {"base.rz": pytest.approx(1.0)}


# ------------------------------------------------------------------ identification
def test_identify_recovers_the_errors_within_their_intervals():
    q, m = data(21, 60)
    res = km.identify(CHAIN, q, m)
    assert res.kept == KEPT and res.converged and res.dof == 60 * 3 - 8
    truth = dict(TRUE, **{"j1.theta": TRUE["j1.theta"] + TRUE["base.rz"]})   # the merged sum
    for k, name in enumerate(res.kept):
        lo, hi = res.ci95[k]
        assert lo <= truth[name] <= hi, (name, truth[name], lo, hi)
        tol = 0.002 if CHAIN.unit(name) == "deg" else 0.005
        assert res.value(name) == pytest.approx(truth[name], abs=tol), name
    for name in ("base.rz", "j2.d", "j3.theta", "j1.alpha"):
        assert res.value(name) == 0.0                # fixed or merged: left at p0
    assert res.sigma_xy_mm == pytest.approx(SIGMA_XY, rel=0.25)
    assert res.sigma_phi_deg == pytest.approx(SIGMA_PHI, rel=0.25)
    assert res.phi_weight_mm_per_deg == pytest.approx(SIGMA_XY / SIGMA_PHI, rel=0.4)
    assert res.rms_xy_mm < 3 * SIGMA_XY and res.residuals.shape == (60, 3)
    assert res.condition_number < 20 and res.report.kept == KEPT
    json.dumps(res.as_dict())


def test_interval_coverage_is_about_95_percent():
    hits = []
    for seed in range(40):
        q, m = data(100 + seed, 30)
        res = km.identify(CHAIN, q, m)
        truth = np.array([TRUE[n] + (TRUE["base.rz"] if n == "j1.theta" else 0.0) for n in res.kept])
        hits += list((res.ci95[:, 0] <= truth) & (truth <= res.ci95[:, 1]))
    assert 0.90 <= np.mean(hits) <= 0.99


def test_noise_free_data_are_recovered_exactly():
    q = poses(np.random.default_rng(6), 20)
    res = km.identify(CHAIN, q, CHAIN.predict(q, P_TRUE))
    np.testing.assert_allclose(res.value("j1.theta"), 0.15, atol=1e-9)
    np.testing.assert_allclose([res.value(n) for n in ("j1.a", "j2.a", "base.x")], [0.3, -0.25, 3.0], atol=1e-8)


def test_standard_errors_shrink_with_more_poses():
    few = km.identify(CHAIN, *data(31, 20))
    many = km.identify(CHAIN, *data(32, 160))
    assert np.all(many.std_err < 0.6 * few.std_err)          # ~ 1/√8 ≈ 0.35 expected


def test_identify_with_a_fixed_phi_weight():
    res = km.identify(CHAIN, *data(21, 60), phi_weight_mm_per_deg=km.phi_weight_default(CHAIN))
    assert res.phi_weight_mm_per_deg == pytest.approx(1000 * np.pi / 180)
    assert res.value("j2.a") == pytest.approx(-0.25, abs=0.005)


def test_singular_designs_raise():
    q, m = data(41, 2)
    with pytest.raises(CalibrationError, match=r"2 poses × 3 = 6 equations for 8 parameters"):
        km.identify(CHAIN, q, m)
    q, m = data(42, 30)
    q[:, 0], q[:, 1] = 30.0, 60.0                          # θ4 still varies
    with pytest.raises(CalibrationError, match=r"singular design matrix: rank [0-7] < 8"):
        km.identify(CHAIN, q, CHAIN.predict(q, P_TRUE))
    q, m = data(43, 30)
    with pytest.raises(CalibrationError, match=r"rank 8 < 9 .*base\.rz not determined"):
        km.identify(CHAIN, q, m, kept=KEPT + ("base.rz",))
    with pytest.raises(CalibrationError, match="rank 0"):
        km.identify(CHAIN, q, m, kept=())


def test_identify_input_errors_name_the_pose():
    q, m = data(44, 20)
    m[7, 2] = np.inf
    with pytest.raises(CalibrationError, match="measured of pose 7 is not finite"):
        km.identify(CHAIN, q, m)
    with pytest.raises(CalibrationError, match=r"measured must have shape \(20, 3\)"):
        km.identify(CHAIN, q, m[:, :2])
    with pytest.raises(CalibrationError, match=r"measured must have shape \(20, 3\)"):
        km.identify(CHAIN, q, m[:19])


def test_no_convergence_names_the_iterations_and_the_last_update():
    with pytest.raises(CalibrationError, match=r"did not converge after 1 iteration: .* mm rms"):
        km.identify(CHAIN, *data(45, 20), max_iter=1)


# ------------------------------------------------------------------ pose selection
def test_d_optimal_selection_beats_random_selection():
    cand = poses(np.random.default_rng(51), 400)
    n = 12
    idx = km.select_poses(CHAIN, cand, n)
    assert len(idx) == n and len(set(idx.tolist())) == n
    cols = [CHAIN.index(k) for k in KEPT]
    norms = np.linalg.norm(km.design_matrix(CHAIN, cand)[:, cols], axis=0)

    def logdet_and_cond(ix):
        """log det of the information matrix as select_poses scales it; cond of the
        unit-column J (the condition number identify reports)."""
        J = km.design_matrix(CHAIN, cand[ix])[:, cols]
        s = np.linalg.svd(J / norms, compute_uv=False)
        return np.sum(np.log(s ** 2)), np.linalg.cond(J / np.linalg.norm(J, axis=0))

    rng = np.random.default_rng(52)
    rand = np.array([logdet_and_cond(rng.choice(400, n, replace=False)) for _ in range(30)])
    logdet, cond = logdet_and_cond(idx)
    assert logdet > rand[:, 0].max()                       # the criterion itself
    assert cond < np.median(rand[:, 1])                    # and a better-conditioned design
    seeded = km.select_poses(CHAIN, cand, n, rng=np.random.default_rng(53))
    assert len(set(seeded.tolist())) == n and logdet_and_cond(seeded)[0] > rand[:, 0].max()
    with pytest.raises(CalibrationError, match="cannot select 2 of 400"):
        km.select_poses(CHAIN, cand, 2)


# ------------------------------------------------------------------ held-out check
def test_holdout_passes_for_a_good_calibration():
    qf, mf = data(61, 40)
    qh, mh = data(62, 30)
    res = km.identify(CHAIN, qf, mf)
    hc = km.holdout_check(CHAIN, res.p, qh, mh, q_fit=qf, measured_fit=mf)
    assert hc.passed, hc.reason
    assert hc.rms_xy_before_mm > 0.2 and hc.rms_xy_after_mm < 3 * SIGMA_XY
    assert hc.gain > 0.9 and hc.ratio < 3.0 and hc.n_hold == 30
    json.dumps(hc.as_dict())


def test_holdout_fails_for_a_model_fitted_to_garbage():
    qf, _ = data(63, 40)
    other = CHAIN.errors({"j1.a": -1.5, "j2.a": 2.0, "j2.theta": 0.3, "base.x": 3.0, "base.y": -2.0})
    mf = measure(np.random.default_rng(64), qf, other)   # another robot's measurements
    qh, mh = data(65, 30)
    res = km.identify(CHAIN, qf, mf)
    hc = km.holdout_check(CHAIN, res.p, qh, mh, q_fit=qf, measured_fit=mf)
    assert not hc.passed and hc.gain < 0.1 and "gain" in hc.reason


def test_holdout_fails_when_calibration_does_not_help():
    nominal = CHAIN.errors({"base.x": 3.0, "base.y": -2.0, "base.rz": 0.1})  # only the board is off
    qf, mf = data(66, 40, nominal)
    qh, mh = data(67, 30, nominal)
    res = km.identify(CHAIN, qf, mf)
    hc = km.holdout_check(CHAIN, res.p, qh, mh, q_fit=qf, measured_fit=mf)
    assert not hc.passed and "required" in hc.reason


def test_holdout_input_errors_name_the_pose():
    qf, mf = data(68, 20)
    qh, mh = data(69, 10)
    qh[4, 0] = np.nan
    with pytest.raises(CalibrationError, match="q_hold of pose 4"):
        km.holdout_check(CHAIN, np.zeros(19), qh, mh, q_fit=qf, measured_fit=mf)


def hand_camera_reduction(rng, q, p, points, chain=CHAIN, sigma=SIGMA_XY):
    """Board measurements as the hand camera's reduction gives them: the known point b
    less where a camera turning with the TRUE tool sees it (noise ``sigma`` mm), turned
    back by the NOMINAL tool orientation; and the lever of each pose, (b − m, φ₀)."""
    true = chain.predict(q, p)
    phi0 = chain.predict(q)[:, 2]

    def turn(v, deg):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])
    h = turn(points - true[:, :2], -true[:, 2]) + rng.normal(0.0, sigma, (len(q), 2))
    m = points - turn(h, phi0)
    return m, np.column_stack([points - m, phi0])


@pytest.mark.parametrize("zeros, bias", [(0.0, (0.0, 0.005)), (0.05, (0.005, 0.02)), (0.2, (0.03, 0.1))])
def test_the_lever_redoes_the_hand_cameras_reduction_with_the_models_tool_orientation(zeros, bias):
    # zeros of the same sign turn the tool by their sum; the reduction with the nominal φ
    # then puts each pose a little further out (the zeros' tangential error turned by
    # Δφ), and the links absorb it (noise-free here, so that is all there is); with the
    # lever the fit recovers every error exactly
    truth = CHAIN.errors({"j1.theta": zeros, "j2.theta": zeros, "j1.a": 0.3, "j2.a": -0.25,
                          "base.x": 3.0, "base.y": -2.0, "base.rz": 0.1})
    rng = np.random.default_rng(7)
    q = poses(rng, 60)
    points = CHAIN.predict(q)[:, :2] + rng.uniform(-3.0, 3.0, (60, 2))   # the point a pose is over
    m, lever = hand_camera_reduction(rng, q, truth, points, sigma=0.0)
    kept = ("j1.theta", "j2.theta", "j1.a", "j2.a", "j4.a", "base.x", "base.y")   # base.rz: in j1.theta
    expect = truth.copy()
    expect[CHAIN.index("j1.theta")] += truth[CHAIN.index("base.rz")]
    biased = km.identify(CHAIN, q, m, kept=kept, position_only=True)
    fixed = km.identify(CHAIN, q, m, kept=kept, position_only=True, lever=lever)
    for name in kept:
        assert fixed.value(name) == pytest.approx(expect[CHAIN.index(name)], abs=1e-6), name
    long = sum(biased.value(n) - truth[CHAIN.index(n)] for n in ("j1.a", "j2.a"))
    assert bias[0] <= long < bias[1]
    assert fixed.rms_xy_mm < 1e-6 < biased.rms_xy_mm


def test_the_lever_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    q = poses(rng, 12)
    points = CHAIN.predict(q)[:, :2] + rng.uniform(-3.0, 3.0, (12, 2))
    m, lever = hand_camera_reduction(rng, q, P_TRUE, points)
    m = np.column_stack([m, CHAIN.predict(q)[:, 2]])
    lever[::4] = 0.0                                   # poses measured directly
    p = P_TRUE + 0.01
    J = km.jacobian(CHAIN, q, p, w=0.0, lever=lever)
    h = 1e-5
    for k in range(CHAIN.n_params):
        e = np.zeros(CHAIN.n_params)
        e[k] = h
        d = -(km.residuals(CHAIN, q, m, p + e, lever=lever) - km.residuals(CHAIN, q, m, p - e, lever=lever)) / (2 * h)
        np.testing.assert_allclose(J[:, k].reshape(-1, 3)[:, :2], d[:, :2], atol=1e-6, err_msg=CHAIN.param_names[k])


def test_a_lever_of_the_wrong_shape_is_refused():
    q, m = data(1, 10)
    with pytest.raises(CalibrationError, match=r"lever must have shape \(10, 3\)"):
        km.identify(CHAIN, q, m, lever=np.zeros((9, 3)))
    bad = np.zeros((10, 3))
    bad[4, 1] = np.nan
    with pytest.raises(CalibrationError, match="lever of pose 4 is not finite"):
        km.residuals(CHAIN, q, m, P_TRUE, lever=bad)
