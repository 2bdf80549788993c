"""The planar replay's exact Jacobian (cell/diagnosis/jacobian.py, what the station lags'
fit of a planar campaign evaluates) against central finite differences, for every
vocabulary effect at once and for the per-station lags; its values against the replay
itself."""
import numpy as np
import pytest

from cell import effects as fx
from cell.diagnosis import jacobian
from cell.diagnosis.replay import predict, prepare
from cell.sim.campaigns import Design, make_campaign

EVERYTHING = [  # every effect of the vocabulary, away from any bound and from λ = 0
    fx.make_effect("joint_offset", ("j1", "j2"), {"j1_offset_deg": 0.1, "j2_offset_deg": -0.05}),
    fx.make_effect("gear_ratio", ("j2",), {"j2_gear_ratio_rel": 1e-3}),
    fx.make_effect("cyclic_error", ("j1", "j2"), {
        "j1_cyclic_amp_deg": 0.05, "j1_cyclic_phase_deg": 30.0,
        "j2_cyclic_amp_deg": 0.03, "j2_cyclic_phase_deg": 100.0, "j2_cyclic_period_deg": 120.0}),
    fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.05}),
    fx.make_effect("link_length", ("j1",), {"j1_link_delta_mm": 0.5}),
    fx.make_effect("thermal_drift", (), {"thermal_expansion_per_k": 2e-5}),
    fx.make_effect("camera_rotation", (), {"camera_rotation_deg": 0.05}),
    fx.make_effect("camera_scale", (), {"camera_scale_rel": 1e-3}),
    fx.make_effect("comm_delay", (), {"comm_delay_sigma_ms": 1.3}),
]


@pytest.fixture(scope="module")
def data():
    return prepare(make_campaign([], 3, Design(n_points=40, n_moves=2)))


def test_every_effect_has_a_derivative():
    assert jacobian.coverage_check() == []


def test_values_are_the_replays(data):
    pp, pq = predict(data, EVERYTHING, 25.0)
    y, _ = jacobian.evaluate(jacobian.rows_of(data), EVERYTHING, 25.0)
    assert np.abs(np.vstack([pp, pq]) - y).max() < 1e-12


def _fd(f, x0, i, rel=1e-6):
    h = rel * max(1.0, abs(x0[i]))
    xp, xm = x0.copy(), x0.copy()
    xp[i] += h
    xm[i] -= h
    return (f(xp) - f(xm)) / (2 * h)


def test_jacobian_matches_finite_differences(data):
    rows = jacobian.rows_of(data)
    x0, names = fx.stack_vectors(EVERYTHING)
    x0 = np.append(x0, 25.0)
    _, J = jacobian.evaluate(rows, EVERYTHING, 25.0, jac=True, with_path_temp=True)
    assert J.shape == (rows.n, 2, len(names) + 1)

    def f(x):
        return jacobian.evaluate(rows, fx.split_vector(EVERYTHING, x[:-1]), x[-1])[0]
    for i, name in enumerate(names + ["path_temp_c"]):
        fd = _fd(f, x0, i)
        scale = np.abs(fd).max()
        assert scale > 0, name
        assert np.abs(fd - J[:, :, i]).max() < 1e-6 * scale, name


def test_lag_jacobian_matches_finite_differences(data):
    rows = jacobian.rows_of(data)
    static = [EVERYTHING[1], EVERYTHING[2]]          # gear and cyclic: ∂θ/∂a ≠ 1
    lags = np.array([1.7, 3.1])
    _, J = jacobian.evaluate(rows, static, None, jac=True, lags_ms=lags)

    def f(x):
        return jacobian.evaluate(rows, static, None, lags_ms=x)[0]
    for j in range(2):
        fd = _fd(f, lags, j)
        assert np.abs(fd - J[:, :, -2 + j]).max() < 1e-6 * np.abs(fd).max()
        assert np.all(J[:rows.n_points, :, -2 + j] == 0)          # points never move late


def test_two_comms_stages_are_refused(data):
    with pytest.raises(ValueError, match="at most one comms effect"):
        jacobian.evaluate(jacobian.rows_of(data), [EVERYTHING[-1]], lags_ms=[1.0, 2.0])
