"""Leave-one-fold-out prediction error of linear least-squares fits: the one out-of-sample
yardstick of the diagnosis, planar and chain alike. Pure numerics.

A fold is a group of residual rows left out together (a pose's markers, the poses at one
place, a measured move). For a design ``J`` and residual ``r`` (the model linearised at
a reference solution), each fold's held-out residual is that of the fit on all other
folds, formed explicitly; its squares summed and divided by the fold's size are the
fold's error. Two ways to ask:

* :func:`at_solution`: every column, ``r`` at the least-squares solution (the hat-matrix
  form, ``(I − H_gg)⁻¹ r_g``), with the pieces a cluster-robust covariance needs;
* :class:`Folds`: any subset of the columns, the folds' Gram pieces stacked once so a
  subset costs one batched solve of its own small normal equations (screening many
  subsets).

Both agree to rounding on the same columns. ``dims`` is the number of scalar residuals
per measured point (3 for a 3-D sensor, 2 for a camera that sees x, y); a fold's error is
its sum of squares over its **points** (``per="point"``) or over its scalar residuals
(``per="scalar"``).
"""
from __future__ import annotations

import math

import numpy as np

from cell.numerics.stacks import times_shared
from cell.numerics.sums import squares_last


def scaled(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J`` with unit-norm columns (zero columns left as they are) and the scales."""
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    return J / scale, scale


def by_group(group: np.ndarray, n_groups: int, dims: int) -> np.ndarray:
    """(G, Rmax) indices of each group's scalar residual rows (``dims`` per point of
    ``group`` (M,)), padded with −1."""
    rows = np.repeat(group, dims)
    order = np.argsort(rows, kind="stable")
    counts = np.bincount(rows, minlength=n_groups)
    out = -np.ones((n_groups, int(counts.max()) if len(counts) else 0), dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    g = rows[order]                                   # each sorted row's group
    out[g, np.arange(len(order)) - start[g]] = order
    return out


def blocks(Js: np.ndarray, r: np.ndarray, group: np.ndarray, n_groups: int, dims: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each group's rows of the design ``Js`` and the residual ``r`` side by side, zero-padded
    to one length (:func:`by_group`): (Jg (G, R, n), rg (G, R), pad (G, R) True where
    padded)."""
    if one_point_folds(group, n_groups):           # each fold one point: a reordering
        Jg, rg = np.empty((n_groups, dims, Js.shape[1])), np.empty((n_groups, dims))
        Jg[group], rg[group] = Js.reshape(len(group), dims, -1), r.reshape(len(group), dims)
        return Jg, rg, np.zeros((n_groups, dims), dtype=bool)
    idx = by_group(group, n_groups, dims)
    pad = idx < 0
    safe = np.where(pad, 0, idx)
    return np.where(pad[..., None], 0.0, Js[safe]), np.where(pad, 0.0, r[safe]), pad


def one_point_folds(group: np.ndarray, n_groups: int) -> bool:
    """Whether every fold holds exactly one point (``group`` a permutation of the folds):
    then a fold's rows are its point's ``dims`` rows, and no padding is needed."""
    return len(group) == n_groups and bool(np.all(np.bincount(group, minlength=n_groups) == 1))


def solve_small(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M⁻¹ v`` for a stack of small systems (M (..., d, d), v (..., d)), in closed form for
    d ≤ 2 (LAPACK's per-matrix overhead dominates thousands of 2 × 2 solves), else
    :func:`numpy.linalg.solve`. Raises LinAlgError when a system is exactly singular."""
    d = M.shape[-1]
    if d == 1:
        det = M[..., 0, 0]
        if np.any(det == 0):
            raise np.linalg.LinAlgError("singular matrix")
        return v / det[..., None]
    if d == 2:
        a, b, c, e = M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1]
        det = a * e - b * c
        if np.any(det == 0):
            raise np.linalg.LinAlgError("singular matrix")
        x, y = v[..., 0], v[..., 1]
        return np.stack([(e * x - b * y) / det, (a * y - c * x) / det], axis=-1)
    return np.linalg.solve(M, v[..., None])[..., 0]


def _sizes(pad: np.ndarray, dims: int, per: str) -> np.ndarray:
    n = (~pad).sum(1).astype(float)
    return n / dims if per == "point" else n


GRAM_PADDING = 4.0      # folds padded beyond this many times their rows keep Gram pieces only


def _fold_grams(Js: np.ndarray, r: np.ndarray, rows: np.ndarray, n_groups: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each fold's JᵀJ (F, n, n), Jᵀr (F, n) and rᵀr (F,) from its rows (``rows`` the fold
    of each scalar row), without padding."""
    n = Js.shape[1]
    G, b, rr = np.zeros((n_groups, n, n)), np.zeros((n_groups, n)), np.zeros(n_groups)
    order = np.argsort(rows, kind="stable")
    bounds = np.searchsorted(rows[order], np.arange(n_groups + 1))
    for g in range(n_groups):
        idx = order[bounds[g]:bounds[g + 1]]
        if len(idx):
            Jg, rg = Js[idx], r[idx]
            G[g], b[g], rr[g] = Jg.T @ Jg, Jg.T @ rg, rg @ rg
    return G, b, rr


def at_solution(J: np.ndarray, r: np.ndarray, group: np.ndarray, n_groups: int, dims: int = 3,
                per: str = "point", known: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Leave-one-fold-out of the least-squares fit with design ``J`` and residuals ``r``
    at its solution, folds ``group`` per point: (rms of the held-out point errors, per-fold
    error (G,), (JᵀJ)⁻¹ of the column-scaled design, the scales). All folds at once
    (padded blocks); a singular ``I − H_gg`` gives inf. A fold of more rows R than columns
    n (a measured move's samples) is taken out of the normal equations instead, the same
    residual at an n × n solve: e_g = r_g + J_g (A − J_gᵀJ_g)⁻¹ J_gᵀ r_g. Folds of very
    unequal size (a move's hundreds of samples beside places of a few poses) are padded
    in two batches, the small folds and the large (:func:`_size_classes`), not all to the
    largest. ``known``: the (JᵀJ)⁻¹ and scales an earlier call on the same ``J`` returned
    (other folds): not found again."""
    if known is None:
        Js, scale = scaled(J)
        Ainv = None
    else:
        Ainv, scale = known
        Js = J / scale                                # as scaled(J) divides
    A = Js.T @ Js
    if Ainv is None:
        Ainv = np.linalg.pinv(A, rcond=1e-12)
    counts = np.bincount(group, minlength=n_groups)
    ss = np.zeros(n_groups)
    normal = dims * (int(counts.max()) if len(counts) else 0) > Js.shape[1]
    try:
        for folds in _size_classes(counts, dims):
            if folds is None:
                Jg, rg, _ = blocks(Js, r, group, n_groups, dims)      # (G, R, n), (G, R)
            else:
                Jg, rg = _blocks_of(Js, r, group, folds, dims)
            if normal:
                Gg = Jg.transpose(0, 2, 1) @ Jg
                c = np.einsum("grn,gr->gn", Jg, rg)
                loo = rg + np.einsum("grn,gn->gr", Jg, np.linalg.solve(A - Gg, c[..., None])[..., 0])
            else:
                H = times_shared(Jg, Ainv) @ Jg.transpose(0, 2, 1)
                I = np.broadcast_to(np.eye(rg.shape[1]), H.shape)
                loo = solve_small(I - H, rg)
            ss[slice(None) if folds is None else folds] = squares_last(loo)
    except np.linalg.LinAlgError:
        return math.inf, np.full(n_groups, math.inf), Ainv, scale
    size = counts.astype(float) if per == "point" else counts * float(dims)
    total = float(math.sqrt(np.sum(ss) / max(float(counts.sum()), 1)))
    return total, ss / np.maximum(size, 1), Ainv, scale


def _size_classes(counts: np.ndarray, dims: int) -> list:
    """The batches :func:`at_solution` pads its folds in: ``[None]`` (every fold at once)
    unless padding all to the largest would more than :data:`GRAM_PADDING`-fold the rows;
    then the folds of at most that many times the mean size, and the rest (index arrays)."""
    total = int(counts.sum())
    if not total or int(counts.max()) * len(counts) <= GRAM_PADDING * total:
        return [None]
    large = counts > GRAM_PADDING * total / len(counts)
    return [f for f in (np.flatnonzero(~large), np.flatnonzero(large)) if len(f)]


def _blocks_of(Js: np.ndarray, r: np.ndarray, group: np.ndarray, folds: np.ndarray, dims: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`blocks` of the folds ``folds`` (indices) alone, in that order, padding
    zero-filled: (Jg (F, R, n), rg (F, R))."""
    local = -np.ones(int(group.max()) + 1, dtype=np.int64)
    local[folds] = np.arange(len(folds))
    pts = np.flatnonzero(local[group] >= 0)
    rows = (pts[:, None] * dims + np.arange(dims)).ravel()
    Jg, rg, _ = blocks(Js[rows], r[rows], local[group[pts]], len(folds), dims)
    return Jg, rg


def _frozen(res: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
    """A leave-out answer whose per-fold array can no longer be changed (it is kept)."""
    res[1].flags.writeable = False
    return res


class Folds:
    """Leave-one-fold-out of the linear least-squares fits of ``r`` on column subsets of
    one design ``Js``, folds ``group`` per point (``n_groups``; ``dims`` scalar rows per
    point, rows point-major). The folds' Gram pieces are stacked once; each subset then
    costs one batched solve of its small normal equations with the fold taken out (no
    refit of the rows), and the held-out residual is formed explicitly, so it equals
    :func:`at_solution` of that subset's fit to rounding.

    ``base``: the first ``base`` columns (a nuisance every subset holds, the chain's
    registration) are eliminated once per fold (Schur complement: the held-out residual
    ``u`` and columns ``W`` of the rest with the base's least squares taken out, and the
    reduced normal equations ``M β = z``), so a subset then costs a solve of the size of its
    other columns only. A fold whose base block is exactly singular makes every subset take
    the full solve (which then fails as it would).

    ``ridge``: a relative Tikhonov term (× the largest diagonal of each fold-out system,
    plus the smallest positive double) that keeps a fold whose removal leaves a column
    unseen finite instead of failing; 0 lets such a fold fail (its error inf).

    Folds of very unequal size (a measured move's hundreds of samples beside poses of one
    point) would pad every fold to the largest: when padding would more than
    :data:`GRAM_PADDING`-fold the rows, each fold keeps only its Gram pieces (JᵀJ, Jᵀr,
    rᵀr) and the held-out error is ‖r_g − J_g γ‖² = rᵀr − 2γᵀJᵀr + γᵀJᵀJγ (``gram``)."""

    def __init__(self, Js: np.ndarray, r: np.ndarray, group: np.ndarray, n_groups: int,
                 base: int = 0, dims: int = 3, per: str = "point", ridge: float = 0.0):
        rows = np.repeat(group, dims)
        counts = np.bincount(rows, minlength=n_groups).astype(float)
        self.gram = bool(len(rows)) and counts.max() * n_groups > GRAM_PADDING * len(rows)
        if self.gram:
            self.G, self.b, self.rr = _fold_grams(Js, r, rows, n_groups)
            self.Jg = self.rg = None
            self.size = counts / dims if per == "point" else counts
            self.n_pts = len(rows) / dims
        else:
            self.Jg, self.rg, pad = blocks(Js, r, group, n_groups, dims)  # (F, R, n), (F, R)
            self.G = self.Jg.transpose(0, 2, 1) @ self.Jg                 # (F, n, n)
            self.b = np.einsum("frn,fr->fn", self.Jg, self.rg)
            self.size = _sizes(pad, dims, per)
            self.n_pts = _sizes(pad, dims, "point").sum()
        self.Gt, self.bt = self.G.sum(0), self.b.sum(0)
        self.ridge = ridge
        self.base = base
        self.points = None
        self._known: dict[tuple, tuple[float, np.ndarray]] = {}    # column subset → its loo
        if not (base and self._eliminate(base)):
            self.base = 0               # nothing eliminated: the fold-out system as it is
            self.u, self.W = self.rg, self.Jg
            if self.gram:
                self.uu, self.Wu, self.WW = self.rr, self.b, self.G
            elif not ridge and one_point_folds(group, n_groups):
                self.points = (Js.reshape(len(group), dims, -1), r.reshape(len(group), dims), group)
            # the hat-matrix route of one-point folds solves no fold-out system
            self.M, self.z = (None, None) if self.points is not None else \
                (self.Gt - self.G, self.bt - self.b)

    @property
    def n_folds(self) -> int:
        return len(self.G)

    def _eliminate(self, nb: int) -> bool:
        """Eliminate the first ``nb`` columns (class docstring); False when a fold's base
        block is singular (nothing is eliminated then)."""
        A = self.Gt - self.G                                          # (F, n, n) fold out
        c = self.bt - self.b
        try:
            sol = np.linalg.solve(A[:, :nb, :nb],
                                  np.concatenate([A[:, :nb, nb:], c[:, :nb, None]], axis=2))
        except np.linalg.LinAlgError:
            return False
        X, x = sol[:, :, :-1], sol[:, :, -1]                          # (F, nb, m), (F, nb)
        Apr = A[:, nb:, :nb]
        self.M = A[:, nb:, nb:] - Apr @ X                             # (F, m, m)
        self.z = c[:, nb:] - np.einsum("fmr,fr->fm", Apr, x)          # (F, m)
        if self.gram:     # u = r − J_B x, W = J_R − J_B X, in the fold's Gram pieces
            G, b = self.G, self.b
            GBB, GBR, GRR, bB, bR = G[:, :nb, :nb], G[:, :nb, nb:], G[:, nb:, nb:], b[:, :nb], b[:, nb:]
            GBBx = np.einsum("fij,fj->fi", GBB, x)
            self.uu = self.rr - 2 * np.einsum("fi,fi->f", x, bB) + np.einsum("fi,fi->f", x, GBBx)
            self.Wu = (bR - np.einsum("fji,fj->fi", GBR, x) - np.einsum("fji,fj->fi", X, bB)
                       + np.einsum("fji,fj->fi", X, GBBx))
            XtGBR = X.transpose(0, 2, 1) @ GBR
            self.WW = GRR - XtGBR - XtGBR.transpose(0, 2, 1) + X.transpose(0, 2, 1) @ GBB @ X
            return True
        Jr = self.Jg[:, :, :nb]
        self.u = self.rg - np.einsum("fRr,fr->fR", Jr, x)             # (F, R)
        self.W = self.Jg[:, :, nb:] - Jr @ X                          # (F, R, m)
        return True

    def _ridged(self, A: np.ndarray) -> np.ndarray:
        if not self.ridge or A.shape[-1] == 0:
            return A
        lam = self.ridge * np.max(np.abs(np.diagonal(A, axis1=-2, axis2=-1)), axis=-1) + 1e-300
        return A + lam[..., None, None] * np.eye(A.shape[-1])

    def _result(self, e: np.ndarray) -> tuple[float, np.ndarray]:
        return self._from_ss(squares_last(e))

    def _from_ss(self, ss: np.ndarray) -> tuple[float, np.ndarray]:
        ss = np.maximum(ss, 0.0)                  # a Gram form's rounding below zero
        return (float(math.sqrt(np.sum(ss) / max(self.n_pts, 1))),
                ss / np.maximum(self.size, 1))

    def loo(self, cols) -> tuple[float, np.ndarray]:
        """(rms of the held-out point errors, per-fold error (F,)) of the fit on columns
        ``cols`` (indices; empty: the residual as it is). A subset asked about again is
        answered from the first answer (screening asks the same subsets many times); its
        per-fold array is read-only."""
        cols = np.asarray(cols, dtype=np.int64)
        if self.points is not None and len(cols):
            return self._one_point_each(cols[None])[0]
        key = ("loo",) + tuple(int(c) for c in cols)
        if key not in self._known:
            self._known[key] = _frozen(self._loo(cols))
        return self._known[key]

    def _loo(self, cols: np.ndarray) -> tuple[float, np.ndarray]:
        nb = self.base
        if len(cols) >= nb and np.array_equal(cols[:nb], np.arange(nb)):
            S = cols[nb:] - nb
            if not len(S):
                return self._from_ss(self.uu) if self.gram else self._result(self.u)
            try:
                beta = np.linalg.solve(self._ridged(self.M[:, S[:, None], S]),
                                       self.z[:, S, None])[..., 0]
            except np.linalg.LinAlgError:
                return math.inf, np.full(self.n_folds, math.inf)
            if self.gram:
                return self._from_ss(self.uu - 2 * np.einsum("fk,fk->f", beta, self.Wu[:, S])
                                     + np.einsum("fk,fkl,fl->f", beta, self.WW[:, S[:, None], S], beta))
            return self._result(self.u - np.einsum("frk,fk->fr", self.W[:, :, S], beta))
        if not len(cols):
            return self._from_ss(self.rr) if self.gram else self._result(self.rg)
        A = self.Gt[np.ix_(cols, cols)] - self.G[:, cols[:, None], cols]
        rhs = self.bt[cols] - self.b[:, cols]
        try:
            beta = np.linalg.solve(self._ridged(A), rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return math.inf, np.full(self.n_folds, math.inf)
        if self.gram:
            return self._from_ss(self.rr - 2 * np.einsum("fk,fk->f", beta, self.b[:, cols])
                                 + np.einsum("fk,fkl,fl->f", beta, self.G[:, cols[:, None], cols], beta))
        return self._result(self.rg - np.einsum("frk,fk->fr", self.Jg[:, :, cols], beta))

    def _one_point_each(self, S: np.ndarray) -> list[tuple[float, np.ndarray]]:
        """:meth:`loo` of each row of ``S`` (t, k) when every fold is one point and nothing
        is eliminated: the fit on every fold, then each point's held-out residual
        ``(I − H_gg)⁻¹ e_g`` (``H_gg`` its ``dims`` × ``dims`` block of the hat matrix),
        exact for any ``r``: one k × k solve per subset instead of one per fold, the subsets
        not asked about before in one batch (a singular one alone fails, its errors inf).
        Each subset's answer is computed on its own slices of the batch, so it is the same
        whichever batch it comes in, and kept (read-only) for the next time."""
        keys = [tuple(int(c) for c in row) for row in S]
        new = [i for i, key in enumerate(keys) if key not in self._known]
        if new:
            for i, res in zip(new, self._points_loo(S[new])):
                self._known[keys[i]] = _frozen(res)
        return [self._known[key] for key in keys]

    def _points_loo(self, S: np.ndarray) -> list[tuple[float, np.ndarray]]:
        Jp, rp, fold_of = self.points
        try:
            Ainv = np.linalg.inv(self.Gt[S[:, :, None], S[:, None, :]])   # (t, k, k)
            Jc = Jp[:, :, S].transpose(2, 0, 1, 3)                        # (t, P, dims, k)
            beta = (Ainv @ self.bt[S][..., None])[..., 0]                 # (t, k)
            e = rp[None] - (Jc @ beta[:, None, :, None])[..., 0]          # (t, P, dims)
            JA = np.stack([times_shared(c, a) for c, a in zip(Jc, Ainv)])  # (t, P, dims, k)
            H = JA @ Jc.transpose(0, 1, 3, 2)                             # (t, P, dims, dims)
            out = solve_small(np.eye(H.shape[-1]) - H, e)
        except np.linalg.LinAlgError:                                     # tell which: one at a time
            if len(S) == 1:
                return [(math.inf, np.full(self.n_folds, math.inf))]
            return [self._points_loo(c[None])[0] for c in S]
        ss = np.empty((len(S), self.n_folds))
        ss[:, fold_of] = squares_last(out)
        return [self._from_ss(q) for q in ss]

    def loo_each(self, subsets: list) -> list[tuple[float, np.ndarray]]:
        """:meth:`loo` of each column list of ``subsets`` (all of one length), solved in
        one batch when each holds the eliminated base columns first."""
        if not subsets:
            return []
        S = np.asarray(subsets, dtype=np.int64)                       # (t, c)
        nb = self.base
        if self.points is not None and S.shape[1]:
            return self._one_point_each(S)
        if S.shape[1] <= nb or not (S[:, :nb] == np.arange(nb)).all():
            return [self._loo(np.asarray(c, dtype=np.int64)) for c in subsets]
        S = S[:, nb:] - nb                                            # (t, k)
        try:
            beta = np.linalg.solve(self._ridged(self.M[:, S[:, :, None], S[:, None, :]]),
                                   self.z[:, S, None])[..., 0]         # (F, t, k)
        except np.linalg.LinAlgError:                                 # tell which: one at a time
            return [self._loo(np.asarray(c, dtype=np.int64)) for c in subsets]
        if self.gram:
            ss = np.maximum(self.uu[None] - 2 * np.einsum("ftk,ftk->tf", beta, self.Wu[:, S])
                            + np.einsum("ftk,ftkl,ftl->tf", beta,
                                        self.WW[:, S[:, :, None], S[:, None, :]], beta), 0.0)
        else:
            e = self.u[None] - np.einsum("frtk,ftk->tfr", self.W[:, :, S], beta)
            ss = squares_last(e)                                # (t, F)
        per = ss / np.maximum(self.size, 1)
        total = np.sqrt(np.sum(ss, axis=1) / max(self.n_pts, 1))
        return [(float(t), q) for t, q in zip(total, per)]
