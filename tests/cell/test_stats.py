"""cell.numerics.stats against scipy.stats (the reference it avoids importing at run time).

Grid: dof 1..20, then 25..400; p from 1e-12 to 1 − 1e-9 (both tails, and the middle).
Tolerances (relative): quantiles 1e-11, tail probabilities 1e-10; the worst seen when
written was 2e-14 for the chi-square quantiles, 3e-13 for the t quantile and 1e-12 for
the tails. The tails are checked at scipy's
own quantile for ``p`` and compared with ``p``: at p = 1 − 1e-9, ``scipy.stats.f.sf``
rounds to 1.0 where ``1 - f.cdf`` and cell.numerics.stats keep the 1e-9."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from cell.numerics.stats import (chi2_isf, chi2_ppf, chi2_sf, f_sf, t_ppf, t_quantile, t_sf,
                        wilcoxon_greater)

DOFS = list(range(1, 21)) + [25, 30, 40, 50, 75, 100, 150, 200, 250, 300, 350, 400]
PS = [1e-12, 1e-10, 1e-8, 1e-6, 1e-4, 1e-3, 0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9,
      0.95, 0.99, 0.999, 1 - 1e-6, 1 - 1e-9]
Q_TOL = 1e-11
P_TOL = 1e-10


@pytest.mark.parametrize("dof", DOFS)
def test_chi2_against_scipy(dof):
    for p in PS:
        assert chi2_isf(p, dof) == pytest.approx(stats.chi2.isf(p, dof), rel=Q_TOL)
        assert chi2_ppf(p, dof) == pytest.approx(stats.chi2.ppf(p, dof), rel=Q_TOL)
        assert chi2_sf(stats.chi2.isf(p, dof), dof) == pytest.approx(p, rel=P_TOL)


@pytest.mark.parametrize("dof", DOFS)
def test_t_against_scipy(dof):
    for p in PS:
        assert t_ppf(p, dof) == pytest.approx(stats.t.ppf(p, dof), rel=Q_TOL, abs=1e-300)
        assert t_sf(stats.t.isf(p, dof), dof) == pytest.approx(p, rel=P_TOL)


@pytest.mark.parametrize("dfn", [1, 2, 3, 5, 10, 50, 400])
def test_f_sf_against_scipy(dfn):
    for dfd in DOFS[::3]:
        for p in PS:
            assert f_sf(stats.f.isf(p, dfn, dfd), dfn, dfd) == pytest.approx(p, rel=P_TOL)


def test_edges():
    assert chi2_sf(0.0, 3) == 1.0 and chi2_sf(np.inf, 3) == 0.0
    assert chi2_isf(1.0, 3) == 0.0 and chi2_isf(0.0, 3) == np.inf
    assert f_sf(0.0, 2, 7) == 1.0 and t_ppf(0.5, 4) == 0.0
    assert t_sf(-2.0, 6) == pytest.approx(stats.t.cdf(2.0, 6), rel=P_TOL)


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


def test_median_is_numpys_without_loading_numpy_ma():
    import subprocess
    import sys

    from cell.numerics.stats import median
    rng = np.random.default_rng(5)
    for n in (1, 2, 3, 10, 11, 64):
        x = rng.normal(size=(n, 3))
        assert median(x[:, 1]) == np.median(x[:, 1])
        assert np.array_equal(median(x, axis=0), np.median(x, axis=0))
    assert np.isnan(median([1.0, np.nan, 3.0])) and np.isnan(median([]))
    code = ("import sys, numpy as np; from cell.numerics.stats import median; median(np.arange(6.0)); "
            "print('numpy.ma' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_ranks_average_ties_as_scipy_does():
    from cell.numerics.stats import _ranks
    rng = np.random.default_rng(4)
    for n in (0, 1, 7, 50, 300):
        a = np.round(rng.normal(size=n), 1)            # many ties
        assert np.array_equal(_ranks(a), stats.rankdata(a)), n


def test_normal_cdf_and_ppf_are_normaldists_to_the_bit_without_importing_statistics():
    import math
    import subprocess
    import sys
    from statistics import NormalDist

    from cell.numerics.stats import normal_cdf, normal_ppf
    rng = np.random.default_rng(11)
    xs = [0.0, -0.0, 1e-300, -40.0, 40.0, math.inf, -math.inf] + list(rng.normal(0, 4, 2000))
    for x in xs:
        assert normal_cdf(x) == NormalDist().cdf(x)
    ps = [1e-300, 1e-12, 0.02425, 0.5, 0.97575, 1 - 1e-16] + list(rng.uniform(0, 1, 2000)) \
        + list(10.0 ** -rng.uniform(0, 300, 500))
    for p in ps:
        assert normal_ppf(p) == NormalDist().inv_cdf(p)
    for p in (0.0, 1.0, -0.5, 2.0):
        with pytest.raises(ValueError):
            normal_ppf(p)
    code = "import sys; import cell.numerics.stats; print('statistics' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
