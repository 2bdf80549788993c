"""The diagnosis's parts on small hand-made data: where-analysis, candidates, a single fit,
the path-noise estimate, the campaign preparation."""
import numpy as np
import pytest

from cell import effects as fx
from cell.diagnosis import where
from cell.diagnosis.candidates import merge, single_candidates
from cell.diagnosis.fit import fit_candidate, label, subset
from cell.diagnosis.replay import first_step_dirs, path_noise_mm, prepare, residuals
from cell.sim.campaigns import Design, make_campaign

D = Design(n_points=120, n_moves=3)


@pytest.fixture(scope="module")
def data():
    return prepare(make_campaign([], 31, D))


def test_nominal_replay_of_a_none_campaign_is_noise(data):
    rp, rq = residuals(data)
    # points: repeatability 0.01 + measurement 0.005 per axis; paths: measurement only
    assert np.std(rp) == pytest.approx(np.hypot(0.01, 0.005), rel=0.15)
    assert np.std(rq) == pytest.approx(0.005, rel=0.15)
    assert path_noise_mm(data) == pytest.approx(0.005, rel=0.15)


def _where_of(data, r):
    return where.analyse(data, r, np.zeros((data.n_path, 2)))


def test_where_names_what_a_residual_varies_with(data):
    p = data.points
    j1, j2, u1, u2 = where.jacobian_cols(500.0, 500.0, p.cmd)
    noise = np.random.default_rng(0).normal(0, 0.002, p.xy.shape)
    w = _where_of(data, 0.05 * j2 + noise)                          # j2 off by 0.05°
    assert (w.depends_on, w.joint) == ("constant", "j2")
    assert w.effect_sizes["constant"]["r2"] > 0.95
    w = _where_of(data, 0.03 * j1 * p.dirs[:, :1] + noise)          # j1 direction-dependent
    assert (w.depends_on, w.joint) == ("direction", "j1")
    dT = (p.temp - 20.0)[:, None]
    w = _where_of(data, 1e-4 * dT * (500 * u1 + 500 * u2) + noise)  # grows with temperature
    assert w.depends_on == "temperature"
    assert w.per_joint_rms_deg["j1"] is not None


def test_candidates_follow_the_data():
    c = make_campaign([], 32, Design(n_points=60, n_moves=0, rise_c=0.0))
    c.points["j2_dir"][:] = 1.0                                     # j2 always from below
    cands, skipped = single_candidates(prepare(c))
    labels = {label(x) for x in cands}
    assert "backlash[j1]" in labels and "backlash[j2]" not in labels
    assert "both directions" in skipped["backlash[j2]"]
    assert "thermal_drift" in skipped and "comm_delay" in skipped
    assert {"camera_scale", "camera_rotation", "gear_ratio[j1]"} <= labels


def test_merge_of_two_singles():
    a, b = (("backlash", ("j1",)),), (("backlash", ("j2",)),)
    assert merge(a, b) == (("backlash", ("j1", "j2")),)
    assert merge(a, a) is None
    assert merge((("camera_scale", ()),), (("joint_offset", ("j2",)),)) == \
        (("joint_offset", ("j2",)), ("camera_scale", ()))
    assert merge((("camera_scale", ()),), (("camera_scale", ()),)) is None


def test_fit_from_the_guess_recovers_an_anti_phase_cyclic_error():
    # truth in anti-phase with the guess (phase 0): the linear start must avoid the amp=0 bound
    truth = fx.make_effect("cyclic_error", ("j1",), {"j1_cyclic_amp_deg": 0.05,
                                                     "j1_cyclic_phase_deg": 180.0})
    d = prepare(make_campaign([truth], 33, Design(n_points=120, n_moves=0)))
    fd, hd = subset(d, "fit"), subset(d, "holdout")
    r = fit_candidate(((("cyclic_error", ("j1",))),), fd, hd, 2 * fd.n_points)
    assert r.identifiable and r.success
    assert r.params["j1_cyclic_amp_deg"] == pytest.approx(0.05, rel=0.02)
    assert r.params["j1_cyclic_phase_deg"] == pytest.approx(180.0, abs=2.0)
    lo, hi = r.ci95["j1_cyclic_amp_deg"]
    assert lo < 0.05 * 1.01 and hi > 0.05 * 0.99
    assert r.holdout.rms < 0.02


def test_degenerate_pair_is_not_identifiable():
    # without a camera centre offset from the base, camera rotation IS a j1 offset
    truth = fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.1})
    c = make_campaign([truth], 34, Design(n_points=80, n_moves=0, camera_center_mm=(0.0, 0.0)))
    d = prepare(c)
    fd, hd = subset(d, "fit"), subset(d, "holdout")
    r = fit_candidate(((("joint_offset", ("j1",))), ("camera_rotation", ())), fd, hd,
                      2 * fd.n_points)
    assert not r.identifiable and ("correlation" in r.reason or "condition" in r.reason)


def test_first_step_dirs():
    cmd = np.array([[0, 5], [0, 4], [1, 4], [2, 3]], float)
    assert first_step_dirs(cmd).tolist() == [1.0, -1.0]
    assert first_step_dirs(np.zeros((3, 2))).tolist() == [0.0, 0.0]
