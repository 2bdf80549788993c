"""diagnosis.noise.neighbours: the exact k-nearest search that replaced scipy's cKDTree in
the noise estimate and the outlier flags, held to cKDTree (the reference here only) on
data without ties, in one dimension (path time) and two (joint space)."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from cell.diagnosis.noise import neighbours


def reference(coords, k, use):
    idx = np.flatnonzero(use)
    _, nb = cKDTree(coords[idx]).query(coords, k=k + 1)
    nb = idx[nb]
    own = nb[:, 0] == np.arange(len(coords))
    return np.where(own[:, None], np.roll(nb, -1, axis=1), nb)[:, :k]


@pytest.mark.parametrize("d, n", [(1, 2000), (1, 20), (2, 300), (2, 2500)])
@pytest.mark.parametrize("k", [8, 16])
def test_same_neighbours_as_a_kd_tree(d, n, k):
    rng = np.random.default_rng(d * n + k)
    coords = rng.normal(size=(n, d))
    use = rng.random(n) > 0.1
    np.testing.assert_array_equal(neighbours(coords, k, use), reference(coords, k, use))
    np.testing.assert_array_equal(neighbours(coords, k), reference(coords, k, np.ones(n, bool)))


def test_the_row_itself_is_left_out_even_among_duplicates():
    coords = np.array([[0.0, 0.0]] * 4 + [[1.0, 0.0], [2.0, 0.0]])
    nb = neighbours(coords, 3)
    for i, row in enumerate(nb):
        assert i not in row and len(set(row)) == 3
    assert set(nb[0]) == {1, 2, 3}


@pytest.mark.parametrize("layout", ["lattice", "clusters", "line", "outlier"])
def test_the_grid_search_finds_the_rows_and_order_of_comparing_every_pair(layout):
    # ties broken by position as the pairwise search breaks them: on a lattice of few
    # values most distances tie, and duplicates are distance 0
    from cell.diagnosis.noise import _nearest_dense, _nearest_grid
    rng = np.random.default_rng(5)
    coords = {"lattice": rng.integers(0, 6, (700, 2)).astype(float),
              "clusters": np.repeat(rng.normal(size=(40, 2)) * 30, 20, axis=0)
              + rng.normal(size=(800, 2)) * 0.01,
              "line": np.c_[np.zeros(400), np.arange(400.0)],
              "outlier": np.r_[rng.normal(size=(400, 2)), [[1e6, -1e6]]]}[layout]
    for m in (5, 9, 17):
        for query in (coords, coords[::3] + 0.37):
            np.testing.assert_array_equal(_nearest_grid(coords, query, m),
                                          _nearest_dense(coords, query, m))


def test_squared_distances_gathered_by_coordinate_are_those_of_the_gathered_rows():
    # the grid search gathers each coordinate alone: the same bits as the rows' distances,
    # for pairs of index arrays and for a column of queries against a block of rows
    from cell.diagnosis.noise import _sq_dist_at

    def _sq_dist(query, data):               # the distances of rows gathered whole
        return (query[..., 0] - data[..., 0]) ** 2 + (query[..., 1] - data[..., 1]) ** 2
    rng = np.random.default_rng(5)
    q, d = rng.normal(0, 90, (300, 2)), rng.normal(0, 90, (500, 2))
    qi, di = rng.integers(0, 300, 4000), rng.integers(0, 500, 4000)
    assert np.array_equal(_sq_dist_at(q, qi, d, di), _sq_dist(q[qi], d[di]))
    block = rng.integers(0, 500, (300, 18))
    assert np.array_equal(_sq_dist_at(q, np.arange(300)[:, None], d, block),
                          _sq_dist(q[:, None, :], d[block]))
