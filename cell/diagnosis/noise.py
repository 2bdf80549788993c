"""The noise of a static point measurement (repeatability and camera together), from the
data when nobody gives it. Pure numerics.

The point noise σ (per axis) of a planar campaign's report (``noise.estimates``, the v1
figures), and the pieces the diagnosis's own noise (:mod:`.chain.noise`) is made of.
Sources, in the order they are tried:

* ``given``: ``--noise-mm``.
* ``repeats``: poses revisited with the same commanded joints (and, with direction
  columns, the same approach directions): the pooled within-group scatter of the remainder,
  2·(n_g − 1) degrees of freedom per group of n_g visits.
* ``residual``: the remainder's own structure. Two model-free difference estimators, each
  robust (1.4826 × median absolute deviation) and each at most inflated by structure it does
  not cancel, so the smaller is taken:

  - *joint-space neighbours*: every point's remainder predicted by a local plane through its
    :data:`NEIGHBOURS` nearest neighbours in (θ1, θ2) (leave-one-out); the prediction error
    over √(1 + Σw²) (w the plane's weights) has σ per axis when the remainder is noise plus
    anything smooth in joint space;
  - *time order*: differences of consecutive points in time over √2 (cancels what drifts
    slowly: a knock or warm-up between poses).

  A remainder that varies from pose to pose without pattern in joints or time (backlash
  without direction columns, repeatability) counts as noise here: this source can only say
  "the remainder is at least this systematic".
* ``paths``: the path samples' noise (second differences along each move, :mod:`.replay`)
  when the points cannot give one; it lacks the repeatability.

Every estimate also carries a 95 % upper bound, σ·√(dof/χ²_dof(0.05)) (effective dof of
the median-based estimators: 37 % of the values), which the decision uses, so a noise estimated
from few values does not make a gap look systematic.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.numerics.stats import chi2_ppf, distinct, median

NEIGHBOURS = 8
MIN_POINTS = 20
MIN_SIN_THETA2 = 0.15      # nearer the stretched arm the remainder's joint-space image is unusable
MAD_EFFICIENCY = 0.37


@dataclass
class Noise:
    """σ per axis (mm) of a point measurement, its ``source`` (given, repeats, residual,
    paths), ``method`` in words, degrees of freedom ``dof`` and 95 % upper bound."""

    sigma_mm: float
    source: str
    method: str
    dof: float
    upper95_mm: float

    def as_dict(self) -> dict:
        return {"sigma_mm": round(self.sigma_mm, 7), "source": self.source,
                "method": self.method, "dof": round(float(self.dof), 1),
                "upper95_mm": round(self.upper95_mm, 7)}


def upper95(sigma: float, dof: float) -> float:
    """95 % upper confidence bound of a σ estimated with ``dof`` degrees of freedom: σ itself
    for infinitely many (a σ that is given, not estimated), ∞ for none or NaN."""
    if dof == math.inf:
        return float(sigma)
    if not math.isfinite(dof) or dof <= 0:
        return math.inf
    return sigma * math.sqrt(dof / float(chi2_ppf(0.05, dof)))


def mad(v: np.ndarray) -> float:
    """1.4826 × median absolute deviation of all values of ``v``: a robust σ."""
    v = np.asarray(v, float).ravel()
    return 1.4826 * float(median(np.abs(v - median(v))))


def given(sigma_mm: float) -> Noise:
    return Noise(float(sigma_mm), "given", "--noise-mm", math.inf, upper95(sigma_mm, math.inf))


def from_paths(sigma_mm: float | None, n: int) -> Noise | None:
    if sigma_mm is None:
        return None
    dof = MAD_EFFICIENCY * 2 * n
    return Noise(float(sigma_mm), "paths", "second differences along the moves (camera only)",
                 dof, upper95(float(sigma_mm), dof))


def pooled(groups: np.ndarray, values: np.ndarray) -> tuple[float | None, int]:
    """σ per axis of ``values`` (N, d) that should agree within each group (the same pose
    measured again), pooled over the groups: √(Σ_groups Σ ‖x − x̄‖² / Σ d·(n − 1)), groups
    taken in the order of their labels ``groups`` (N,) (a label < 0: the row is in none).
    Groups of one row add nothing. Returns (σ, degrees of freedom), (None, 0) without any
    group of two. Every campaign's revisit noise comes from here."""
    values = np.asarray(values, dtype=float)
    ss, dof = 0.0, 0
    for g in distinct(groups[groups >= 0]):
        x = values[groups == g]
        if len(x) > 1:
            ss += float(np.sum((x - x.mean(axis=0)) ** 2))
            dof += values.shape[1] * (len(x) - 1)
    return (math.sqrt(ss / dof), dof) if dof else (None, 0)


def revisits(key: np.ndarray) -> tuple[np.ndarray, int]:
    """The revisit group of every row of ``key`` (N, k): rows whose keys agree to 10⁻⁶ (the
    same joints, and whatever else must be equal for two visits to agree) share a label,
    a row with no twin gets −1; and the number of groups of two or more. Both diagnoses
    group their revisits here and pool them with :func:`pooled`."""
    _, inv, counts = np.unique(np.round(key, 6), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    return np.where(counts[inv] > 1, inv, -1), int(np.sum(counts > 1))


def repeats(cmd: np.ndarray, dirs: np.ndarray | None, r: np.ndarray) -> Noise | None:
    """Pooled within-group σ of remainder ``r`` (n,2) over poses with equal ``cmd`` (and
    ``dirs``) (:func:`revisits`, :func:`pooled`); None without a revisited pose."""
    labels, n_groups = revisits(cmd if dirs is None else np.column_stack([cmd, dirs]))
    sigma, dof = pooled(labels, r)
    if sigma is None:
        return None
    return Noise(sigma, "repeats", f"scatter of {n_groups} revisited poses", dof,
                 upper95(sigma, dof))


def plane_weights(coords: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """Weights W (n,k) with which the least-squares plane through each point's neighbours
    ``nb`` (n,k) at ``coords`` (n,d) predicts the value at the point: v̂_i = Σ W_ik·v_nb[i,k]
    (normal equations, batched; a tiny ridge on the slopes keeps coincident neighbours
    solvable, the prediction then being their mean)."""
    n, k = nb.shape
    X = np.concatenate([np.ones((n, k, 1)), coords[nb] - coords[:, None, :]], axis=2)
    G = np.einsum("nki,nkj->nij", X, X)
    m = G.shape[1]
    ridge = 1e-9 * np.einsum("nii->n", G)[:, None, None] * np.diag([0.0] + [1.0] * (m - 1))
    e0 = np.zeros((n, m, 1))
    e0[:, 0, 0] = 1.0
    a = np.linalg.solve(G + ridge, e0)[:, :, 0]             # (XᵀX)⁻¹ e₀, symmetric
    return np.einsum("nkj,nj->nk", X, a)


def _nearest(data: np.ndarray, query: np.ndarray, m: int) -> np.ndarray:
    """(nq, m) rows of ``data`` (n,d) nearest each row of ``query`` (nq,d), nearest first,
    Euclidean; equal distances in a fixed order (by position in ``data`` in d > 1, in
    ``data`` sorted in d = 1). Exact: one dimension searches a window of 2m sorted values
    around each query (O(n·m)); two dimensions, beyond a few hundred rows, the grid cells
    within a bound of each query's m-th distance (:func:`_nearest_grid`); more dimensions
    compare every pair (:func:`_nearest_dense`)."""
    n = len(data)
    if data.shape[1] == 1 and n > 2 * m:
        order = np.argsort(data[:, 0], kind="stable")
        v = data[order, 0]
        q = query[:, 0]
        start = np.clip(np.searchsorted(v, q) - m, 0, n - 2 * m)
        win = start[:, None] + np.arange(2 * m)
        pick = np.argsort(np.abs(v[win] - q[:, None]), axis=1, kind="stable")[:, :m]
        return order[np.take_along_axis(win, pick, axis=1)]
    if data.shape[1] == 2 and n > 2 * m and n * len(query) > GRID_PAIRS \
            and np.isfinite(data).all() and np.isfinite(query).all():
        found = _nearest_grid(data, query, m)
        if found is not None:
            return found
    return _nearest_dense(data, query, m)


GRID_PAIRS = 60_000     # fewer query × data pairs: comparing every pair is as quick


def _nearest_dense(data: np.ndarray, query: np.ndarray, m: int) -> np.ndarray:
    """:func:`_nearest` by comparing every pair, a block of queries at a time (O(nq·n)):
    the m smallest squared distances and any tied with them, then a stable sort."""
    n = len(data)
    out = np.empty((len(query), m), dtype=np.intp)
    step = max(1, 2 ** 20 // max(n, 1))
    for b in range(0, len(query), step):
        d2 = np.einsum("qnd->qn", (query[b:b + step, None, :] - data[None, :, :]) ** 2)
        if m < n:
            kth = np.partition(d2, m - 1, axis=1)[:, m - 1:m]
            d2 = np.where(d2 <= kth, d2, np.inf)       # the m nearest, and any tied with them
        out[b:b + step] = np.argsort(d2, axis=1, kind="stable")[:, :m]
    return out


def _sq_dist_at(query: np.ndarray, qi: np.ndarray, data: np.ndarray, di: np.ndarray) -> np.ndarray:
    """Squared 2-D distances between the query rows ``qi`` and the data rows ``di`` (index
    arrays that broadcast), rounded as :func:`_nearest_dense` rounds them (a sum of two
    squares is one rounding), each coordinate gathered alone rather than whole rows."""
    q0, q1, d0, d1 = query[:, 0], query[:, 1], data[:, 0], data[:, 1]
    return (q0[qi] - d0[di]) ** 2 + (q1[qi] - d1[di]) ** 2


def _morton(p: np.ndarray, lo: np.ndarray, span: np.ndarray) -> np.ndarray:
    """Z-order key of 2-D points ``p`` quantised to 16 bits per axis over ``lo`` + ``span``."""
    c = np.clip(((p - lo) / span * 65535).astype(np.int64), 0, 65535)
    key = np.zeros(len(p), np.int64)
    for bit in range(16):
        key |= ((c[:, 0] >> bit) & 1) << (2 * bit) | ((c[:, 1] >> bit) & 1) << (2 * bit + 1)
    return key


def _nearest_grid(data: np.ndarray, query: np.ndarray, m: int) -> np.ndarray | None:
    """:func:`_nearest` in two dimensions, the same rows in the same order as
    :func:`_nearest_dense`: an upper bound ``u`` of each query's m-th squared distance
    (the m-th smallest among its 2m neighbours in x, in y and in Z order: any m rows bound
    it), then every row in the grid cells that the square of half-side √u (widened by
    10⁻⁹) touches, of which those within ``u`` are sorted by (distance, position) as the
    dense search sorts them. None should a query be left with fewer than m rows (it
    cannot: the rows behind its bound are among them)."""
    n, nq = len(data), len(query)
    w = min(n, 2 * m)
    lo, span = data.min(axis=0), np.ptp(data, axis=0)
    span = np.where(span > 0, span, 1.0)
    bound = np.full(nq, np.inf)
    for kd, kq in ((data[:, 0], query[:, 0]), (data[:, 1], query[:, 1]),
                   (_morton(data, lo, span), _morton(query, lo, span))):
        order = np.argsort(kd, kind="stable")
        start = np.clip(np.searchsorted(kd[order], kq) - m, 0, n - w)
        d2 = _sq_dist_at(query, np.arange(nq)[:, None], data, order[start[:, None] + np.arange(w)])
        bound = np.minimum(bound, np.partition(d2, m - 1, axis=1)[:, m - 1])
    half = np.sqrt(bound) * (1 + 1e-9) + 1e-300
    # cells of side h: about two bounds wide, coarser while the queries span many columns
    h = max(2.0 * float(median(half)), float(span.max()) / 2 ** 20)
    top = np.floor(span / h).astype(np.int64)
    while True:
        c_lo = np.maximum(np.floor((query - half[:, None] - lo) / h), 0).astype(np.int64)
        c_hi = np.minimum(np.floor((query + half[:, None] - lo) / h), top).astype(np.int64)
        n_col = np.where(c_hi[:, 1] >= c_lo[:, 1], np.maximum(c_hi[:, 0] - c_lo[:, 0] + 1, 0), 0)
        if n_col.sum() <= 4 * nq:
            break
        h *= 2.0
        top = np.floor(span / h).astype(np.int64)
    ny = int(top[1]) + 1
    cell = np.minimum(np.floor((data - lo) / h).astype(np.int64), top)
    key = cell[:, 0] * ny + cell[:, 1]
    order = np.argsort(key, kind="stable")
    key = key[order]
    # each query's columns, then in each column the rows of its cells (one index range)
    qc = np.repeat(np.arange(nq), n_col)
    col = c_lo[qc, 0] + _ramp(n_col)
    a = np.searchsorted(key, col * ny + c_lo[qc, 1], side="left")
    b = np.searchsorted(key, col * ny + c_hi[qc, 1], side="right")
    qid = np.repeat(qc, b - a)
    idx = order[np.repeat(a, b - a) + _ramp(b - a)]
    d2 = _sq_dist_at(query, qid, data, idx)
    near = d2 <= bound[qid]
    qid, idx, d2 = qid[near], idx[near], d2[near]
    counts = np.bincount(qid, minlength=nq)
    if counts.min() < m:
        return None
    first = np.cumsum(counts) - counts
    return idx[np.lexsort((idx, d2, qid))][first[:, None] + np.arange(m)]


def _ramp(counts: np.ndarray) -> np.ndarray:
    """0, 1, …, c − 1 for each c of ``counts``, concatenated."""
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def neighbours(coords: np.ndarray, k: int, use: np.ndarray | None = None) -> np.ndarray:
    """(n, k) indices of the ``k`` rows nearest each row of ``coords`` (n,d) among the
    rows ``use`` marks (default all), the row itself left out, nearest first
    (:func:`_nearest`). Needs at least k + 1 rows in ``use``."""
    idx = np.arange(len(coords)) if use is None else np.flatnonzero(use)
    nb = idx[_nearest(coords[idx], coords, min(k + 1, len(idx)))]
    own = nb == np.arange(len(coords))[:, None]
    return np.take_along_axis(nb, np.argsort(own, axis=1, kind="stable"), axis=1)[:, :k]


def local_plane(coords: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-out local planes: for each of n points at ``coords`` (n,d), its ``k``
    nearest other points ``nb`` (n,k) (:func:`neighbours`) and their weights ``W`` (n,k)
    (:func:`plane_weights`). For independent noise of σ, v_i − v̂_i has σ²·(1 + Σ_k W_ik²)."""
    nb = neighbours(coords, k)
    return nb, plane_weights(coords, nb)


def _whitened_mad(e: np.ndarray, cov: np.ndarray) -> float:
    """Robust σ of differences ``e`` (n,2) whose noise covariance is σ²·``cov`` (n,2,2)."""
    L = np.linalg.cholesky(cov)
    z = np.linalg.solve(L, e[:, :, None])[:, :, 0]
    return mad(z)


def residual(cmd: np.ndarray, time_s: np.ndarray, r: np.ndarray, links=(1.0, 1.0)
             ) -> Noise | None:
    """σ from the structure of remainder ``r`` (n,2) mm at joints ``cmd`` (n,2) deg,
    measured at ``time_s`` (n,), arm of link lengths ``links`` mm (module docstring); None
    with fewer than :data:`MIN_POINTS` usable points."""
    from cell.diagnosis.where import jacobian_cols
    ok = np.abs(np.sin(np.radians(cmd[:, 1]))) > MIN_SIN_THETA2
    cmd, time_s, r = cmd[ok], time_s[ok], r[ok]
    n = len(r)
    if n < MIN_POINTS:
        return None
    j1, j2, _, _ = jacobian_cols(float(links[0]), float(links[1]), cmd)
    Jinv = np.linalg.inv(np.stack([j1, j2], axis=2))           # (n,2,2) deg/mm
    dq = np.einsum("nij,nj->ni", Jinv, r)                     # the remainder in joint space
    C = Jinv @ np.swapaxes(Jinv, 1, 2)                         # its noise covariance / σ²
    k = min(NEIGHBOURS, n - 1)
    nb, W = local_plane(cmd, k)
    e = dq - np.einsum("nk,nkc->nc", W, dq[nb])
    cov = C + np.einsum("nk,nkij->nij", W ** 2, C[nb])
    s_joint = _whitened_mad(e, cov)
    o = np.argsort(time_s, kind="stable")
    s_time = _whitened_mad(dq[o][1:] - dq[o][:-1], C[o][1:] + C[o][:-1])
    dof = MAD_EFFICIENCY * 2 * n
    if s_time < s_joint:
        return Noise(s_time, "residual", "differences of consecutive points in time, in "
                     "joint space", dof, upper95(s_time, dof))
    return Noise(s_joint, "residual", f"local planes through {k} joint-space neighbours, in "
                 "joint space", dof, upper95(s_joint, dof))


def best(*estimates: Noise | None) -> Noise | None:
    """``given`` if present, else the estimate with the smallest 95 % upper bound among
    the point estimates, else the path one."""
    ok = [e for e in estimates if e is not None]
    for e in ok:
        if e.source == "given":
            return e
    pts = [e for e in ok if e.source in ("repeats", "residual")]
    if pts:
        return min(pts, key=lambda e: e.upper95_mm)
    return next((e for e in ok if e.source == "paths"), None)
