"""cell.numerics.lsq: the bounded Levenberg–Marquardt that replaced scipy's least_squares in the
planar diagnosis, held to closed-form solutions and to scipy (the reference here only)."""
import numpy as np
import pytest
from scipy.optimize import least_squares as scipy_lsq

from cell.numerics.lsq import least_squares

T = np.linspace(0.0, 4.0, 60)
Y = 2.0 * np.exp(-1.3 * T) + 0.3 + 0.01 * np.random.default_rng(0).standard_normal(60)


def decay(x):
    return x[0] * np.exp(-x[1] * T) + x[2] - Y


def decay_jac(x):
    e = np.exp(-x[1] * T)
    return np.column_stack([e, -x[0] * T * e, np.ones_like(T)])


def test_linear_problem_is_the_least_squares_solution():
    rng = np.random.default_rng(1)
    A, b = rng.normal(size=(50, 4)) * [1.0, 10.0, 0.1, 1e3], rng.normal(size=50)
    sol = least_squares(lambda x: A @ x - b, np.zeros(4), lambda x: A)
    assert sol.success
    np.testing.assert_allclose(sol.x, np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-9)


def test_rosenbrock_reaches_the_minimum():
    def f(x):
        return np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])

    def j(x):
        return np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])
    sol = least_squares(f, [-1.2, 1.0], j)
    assert sol.success and sol.cost < 1e-20
    np.testing.assert_allclose(sol.x, [1.0, 1.0], atol=1e-10)


@pytest.mark.parametrize("lo, hi", [(-np.inf, np.inf), ([0.0, 0.0, 0.35], [5.0, 5.0, 1.0]),
                                    ([0.0, 1.5, -1.0], [5.0, 3.0, 1.0])])
def test_matches_scipy_trf_with_and_without_bounds(lo, hi):
    ours = least_squares(decay, [1.0, 1.6, 0.5], decay_jac, lo, hi)
    ref = scipy_lsq(decay, [1.0, 1.6, 0.5], decay_jac, bounds=(lo, hi), method="trf",
                    x_scale="jac")
    assert ours.success
    np.testing.assert_allclose(ours.x, ref.x, rtol=1e-6, atol=1e-9)
    assert ours.cost <= ref.cost * (1 + 1e-9)
    np.testing.assert_allclose(ours.jac, decay_jac(ours.x))
    np.testing.assert_allclose(ours.fun, decay(ours.x))


def test_a_parameter_held_on_its_bound_is_reported_active():
    sol = least_squares(decay, [1.0, 1.0, 0.5], decay_jac, [0.0, 0.0, 0.35], [5.0, 5.0, 1.0])
    assert sol.x[2] == 0.35 and sol.active.tolist() == [0, 0, -1]
    sol = least_squares(decay, [1.0, 1.0, 0.1], decay_jac, [0.0, 0.0, -1.0], [5.0, 5.0, 0.2])
    assert sol.x[2] == 0.2 and sol.active.tolist() == [0, 0, 1]


def test_forward_differences_agree_with_the_exact_jacobian():
    a = least_squares(decay, [1.0, 1.0, 0.5], decay_jac, [0.0, 0.0, 0.0], [5.0, 1.2, 1.0])
    b = least_squares(decay, [1.0, 1.0, 0.5], "2-point", [0.0, 0.0, 0.0], [5.0, 1.2, 1.0])
    np.testing.assert_allclose(b.x, a.x, rtol=1e-6)
    assert b.nfev > a.nfev and b.njev == 0


def test_max_nfev_stops_unconverged():
    sol = least_squares(decay, [1.0, 1.0, 0.5], decay_jac, max_nfev=2)
    assert sol.status == 0 and not sol.success and sol.nfev == 2


def test_a_non_finite_trial_is_refused_not_accepted():
    def f(x):
        return np.array([np.nan if x[0] > 2.0 else x[0] - 3.0])
    sol = least_squares(f, [0.0], lambda x: np.ones((1, 1)))
    assert np.isfinite(sol.cost) and sol.x[0] <= 2.0


@pytest.mark.parametrize("x0, lo, hi, what", [([0.0], [1.0], [2.0], "outside the bounds"),
                                              ([1.0], [2.0], [1.0], "below its upper bound"),
                                              ([np.inf], None, None, "not finite")])
def test_bad_input_raises_value_error(x0, lo, hi, what):
    with pytest.raises(ValueError, match=what):
        least_squares(lambda x: x - 1.0, x0, lambda x: np.eye(1), lo, hi)
