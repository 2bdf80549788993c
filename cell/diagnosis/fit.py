"""Fit one candidate (one or two vocabulary effects) on the fit rows. Pure numerics.

A candidate is a tuple of components ``(effect name, joints)``. :func:`fit_candidate` adds
it to the simulation and fits its parameters with ``scipy.optimize.least_squares`` (trf,
the vocabulary's bounds) on the fit rows only, starting from ``Effect.guess()`` (cyclic
error: amplitude and phase from a linear projection of the residual, so a start in
anti-phase cannot stall on the amplitude's zero bound).

Noise model: every table (points, path samples) has its own Gaussian σ per axis, unknown.
The fit is iteratively reweighted: round 1 weighs every scalar residual alike, round 2
weighs each table by 1/its round-1 rms (the maximum-likelihood weights). ``rounds=1``
stops after round 1; ``start=`` continues a round-1 result with round 2 (the search does
round 1 for every candidate and round 2 for the best few only). The score is the
profile log-likelihood ``−2 ln L = Σ_t n_t·ln(RSS_t/n_t)`` (n_t scalar residuals of table
t), and ``BIC = −2 ln L + k·ln n`` (k fitted parameters). 95 % intervals: ±1.96·SE from
the weighted Jacobian at the solution, ``cov = s²·(JᵀJ)⁻¹`` with s² the weighted residual
variance. Identifiability: a parameter without sensitivity, a column-scaled Jacobian with
condition number above :data:`MAX_COND` or a parameter correlation beyond
:data:`MAX_CORR` makes the candidate not identifiable.

Path temperature: paths.csv has no temperature, so a candidate with thermal_drift fits the
temperature the moves were made at (``path_temp_c``, °C) as a nuisance parameter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
import numpy as np
from scipy.optimize import least_squares

from cell import effects as fx
from cell.diagnosis.replay import DiagData, PointsData, predict
from cell.diagnosis.replay import residuals as resid

MAX_CORR = 0.995
MAX_COND = 1e4
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

    @property
    def label(self) -> str:
        return label(self.candidate)

    @property
    def holdout(self) -> TableStats:
        return combined(self.hold_points, self.hold_paths)


def nominal_result(fit_d: DiagData, hold_d: DiagData) -> FitResult:
    """The nominal model (no effect) scored like a candidate (k = 0)."""
    fp, fq = resid(fit_d, [], None)
    hp, hq = resid(hold_d, [], None)
    n2 = neg2_loglik(fp, fq)
    return FitResult((), [], {}, {}, 0, n2, n2, TableStats.of(fp), TableStats.of(fq),
                     TableStats.of(hp), TableStats.of(hq))


def _templates(c: Candidate) -> list[fx.EffectInstance]:
    return [fx.EFFECTS[name].guess(joints) for name, joints in c]


def _cyclic_start(d: DiagData, tmpl: list[fx.EffectInstance], rp, rq) -> list[fx.EffectInstance]:
    """Replace cyclic_error starts by a linear projection of the nominal residual onto the
    sin/cos responses of each joint (the effect functions evaluated at amplitude 1e-3)."""
    out = list(tmpl)
    r = np.concatenate([rp.ravel(), rq.ravel()])
    base = np.concatenate([x.ravel() for x in predict(d, [])])
    for i, e in enumerate(tmpl):
        if e.effect != "cyclic_error":
            continue
        params = dict(e.params)
        for j in e.joints:
            cols = []
            for ph in (0.0, 90.0):
                probe = dict(e.params)
                for jj in e.joints:
                    probe[f"{jj}_cyclic_amp_deg"] = 0.0
                probe[f"{j}_cyclic_amp_deg"], probe[f"{j}_cyclic_phase_deg"] = 1e-3, ph
                sim = predict(d, [fx.make_effect("cyclic_error", e.joints, probe)])
                cols.append((np.concatenate([x.ravel() for x in sim]) - base) / 1e-3)
            coef, *_ = np.linalg.lstsq(np.column_stack(cols), r, rcond=None)
            spec = e.spec.spec_of(f"{j}_cyclic_amp_deg")
            params[f"{j}_cyclic_amp_deg"] = float(np.clip(math.hypot(*coef), spec.typical[0],
                                                          0.9 * spec.bounds[1]))
            params[f"{j}_cyclic_phase_deg"] = math.degrees(math.atan2(coef[1], coef[0]))
        out[i] = fx.make_effect(e.effect, e.joints, params)
    return out


def fit_candidate(c: Candidate, fit_d: DiagData, hold_d: DiagData, n_total: int,
                  rounds: int = 2, start: FitResult | None = None) -> FitResult:
    """Fit candidate ``c`` on ``fit_d`` (see module docstring), score it on ``hold_d``.

    ``n_total`` is the number of scalar fit residuals (for BIC's ln n); ``start`` a previous
    result of the same candidate to continue from (fewer iterations). Never raises for a
    poor fit: a failed solve gives ``success=False`` and ``identifiable=False``.
    """
    tmpl = _templates(c)
    nominal_rp, nominal_rq = resid(fit_d, [], None)
    if start is None and any(e.effect == "cyclic_error" for e in tmpl):
        tmpl = _cyclic_start(fit_d, tmpl, nominal_rp, nominal_rq)
    x0, names = fx.stack_vectors(tmpl if start is None else start.effects)
    lo = np.concatenate([e.bounds()[0] for e in tmpl]) if tmpl else np.zeros(0)
    hi = np.concatenate([e.bounds()[1] for e in tmpl]) if tmpl else np.zeros(0)
    has_tp = any(e.effect == "thermal_drift" for e in tmpl) and bool(fit_d.moves)
    if has_tp:
        t0 = start.path_temp_c if start is not None and start.path_temp_c is not None else \
            (float(np.mean(fit_d.points.temp)) if fit_d.points is not None
             and fit_d.points.temp is not None else 20.0)
        x0, lo, hi = np.append(x0, t0), np.append(lo, -50.0), np.append(hi, 150.0)
        names = names + ["path_temp_c"]
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.clip(x0, lo + 1e-9 * span, hi - 1e-9 * span)   # strictly inside: trf needs it
    n_eff = len(x0) - int(has_tp)

    def unpack(x):
        effs = fx.split_vector(tmpl, x[:n_eff])
        return effs, (float(x[n_eff]) if has_tp else None)

    w = np.array([1.0, 1.0])
    if start is not None:
        w = 1.0 / np.maximum([start.fit_points.rms, start.fit_paths.rms], 1e-6)

    def fun(x):
        effs, tp = unpack(x)
        rp, rq = resid(fit_d, effs, tp)
        return np.concatenate([w[0] * rp.ravel(), w[1] * rq.ravel()])

    res, ok = None, True
    for rnd in range(rounds):
        try:
            res = least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale="jac",
                                max_nfev=200)
        except (ValueError, np.linalg.LinAlgError, fx.ConfigError):
            ok = False
            break
        x0 = res.x
        effs, tp = unpack(res.x)
        rp, rq = resid(fit_d, effs, tp)
        w = 1.0 / np.maximum([TableStats.of(rp).rms or 1.0, TableStats.of(rq).rms or 1.0], 1e-6)
    if res is None or not ok:
        n2 = neg2_loglik(nominal_rp, nominal_rq)
        z = TableStats(0, math.inf, math.inf)
        return FitResult(c, tmpl, {}, {}, len(x0), n2, math.inf, z, z, z, z, False,
                         "the solver failed", success=False)
    effs, tp = unpack(res.x)
    rp, rq = resid(fit_d, effs, tp)
    n2 = neg2_loglik(rp, rq)
    k = len(res.x)
    bic = n2 + k * math.log(max(n_total, 2))
    hp, hq = resid(hold_d, effs, tp)
    out = FitResult(c, effs, {}, {}, k, n2, bic, TableStats.of(rp), TableStats.of(rq),
                    TableStats.of(hp), TableStats.of(hq), path_temp_c=tp,
                    success=bool(res.status > 0))
    # weighted Jacobian of the last round -> covariance, intervals, identifiability
    J = res.jac
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
