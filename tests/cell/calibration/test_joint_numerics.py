"""Seed 004 single-joint calibration numerics (cell.calibration.joint, its result types and
plot in cell.calibration.joint_result): circle fit (with a radius prior), angles, the error
model's estimates and intervals, harmonic selection, pretravel sweeps, errors, the plot.

Golden values: the constructed truth in this file (:func:`make_sweep`), no camera. The
target centre seen by a hand camera at true joint angle θ_t is
c = C0 + R·(cos(φ0 − θ_t), sin(φ0 − θ_t)) (sense −1), with
θ_t = θ + offset + ε·θ − dir·b/2 + A·sin(2πθ/P + φ), dir = the sign of the last motion
(forward pass −1 but +1 at its +limit image, reached moving up from zero; return pass +1
but −1 at its −limit image, the turn-around pose shared with the forward pass). With
``pretravel`` (each pass starts one step beyond its first angle) every forward image has
dir −1 and every return image +1, and the two −limit images are two poses.
"""
import json
import math

import numpy as np
import pytest

from cell.calibration import joint as jc
from cell.errors import CalibrationError

C0_ANGLE = 80.0  # deg, constructed: where the target sits on the circle at θ = 0


def make_sweep(seed=0, *, radius=1000.0, runs=3, limit=1.5, step=0.1, eps=4e-4, b=0.012,
               amp=0.0, period=1.0, phase=30.0, offset=0.05, noise_mm=0.002, joint_sd=0.0,
               pretravel=False):
    """A sweep from the constructed truth of the module docstring, and that truth."""
    rng = np.random.default_rng(seed)
    nom = limit - step * np.arange(int(round(2 * limit / step)) + 1)
    m = len(nom)
    dirs = np.array([[-1.0] * m, [1.0] * m]) if pretravel else \
        np.array([[1.0] + [-1.0] * (m - 1), [1.0] * (m - 1) + [-1.0]])
    zero_dirs = rng.choice([-1.0, 1.0], runs)  # how each run's zero image was approached

    def true(th, d):
        return (th + offset + eps * th - d * b / 2
                + amp * np.sin(2 * np.pi * th / period + math.radians(phase)))
    th0 = true(0.0, zero_dirs) + rng.normal(0, joint_sd, runs)
    th = true(nom[None, None, :], dirs[None]) + rng.normal(0, joint_sd, (runs, 2, m))
    if not pretravel:
        th[:, 1, -1] = th[:, 0, -1]  # the turn-around: one pose, photographed twice
    c0 = -radius * np.array([math.cos(math.radians(C0_ANGLE)), math.sin(math.radians(C0_ANGLE))])

    def image(t):
        a = np.radians(C0_ANGLE - t)
        xy = c0 + radius * np.stack([np.cos(a), np.sin(a)], -1)
        return xy + rng.normal(0, noise_mm, xy.shape)
    sweep = jc.JointSweep("j1", step, nom, image(th0), image(th[:, 0]), image(th[:, 1]), pretravel)
    c_runs = zero_dirs * b / 2 - amp * math.sin(math.radians(phase))  # e = ... − Δθ(zero image)
    return sweep, {"center": c0, "radius": radius, "b": b, "eps": eps, "amp": amp,
                   "phase": phase, "offset": float(c_runs.mean())}


def inside(est, value):
    return est.low <= value <= est.high


# ------------------------------------------------------------------ circle fit
def test_full_circle_is_recovered_to_round_off():
    a = np.radians(np.arange(0, 360, 30.0))
    p = np.array([3.0, -4.0]) + 250.0 * np.column_stack([np.cos(a), np.sin(a)])
    f = jc.fit_circle(p)
    assert np.allclose(f.center, [3.0, -4.0], atol=1e-9)
    assert f.radius == pytest.approx(250.0, abs=1e-9)
    assert f.rms < 1e-9 and f.n == 12 and f.start == "taubin"


def test_short_arc_centre_is_loose_but_its_covariance_and_the_angles_are_right():
    # 3° of a 1000 mm circle (52 mm chord), 61 points, 2 µm noise: constructed here
    rng = np.random.default_rng(11)
    c, r = np.array([-173.6, -984.8]), 1000.0
    phi = np.radians(80 + np.linspace(-1.5, 1.5, 61))
    p = c + r * np.column_stack([np.cos(phi), np.sin(phi)]) + rng.normal(0, 0.002, (61, 2))
    f = jc.fit_circle(p)
    sr = math.sqrt(f.cov[2, 2])
    assert np.linalg.norm(f.center - c) < 10.0 and abs(f.radius - r) < 4 * sr
    assert 0.5 < sr < 10.0  # the radius is known to mm, not µm, from a 3° arc
    a = jc.step_angles(p, f, sense=1)
    got, want = a - a[0], np.degrees(phi - phi[0])
    # to first order a radius error only scales the angles (by r_true / r_fit) ...
    assert np.max(np.abs(got * f.radius / r - want)) < 5e-4
    # ... so the angle error stays within what cov(r) says: ≤ 4σ_r/r of the 3° span
    assert np.max(np.abs(got - want)) < 4 * sr / r * 3.0 + 5e-4
    hinted = jc.fit_circle(p, center_hint=c + [30.0, -40.0])
    assert hinted.start == "hint" and np.allclose(hinted.center, f.center, atol=1e-6)


def test_step_angles_turn_with_sense_and_unwrap():
    a = np.radians(np.arange(170, 200, 5.0))  # crosses ±180°
    p = np.column_stack([np.cos(a), np.sin(a)]) * 100.0
    f = jc.fit_circle(p)
    assert np.allclose(np.diff(jc.step_angles(p, f, sense=1)), 5.0, atol=1e-9)
    assert np.allclose(np.diff(jc.step_angles(p, f)), -5.0, atol=1e-9)  # default: hand camera


@pytest.mark.parametrize("points, match", [
    (np.ones((4, 2)) * np.arange(4)[:, None], "too few points: 4 < 5"),
    ([[0, 0], [1, 1], [2, 0], [np.nan, 1], [3, 3]], "point 3 .* not finite"),
    ([[0, 0]] * 3 + [[1, 1]] * 3, "only 2 distinct"),
    (np.column_stack([np.arange(9.0), 2 * np.arange(9.0) + 1]), "too short/straight"),
    (np.zeros((6, 3)), "shape"),
])
def test_circle_fit_refuses(points, match):
    with pytest.raises(CalibrationError, match=match):
        jc.fit_circle(points)


def _arc(seed, *, span_deg=2.0, n=41, noise_mm=0.010):
    """Constructed here: ``span_deg`` of the 1000 mm circle about (-173.6, -984.8) mm."""
    rng = np.random.default_rng(seed)
    c, r = np.array([-173.6, -984.8]), 1000.0
    phi = np.radians(80 + np.linspace(-span_deg / 2, span_deg / 2, n))
    return c + r * np.column_stack([np.cos(phi), np.sin(phi)]) + rng.normal(0, noise_mm, (n, 2)), c, r


def test_radius_prior_pins_the_radius_of_a_short_arc():
    # 2° of a 1000 mm circle (35 mm chord, 0.15 mm sagitta), 41 points, 10 µm noise: the
    # points alone fix the radius to tens of mm; a prior 0.3 mm off, sigma 0.5 mm, to ~0.5 mm
    p, c, r = _arc(21)
    free = jc.fit_circle(p)
    assert 10.0 < math.sqrt(free.cov[2, 2]) < 100.0
    r0, sig = r + 0.3, 0.5
    f = jc.fit_circle(p, radius_prior=(r0, sig))
    assert math.sqrt(f.cov[2, 2]) <= 0.5 * 1.01  # no better than the prior alone
    assert abs(f.radius - r) < 3 * sig and abs(f.radius - r0) < sig  # pulled to the prior
    assert np.linalg.norm(f.center - c) < 3.0 and f.n == 41
    assert f.rms == pytest.approx(free.rms, rel=0.05)  # the prior hardly costs the points


@pytest.mark.parametrize("prior", [(1000.0, -0.5), (1000.0, 0.0), (1000.0, math.nan),
                                   (1000.0, math.inf), (-1000.0, 0.5), (0.0, 0.5),
                                   (math.inf, 0.5), (math.nan, 0.5)])
def test_bad_radius_prior_is_refused(prior):
    p, _, _ = _arc(21)
    with pytest.raises(CalibrationError, match="radius_prior"):
        jc.fit_circle(p, radius_prior=prior)
    sw, _ = make_sweep(runs=1)
    with pytest.raises(CalibrationError, match=r"j1: circle .*radius_prior"):
        jc.analyse(sw, radius_prior=prior)


def test_noisy_straight_line_is_refused():
    rng = np.random.default_rng(3)
    x = np.linspace(0, 52, 40)
    p = np.column_stack([x, 0.5 * x]) + rng.normal(0, 0.002, (40, 2))
    with pytest.raises(CalibrationError, match="too short/straight"):
        jc.fit_circle(p)


# ------------------------------------------------------------------ analysis
@pytest.mark.parametrize("radius, limit, step", [(1000.0, 1.5, 0.1), (500.0, 3.0, 0.2)])
def test_noise_free_sweep_gives_the_truth_nearly_exactly(radius, limit, step):
    sw, t = make_sweep(radius=radius, limit=limit, step=step, amp=0.003, noise_mm=0.0)
    res = jc.analyse(sw, harmonics=1, period_deg=1.0)
    assert res.backlash_deg.value == pytest.approx(t["b"], abs=1e-9)
    assert res.gear_ratio_error.value == pytest.approx(t["eps"], abs=1e-9)
    assert res.offset_deg.value == pytest.approx(t["offset"], abs=1e-9)
    (h,) = res.harmonics
    assert h.k == 1 and h.amplitude.value == pytest.approx(0.003, abs=1e-9)
    assert h.phase.value == pytest.approx(30.0, abs=1e-5)
    assert res.residual_rms_deg < 1e-9 and res.n_images == 3 * 63 and res.n_runs == 3
    assert res.harmonic_tests[0].status == "fixed"
    assert res.circle.radius == pytest.approx(radius, rel=1e-9)


def test_table_steps_and_turning_points():
    sw, t = make_sweep(noise_mm=0.0, eps=4e-4, b=0.012)
    res = jc.analyse(sw, harmonics=0)
    rows, m = res.rows, len(res.rows)
    assert rows[0].nominal_deg == pytest.approx(1.5) and rows[-1].nominal_deg == pytest.approx(-1.5)
    # interior: forward − return = b; at both limits the passes share an approach direction
    assert all(abs(r.difference_deg - t["b"]) < 1e-9 for r in rows[1:-1])
    assert abs(rows[0].difference_deg) < 1e-9 and abs(rows[-1].difference_deg) < 1e-9
    # the first step after each reversal falls short by b; the others gain ε·step
    assert rows[1].forward_step_deg == pytest.approx(-t["b"] + t["eps"] * 0.1, abs=1e-9)
    assert rows[m - 2].return_step_deg == pytest.approx(-t["b"] + t["eps"] * 0.1, abs=1e-9)
    assert all(abs(r.forward_step_deg - t["eps"] * 0.1) < 1e-9 for r in rows[2:])
    assert math.isnan(rows[0].forward_step_deg) and math.isnan(rows[-1].return_step_deg)
    assert rows[5].forward_deg - rows[6].forward_deg == pytest.approx(t["eps"] * 0.1, abs=1e-9)
    assert res.repeatability_deg < 1e-9  # runs differ only by their zero image's offset


def test_noisy_sweep_estimates_lie_in_their_intervals_and_the_intervals_are_sane():
    sw, t = make_sweep(7, amp=0.003, noise_mm=0.002, joint_sd=3e-4)
    res = jc.analyse(sw, period_deg=1.0)
    assert inside(res.backlash_deg, t["b"]) and res.backlash_deg.high - res.backlash_deg.low < 1e-3
    assert inside(res.gear_ratio_error, t["eps"])
    assert res.gear_ratio_ppm.high - res.gear_ratio_ppm.low < 2e4  # short arc: se from the radius
    assert inside(res.offset_deg, t["offset"])
    (h,) = res.harmonics
    assert inside(h.amplitude, t["amp"]) and inside(h.phase, t["phase"])
    assert h.amplitude.high - h.amplitude.low < 1e-3
    assert 1e-4 < res.repeatability_deg < 1e-3  # joint 3e-4° ⊕ camera 2 µm/1 m


def test_backlash_and_gear_ratio_intervals_cover_the_truth_about_95_percent():
    hits_b = hits_e = 0
    est_b, half_b = [], []
    for seed in range(40):
        sw, t = make_sweep(100 + seed, runs=2, noise_mm=0.002, joint_sd=3e-4)
        res = jc.analyse(sw, harmonics=0)
        hits_b += inside(res.backlash_deg, t["b"])
        hits_e += inside(res.gear_ratio_error, t["eps"])
        est_b.append(res.backlash_deg.value)
        half_b.append((res.backlash_deg.high - res.backlash_deg.low) / 2)
    assert 35 <= hits_b <= 40 and 35 <= hits_e <= 40
    # the interval width matches the real scatter of the estimate (not absurdly wide)
    ratio = np.mean(half_b) / 1.96 / np.std(est_b, ddof=1)
    assert 0.6 < ratio < 1.6


def test_auto_harmonics_picks_none_when_there_is_none_and_the_right_one_when_there_is():
    sw, _ = make_sweep(5, amp=0.0, noise_mm=0.002, joint_sd=3e-4)
    res = jc.analyse(sw, period_deg=1.0)
    assert res.harmonics == ()
    sw, _ = make_sweep(5, amp=0.003, noise_mm=0.002, joint_sd=3e-4)
    res = jc.analyse(sw, period_deg=1.0)
    assert [h.k for h in res.harmonics] == [1]
    status = {t.k: t.status for t in res.harmonic_tests}
    assert status == {1: "accepted", 2: "rejected", 3: "rejected", 4: "rejected",
                      5: "not identifiable", 6: "not identifiable"}  # P/5 = 2·step: aliased
    sw, _ = make_sweep(5, amp=0.0, noise_mm=0.0)
    assert jc.analyse(sw, period_deg=1.0).harmonics == ()  # round-off is no harmonic


def test_a_period_much_longer_than_the_range_is_reported_not_fitted():
    sw, _ = make_sweep(5, amp=0.003, period=360.0, noise_mm=0.002)
    res = jc.analyse(sw, period_deg=360.0, max_harmonic=3)
    assert res.harmonics == ()
    assert [t.status for t in res.harmonic_tests] == ["not identifiable"] * 3
    assert "over a range of 3° (period 360°)" in res.harmonic_tests[0].reason


@pytest.mark.parametrize("eps", [0.0, 3e-4])
def test_radius_prior_narrows_the_gear_ratio_interval_on_a_short_arc(eps):
    # 2° range (limit 1°), 10 µm noise: without a prior the radius, so the angle scale and
    # ε, is known to a few % (interval ~7e4 ppm wide); a prior 0.3 mm off, sigma 0.5 mm,
    # narrows it ~35× (to ~2000 ppm) and shifts ε by about −0.3/1000 = −300 ppm, inside it
    sw, t = make_sweep(3, limit=1.0, eps=eps, noise_mm=0.010)
    free = jc.analyse(sw, harmonics=0)
    held = jc.analyse(sw, harmonics=0, radius_prior=(t["radius"] + 0.3, 0.5))
    width = lambda e: e.high - e.low
    assert width(free.gear_ratio_ppm) > 10 * width(held.gear_ratio_ppm)
    assert width(held.gear_ratio_ppm) < 3000
    assert inside(held.gear_ratio_ppm, 1e6 * eps) and inside(free.gear_ratio_ppm, 1e6 * eps)
    assert math.sqrt(held.circle.cov[2, 2]) <= 0.5 * 1.01
    assert inside(held.backlash_deg, t["b"])


def test_pretravel_sweep_every_image_arrives_in_its_pass_direction():
    # noise-free, constructed truth: with pretravel the passes differ by b at the limits too,
    # and no step falls short (no reversal inside a pass)
    sw, t = make_sweep(noise_mm=0.0, pretravel=True)
    res = jc.analyse(sw, harmonics=0)
    assert np.array_equal(res.dirs, [[-1.0] * 31, [1.0] * 31])
    assert res.backlash_deg.value == pytest.approx(t["b"], abs=1e-9) and res.residual_rms_deg < 1e-9
    assert all(abs(r.difference_deg - t["b"]) < 1e-9 for r in res.rows)
    assert res.rows[1].forward_step_deg == pytest.approx(t["eps"] * 0.1, abs=1e-9)
    assert res.rows[-2].return_step_deg == pytest.approx(t["eps"] * 0.1, abs=1e-9)


def test_pretravel_flag_sets_the_turning_point_directions():
    # 2 µm noise on a 1000 mm radius: ≈ 1.15e-4° per image (constructed truth in this test)
    noise_deg = math.degrees(0.002 / 1000.0)
    sw, t = make_sweep(1, b=0.012, noise_mm=0.002, pretravel=True)
    res = jc.analyse(sw, harmonics=0)
    assert inside(res.backlash_deg, t["b"]) and inside(res.gear_ratio_error, t["eps"])
    assert 0.7 * noise_deg < res.residual_rms_deg < 1.3 * noise_deg
    # the same images read with the plain procedure's turning points (dir +1 at the forward
    # +limit image, −1 at the return −limit image): those 2·R images miss by b, so the
    # residual is far above the noise (≈ 18× here)
    plain = jc.analyse(jc.JointSweep(sw.joint, sw.step_deg, sw.nominal_deg, sw.zero,
                                     sw.forward, sw.return_), harmonics=0)
    assert plain.residual_rms_deg > 5 * res.residual_rms_deg


def test_as_dict_is_plain_json():
    sw, _ = make_sweep(amp=0.003)
    d = jc.analyse(sw, period_deg=1.0).as_dict()

    def plain(x):
        if isinstance(x, dict):
            return all(isinstance(k, str) and plain(v) for k, v in x.items())
        if isinstance(x, list):
            return all(plain(v) for v in x)
        return x is None or type(x) in (str, int, float, bool)
    assert plain(d) and json.loads(json.dumps(d)) == d
    assert d["table"][0]["forward_step_deg"] is None
    assert d["gear_ratio_error_ppm"]["unit"] == "ppm" and d["harmonics"][0]["k"] == 1


def test_one_run_still_gives_intervals_but_no_run_to_run_figures():
    sw, t = make_sweep(9, runs=1, noise_mm=0.002, joint_sd=3e-4)
    res = jc.analyse(sw, harmonics=0)
    assert inside(res.backlash_deg, t["b"]) and inside(res.offset_deg, t["offset"])
    assert res.repeatability_deg is None and math.isnan(res.rows[3].forward_sd_deg)
    d = res.as_dict()
    assert d["repeatability_deg"] is None and d["table"][3]["forward_sd_deg"] is None


@pytest.mark.parametrize("module", ["cell.calibration.joint", "cell.calibration.joint_result"])
def test_importing_the_module_does_not_import_matplotlib(module):
    import subprocess
    import sys
    code = f"import sys, {module}; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_result_types_and_plot_are_re_exported_from_joint():
    from cell.calibration import joint_result as jr
    for name in ("Estimate", "Harmonic", "HarmonicTest", "Row", "JointResult", "plot"):
        assert getattr(jc, name) is getattr(jr, name) and name in jc.__all__


# ------------------------------------------------------------------ refusals
def test_lost_target_names_run_pass_step_and_angle():
    sw, _ = make_sweep(runs=3)
    ret = np.array(sw.return_)
    ret[2, 7] = np.nan
    bad = jc.JointSweep("j1", sw.step_deg, sw.nominal_deg, sw.zero, sw.forward, ret)
    with pytest.raises(CalibrationError, match=r"j1: target lost in run 2 return pass step 7 "
                                               r"\(θ = 0\.8°\)"):
        jc.analyse(bad)
    zero = np.array(sw.zero)
    zero[1] = np.nan
    with pytest.raises(CalibrationError, match="run 1 zero image"):
        jc.analyse(jc.JointSweep("j1", 0.1, sw.nominal_deg, zero, sw.forward, sw.return_))


def test_sweep_validation_names_the_bad_array_and_image():
    sw, _ = make_sweep(runs=2)
    nom, z, f, r = sw.nominal_deg, sw.zero, sw.forward, sw.return_
    with pytest.raises(CalibrationError, match=r"forward has shape \(2, 30, 2\)"):
        jc.JointSweep("j1", 0.1, nom, z, f[:, :-1], r)
    with pytest.raises(CalibrationError, match=r"zero has shape"):
        jc.JointSweep("j1", 0.1, nom, z[:, :1], f, r)
    half = np.array(f)
    half[1, 3, 0] = np.inf
    with pytest.raises(CalibrationError, match=r"run 1 forward pass step 3 \(θ = 1\.2°\)"):
        jc.JointSweep("j1", 0.1, nom, z, half, r)
    with pytest.raises(CalibrationError, match="steps of 0.2°"):
        jc.JointSweep("j1", 0.2, nom, z, f, r)
    with pytest.raises(CalibrationError, match="sense"):
        jc.analyse(sw, sense=2)
    with pytest.raises(CalibrationError, match="harmonics"):
        jc.analyse(sw, harmonics="all")


def test_from_visit_order_reverses_the_return_pass():
    sw, _ = make_sweep(runs=1)
    again = jc.JointSweep.from_visit_order("j1", 0.1, sw.nominal_deg, sw.zero, sw.forward,
                                           sw.return_[:, ::-1])
    assert np.array_equal(again.return_, sw.return_)


# ------------------------------------------------------------------ plot
def test_plot_writes_a_png_atomically(tmp_path):
    sw, _ = make_sweep(amp=0.003, noise_mm=0.002, joint_sd=3e-4)
    out = jc.plot(jc.analyse(sw, period_deg=1.0), tmp_path / "j1.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000
    assert [p.name for p in tmp_path.iterdir()] == ["j1.png"]
