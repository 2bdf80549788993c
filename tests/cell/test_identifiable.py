"""The one identifiability rule of the calibrations and the diagnosis
(cell/kinematics/identifiable.py)."""
import numpy as np

from cell.kinematics import identifiable as ident


def _design(seed: int = 0, rows: int = 60):
    rng = np.random.default_rng(seed)
    a, b, c = rng.normal(size=(3, rows))
    return np.column_stack([a, 1000.0 * b, a + 2.0 * b * 1000.0, np.zeros(rows), c])


def test_a_column_in_the_span_of_those_kept_before_it_is_left_out_whatever_its_units():
    J = _design()
    span = ident.greedy(J, range(5))
    assert span.kept == [0, 1, 4]                 # col 2 = col 0 + 2·col 1, col 3 is zero
    assert np.isnan(span.left[3]) and span.left[2] < ident.STRUCTURAL_TOL
    assert abs(span.left[0] - 1.0) < 1e-12 and 0.0 < span.left[4] <= 1.0 + 1e-12


def test_priority_decides_which_of_two_alike_columns_is_kept():
    J = _design()
    assert ident.greedy(J, [2, 1, 0, 4]).kept == [2, 1, 4]   # now col 0 is the sum's part


def test_a_nuisance_absorbs_what_it_spans():
    J = _design()
    Q0 = ident.nuisance_basis(J[:, [0]])
    span = ident.greedy(J, [1, 2, 4], nuisance=Q0)
    assert span.kept == [1, 4] and span.outside(J[:, 0] / np.linalg.norm(J[:, 0]), span.Q0) < 1e-12


def test_a_nearly_repeated_column_is_kept_only_above_the_tolerance():
    J = _design()
    J[:, 2] += 1e-5 * np.linalg.norm(J[:, 2]) * np.random.default_rng(1).normal(size=len(J)) / np.sqrt(len(J))
    assert 2 in ident.greedy(J, range(5), tol=1e-6).kept      # the diagnosis: structurally seen
    assert 2 not in ident.greedy(J, range(5), tol=1e-4).kept  # the calibration: too weak to solve


def test_greedy_gives_each_visited_column_at_unit_norm_as_its_caller_would_divide_it():
    # identifiability names what absorbs a dropped column from these unit columns: they
    # must be the column over its norm, bit for bit; zero and unvisited columns have none
    rng = np.random.default_rng(4)
    J = rng.normal(size=(40, 6)) * np.exp(rng.normal(size=6) * 3)
    J[:, 3] = 0.0
    J[:, 4] = J[:, 0] + J[:, 1]
    span = ident.greedy(J, [5, 4, 3, 0, 1])
    assert sorted(span.unit) == [0, 1, 4, 5]
    for j, v in span.unit.items():
        assert np.array_equal(v, J[:, j] / np.linalg.norm(J[:, j]))
