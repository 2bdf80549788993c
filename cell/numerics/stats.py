"""Distribution functions the diagnosis and the calibration need, without importing
``scipy.stats`` (its import is most of the start-up of every ``cellctl diagnose``).
Scalar, pure Python on :mod:`math`; checked against scipy in ``tests/cell/test_stats.py``.

* :func:`chi2_sf`, :func:`chi2_isf`, :func:`chi2_ppf`: chi-square upper tail, its inverse
  and the quantile, from the regularised incomplete gamma function (series below
  ``x < a + 1``, Lentz continued fraction above; Numerical Recipes §6.2). The inverses
  start from Wilson–Hilferty (or the small-x power law when that start is not positive)
  and take safeguarded Newton steps on the log of the smaller tail in ``ln x``, so that
  p down to 1e-300 and quantiles down to 1e-300 keep their relative accuracy.
* :func:`f_sf`, :func:`t_sf`, :func:`t_ppf`: Fisher F upper tail, Student t upper tail and
  exact t quantile, from the regularised incomplete beta function (continued fraction,
  Numerical Recipes §6.4); :func:`t_ppf` is Newton on the smaller tail from
  :func:`t_quantile`.
* :func:`t_quantile`: Student t quantile, the cheap approximation the chain fit uses;
  closed forms for 1 and 2 degrees of freedom, the Cornish–Fisher expansion (Abramowitz &
  Stegun 26.7.5) beyond, which is within 4·10⁻³ of the exact value from 3 degrees of
  freedom on (3·10⁻⁴ from 5).
* :func:`wilcoxon_greater`: one-sided Wilcoxon signed-rank p-value that paired
  differences are shifted above zero; exact (by counting) up to 30 pairs without ties,
  normal approximation with tie and continuity corrections beyond.
* :func:`median`: ``numpy.median``'s value by partition, without the import of
  ``numpy.ma`` that ``numpy.median`` pays on its first call (about 8 ms of a diagnosis);
  :func:`distinct`: ``numpy.unique``'s values without it (numpy 2 imports ``numpy.ma``
  on a plain ``numpy.unique`` to ask whether the array is masked).
* :func:`normal_cdf`, :func:`normal_ppf`: ``statistics.NormalDist()``'s ``cdf`` and
  ``inv_cdf``, the same expression and the same C quantile function, without importing
  :mod:`statistics` (it loads random, fractions and decimal, about 4 ms of a diagnosis).
"""
from __future__ import annotations

import math

import numpy as np

try:
    from _statistics import _normal_dist_inv_cdf     # what NormalDist.inv_cdf calls
except ImportError:                                   # a Python built without it
    from statistics import _normal_dist_inv_cdf

EXACT_MAX = 30
_EPS = 1e-15
_TINY = 1e-300
_MAX_TERMS = 100_000
_SQRT2 = math.sqrt(2.0)


def normal_cdf(x: float) -> float:
    """P(Z ≤ x) of the standard normal, as ``NormalDist().cdf(x)`` computes it."""
    return 0.5 * (1.0 + math.erf(x / _SQRT2))


def normal_ppf(p: float) -> float:
    """The standard normal's quantile ``p`` (0 < p < 1; else ValueError), as
    ``NormalDist().inv_cdf(p)`` computes it."""
    if p <= 0.0 or p >= 1.0:
        raise ValueError("p must be in the range 0.0 < p < 1.0")
    return _normal_dist_inv_cdf(p, 0.0, 1.0)


def _gamma_prefix(a: float, x: float) -> float:
    """``x^a e^-x / Γ(a)``, in logs (a up to thousands)."""
    return math.exp(a * math.log(x) - x - math.lgamma(a))


def _gamma_series(a: float, x: float) -> float:
    """Regularised lower incomplete gamma P(a, x) by its series (good for x < a + 1)."""
    ap, term = a, 1.0 / a
    total = term
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * _gamma_prefix(a, x)


def _gamma_cf(a: float, x: float) -> float:
    """Regularised upper incomplete gamma Q(a, x) by its continued fraction (x ≥ a + 1)."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * _gamma_prefix(a, x)


def _gamma_tails(a: float, x: float) -> tuple[float, float]:
    """(P(a, x), Q(a, x)); the one not computed directly is 1 minus the other."""
    if x <= 0.0:
        return 0.0, 1.0
    if math.isinf(x):
        return 1.0, 0.0
    if x < a + 1.0:
        p = _gamma_series(a, x)
        return p, 1.0 - p
    q = _gamma_cf(a, x)
    return 1.0 - q, q


def chi2_sf(x: float, dof: float) -> float:
    """P(X > x) for X chi-square with ``dof`` > 0 degrees of freedom."""
    return _gamma_tails(0.5 * dof, 0.5 * x)[1]


def chi2_cdf(x: float, dof: float) -> float:
    """P(X ≤ x) for X chi-square with ``dof`` > 0 degrees of freedom."""
    return _gamma_tails(0.5 * dof, 0.5 * x)[0]


def _chi2_logpdf(x: float, dof: float) -> float:
    a = 0.5 * dof
    return (a - 1.0) * math.log(x) - 0.5 * x - a * math.log(2.0) - math.lgamma(a)


def _solve_log_tail(tail, log_density, target: float, upper: bool, u0: float) -> float:
    """``x`` with ``tail(x) == target`` (``tail`` the upper tail if ``upper``, else the
    lower), by Newton on ``ln tail`` against ``u = ln x`` from ``u0``, kept inside a
    bracket that bisection narrows when a step would leave it."""
    log_t = math.log(target)
    lo, hi = -math.inf, math.inf
    u = u0
    for _ in range(200):
        x = math.exp(u)
        t = tail(x)
        if t <= 0.0:
            g, slope = -math.inf, None
        else:
            g = math.log(t) - log_t
            slope = (-1.0 if upper else 1.0) * math.exp(log_density(x) + u) / t
        if g == 0.0:
            return x
        if (g > 0.0) == upper:      # tail too heavy: x must grow (upper) / shrink (lower)
            lo = u
        else:
            hi = u
        step_ok = slope is not None and slope != 0.0 and math.isfinite(slope)
        new = u - g / slope if step_ok else math.nan
        if not (lo < new < hi):
            if math.isinf(lo):
                new = hi - max(1.0, abs(hi))
            elif math.isinf(hi):
                new = lo + max(1.0, abs(lo))
            else:
                new = 0.5 * (lo + hi)
        if abs(new - u) <= 1e-15 * max(1.0, abs(u)):
            return math.exp(new)
        u = new
    return math.exp(u)


def _chi2_inverse(p_lower: float, p_upper: float, dof: float) -> float:
    if not (0.0 <= p_lower <= 1.0 and 0.0 <= p_upper <= 1.0 and dof > 0):
        return math.nan
    if p_lower == 0.0:
        return 0.0
    if p_upper == 0.0:
        return math.inf
    a = 0.5 * dof
    upper = p_upper < p_lower
    z = -normal_ppf(p_upper) if upper else normal_ppf(p_lower)
    c = 2.0 / (9.0 * dof)
    base = 1.0 - c + z * math.sqrt(c)
    x0 = dof * base ** 3 if base > 0.3 else 0.0
    small = 2.0 * math.exp((math.log(p_lower) + math.lgamma(a + 1.0)) / a)   # P ~ (x/2)^a/Γ(a+1)
    if x0 <= 0.0 or (not upper and small < x0):
        x0 = small
    if upper:
        return _solve_log_tail(lambda x: chi2_sf(x, dof), lambda x: _chi2_logpdf(x, dof),
                               p_upper, True, math.log(x0))
    return _solve_log_tail(lambda x: chi2_cdf(x, dof), lambda x: _chi2_logpdf(x, dof),
                           p_lower, False, math.log(x0))


def chi2_isf(p: float, dof: float) -> float:
    """``x`` with P(X > x) = ``p`` for X chi-square with ``dof`` degrees of freedom."""
    return _chi2_inverse(1.0 - p, p, dof)


def chi2_ppf(p: float, dof: float) -> float:
    """``x`` with P(X ≤ x) = ``p`` for X chi-square with ``dof`` degrees of freedom."""
    return _chi2_inverse(p, 1.0 - p, dof)


def _beta_cf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta (Numerical Recipes ``betacf``)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c = 1.0
    d = 1.0 - qab * x / qap
    d = _TINY if abs(d) < _TINY else d
    d = 1.0 / d
    h = d
    for m in range(1, _MAX_TERMS):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = _TINY if abs(d) < _TINY else d
        c = 1.0 + aa / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = _TINY if abs(d) < _TINY else d
        c = 1.0 + aa / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h


def _beta_reg_pair(a: float, b: float, x: float, y: float) -> float:
    """I_x(a, b) with ``y`` = 1 − x given separately (no cancellation when x is near 1)."""
    if x <= 0.0:
        return 0.0
    if y <= 0.0:
        return 1.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
                     + a * math.log(x) + b * math.log(y))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _beta_cf(a, b, x) / a
    return 1.0 - front * _beta_cf(b, a, y) / b


def f_sf(x: float, dfn: float, dfd: float) -> float:
    """P(F > x) for F Fisher-distributed with ``dfn``, ``dfd`` degrees of freedom."""
    if x <= 0.0:
        return 1.0
    if math.isinf(x):
        return 0.0
    den = dfd + dfn * x
    return _beta_reg_pair(0.5 * dfd, 0.5 * dfn, dfd / den, dfn * x / den)


def t_sf(t: float, dof: float) -> float:
    """P(T > t) for T Student-t with ``dof`` > 0 degrees of freedom."""
    if math.isinf(t):
        return 0.0 if t > 0 else 1.0
    t2 = t * t
    den = dof + t2
    half = 0.5 * _beta_reg_pair(0.5 * dof, 0.5, dof / den, t2 / den)
    return half if t > 0 else 1.0 - half


def _t_logpdf(t: float, dof: float) -> float:
    return (math.lgamma(0.5 * (dof + 1.0)) - math.lgamma(0.5 * dof)
            - 0.5 * math.log(dof * math.pi) - 0.5 * (dof + 1.0) * math.log1p(t * t / dof))


def t_ppf(p: float, dof: float) -> float:
    """``t`` with P(T ≤ t) = ``p`` (0 < p < 1) for T Student-t with ``dof`` > 0 degrees of
    freedom; about 1e-12 relative up to 10⁴ dof, 1e-9 at 10⁶. :func:`t_quantile` is the
    chain fit's cheaper approximation."""
    if not (0.0 < p < 1.0 and dof > 0):
        return {0.0: -math.inf, 1.0: math.inf}.get(p, math.nan)
    if p == 0.5:
        return 0.0
    sign, q = (1.0, 1.0 - p) if p > 0.5 else (-1.0, p)   # q, the smaller tail, is exact
    if dof == 1:
        return sign / math.tan(math.pi * q)
    start = t_quantile(1.0 - q, max(int(dof), 1))
    start = start if start > 0 and math.isfinite(start) else 1.0
    return sign * _solve_log_tail(lambda x: t_sf(x, dof), lambda x: _t_logpdf(x, dof),
                                  q, True, math.log(start))


def t_quantile(p: float, dof: int) -> float:
    """Quantile ``p`` (0 < p < 1) of Student's t with ``dof`` ≥ 1 degrees of freedom."""
    if dof == 1:
        return math.tan(math.pi * (p - 0.5))
    if dof == 2:
        return (2 * p - 1) / math.sqrt(2 * p * (1 - p))
    z = normal_ppf(p)
    v = float(dof)
    g1 = (z ** 3 + z) / 4
    g2 = (5 * z ** 5 + 16 * z ** 3 + 3 * z) / 96
    g3 = (3 * z ** 7 + 19 * z ** 5 + 17 * z ** 3 - 15 * z) / 384
    g4 = (79 * z ** 9 + 776 * z ** 7 + 1482 * z ** 5 - 1920 * z ** 3 - 945 * z) / 92160
    return z + g1 / v + g2 / v ** 2 + g3 / v ** 3 + g4 / v ** 4


def _ranks(a: np.ndarray) -> np.ndarray:
    """Average ranks (1-based) of ``a``."""
    order = np.argsort(a, kind="stable")
    s = a[order]
    first = np.r_[True, s[1:] != s[:-1]] if len(s) else np.zeros(0, bool)
    starts = np.flatnonzero(first)
    ends = np.r_[starts[1:], len(s)] - 1                 # each run of ties: its first, last
    r = np.empty(len(a))
    r[order] = ((starts + ends) / 2 + 1)[np.cumsum(first) - 1]
    return r


def wilcoxon_greater(diff) -> float:
    """One-sided p that the paired differences ``diff`` are shifted above zero (zeros
    dropped, Wilcoxon's rule). 1.0 when nothing is left."""
    d = np.asarray(diff, dtype=float)
    d = d[d != 0]
    n = len(d)
    if n == 0:
        return 1.0
    r = _ranks(np.abs(d))
    w = float(r[d > 0].sum())
    if n <= EXACT_MAX and np.all(r == np.round(r)) and len(set(r)) == n:
        counts = np.zeros(n * (n + 1) // 2 + 1)
        counts[0] = 1.0
        for k in range(1, n + 1):
            counts[k:] = counts[k:] + counts[:-k].copy()
        return float(counts[int(w):].sum() / counts.sum())
    mean = n * (n + 1) / 4
    _, t = np.unique(r, return_counts=True)
    var = n * (n + 1) * (2 * n + 1) / 24 - float(np.sum(t ** 3 - t)) / 48
    z = (w - mean - 0.5) / math.sqrt(var) if var > 0 else 0.0
    return 1.0 - normal_cdf(z)


def distinct(v, axis: int | None = None) -> np.ndarray:
    """``numpy.unique(v, axis=axis)``: the sorted distinct values (rows along ``axis`` 0),
    by the path of ``numpy.unique`` that does not import ``numpy.ma``."""
    return np.unique(v, axis=axis, return_inverse=True)[0]


def median(v, axis: int | None = None):
    """The median of ``v`` (all values, or along ``axis``), equal to ``numpy.median``'s:
    the middle value, or the mean of the two middle ones; NaN where a NaN is among the
    values, NaN for no values."""
    a = np.asarray(v, dtype=float)
    if axis is None:
        a, axis = a.ravel(), 0
    n = a.shape[axis]
    if n == 0:
        shape = a.shape[:axis] + a.shape[axis + 1:]
        return np.full(shape, np.nan) if shape else math.nan
    k = n // 2
    part = np.partition(a, (k - 1, k) if n % 2 == 0 else k, axis=axis)
    mid = part.take(k, axis=axis)
    if n % 2 == 0:
        mid = (part.take(k - 1, axis=axis) + mid) / 2.0
    bad = np.isnan(a).any(axis=axis)
    mid = np.where(bad, np.nan, mid)
    return float(mid) if np.ndim(mid) == 0 else mid
