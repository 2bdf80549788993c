"""cell.chain.stats against scipy.stats (the reference it avoids importing at run time)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from cell.chain.stats import t_quantile, wilcoxon_greater


@pytest.mark.parametrize("dof", [1, 2, 3, 5, 10, 25, 100])
def test_t_quantile(dof):
    tol = 4e-3 if dof < 5 else 3e-4
    assert t_quantile(0.975, dof) == pytest.approx(stats.t.ppf(0.975, dof), abs=tol)


@pytest.mark.parametrize("n", [5, 12, 26, 30])
def test_wilcoxon_exact_matches_scipy(n):
    d = np.random.default_rng(n).normal(0.3, 1.0, n)
    assert wilcoxon_greater(d) == pytest.approx(stats.wilcoxon(d, alternative="greater").pvalue, rel=1e-9)


def test_wilcoxon_large_samples_and_degenerate_input():
    d = np.random.default_rng(1).normal(0.3, 1.0, 80)
    assert wilcoxon_greater(d) == pytest.approx(stats.wilcoxon(d, alternative="greater").pvalue, abs=2e-3)
    assert wilcoxon_greater(np.zeros(5)) == 1.0
    assert wilcoxon_greater(-np.arange(1, 20.0)) > 0.99
