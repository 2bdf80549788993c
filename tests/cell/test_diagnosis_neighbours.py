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
