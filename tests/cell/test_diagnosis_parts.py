"""The diagnosis's parts on small hand-made data: where-analysis, what a campaign cannot
identify, a fit from its start, the path-noise estimate, the campaign preparation."""
import numpy as np
import pytest

from cell import effects as fx
from cell.diagnosis import where
from cell.diagnosis.answer import diagnose_campaign
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


def test_what_the_data_cannot_identify_is_named_with_its_reason():
    c = make_campaign([], 32, Design(n_points=60, n_moves=0, rise_c=0.0))
    c.points["j2_dir"][:] = 1.0                                     # j2 always from below
    ni = diagnose_campaign(c).report["not_identifiable"]
    assert "j1_backlash_deg" not in ni and "j2_backlash_deg" in ni, ni
    assert "comm_delay_sigma_ms" in ni and "paths.csv" in ni["comm_delay_sigma_ms"]
    assert not {"camera_scale_rel", "camera_rotation_deg", "j1_gear_ratio_rel"} & set(ni)


def test_an_anti_phase_cyclic_error_is_recovered():
    # truth in anti-phase with a zero-phase guess: the fit must not stall on the amplitude
    truth = fx.make_effect("cyclic_error", ("j1",), {"j1_cyclic_amp_deg": 0.05,
                                                     "j1_cyclic_phase_deg": 180.0})
    rep = diagnose_campaign(make_campaign([truth], 33, Design(n_points=120, n_moves=0))).report
    cause = rep["cause"]
    assert (cause["effect"], cause["joints"]) == ("cyclic_error", ["j1"]), cause
    assert cause["params"]["j1_cyclic_amp_deg"] == pytest.approx(0.05, rel=0.05)
    assert cause["params"]["j1_cyclic_phase_deg"] == pytest.approx(180.0, abs=3.0)
    lo, hi = cause["ci95"]["j1_cyclic_amp_deg"]
    assert lo < 0.05 < hi
    assert rep["holdout"]["rms_after_mm"] < 0.02


def test_a_camera_turn_about_the_base_is_a_j1_offset():
    # with the camera centred on the base, turning the camera IS turning j1: not both
    truth = fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.1})
    c = make_campaign([truth], 34, Design(n_points=80, n_moves=0, camera_center_mm=(0.0, 0.0)))
    rep = diagnose_campaign(c).report
    assert "camera_rotation" not in rep["cause"]["label"], rep["cause"]
    assert rep["cause"]["effect"] == "joint_offset" and rep["cause"]["joints"] == ["j1"]


def test_first_step_dirs():
    cmd = np.array([[0, 5], [0, 4], [1, 4], [2, 3]], float)
    assert first_step_dirs(cmd).tolist() == [1.0, -1.0]
    assert first_step_dirs(np.zeros((3, 2))).tolist() == [0.0, 0.0]
