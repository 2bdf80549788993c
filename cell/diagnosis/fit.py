"""Fit one candidate (one or two vocabulary effects) on the fit rows. Pure numerics.

A candidate is a tuple of components ``(effect name, joints)``. :func:`fit_candidate` adds
it to the simulation and fits its parameters with :func:`cell.numerics.lsq.least_squares` (bounded
Levenberg–Marquardt, the vocabulary's bounds, the exact Jacobian of :mod:`.jacobian`;
finite differences on request) on the fit rows only (rows flagged as outliers left out,
:mod:`.robust`). It starts from the linearised fit of :mod:`.screen` (so a cyclic error
in anti-phase with any fixed guess cannot stall on the amplitude's zero bound). A cyclic
error is fitted at a given harmonic order k (period 360°/k, a constant of the vocabulary's
``cyclic_period_deg``); the screening picks k.

Noise model: every table (points, path samples) has its own Gaussian σ per axis, unknown.
The fit is iteratively reweighted: each round weighs each table by 1/its rms of the round
before (the maximum-likelihood weights; the first round takes the screening's weights or
weighs every scalar residual alike). The score is the profile log-likelihood
``−2 ln L = Σ_t n_t·ln(RSS_t/n_t)`` (n_t scalar residuals of table t), and
``BIC = −2 ln L + k·ln n + 2·ln(4)·(cyclic joints)`` (k fitted parameters; the last term is
the cost of having chosen one of four harmonic orders, :mod:`.screen`). 95 % intervals:
±1.96·SE from the weighted Jacobian at the solution, ``cov = s²·(JᵀJ)⁻¹`` with s² the
weighted residual variance. Identifiability: a parameter without sensitivity, a
column-scaled Jacobian with condition number above :data:`MAX_COND` or a parameter
correlation beyond :data:`MAX_CORR` makes the candidate not identifiable.

Path temperature: paths.csv has no temperature, so a candidate with thermal_drift fits the
temperature the moves were made at (``path_temp_c``, °C) as a nuisance parameter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
import numpy as np

from cell import effects as fx
from cell.diagnosis.jacobian import evaluate, rows_of
from cell.diagnosis.replay import DiagData, PointsData, predict
from cell.diagnosis.screen import MAX_COND, MAX_CORR, ORDER_COST, ORDERS
from cell.numerics.lsq import least_squares

JACOBIANS = ("analytic", "2-point")
Z95 = 1.959963984540054

Candidate = tuple[tuple[str, tuple[str, ...]], ...]


def label(c: Candidate) -> str:
    """Readable name: ``backlash[j2]+camera_scale``."""
    return "+".join(f"{e}[{','.join(j)}]" if j else e for e, j in c)


def subset(d: DiagData, which: str) -> DiagData:
    """The fit (``which="fit"``) or holdout rows of ``d`` as a DiagData of their own."""
    want = which == "fit"
    pts = None
    if d.points is not None:
        p, m = d.points, d.points.fit == want
        if m.any():
            pts = PointsData(p.cmd[m], p.dirs[m], p.time[m],
                             None if p.temp is None else p.temp[m],
                             None if p.payload is None else p.payload[m], p.xy[m], p.fit[m],
                             p.sample[m], p.has_dirs)
    moves = [mv for mv in d.moves if mv.fit == want]
    return DiagData(d.geometry, d.center, d.stations, d.order, pts, moves, d.split_source,
                    d.source)


@dataclass
class TableStats:
    """Per-table residual summary: ``n`` rows, ``rms`` / ``max`` of the residual norm, mm."""

    n: int
    rms: float
    max: float

    @staticmethod
    def of(r: np.ndarray) -> "TableStats":
        if len(r) == 0:
            return TableStats(0, 0.0, 0.0)
        nrm = np.hypot(r[:, 0], r[:, 1])
        return TableStats(len(r), float(np.sqrt(np.mean(nrm ** 2))), float(nrm.max()))


def combined(a: TableStats, b: TableStats) -> TableStats:
    n = a.n + b.n
    if n == 0:
        return TableStats(0, 0.0, 0.0)
    return TableStats(n, math.sqrt((a.n * a.rms ** 2 + b.n * b.rms ** 2) / n), max(a.max, b.max))


def neg2_loglik(rp: np.ndarray, rq: np.ndarray) -> float:
    """Profile −2 ln L (constants dropped) of residual tables with unknown σ each."""
    out = 0.0
    for r in (rp, rq):
        n = r.size
        if n:
            out += n * math.log(max(float(np.sum(r ** 2)) / n, 1e-30))
    return out


@dataclass
class FitResult:
    """One fitted candidate. ``effects`` the fitted instances; ``params`` / ``ci95`` by full
    parameter name (mm, deg, …; cyclic phase wrapped to [0, 360)); ``path_temp_c`` the
    nuisance path temperature (None unless fitted); ``k`` fitted parameters; ``bic`` on
    the fit rows; ``fit`` / ``holdout`` per-table residual stats (points, paths)."""

    candidate: Candidate
    effects: list[fx.EffectInstance]
    params: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    k: int
    neg2ll: float
    bic: float
    fit_points: TableStats
    fit_paths: TableStats
    hold_points: TableStats
    hold_paths: TableStats
    identifiable: bool = True
    reason: str = ""
    max_corr: float = 0.0
    cond: float = 1.0
    path_temp_c: float | None = None     # nuisance; extras["path_temp_c"] = (value, ci95)
    success: bool = True
    extras: dict = field(default_factory=dict)
    orders: dict = field(default_factory=dict)   # cyclic error: {joint: cycles per revolution}
    approx: bool = False      # True: only the linearised screening (:mod:`.screen`) fitted it

    @property
    def label(self) -> str:
        return label(self.candidate)

    @property
    def holdout(self) -> TableStats:
        return combined(self.hold_points, self.hold_paths)


def hold_residuals(d: DiagData, effects, path_temp_c=None) -> tuple[np.ndarray, np.ndarray]:
    """measured − simulated (points, path samples) of ``d`` under ``effects`` (all rows)."""
    rows = rows_of(d)
    r = rows.meas - evaluate(rows, effects, path_temp_c)[0]
    return r[:rows.n_points], r[rows.n_points:]


def nominal_result(fit_d: DiagData, hold_d: DiagData, keep=None) -> FitResult:
    """The nominal model (no effect) scored like a candidate (k = 0); ``keep`` as in
    :func:`fit_candidate`."""
    fp, fq = hold_residuals(fit_d, [])
    if keep is not None:
        kp = np.asarray(keep, bool)
        fp, fq = fp[kp[:len(fp)]], fq[kp[len(fp):]]
    hp, hq = hold_residuals(hold_d, [])
    n2 = neg2_loglik(fp, fq)
    return FitResult((), [], {}, {}, 0, n2, n2, TableStats.of(fp), TableStats.of(fq),
                     TableStats.of(hp), TableStats.of(hq))


def _templates(c: Candidate, orders: dict | None = None) -> list[fx.EffectInstance]:
    out = []
    for name, joints in c:
        e = fx.EFFECTS[name].guess(joints)
        if name == "cyclic_error" and orders:
            params = dict(e.params)
            for j in joints:
                params[f"{j}_cyclic_period_deg"] = 360.0 / orders.get(j, 1)
            e = fx.make_effect(name, joints, params)
        out.append(e)
    return out


def _linear_start(c: Candidate, fit_d: DiagData, hold_d: DiagData, keep, orders):
    """Start (instances, path temperature, orders) from the linearised fit of ``c`` alone
    (:mod:`.screen`); with ``orders`` given, that harmonic variant."""
    from cell.diagnosis import screen
    B = screen.basis(fit_d, hold_d, [c], keep, None)
    if orders:
        keys = [k for k in screen.keys_of(c)
                if all(kk[2] == orders.get(kk[1]) for kk in k if kk[0] == "cyclic_error")][0]
        sc = screen.fit_variant(B, c, keys)
    else:
        sc = screen.screen(B, c)
    insts, tp = screen.start_params(B, sc)
    return insts, tp, sc.orders


def fit_candidate(c: Candidate, fit_d: DiagData, hold_d: DiagData, n_total: int,
                  rounds: int = 2, start: FitResult | None = None, orders: dict | None = None,
                  x0=None, jac: str = "analytic", keep=None, weights=None) -> FitResult:
    """Fit candidate ``c`` on ``fit_d`` (see module docstring), score it on ``hold_d``.

    ``n_total`` is the number of scalar fit residuals (for BIC's ln n); ``start`` a previous
    result of the same candidate to continue from; ``x0`` a starting point
    ``(instances, path_temp_c)`` (e.g. from :mod:`.screen`), else the linearised fit of
    ``c`` alone; ``orders`` {joint: cycles per revolution} of a cyclic error (default: the
    screened best, or 1 with ``start``); ``jac`` ``"analytic"`` (:mod:`.jacobian`) or
    ``"2-point"`` (finite differences, as before the analytic Jacobians); ``keep`` a (rows,)
    bool mask of the fit rows that count (outliers out); ``weights`` per-table weights to
    begin with. Never raises for a poor fit: a failed solve gives ``success=False`` and
    ``identifiable=False``; raises ValueError for an unknown ``jac`` or ``orders`` that are
    not cycles per revolution of :data:`.screen.ORDERS` on the candidate's cyclic joints.
    """
    if jac not in JACOBIANS:
        raise ValueError(f"jac {jac!r}: choose from {', '.join(JACOBIANS)}")
    cyc = [j for name, joints in c if name == "cyclic_error" for j in joints]
    bad = {j: k for j, k in (orders or {}).items() if j not in cyc or k not in ORDERS}
    if bad:
        raise ValueError(f"orders {bad}: give cycles per revolution from {list(ORDERS)} for "
                         f"the joints of the candidate's cyclic error {cyc}")
    rows = rows_of(fit_d)
    kp = np.ones(rows.n, bool) if keep is None else np.asarray(keep, bool)
    sel_p = np.flatnonzero(kp[:rows.n_points])
    sel_q = rows.n_points + np.flatnonzero(kp[rows.n_points:])
    n_p = 2 * len(sel_p)
    tp0 = None
    if start is not None:
        tmpl, tp0, orders = list(start.effects), start.path_temp_c, dict(start.orders)
    elif x0 is not None:
        tmpl, tp0 = list(x0[0]), x0[1]
        orders = {j: round(360.0 / e.params[f"{j}_cyclic_period_deg"])
                  for e in tmpl if e.effect == "cyclic_error" for j in e.joints}
    elif any(name == "cyclic_error" for name, _ in c) or orders:
        tmpl, tp0, orders = _linear_start(c, fit_d, hold_d, keep, orders)
    else:
        tmpl = _templates(c, orders)
    orders = dict(orders or {})
    x_eff, names = fx.stack_vectors(tmpl)
    lo = np.concatenate([e.bounds()[0] for e in tmpl]) if tmpl else np.zeros(0)
    hi = np.concatenate([e.bounds()[1] for e in tmpl]) if tmpl else np.zeros(0)
    has_tp = any(e.effect == "thermal_drift" for e in tmpl) and bool(fit_d.moves)
    x0v = x_eff
    if has_tp:
        t0 = tp0 if tp0 is not None else \
            (float(np.mean(fit_d.points.temp)) if fit_d.points is not None
             and fit_d.points.temp is not None else 20.0)
        x0v, lo, hi = np.append(x0v, t0), np.append(lo, -50.0), np.append(hi, 150.0)
        names = names + ["path_temp_c"]
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0v = np.clip(x0v, lo + 1e-9 * span, hi - 1e-9 * span)   # none starts held on a bound
    n_eff = len(x0v) - int(has_tp)
    meas = rows.meas

    def unpack(x):
        effs = fx.split_vector(tmpl, x[:n_eff])
        return effs, (float(x[n_eff]) if has_tp else None)

    def resid_of(x, want_jac=False):
        effs, tp = unpack(x)
        pred, J = evaluate(rows, effs, tp, jac=want_jac, with_path_temp=has_tp)
        r = meas - pred
        return r, J

    w = np.array([1.0, 1.0]) if weights is None else np.asarray(weights, float)
    if start is not None:
        w = 1.0 / np.maximum([start.fit_points.rms or 1.0, start.fit_paths.rms or 1.0], 1e-6)
    def fun(x):
        r, _ = resid_of(x)
        return np.concatenate([w[0] * r[sel_p].ravel(), w[1] * r[sel_q].ravel()])

    def jacf(x):
        _, J = resid_of(x, True)
        return -np.concatenate([w[0] * J[sel_p].reshape(-1, J.shape[2]),
                                w[1] * J[sel_q].reshape(-1, J.shape[2])])

    res, ok, w_res = None, True, w
    for rnd in range(rounds):
        try:
            res = least_squares(fun, x0v, jacf if jac == "analytic" else "2-point", lo, hi,
                                max_nfev=200)
        except (ValueError, np.linalg.LinAlgError, fx.ConfigError):
            ok = False
            break
        x0v, w_res = res.x, w
        rp, rq = (res.fun[:n_p] / w[0]).reshape(-1, 2), (res.fun[n_p:] / w[1]).reshape(-1, 2)
        w = 1.0 / np.maximum([TableStats.of(rp).rms or 1.0, TableStats.of(rq).rms or 1.0], 1e-6)
    if res is None or not ok:
        r0 = meas - evaluate(rows, [])[0]
        n2 = neg2_loglik(r0[sel_p], r0[sel_q])
        z = TableStats(0, math.inf, math.inf)
        return FitResult(c, tmpl, {}, {}, len(x0v), n2, math.inf, z, z, z, z, False,
                         "the solver failed", success=False, orders=orders)
    effs, tp = unpack(res.x)
    rp, rq = (res.fun[:n_p] / w_res[0]).reshape(-1, 2), (res.fun[n_p:] / w_res[1]).reshape(-1, 2)
    n2 = neg2_loglik(rp, rq)
    k = len(res.x)
    n_cyc = sum(len(e.joints) for e in effs if e.effect == "cyclic_error")
    bic = n2 + k * math.log(max(n_total, 2)) + ORDER_COST * n_cyc
    hp, hq = hold_residuals(hold_d, effs, tp)
    out = FitResult(c, effs, {}, {}, k, n2, bic, TableStats.of(rp), TableStats.of(rq),
                    TableStats.of(hp), TableStats.of(hq), path_temp_c=tp,
                    success=bool(res.status > 0), orders=orders)
    # Jacobian at the solution, weighted as the next round would -> covariance, intervals,
    # identifiability
    J = np.concatenate([res.jac[:n_p] * (w[0] / w_res[0]), res.jac[n_p:] * (w[1] / w_res[1])]) \
        if jac == "analytic" else res.jac
    s2 = float(np.sum(res.fun ** 2)) / max(len(res.fun) - k, 1)
    raw = np.linalg.norm(J, axis=0)
    norms = np.where(raw > 1e-12 * max(raw.max(), 1e-300), raw, 1.0)  # scale; 0 columns stay 0
    ke = n_eff   # identifiability is judged on the effect parameters (not the nuisance)
    if np.any(raw[:ke] <= 1e-12 * max(raw.max(), 1e-300)):
        out.identifiable, out.reason = False, "a parameter has no effect on the data"
        cov = np.full((k, k), np.inf)
    else:
        Jn = J / norms
        sv = np.linalg.svd(Jn[:, :ke], compute_uv=False)
        out.cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
        cov_n = np.linalg.pinv(Jn.T @ Jn)
        cov = cov_n / np.outer(norms, norms) * s2
        sd = np.sqrt(np.maximum(np.diag(cov_n), 1e-300))
        corr = (cov_n / np.outer(sd, sd))[:ke, :ke]
        np.fill_diagonal(corr, 0.0)
        out.max_corr = float(np.max(np.abs(corr))) if ke > 1 else 0.0
        if out.cond > MAX_COND:
            out.identifiable, out.reason = False, f"Jacobian condition number {out.cond:.3g}"
        elif out.max_corr > MAX_CORR:
            out.identifiable, out.reason = False, \
                f"parameter correlation {out.max_corr:.4f} (near ±1)"
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    all_names = names
    for i, n in enumerate(all_names):
        v = float(res.x[i])
        lo_i, hi_i = v - Z95 * se[i], v + Z95 * se[i]
        if n.endswith("cyclic_phase_deg"):
            shift = (v % 360.0) - v
            v, lo_i, hi_i = v + shift, lo_i + shift, hi_i + shift
        if n == "path_temp_c":
            out.extras["path_temp_c"] = (v, (lo_i, hi_i))
            continue
        out.params[n] = v
        out.ci95[n] = (lo_i, hi_i)
    out.effects = [fx.EffectInstance(e.effect, e.joints,
                                     {**e.params, **{n: out.params[n] for n in e.fit_names}})
                   for e in effs]
    return out


def component_sizes(r: FitResult, fit_d: DiagData) -> list[float]:
    """rms displacement (mm) each fitted component alone makes on the fit rows."""
    base = np.concatenate([x.ravel() for x in predict(fit_d, [])])
    out = []
    for e in r.effects:
        sim = np.concatenate([x.ravel() for x in predict(fit_d, [e], r.path_temp_c)])
        out.append(float(np.sqrt(np.mean((sim - base) ** 2) * 2)))
    return out
