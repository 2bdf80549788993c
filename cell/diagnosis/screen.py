"""Linearised screening of candidates: one Gauss–Newton step from the nominal model for
every candidate, ranked by approximate BIC, before the full non-linear fits of the few the
decision needs (:mod:`.rank`). Pure numerics.

Every parameter of every single candidate gets a response column: its exact derivative
(:mod:`.jacobian`) at the nominal model, on the fit and holdout rows. A candidate's
linearised fit is the weighted linear least squares of the nominal residual on its columns,
computed from per-table Gram matrices (AᵀA, Aᵀr, rᵀr of the points and of the path
samples), so a candidate costs a k×k solve whatever the number of rows. The weights follow
the profile likelihood of :mod:`.fit` (each table its own σ; three reweighting rounds).

An effect is linearised by its first fitted parameter at zero size, unless its definition
declares a linear parametrisation (:class:`cell.effects.Linear`); this module names no
effect. Today two effects declare one, which makes the linearisation exact in the
parameters:

* cyclic error a·sin(2π·k·θ/360 + φ) = c·sin(kθ) + s·cos(kθ): two probe columns per
  harmonic order k of its ``orders`` (:data:`ORDERS`); a = √(c² + s²), φ = atan2(s, c);
* thermal drift with moves (``path_nuisance``): α·l·(T − T_ref) on the points and β·l on
  the path samples (β = α·(T_path − T_ref), the path temperature being a nuisance).

Bounds (backlash width and comm delay ≥ 0, the thermal expansion's range) are kept by
holding a parameter that leaves its bound at the bound and solving for the others; probe
and nuisance columns are unbounded.

Harmonic order (an effect with ``orders``, today the cyclic error): every order is
screened per joint (all combinations when a candidate carries the effect on both joints)
and the best kept; the others' Δ(−2 ln L) is its evidence (:func:`order_evidence`).
Choosing among the orders costs ``2·ln(number of orders)`` in BIC per joint (a uniform
prior over the orders).
:func:`order_separation` says from the layout alone (the angles of the fit rows) whether
two orders can be told apart at all: the largest canonical correlation between their
response columns, against :data:`MAX_CORR`.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis.jacobian import evaluate, rows_of
from cell.diagnosis.replay import DiagData

#: the harmonic orders screened (those of the effect that declares orders: the cyclic error)
ORDERS = next(e.linear.orders for e in fx.EFFECTS.values() if e.linear and e.linear.orders)
ORDER_COST = 2.0 * math.log(len(ORDERS))
MAX_CORR = 0.995     # a parameter correlation beyond: the candidate is not identifiable
MAX_COND = 1e4       # a column-scaled condition number beyond: not identifiable
ROUNDS = 3

Key = tuple   # (effect, joint | None, order | None)


@dataclass
class Table:
    """Gram pieces of one table on one row set: ``G`` = AᵀA, ``b`` = Aᵀr, ``c`` = rᵀr,
    ``n`` scalar residuals (2 per row)."""

    G: np.ndarray
    b: np.ndarray
    c: float
    n: int

    @staticmethod
    def of(A: np.ndarray, r: np.ndarray) -> "Table":
        # einsum, not BLAS: at these sizes a threaded GEMM only burns CPU on idle threads
        return Table(np.einsum("ij,ik->jk", A, A), np.einsum("ij,i->j", A, r),
                     float(np.einsum("i,i->", r, r)), len(r))


@dataclass
class Basis:
    """Response columns of every single candidate's parameters at the nominal model:
    ``cols`` key -> column indices; ``fit`` / ``hold`` (points, paths) Tables; ``lo`` /
    ``hi`` bounds per column; ``nuisance`` columns left out of the identifiability
    check; ``n_folds`` cross-validation folds of the fit rows and ``fold_rows`` the rows
    in them: (A (n, 2, m), residual (n, 2), fold (n,), table (n,): 0 points, 1 path
    samples), for :mod:`.crossval`."""

    cols: dict
    fit: tuple[Table, Table]
    hold: tuple[Table, Table]
    lo: np.ndarray
    hi: np.ndarray
    nuisance: set = field(default_factory=set)
    n_total: int = 0
    t_ref: float = 20.0
    point_temp_mean: float | None = None
    has_paths: bool = False
    n_folds: int = 0
    fold_rows: tuple | None = None


def _orders(name: str) -> tuple[int, ...]:
    lin = fx.EFFECTS[name].linear
    return lin.orders if lin is not None else ()


def _instances(name: str, joint: str | None, order: int | None):
    """Linearisation points (zero effect) whose first fitted column is the response: the
    effect's declared probes (:class:`cell.effects.Linear`) at ``order``, else the
    zero-sized effect."""
    eff = fx.EFFECTS[name]
    joints = (joint,) if joint else ()
    lin = eff.linear
    if lin is None or not lin.probes:
        return [eff.zero(joints)]
    pre = f"{joint}_" if eff.per_joint else ""
    base = dict(eff.zero(joints).params)
    at = lin.at_order(order) if order is not None and lin.at_order else {}
    out = []
    for probe in lin.probes:
        set_ = {pre + k: v for k, v in {**at, **probe}.items()}
        out.append(fx.make_effect(name, joints, {**base, **set_}))
    return out


def keys_of(c) -> list[list[Key]]:
    """The column keys of candidate ``c`` per harmonic variant: a list (one per combination
    of orders) of key lists."""
    fixed: list[Key] = []
    ordered: list[tuple[str, str]] = []
    for name, joints in c:
        if _orders(name):
            ordered += [(name, j) for j in joints]
        elif joints:
            fixed += [(name, j, None) for j in joints]
        else:
            fixed.append((name, None, None))
    out = []
    for ks in itertools.product(*[_orders(n) for n, _ in ordered]):
        out.append(fixed + [(n, j, k) for (n, j), k in zip(ordered, ks)])
    return out


def _keys(cands) -> list[Key]:
    keys: list[Key] = []
    for c in cands:
        for var in keys_of(c):
            for k in var:
                if k not in keys:
                    keys.append(k)
    return keys


def responses(row_sets, keys: list[Key], has_paths: bool):
    """Response columns of parameters ``keys`` at the nominal model on each of ``row_sets``
    (:class:`~cell.diagnosis.jacobian.Rows`): ([(n, 2, ncol) per row set], cols {key: column
    indices}, lo, hi, nuisance columns, t_ref). One evaluation per row set: every
    linearisation point (all at zero effect) in one list."""
    insts, where_col = [], []          # where_col: (key, position of the response column)
    pos, t_ref = 0, 20.0
    for key in keys:
        for inst in _instances(*key):
            insts.append(inst)
            where_col.append((key, pos))
            pos += len(inst.fit_names)
            lin = inst.spec.linear
            if lin is not None and lin.path_nuisance:
                t_ref = inst.params[lin.path_nuisance]
    tp = t_ref + 1.0      # a path temperature 1 K above the reference: β's column
    Js = [evaluate(rows, insts, tp, jac=True)[1] for rows in row_sets]
    cols: dict = {}
    lo, hi, nuis = [], [], set()
    takes: list[list] = [[] for _ in row_sets]
    for key, p in where_col:
        eff = fx.EFFECTS[key[0]]
        spec, lin = eff.params[0], eff.linear
        probed = lin is not None and bool(lin.probes)
        parts = [None]
        if lin is not None and lin.path_nuisance:
            parts = ["points", "paths"] if has_paths else ["points"]
        for part in parts:
            if part == "paths":
                nuis.add(len(lo))
            cols.setdefault(key, []).append(len(lo))
            for take, J, rows in zip(takes, Js, row_sets):
                a = J[:, :, p]
                if part == "points":
                    a = a.copy()
                    a[rows.n_points:] = 0.0
                elif part == "paths":
                    a = a.copy()
                    a[:rows.n_points] = 0.0
                take.append(a)
            b = (-math.inf, math.inf) if probed or part == "paths" else spec.bounds
            lo.append(b[0])
            hi.append(b[1])
    As = [np.stack(take, axis=2) if take else np.zeros((rows.n, 2, 0))
          for take, rows in zip(takes, row_sets)]
    return As, cols, np.array(lo, float), np.array(hi, float), nuis, t_ref


def basis(fit_d: DiagData, hold_d: DiagData, cands, keep_fit=None, keep_hold=None,
          fit_folds=None) -> Basis:
    """The :class:`Basis` of candidates ``cands`` on the fit and holdout rows; ``keep_*``
    (n_rows,) bool masks of the rows that count (None = all); ``fit_folds`` (n_fit_rows,)
    int fold of each fit row for cross-validation (:mod:`.crossval`; −1 = in no fold),
    or None."""
    rf, rh = rows_of(fit_d), rows_of(hold_d)
    has_paths = rf.n_path > 0
    (Af, Ah), cols, lo, hi, nuis, t_ref = responses((rf, rh), _keys(cands), has_paths)
    r0f = rf.meas - evaluate(rf, [])[0]
    r0h = rh.meas - evaluate(rh, [])[0]

    def tables(A, r0, rows, keep):
        kp = np.ones(rows.n, bool) if keep is None else np.asarray(keep, bool)
        out = []
        for sl in (slice(0, rows.n_points), slice(rows.n_points, rows.n)):
            m = kp[sl]
            a = A[sl][m].reshape(-1, A.shape[2])
            out.append(Table.of(a, r0[sl][m].ravel()))
        return tuple(out)

    tf = tables(Af, r0f, rf, keep_fit)
    th = tables(Ah, r0h, rh, keep_hold)
    pt = fit_d.points.temp if fit_d.points is not None and fit_d.points.temp is not None else None
    B = Basis(cols, tf, th, lo, hi, nuis, tf[0].n + tf[1].n, t_ref,
              None if pt is None else float(np.mean(pt)), has_paths)
    if fit_folds is not None:
        kp = np.ones(rf.n, bool) if keep_fit is None else np.asarray(keep_fit, bool)
        folds = np.where(kp, np.asarray(fit_folds), -1)
        inside = folds >= 0
        B.n_folds = int(folds.max()) + 1 if len(folds) else 0
        B.fold_rows = (Af[inside], r0f[inside], folds[inside],
                       (np.arange(rf.n) >= rf.n_points)[inside].astype(int))
    return B


@dataclass
class Screened:
    """One candidate variant's linearised fit: ``keys`` its column keys and ``S`` their
    indices, ``x`` coefficients, ``rss`` / ``hold_rss`` (points, paths) in mm², ``neg2ll``,
    ``bic`` (with the order cost), ``k``, identifiability (``identifiable``, ``reason``,
    ``cond``, ``max_corr``), ``orders`` {joint: k}, ``order_dev`` {joint: {k: Δ(−2 ln L)}}
    and the final table ``weights``."""

    candidate: tuple
    keys: list
    x: np.ndarray
    rss: tuple[float, float]
    hold_rss: tuple[float, float]
    neg2ll: float
    bic: float
    k: int
    identifiable: bool = True
    reason: str = ""
    cond: float = 1.0
    max_corr: float = 0.0
    orders: dict = field(default_factory=dict)
    order_dev: dict = field(default_factory=dict)
    weights: tuple[float, float] = (1.0, 1.0)
    S: list = field(default_factory=list)


def _identifiability(G: np.ndarray, ke: list[int]) -> tuple[bool, str, float, float]:
    """(identifiable, reason, condition number, largest correlation) of weighted Gram
    ``G`` judged on parameters ``ke`` (the nuisance left out), as :mod:`.fit` judges the
    Jacobian."""
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    if np.any(d[ke] <= 1e-12 * max(d.max(), 1e-300)):
        return False, "a parameter has no effect on the data", math.inf, 0.0
    Gn = G / np.outer(d, d)
    ev = np.linalg.eigvalsh(Gn[np.ix_(ke, ke)])
    cond = math.sqrt(ev[-1] / ev[0]) if ev[0] > 0 else math.inf
    mc = 0.0
    if len(ke) > 1:
        cov = np.linalg.pinv(Gn)
        sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
        corr = (cov / np.outer(sd, sd))[np.ix_(ke, ke)]
        np.fill_diagonal(corr, 0.0)
        mc = float(np.max(np.abs(corr)))
    if cond > MAX_COND:
        return False, f"Jacobian condition number {cond:.3g}", cond, mc
    if mc > MAX_CORR:
        return False, f"parameter correlation {mc:.4f} (near ±1)", cond, mc
    return True, "", cond, mc


def _bsolve(Gp, Gq, bp, bq, w, lo, hi) -> np.ndarray:
    """Weighted least squares of V column sets at once: (V,k,k) Grams and (V,k) right-hand
    sides of the two tables, (V,2) weights, (V,k) bounds. A coefficient that leaves its
    bound is held there and the others solved again (one per round, at most k rounds)."""
    G = w[:, 0, None, None] ** 2 * Gp + w[:, 1, None, None] ** 2 * Gq
    b = w[:, :1] ** 2 * bp + w[:, 1:] ** 2 * bq
    V, k = b.shape
    ridge = 1e-12 * np.max(np.abs(np.diagonal(G, axis1=1, axis2=2)), axis=1) + 1e-300
    G = G + ridge[:, None, None] * np.eye(k)
    fixed = np.zeros((V, k), bool)
    xf = np.zeros((V, k))
    eye = np.eye(k)
    x = np.zeros((V, k))
    for _ in range(k + 1):
        if fixed.any():
            bm = b - np.einsum("vij,vj->vi", G, np.where(fixed, xf, 0.0))
            keep = ~fixed
            Gm = G * keep[:, :, None] * keep[:, None, :] + eye * fixed[:, :, None]
            bm = np.where(fixed, xf, bm)
        else:
            Gm, bm = G, b
        x = np.linalg.solve(Gm, bm[:, :, None])[:, :, 0]
        viol = ~fixed & ((x < lo) | (x > hi))
        if not viol.any():
            break
        rows = np.flatnonzero(viol.any(axis=1))
        first = np.argmax(viol[rows], axis=1)
        fixed[rows, first] = True
        xf[rows, first] = np.clip(x[rows, first], lo[rows, first], hi[rows, first])
    return x


def _brss(Gp, bp, c, x) -> np.ndarray:
    return np.maximum(c - 2.0 * np.einsum("vi,vi->v", x, bp)
                      + np.einsum("vi,vij,vj->v", x, Gp, x), 0.0)


def _batch(B: Basis, items: list[tuple]) -> list[Screened]:
    """Linearised fits of variants ``items`` = [(candidate, keys)] (all with the same
    number of columns), batched."""
    S = np.array([[i for k in keys for i in B.cols[k]] for _, keys in items], int)
    (tp, tq), n = B.fit, (B.fit[0].n, B.fit[1].n)
    ix = (S[:, :, None], S[:, None, :])
    Gp, Gq, bp, bq = tp.G[ix], tq.G[ix], tp.b[S], tq.b[S]
    lo, hi = B.lo[S], B.hi[S]
    w = np.ones((len(items), 2))
    for _ in range(ROUNDS):
        x = _bsolve(Gp, Gq, bp, bq, w, lo, hi)
        rss = np.column_stack([_brss(Gp, bp, tp.c, x), _brss(Gq, bq, tq.c, x)])
        w = np.column_stack([1.0 / np.maximum(np.sqrt(rss[:, t] / n[t]), 1e-9) if n[t]
                             else np.ones(len(items)) for t in range(2)])
    n2 = sum(n[t] * np.log(np.maximum(rss[:, t] / n[t], 1e-30)) for t in range(2) if n[t])
    n2 = np.broadcast_to(np.asarray(n2, float), (len(items),))
    out = []
    lnn = math.log(max(B.n_total, 2))
    for v, (c, keys) in enumerate(items):
        cost = sum(2.0 * math.log(len(_orders(kk[0]))) for kk in keys if kk[2] is not None)
        k = S.shape[1]
        out.append(Screened(c, keys, x[v], (float(rss[v, 0]), float(rss[v, 1])), (0.0, 0.0),
                            float(n2[v]), float(n2[v]) + k * lnn + cost, k,
                            orders={kk[1]: kk[2] for kk in keys if kk[2] is not None},
                            weights=(float(w[v, 0]), float(w[v, 1])), S=list(S[v])))
    return out


def _bfinish(B: Basis, group: list[Screened]) -> None:
    """Holdout RSS and identifiability (as :func:`_identifiability`; batched where no
    nuisance column is among the variant's) of screened variants with the same number of
    columns."""
    S = np.array([s.S for s in group], int)
    ix = (S[:, :, None], S[:, None, :])
    x = np.array([s.x for s in group])
    hp = _brss(B.hold[0].G[ix], B.hold[0].b[S], B.hold[0].c, x)
    hq = _brss(B.hold[1].G[ix], B.hold[1].b[S], B.hold[1].c, x)
    w = np.array([s.weights for s in group])
    G = w[:, 0, None, None] ** 2 * B.fit[0].G[ix] + w[:, 1, None, None] ** 2 * B.fit[1].G[ix]
    for v, s in enumerate(group):
        s.hold_rss = (float(hp[v]), float(hq[v]))
    plain = np.array([not any(col in B.nuisance for col in s.S) for s in group])
    for v in np.flatnonzero(~plain):
        s = group[v]
        ke = [i for i, col in enumerate(s.S) if col not in B.nuisance]
        s.identifiable, s.reason, s.cond, s.max_corr = _identifiability(G[v], ke)
    if not plain.any():
        return
    Gp = G[plain]
    d = np.sqrt(np.maximum(np.diagonal(Gp, axis1=1, axis2=2), 0.0))
    dead = np.any(d <= 1e-12 * np.maximum(d.max(axis=1, keepdims=True), 1e-300), axis=1)
    dn = np.where(d > 0, d, 1.0)
    Gn = Gp / (dn[:, :, None] * dn[:, None, :])
    ev = np.linalg.eigvalsh(Gn)
    cond = np.where(ev[:, 0] > 0, np.sqrt(ev[:, -1] / np.where(ev[:, 0] > 0, ev[:, 0], 1.0)),
                    np.inf)
    mc = np.zeros(len(Gp))
    if S.shape[1] > 1:
        cov = np.linalg.pinv(Gn)
        sd = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 1e-300))
        corr = np.abs(cov / (sd[:, :, None] * sd[:, None, :]))
        corr[:, np.arange(S.shape[1]), np.arange(S.shape[1])] = 0.0
        mc = corr.max(axis=(1, 2))
    for i, v in enumerate(np.flatnonzero(plain)):
        s = group[v]
        if dead[i]:
            s.identifiable, s.reason, s.cond, s.max_corr = \
                False, "a parameter has no effect on the data", math.inf, 0.0
            continue
        s.cond, s.max_corr = float(cond[i]), float(mc[i])
        if s.cond > MAX_COND:
            s.identifiable, s.reason = False, f"Jacobian condition number {s.cond:.3g}"
        elif s.max_corr > MAX_CORR:
            s.identifiable, s.reason = False, f"parameter correlation {s.max_corr:.4f} (near ±1)"


def screen_all(B: Basis, cands) -> dict:
    """{candidate: its best harmonic variant (by −2 ln L)} with the evidence for its orders
    in ``order_dev``, holdout RSS and identifiability; every variant fitted in batches."""
    items = [(c, keys) for c in cands for keys in keys_of(c)]
    by_k: dict[int, list] = {}
    for it in items:
        by_k.setdefault(sum(len(B.cols[k]) for k in it[1]), []).append(it)
    fitted: dict = {}
    for group in by_k.values():
        for sc in _batch(B, group):
            fitted.setdefault(sc.candidate, []).append(sc)
    out = {}
    for c in cands:
        variants = fitted[c]
        best = min(variants, key=lambda v: v.neg2ll)
        for j in best.orders:
            best.order_dev[j] = {v.orders[j]: v.neg2ll - best.neg2ll for v in variants
                                 if all(v.orders[jj] == best.orders[jj]
                                        for jj in best.orders if jj != j)}
        out[c] = best
    by_k2: dict[int, list] = {}
    for sc in out.values():
        by_k2.setdefault(len(sc.S), []).append(sc)
    for group in by_k2.values():
        _bfinish(B, group)
    return out


def screen(B: Basis, c) -> Screened:
    """:func:`screen_all` of one candidate."""
    return screen_all(B, [c])[c]


def fit_variant(B: Basis, c, keys: list[Key]) -> Screened:
    """The linearised fit of candidate ``c`` on columns ``keys`` (one harmonic variant),
    with its holdout RSS and identifiability."""
    sc = _batch(B, [(c, keys)])[0]
    _bfinish(B, [sc])
    return sc


def params_of(B: Basis, s: Screened) -> tuple[list[tuple[str, tuple, dict]], float | None]:
    """The screened solution in the vocabulary's parameters: per component (effect, joints,
    {full name: value}) (constants included), and the path temperature (None without)."""
    coef: dict = {}
    pos = 0
    for key in s.keys:
        n = len(B.cols[key])
        coef[key] = s.x[pos:pos + n]
        pos += n
    comps, tp = [], None
    for name, joints in s.candidate:
        eff = fx.EFFECTS[name]
        lin = eff.linear
        fitted = [p.stem for p in eff.params if p.fitted]
        params: dict[str, float] = {}
        for j in (joints or (None,)):
            pre = f"{j}_" if j else ""
            order = s.orders.get(j) if _orders(name) else None
            v = coef[(name, j, order)]
            if lin is not None and lin.to_params is not None:
                stems = lin.to_params(v, order)
            else:
                stems = {fitted[0]: float(v[0]), **eff.constants()}
            if lin is not None and lin.path_nuisance:
                stems[lin.path_nuisance] = B.t_ref
                if len(v) > 1:
                    alpha = float(v[0])
                    t0 = B.point_temp_mean if B.point_temp_mean is not None else B.t_ref
                    tp = B.t_ref + float(v[1]) / alpha if abs(alpha) > 1e-9 else t0
            params.update({pre + k: val for k, val in stems.items()})
        comps.append((name, tuple(joints), params))
    return comps, tp


def start_params(B: Basis, s: Screened) -> tuple[list[fx.EffectInstance], float | None]:
    """Effect instances (strictly inside their bounds, or inside a parameter's declared
    ``start`` range: e.g. a cyclic amplitude off 0, so its phase has a gradient) and the
    path temperature from a screened solution: the full fit's starting point."""
    comps, tp = params_of(B, s)
    insts = []
    for name, joints, params in comps:
        eff = fx.EFFECTS[name]
        for pn in list(params):
            ps = eff.spec_of(pn)
            if not ps.fitted:
                continue
            lo, hi = ps.start if ps.start is not None else ps.bounds
            span = (hi - lo) if math.isfinite(hi - lo) else 1.0
            params[pn] = float(np.clip(params[pn], lo + 1e-6 * span, hi - 1e-6 * span))
        insts.append(fx.make_effect(name, joints, params))
    if tp is not None:
        tp = float(np.clip(tp, -49.0, 149.0))
    return insts, tp


def order_separation(B: Basis, joint: str) -> tuple[float, tuple[int, int]]:
    """The largest canonical correlation between the response columns of two harmonic
    orders of an effect with orders (the cyclic error) on ``joint`` over the fit rows, and
    that pair of orders."""
    tp, tq = B.fit
    G = tp.G + tq.G
    worst, pair = 0.0, (0, 0)
    keys = sorted((key for key in B.cols if key[1] == joint and key[2] is not None),
                  key=lambda key: key[2])
    for ka, kb in itertools.combinations(keys, 2):
        a, b = ka[2], kb[2]
        ia, ib = B.cols[ka], B.cols[kb]
        try:
            La = np.linalg.cholesky(G[np.ix_(ia, ia)])
            Lb = np.linalg.cholesky(G[np.ix_(ib, ib)])
        except np.linalg.LinAlgError:
            return 1.0, (a, b)
        C = np.linalg.solve(La, G[np.ix_(ia, ib)]) @ np.linalg.inv(Lb).T
        rho = float(np.linalg.svd(C, compute_uv=False)[0])
        if rho > worst:
            worst, pair = rho, (a, b)
    return worst, pair
