"""The diagnosis as one call, its JSON report (spec format ``cell-diagnosis/1``) and its text.

:func:`diagnose` runs the whole chain on a campaign: nominal replay and gap (:mod:`.replay`),
candidate search with outliers set aside and decision (:mod:`.rank`), where the gap lies
(:mod:`.where`), holdout before/after, the point noise (:mod:`.noise`), the unexplained test
and the per-station lags (:mod:`.delay`). Pure numerics: the caller reads the campaign and
prints or writes the result.

The JSON keeps every key of the spec (``format``, ``gap`` with ``where`` {subsystem,
joints, depends_on, summary}, ``ranking`` entries {effect, joints, params, holdout_rms_mm,
score}, ``cause`` {effect, joints, params, ci95}, ``holdout`` {n, rms_before_mm,
rms_after_mm, shrink}, ``unexplained``) and adds: ``gap.points`` / ``gap.paths``,
``gap.where.effect_sizes`` / ``per_joint_rms_deg``, per-entry ``label``, ``components``,
``identifiable``, ``k``, ``fit`` (``full`` or ``linearised``: only screened);
``cause.subsystem``, ``cause.components``, ``cause.test`` (with ``runner_up_fit``),
``cause.confidence`` (``high`` / ``low``) and ``cause.warnings``, ``cause.cyclic_orders``;
``holdout.points`` / ``holdout.paths`` / max values / ``inliers`` (the same figures without
the outliers); ``remainder``; ``not_identifiable``; ``delay``; ``noise`` (``sigma_mm``,
``source`` given / repeats / residual / paths, ``method``, ``dof``, ``upper95_mm``,
``estimates``); ``outliers``; ``spread``; ``search``; ``split``. ``score`` is the BIC on
the fit rows (lower is better). For a two-effect cause, ``effect`` / ``joints`` name the
larger component (by the rms displacement it makes), ``params`` / ``ci95`` hold both
components' parameters. A cyclic error also reports ``jK_cyclic_order`` (cycles per
revolution) and ``jK_cyclic_period_deg``, their "intervals" being the orders in the 95 %
likelihood set; ``jK_cyclic_amp_deg`` / ``jK_cyclic_phase_deg`` keep their meaning.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.diagnosis import delay as delay_mod
from cell.diagnosis import noise as noise_mod
from cell.diagnosis import crossval, rank, robust, where as where_mod
from cell.diagnosis.page import DEPENDS_TEXT, FORMAT, FORMAT_VERSION, describe_cause
from cell.diagnosis.fit import (FitResult, TableStats, combined, component_sizes,
                                hold_residuals)
from cell.diagnosis.replay import DiagData, path_noise_mm, prepare, residuals
from cell.effects import Stage
from cell.measurements import Campaign



@dataclass
class Diagnosis:
    """Everything one diagnosis computed; ``report`` is the JSON-ready dict."""

    data: DiagData
    search: rank.Search
    decision: rank.Decision
    where: where_mod.Where
    remainder: rank.Remainder
    delay: dict | None
    report: dict

    @property
    def cause(self) -> str:
        return self.report["cause"]["effect"]


def _r(v: float, nd: int = 6) -> float:
    return float(round(v, nd)) if math.isfinite(v) else v


def table_stats(t: TableStats) -> dict:
    """``n``, ``rms_mm``, ``max_mm`` of one table's residual (``gap.points``, ``gap.paths``)."""
    return {"n": t.n, "rms_mm": _r(t.rms), "max_mm": _r(t.max)}


def _main_index(r: FitResult, d: DiagData) -> int:
    if len(r.effects) < 2:
        return 0
    sizes = r.extras.get("component_sizes") or component_sizes(r, d)
    return max(range(len(sizes)), key=lambda i: sizes[i])


def _order_params(r: FitResult, orders: dict) -> tuple[dict, dict]:
    """Cyclic error: ``jK_cyclic_order`` (cycles per revolution) and ``jK_cyclic_period_deg``
    with their 95 % likelihood sets as intervals."""
    params, ci = {}, {}
    for j, o in orders.items():
        s95 = o["set95"] or [o["order"]]
        params[f"{j}_cyclic_order"] = o["order"]
        params[f"{j}_cyclic_period_deg"] = _r(o["period_deg"], 9)
        ci[f"{j}_cyclic_order"] = [min(s95), max(s95)]
        ci[f"{j}_cyclic_period_deg"] = [_r(360.0 / max(s95), 9), _r(360.0 / min(s95), 9)]
    return params, ci


def _components(r: FitResult, orders: dict | None = None) -> list[dict]:
    out = []
    for e in r.effects:
        params = {n: _r(r.params[n], 9) for n in e.fit_names}
        if e.effect == "cyclic_error" and orders:
            params.update(_order_params(r, {j: orders[j] for j in e.joints if j in orders})[0])
        out.append({"effect": e.effect, "joints": list(e.joints), "params": params})
    return out


def _entry(r: FitResult, d: DiagData, s: rank.Search) -> dict:
    main = r.effects[_main_index(r, d)] if r.effects else None
    orders = rank.order_report(s, r) if r.orders else {}
    params = {n: _r(v, 9) for n, v in r.params.items()}
    params.update(_order_params(r, orders)[0])
    out = {"effect": main.effect if main else "none", "joints": list(main.joints) if main else [],
           "params": params,
           "holdout_rms_mm": _r(r.holdout.rms), "score": _r(r.bic, 3), "label": r.label,
           "components": _components(r, orders), "k": r.k, "identifiable": r.identifiable,
           "fit": "linearised" if r.approx else "full"}
    if not r.identifiable:
        out["reason"] = r.reason
    return out


def _holdout_inliers(s: rank.Search, chosen: FitResult | None) -> dict:
    """Holdout before/after on the rows that are not outliers."""
    kh = s.outliers.keep_hold
    np_ = s.hold_d.n_points
    b = hold_residuals(s.hold_d, [])
    a = hold_residuals(s.hold_d, chosen.effects, chosen.path_temp_c) if chosen else b
    tb = combined(TableStats.of(b[0][kh[:np_]]), TableStats.of(b[1][kh[np_:]]))
    ta = combined(TableStats.of(a[0][kh[:np_]]), TableStats.of(a[1][kh[np_:]]))
    shrink = 1.0 - ta.rms / tb.rms if tb.rms > 0 else 0.0
    return {"n": tb.n, "rms_before_mm": _r(tb.rms), "rms_after_mm": _r(ta.rms),
            "shrink": _r(shrink, 4)}


def point_noise(d: DiagData, chosen: FitResult | None, keep_points, noise_mm: float | None,
                path_sigma: float | None) -> tuple[noise_mod.Noise | None, dict]:
    """The point noise the unexplained test uses (:mod:`.noise`) and every estimate."""
    r = None
    if d.points is not None:
        r, _ = hold_residuals(d, chosen.effects if chosen else [],
                              chosen.path_temp_c if chosen else None)
    return point_estimates(d, r, keep_points, noise_mm, path_sigma)


def point_estimates(d: DiagData, r_points: np.ndarray | None, keep_points,
                    noise_mm: float | None, path_sigma: float | None
                    ) -> tuple[noise_mod.Noise | None, dict]:
    """(the best point noise, every estimate by source) from the remainder ``r_points``
    (N, 2) mm of a model on ``d``'s static points, those ``keep_points`` marks (not
    outliers); ``noise_mm`` the given σ, ``path_sigma`` the paths' (:mod:`.noise`)."""
    est: dict = {}
    if noise_mm:
        est["given"] = noise_mod.given(noise_mm)
    p = d.points
    if p is not None:
        k = np.asarray(keep_points, bool)
        r = r_points[k]
        rep = noise_mod.repeats(p.cmd[k], p.dirs[k] if p.has_dirs else None, r)
        res = noise_mod.residual(p.cmd[k], p.time[k], r, (d.geometry.l1_mm, d.geometry.l2_mm))
        if rep is not None:
            est["repeats"] = rep
        if res is not None:
            est["residual"] = res
    pth = noise_mod.from_paths(path_sigma, d.n_path)
    if pth is not None:
        est["paths"] = pth
    return noise_mod.best(*est.values()), est


def remainder_where(w: where_mod.Where | None) -> dict:
    """``remainder``'s ``depends_on``, ``joint``, ``rms_mm``: what the remainder of the named
    cause varies with (:func:`.where.analyse`), all None when it was not analysed."""
    return {"depends_on": w.depends_on if w else None, "joint": w.joint if w else None,
            "rms_mm": _r(w.rms_mm) if w else None}


def where_figures(wh: where_mod.Where) -> dict:
    """The ``gap.where`` figures beyond the spec's: ``depends_on_joint``, ``effect_sizes``
    and ``per_joint_rms_deg`` of :func:`.where.analyse`."""
    return {"depends_on_joint": wh.joint,
            "effect_sizes": {k: {kk: (_r(vv) if isinstance(vv, float) else vv)
                                 for kk, vv in v.items() if kk != "explained_ms"}
                             for k, v in wh.effect_sizes.items()},
            "per_joint_rms_deg": {k: (None if v is None else _r(v, 7))
                                  for k, v in wh.per_joint_rms_deg.items()}}


def diagnose(c: Campaign, lines: dict | None = None, noise_mm: float | None = None,
             method: str = "screened", jac: str = "analytic") -> Diagnosis:
    """Diagnose campaign ``c`` (see module docstring). ``lines`` maps table -> file line of
    each row (error messages); ``noise_mm`` the expected σ per axis (mm) of one static point
    measurement, repeatability included, if known (else it is estimated from the data, see
    :mod:`.noise`); ``method`` / ``jac`` as in :func:`.rank.search` (the defaults are the
    fast ones; ``"exhaustive"`` / ``"2-point"`` the way it was done before, for the speed
    benchmark). Raises CampaignFormatError for semantic campaign problems, ValueError for
    an unknown method."""
    d = prepare(c, lines)
    rp, rq = residuals(d)
    gap_p, gap_q = TableStats.of(rp), TableStats.of(rq)
    gap = combined(gap_p, gap_q)
    s = rank.search(d, method, jac)
    keep = robust.keep_all(d, s.outliers)
    wh = where_mod.analyse(d, rp, rq, keep)
    dec, judged = rank.judge(s, rank.decide(s), jac)
    before = s.nominal.holdout
    after = dec.chosen.holdout if dec.chosen else before
    shrink = 1.0 - after.rms / before.rms if before.rms > 0 else 0.0
    inl = _holdout_inliers(s, dec.chosen)
    sigma_q = path_noise_mm(d)
    pn, estimates = point_noise(d, dec.chosen, keep[0], noise_mm, sigma_q)
    rem = rank.unexplained(d, s, dec, inl["shrink"], sigma_q, pn)
    confidence, warnings = rank.assess(s, dec)
    if judged is not None and judged.rivals:
        confidence = "ambiguous"
        tested = [r.label for r in judged.rivals if not r.untestable]
        if tested:
            warnings.insert(0, "the campaign cannot tell the cause from " + ", ".join(tested)
                            + ": they predict the left-out places as well (cause.rivals; "
                            "cause.separating_poses says where to measure next)")
        for r in judged.rivals:
            if r.untestable:
                warnings.insert(0, f"the cause may be {r.label}, which this campaign cannot "
                                f"test ({r.untestable}): measure what it lacks and diagnose again")
    if judged is not None and judged.n_folds < crossval.MIN_FOLDS and confidence == "high":
        confidence = "low"
        warnings.extend(judged.notes)
    if rem.unexplained and confidence == "high":
        confidence = "low"
        warnings.append("the named cause leaves most of the gap unexplained: it is the best "
                        "candidate, not a diagnosis")
    # the lags are fitted with the cause's static part only when the cause explains the gap
    trusted = dec.chosen is not None and not rem.unexplained
    static = [e for e in dec.chosen.effects if e.spec.stage != Stage.COMMS] if trusted else []
    dl = delay_mod.station_lags(d, static, dec.chosen.path_temp_c if trusted else None,
                                s.outliers.keep_fit[s.fit_d.n_points:])

    orders = rank.order_report(s, dec.chosen) if dec.chosen is not None else {}
    if dec.chosen is not None:
        main = dec.chosen.effects[_main_index(dec.chosen, s.fit_d)]
        op, oc = _order_params(dec.chosen, orders)
        cause = {"effect": main.effect, "joints": list(main.joints),
                 "params": {n: _r(v, 9) for n, v in dec.chosen.params.items()} | op,
                 "ci95": {n: [_r(lo, 9), _r(hi, 9)] for n, (lo, hi) in dec.chosen.ci95.items()}
                 | oc,
                 "subsystem": main.spec.subsystem, "components": _components(dec.chosen, orders)}
        if orders:
            cause["cyclic_orders"] = orders
        if "path_temp_c" in dec.chosen.extras:
            v, (lo, hi) = dec.chosen.extras["path_temp_c"]
            cause["nuisance"] = {"path_temp_c": _r(v, 4), "path_temp_c_ci95": [_r(lo, 4), _r(hi, 4)]}
        subsystem, joints = main.spec.subsystem, list(main.joints)
    else:
        cause = {"effect": "none", "joints": [], "params": {}, "ci95": {}, "subsystem": "none",
                 "components": []}
        subsystem, joints = "none", []
    cause["test"] = {"p_value": dec.p_value, "delta_bic": _r(dec.delta_bic, 3),
                     "pair_p_value": dec.pair_p_value, "alpha": rank.ALPHA,
                     "runner_up": dec.runner_up,
                     "runner_up_margin_bic": None if dec.margin_bic is None else _r(dec.margin_bic, 3),
                     "runner_up_fit": None if dec.rival is None else
                     ("linearised" if dec.rival.approx else "full")}
    cause["confidence"] = confidence
    cause["warnings"] = warnings
    cause["label"] = dec.chosen.label if dec.chosen is not None else "none"
    cause["selection"] = _selection(judged, dec)
    cause["rivals"] = _rivals(judged, s)
    cause["separating_poses"] = (
        crossval.separating_poses(s.basis, s.screened, dec.chosen.candidate, judged.rivals,
                                  s.fit_d, d.geometry.limits[:2],
                                  pn.sigma_mm if pn is not None else None)
        if judged is not None and judged.rivals and dec.chosen is not None else [])
    where = {"subsystem": subsystem, "joints": joints, "depends_on": wh.depends_on,
             "summary": _summary(gap, wh, cause, rem)} | where_figures(wh)
    not_ident = dict(s.skipped) | {r.label: r.reason for r in s.ranking if not r.identifiable}
    for j, (rho, pair) in s.order_layout.items():
        if rho > rank.MAX_CORR:
            not_ident[f"cyclic_error[{j}] order"] = (
                f"the angles of {j} in the fit rows cannot separate {pair[0]} from {pair[1]} "
                f"cycles per revolution (canonical correlation {rho:.4f} > {rank.MAX_CORR})")
    noise_rep = {"path_sigma_mm": None if sigma_q is None else _r(sigma_q, 7),
                 "fit_rms_points_mm": _r((dec.chosen or s.nominal).fit_points.rms),
                 "fit_rms_paths_mm": _r((dec.chosen or s.nominal).fit_paths.rms),
                 "sigma_mm": None, "source": None}
    if pn is not None:
        noise_rep |= pn.as_dict()
    noise_rep["estimates"] = {k: v.as_dict() for k, v in estimates.items()}
    report = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "source": c.source,
        "gap": {"rms_mm": _r(gap.rms), "max_mm": _r(gap.max), "n": gap.n, "where": where,
                "points": table_stats(gap_p), "paths": table_stats(gap_q)},
        "ranking": [_entry(r, s.fit_d, s) for r in s.ranking],
        "cause": cause,
        "holdout": {"n": before.n, "rms_before_mm": _r(before.rms), "rms_after_mm": _r(after.rms),
                    "shrink": _r(shrink, 4), "max_before_mm": _r(before.max),
                    "max_after_mm": _r(after.max),
                    "points": {"n": s.nominal.hold_points.n,
                               "rms_before_mm": _r(s.nominal.hold_points.rms),
                               "rms_after_mm": _r((dec.chosen or s.nominal).hold_points.rms)},
                    "paths": {"n": s.nominal.hold_paths.n,
                              "rms_before_mm": _r(s.nominal.hold_paths.rms),
                              "rms_after_mm": _r((dec.chosen or s.nominal).hold_paths.rms)},
                    "inliers": inl},
        "unexplained": rem.unexplained,
        "remainder": {"reasons": rem.reasons, "notes": rem.notes,
                      "systematic_share": None if rem.systematic_share is None
                      else _r(rem.systematic_share, 4),
                      "path_noise_ratio": None if rem.path_noise_ratio is None
                      else _r(rem.path_noise_ratio, 3),
                      "point_noise_ratio": None if rem.point_noise_ratio is None
                      else _r(rem.point_noise_ratio, 3),
                      } | remainder_where(rem.where),
        "not_identifiable": not_ident,
        "delay": dl,
        "noise": noise_rep,
        "outliers": robust.describe(s.outliers, s.fit_d, s.hold_d),
        "spread": {k: (_r(v, 3) if isinstance(v, float) else v) for k, v in s.spread.items()},
        "search": {"method": s.stats.get("method"), "screened": s.stats.get("screened"),
                   "full_fits": s.stats.get("full_fits"),
                   "outlier_rounds": s.stats.get("outlier_rounds")},
        "split": {"source": d.split_source, "fit_rows": s.fit_d.n_points + s.fit_d.n_path,
                  "holdout_rows": s.hold_d.n_points + s.hold_d.n_path},
    }
    return Diagnosis(d, s, dec, wh, rem, dl, report)


def _scored(x: "crossval.Scored") -> dict:
    return {"label": x.label, "k": x.k, "cv_rms": _r(x.cv_rms, 4),
            "p_worse_than_best": _r(x.p_worse, 6), "tied": x.tied}


def _selection(j: "crossval.Judgement | None", dec: rank.Decision) -> dict:
    """How the cause was chosen out of sample (:mod:`.crossval`): folds, the rule and the
    comparison table (prediction rms in noise units, 1 ≈ noise)."""
    if j is None:
        return {"method": "in-sample (BIC)", "folds": 0}
    return {"method": "leave-one-place-out prediction, then fewest parameters",
            "folds": j.n_folds, "places": j.n_places, "alpha": crossval.ALPHA,
            "rival_ratio": crossval.RIVAL_RATIO, "testable": j.testable,
            "best": j.best.label if j.best else None,
            "named": dec.chosen.label if dec.chosen is not None else "none",
            "nominal_cv_rms": _r(j.nominal.cv_rms, 4) if j.nominal else None,
            "table": [_scored(x) for x in j.table[:crossval.REPORTED]], "notes": j.notes}


def _rivals(j: "crossval.Judgement | None", s: rank.Search) -> list[dict]:
    """The tied candidates that are other explanations, with their evidence."""
    if j is None:
        return []
    out = []
    for x in j.rivals:
        comps = [{"effect": e, "joints": list(js)} for e, js in x.candidate]
        if x.untestable:
            out.append({"label": x.label, "k": x.k, "effects": [e for e, _ in x.candidate],
                        "joints": sorted({jn for _, js in x.candidate for jn in js}),
                        "components": comps, "testable": False,
                        "why": f"not testable: {x.untestable}"})
            continue
        sc = s.screened[x.candidate]
        out.append(_scored(x) | {
            "effects": [e for e, _ in x.candidate],
            "joints": sorted({jn for _, js in x.candidate for jn in js}),
            "components": comps,
            "holdout_rms_mm": _r(math.sqrt((sc.hold_rss[0] + sc.hold_rss[1])
                                           / max(s.nominal.holdout.n, 1) / 2)),
            "fit": "linearised", "testable": True})
    return out


def _summary(gap: TableStats, wh: where_mod.Where, cause: dict, rem: rank.Remainder) -> str:
    es = wh.effect_sizes.get(wh.depends_on, {})
    on = f" of {wh.joint}" if wh.joint else ""
    s = (f"The gap (rms {gap.rms:.4f} mm over {gap.n} rows) {DEPENDS_TEXT[wh.depends_on]}{on}: "
         f"that alone explains {100 * es.get('r2', 0.0):.0f} % of its mean square")
    if cause["effect"] == "none":
        s += "; no effect of the vocabulary is supported beyond noise"
    else:
        s += f"; the best-supported cause is {describe_cause(cause)}"
    if rem.unexplained:
        s += ", but most of the gap is left unexplained"
        if rem.where is not None:
            s += f" (the remainder {DEPENDS_TEXT[rem.where.depends_on]})"
    return s + "."
