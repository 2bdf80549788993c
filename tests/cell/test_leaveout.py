"""The one leave-one-fold-out yardstick of the diagnosis (cell.diagnosis.leaveout), held
against refitting with each fold really left out."""
import math

import numpy as np
import pytest

from cell.diagnosis import leaveout


def _problem(seed: int, points: int = 40, dims: int = 3, cols: int = 5, folds: int = 8):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(points * dims, cols)) * rng.uniform(0.1, 10.0, cols)
    r = rng.normal(size=points * dims)
    group = rng.integers(0, folds, points)
    group[:folds] = np.arange(folds)                     # every fold holds a point
    return J, r, group, folds


def _refit(J, r, group, g, cols, dims):
    """The held-out residual of fold ``g`` by a real refit on the other folds."""
    rows = np.repeat(group, dims)
    train, test = rows != g, rows == g
    A = J[:, cols]
    beta = np.linalg.lstsq(A[train], r[train], rcond=None)[0] if len(cols) else np.zeros(0)
    return r[test] - A[test] @ beta


@pytest.mark.parametrize("dims,per", [(3, "point"), (2, "scalar"), (2, "point")])
def test_each_fold_error_is_a_real_refit_without_the_fold(dims, per):
    J, r, group, F = _problem(1, dims=dims)
    folds = leaveout.Folds(leaveout.scaled(J)[0], r, group, F, dims=dims, per=per)
    for cols in ([], [0], [1, 3], [0, 1, 2, 3, 4]):
        total, errors = folds.loo(cols)
        Js = leaveout.scaled(J)[0]
        want = []
        for g in range(F):
            e = _refit(Js, r, group, g, cols, dims)
            size = len(e) / dims if per == "point" else len(e)
            want.append(float(e @ e) / size)
        assert np.allclose(errors, want, rtol=1e-9, atol=1e-12)
        pts = np.bincount(group, minlength=F)
        assert total == pytest.approx(math.sqrt(sum(w * (n if per == "point" else n * dims)
                                                    for w, n in zip(want, pts)) / len(group)))


def test_a_nuisance_eliminated_once_gives_the_same_errors_as_the_full_solve():
    J, r, group, F = _problem(2)
    Js = leaveout.scaled(J)[0]
    plain = leaveout.Folds(Js, r, group, F)
    based = leaveout.Folds(Js, r, group, F, base=2)
    for cols in ([0, 1], [0, 1, 2], [0, 1, 3, 4]):
        assert np.allclose(based.loo(cols)[1], plain.loo(cols)[1], rtol=1e-9)
    batch = based.loo_each([[0, 1, 2], [0, 1, 3], [0, 1, 4]])
    for (t, e), c in zip(batch, ([0, 1, 2], [0, 1, 3], [0, 1, 4])):
        assert np.allclose(e, plain.loo(c)[1], rtol=1e-9)


@pytest.mark.parametrize("folds", [8, 40])
def test_at_the_solution_the_hat_matrix_form_agrees_with_the_folds(folds):
    # 8 folds of about 5 points (15 rows over 5 columns: the fold taken out of the normal
    # equations), 40 of one point (3 rows: I − H solved over them)
    J, r, group, F = _problem(3, folds=folds)
    Js = leaveout.scaled(J)[0]
    res = r - Js @ np.linalg.lstsq(Js, r, rcond=None)[0]
    total, per, _, _ = leaveout.at_solution(J, res, group, F)
    t2, p2 = leaveout.Folds(Js, res, group, F).loo(list(range(J.shape[1])))
    assert np.allclose(per, p2, rtol=1e-8)
    assert total == pytest.approx(t2, rel=1e-8)


def test_a_fold_that_alone_sees_a_column_fails_without_a_ridge_and_stays_finite_with_one():
    J, r, group, F = _problem(4, cols=3)
    rows = np.repeat(group, 3)
    J[:, 2] = np.where(rows == 0, J[:, 2], 0.0)          # only fold 0 moves column 2
    Js = leaveout.scaled(J)[0]
    assert math.isinf(leaveout.Folds(Js, r, group, F).loo([0, 1, 2])[0])
    total, per = leaveout.Folds(Js, r, group, F, ridge=1e-10).loo([0, 1, 2])
    assert np.all(np.isfinite(per)) and math.isfinite(total)


@pytest.mark.parametrize("base", [0, 2])
def test_folds_of_very_unequal_size_keep_gram_pieces_and_agree_with_real_refits(base):
    # 30 folds of one point and 2 of 60 (a measured move's samples beside static poses):
    # padding would multiply the rows ~40-fold, so the folds keep JᵀJ, Jᵀr and rᵀr only
    rng = np.random.default_rng(9)
    dims, cols = 2, 6
    group = np.r_[np.arange(30), np.full(60, 30), np.full(60, 31)]
    J = rng.normal(size=(len(group) * dims, cols)) * rng.uniform(0.1, 10.0, cols)
    r = rng.normal(size=len(group) * dims)
    Js = leaveout.scaled(J)[0]
    folds = leaveout.Folds(Js, r, group, 32, base=base, dims=dims)
    assert folds.gram and folds.n_folds == 32
    subsets = [[0, 1, 2], [0, 1, 3], [0, 1, 5]]
    for c, (total, per) in zip(subsets, folds.loo_each(subsets)):
        want = [np.sum(_refit(Js, r, group, g, c, dims) ** 2) / np.sum(group == g) for g in range(32)]
        assert np.allclose(per, want, rtol=1e-8, atol=1e-12), c
        one_total, one_per = folds.loo(c)
        assert total == pytest.approx(one_total, rel=1e-9) and np.allclose(per, one_per, rtol=1e-9)
    want = [np.sum(_refit(Js, r, group, g, [0, 1], dims) ** 2) / np.sum(group == g) for g in range(32)]
    assert np.allclose(folds.loo([0, 1])[1], want, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("singular_base", [False, True])
def test_subsets_solved_in_one_batch_without_an_eliminated_base_agree_with_real_refits(singular_base):
    # base 0 (a planar campaign read as a chain: nothing to register), or a base whose
    # block is singular in a fold so that nothing could be eliminated: the batch still holds
    J, r, group, F = _problem(5, dims=2)
    if singular_base:
        J[:, 1] = J[:, 0]
    Js = leaveout.scaled(J)[0]
    folds = leaveout.Folds(Js, r, group, F, base=2 if singular_base else 0, dims=2)
    assert folds.base == 0
    subsets = [[2, 3], [2, 4], [3, 4]]
    for c, (total, per) in zip(subsets, folds.loo_each(subsets)):
        want = [np.sum(_refit(Js, r, group, g, c, 2) ** 2) / np.sum(group == g) for g in range(F)]
        assert np.allclose(per, want, rtol=1e-9, atol=1e-12), c
        assert (total, list(per)) == (folds.loo(c)[0], list(folds.loo(c)[1]))


@pytest.mark.parametrize("dims", [1, 2, 3])
def test_folds_of_one_point_each_take_the_hat_matrix_route_and_agree_with_real_refits(dims):
    # every pose its own fold (a planar campaign's static poses and move samples read as a
    # chain): the fit on all folds once, then (I − H_gg)⁻¹ e_g per point
    J, r, _, _ = _problem(6, points=30, dims=dims)
    group = np.random.default_rng(6).permutation(30)
    Js = leaveout.scaled(J)[0]
    folds = leaveout.Folds(Js, r, group, 30, dims=dims)
    assert folds.points is not None and folds.M is None      # no fold-out system is formed
    subsets = [[0, 2], [1, 2], [3, 4]]
    for c, (total, per) in zip(subsets, folds.loo_each(subsets)):
        want = [np.sum(_refit(Js, r, group, g, c, dims) ** 2) for g in range(30)]
        assert np.allclose(per, want, rtol=1e-9, atol=1e-12), c
        one_total, one_per = folds.loo(c)
        assert total == pytest.approx(one_total, rel=1e-12) and np.allclose(per, one_per, rtol=1e-12)
    assert np.allclose(folds.loo([])[1], [np.sum(r.reshape(30, dims)[group == g] ** 2) for g in range(30)])
    assert np.array_equal(folds.loo_each([[]])[0][1], folds.loo([])[1])


def test_the_small_solver_agrees_with_lapack_and_refuses_an_exactly_singular_system():
    rng = np.random.default_rng(7)
    for d in (1, 2, 3):
        M, v = rng.normal(size=(50, d, d)) + 3 * np.eye(d), rng.normal(size=(50, d))
        assert np.allclose(leaveout.solve_small(M, v), np.linalg.solve(M, v[..., None])[..., 0],
                           rtol=1e-12, atol=1e-14)
    with pytest.raises(np.linalg.LinAlgError):
        leaveout.solve_small(np.array([[[1.0, 2.0], [2.0, 4.0]]]), np.ones((1, 2)))


@pytest.mark.parametrize("shape", [(5000,), (20, 300), (1,), (0,), (3,)])
def test_squares_over_a_short_last_axis_have_the_bits_of_numpys_sum(shape):
    # the folds' sums of squares: every width up to 13, values over many magnitudes (so
    # any other order of adding would round differently), contiguous, strided and
    # Fortran-ordered, against the np.sum they replace
    from cell.numerics.sums import squares_last
    rng = np.random.default_rng(7)
    for width in range(14):
        x = rng.normal(size=shape + (width,)) * np.exp(rng.normal(size=shape + (width,)) * 5)
        for y in (x, x[::2], np.asfortranarray(x)):
            want = np.sum(y * y, axis=-1)
            got = squares_last(y)
            assert got.shape == want.shape and np.array_equal(got, want), (shape, width)
    assert squares_last(np.array([3.0, 4.0])) == 25.0        # 1-D: one number, as np.sum


@pytest.mark.parametrize("m", [1, 2, 3, 12])
def test_a_stack_times_one_matrix_as_one_product_has_the_bits_of_the_stacked_product(m):
    # the leave-out's (folds, rows, k) @ (k, k) products: one BLAS call for the stack
    # must round as numpy's call per matrix does, for every k the screening uses,
    # contiguous and strided (a column subset of a wider design)
    from cell.numerics.stacks import times_shared
    rng = np.random.default_rng(13)
    for k in range(1, 16):
        for stack in [(1,), (7,), (3, 300), (1094,)]:
            A = rng.normal(size=stack + (m, k + 2)) * np.exp(rng.normal(size=stack + (m, k + 2)) * 3)
            B = rng.normal(size=(k, k))
            for a in (A[..., :k], np.ascontiguousarray(A[..., 1:k + 1])):
                got = times_shared(a, B)
                assert got.shape == a.shape[:-1] + (k,) and np.array_equal(got, a @ B), (k, stack)


@pytest.mark.parametrize("dims", [2, 3])
def test_at_solution_given_an_earlier_calls_inverse_answers_as_it_would_alone(dims):
    # a fit's per-pose leave-out after its per-place one reuses that call's (J'J)^-1 and
    # scales: the same bits as finding them again, a zero column among them
    J, r, group, F = _problem(4, dims=dims)
    J[:, 2] = 0.0
    first = leaveout.at_solution(J, r, group, F, dims=dims)
    poses = np.arange(len(group))
    alone = leaveout.at_solution(J, r, poses, len(group), dims=dims)
    given = leaveout.at_solution(J, r, poses, len(group), dims=dims, known=first[2:])
    assert given[0] == alone[0]
    for a, b in zip(given[1:], alone[1:]):
        assert np.array_equal(a, b)
