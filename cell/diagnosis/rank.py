"""Which effect: screen every candidate, fit the few that matter, decide. Pure numerics.

Search (:func:`search`):

1. every identifiable single candidate (:func:`.candidates.single_candidates`) and every
   pair of two of them (same effect on both joints merges into one component) is screened:
   a linearised fit on the nominal model's exact Jacobian, ranked by approximate BIC
   (:mod:`.screen`; a cyclic error in every harmonic order 1–4, the best kept);
2. the candidates the decision below looks at (the best single, the best pair and its
   nested single, the best rival of another effect when it is within
   :data:`RIVAL_FULL_FIT` of the cause) are fitted in full (:mod:`.fit`, two reweighted
   rounds, exact Jacobian), and the decision is taken again until it only looks at full
   fits; the ranking lists the full fits and, marked, the screened-only candidates;
3. outliers: the rows the chosen model leaves far off (:mod:`.robust`) are set aside and
   the search repeated until those flags settle (at most :data:`OUTLIER_ROUNDS` rounds).

``method="exhaustive"`` is the search before the screening (every single fitted in full,
pairs of the :data:`PAIR_TOPS` best singles, a second round for the best :data:`REFINE`),
kept for the speed benchmark.

Ranking: identifiable candidates by BIC on the fit rows (lower is better), then the ones
that failed the identifiability check (listed, never chosen).

Decision (:func:`decide`), with family-wise error rate :data:`ALPHA`:

* **none**: the best single is compared with the nominal model by a likelihood-ratio test
  (2·Δln L ~ χ²_k under "no effect"), Bonferroni-corrected over the single variants tried
  (each harmonic order counts). Not significant -> ``none``.
* **pair**: the best pair replaces the best single only if its BIC is lower *and* the
  likelihood-ratio test against its better nested single is significant (Bonferroni over
  the pair variants tried).

Confidence (:func:`assess`): ``low``, with a warning for each reason, when another effect
is within :data:`BIC_STRONG` of the cause (less than "very strong" evidence, Kass &
Raftery 1995), when the fit rows cover too few places (:func:`.robust.spread`), when the
harmonic order of a cyclic cause is not pinned down (the layout cannot separate the orders,
or several lie in the 95 % likelihood set), or when too many rows are far off to be set
aside as outliers.

**Unexplained** (:func:`unexplained`, on the rows that are not outliers): the chosen model
leaves most of the holdout gap (shrink < :data:`MIN_SHRINK`), or what it leaves is still
systematic: a smooth cubic field in (x, y) fitted to the remainder on the fit points
predicts more than :data:`MAX_SYSTEMATIC` of the remainder's mean square on the holdout
points, or the paths' holdout remainder is more than :data:`MAX_PATH_NOISE_RATIO` × the
model-free path noise (second differences along each move), or the points' holdout
remainder is more than :data:`MAX_POINT_NOISE_RATIO_GIVEN` × the point noise (given, or
estimated from revisited poses or from the remainder's own structure, :mod:`.noise`; its
95 % upper bound), else more than :data:`MAX_POINT_NOISE_RATIO_PATHS` × the path noise
(points also carry repeatability, which a path does not show). A remainder that varies from
pose to pose without pattern in joints or time (e.g. backlash without direction columns)
counts as noise for the estimate from the remainder; the report says so in
``remainder.notes``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis import crossval, robust, screen
from cell.diagnosis import where as where_mod
from cell.diagnosis.candidates import merge, single_candidates
from cell.diagnosis.fit import (MAX_CORR, FitResult, TableStats, fit_candidate, hold_residuals,
                                label, nominal_result, subset)
from cell.diagnosis.replay import DiagData
from cell.numerics.stats import chi2_ppf, chi2_sf

ALPHA = 1e-3
REFINE = 4
PAIR_TOPS = 3
MIN_SHRINK = 0.5
MAX_SYSTEMATIC = 0.5
MAX_PATH_NOISE_RATIO = 2.0
MAX_POINT_NOISE_RATIO_GIVEN = 3.0
MAX_POINT_NOISE_RATIO_PATHS = 5.0
BIC_STRONG = 10.0
RIVAL_FULL_FIT = 10 * BIC_STRONG
CHI2_95_1 = float(chi2_ppf(0.95, 1))     # 3.84: 95 % likelihood set of one parameter
OUTLIER_ROUNDS = 3
METHODS = ("screened", "exhaustive")
_CONSTANTS = {name: tuple(p.stem for p in e.params if not p.fitted)   # e.g. cyclic period
              for name, e in fx.EFFECTS.items()}


@dataclass
class Search:
    """All fits of one campaign: ``nominal``, ``singles``, ``pairs``, ``skipped``
    {label: reason}, ``ranking`` (identifiable by BIC, then the rest). Entries with
    ``approx`` were only screened (:mod:`.screen`). ``outliers`` the flags the fits left
    out (:mod:`.robust`), ``spread`` the fit rows' places, ``order_layout`` {joint: (largest
    canonical correlation between two harmonic orders, those orders)}, ``tries`` the
    number of single / pair variants weighed (harmonic orders counted), ``stats`` counts;
    ``basis`` / ``screened`` the screening's columns (with the cross-validation folds) and
    its linearised fits {candidate: Screened}, ``n_places`` the fit poses' places
    (:mod:`.crossval`)."""

    nominal: FitResult
    singles: list[FitResult]
    pairs: list[FitResult]
    skipped: dict[str, str]
    fit_d: DiagData
    hold_d: DiagData
    ranking: list[FitResult] = field(default_factory=list)
    outliers: robust.Outliers | None = None
    spread: dict = field(default_factory=dict)
    order_layout: dict = field(default_factory=dict)
    tries: tuple[int, int] = (0, 0)
    stats: dict = field(default_factory=dict)
    basis: screen.Basis | None = None
    screened: dict = field(default_factory=dict)
    n_places: int = 0


def _key(r: FitResult):
    return (not r.identifiable, r.bic)


def _pairs_of(cands: list) -> list:
    seen, out = set(), []
    for i, a in enumerate(cands):
        for b in cands[i + 1:]:
            c = merge(a, b)
            if c is not None and c not in seen:
                seen.add(c)
                out.append(c)
    return out


def _approx(B: screen.Basis, sc: screen.Screened, n_rows: tuple[int, int]) -> FitResult:
    """A screened candidate as a FitResult (``approx``; no intervals, no max)."""
    comps, tp = screen.params_of(B, sc)
    effects = [fx.EffectInstance(n, j, p) for n, j, p in comps]
    params = {k: v for name, _, p in comps for k, v in p.items()
              if not k.endswith(_CONSTANTS.get(name, ()))}

    def st(rss, n):
        return TableStats(n, math.sqrt(rss / n) if n else 0.0, math.nan)
    n_fit = (B.fit[0].n // 2, B.fit[1].n // 2)
    fp, fq = st(sc.rss[0], n_fit[0]), st(sc.rss[1], n_fit[1])
    hp, hq = st(sc.hold_rss[0], n_rows[0]), st(sc.hold_rss[1], n_rows[1])
    r = FitResult(sc.candidate, effects, params, {}, sc.k, sc.neg2ll, sc.bic, fp, fq, hp, hq,
                  sc.identifiable, sc.reason, sc.max_corr, sc.cond, tp, orders=dict(sc.orders),
                  approx=True)
    r.extras["order_dev"] = sc.order_dev
    if len(sc.candidate) > 1:           # rms displacement of each component (linearised)
        G = B.fit[0].G + B.fit[1].G
        n = max(B.fit[0].n + B.fit[1].n, 1)
        sizes = []
        for name, joints in sc.candidate:
            idx = [i for key in sc.keys if key[0] == name and (key[1] in joints or key[1] is None)
                   for i in B.cols[key]]
            sel = [sc.keys.index(key) for key in sc.keys
                   if key[0] == name and (key[1] in joints or key[1] is None)]
            xs = np.concatenate([sc.x[_slice(B, sc, i)] for i in sel])
            sizes.append(math.sqrt(max(float(xs @ G[np.ix_(idx, idx)] @ xs), 0.0) / n * 2))
        r.extras["component_sizes"] = sizes
    return r


def _slice(B: screen.Basis, sc: screen.Screened, i: int) -> slice:
    start = sum(len(B.cols[k]) for k in sc.keys[:i])
    return slice(start, start + len(B.cols[sc.keys[i]]))


def search(d: DiagData, method: str = "screened", jac: str = "analytic") -> Search:
    """Fit the candidates of ``d`` (module docstring) and rank them, setting outliers aside
    (:mod:`.robust`) until their flags settle. ``method`` ``"screened"`` (linearised
    screening, full fits of what the decision needs) or ``"exhaustive"`` (every single and
    the pairs of the best three fitted in full, as before the screening); ``jac``
    ``"analytic"`` or ``"2-point"`` for the full fits. Raises ValueError for another
    method."""
    if method not in METHODS:
        raise ValueError(f"method {method!r}: choose from {', '.join(METHODS)}")
    fit_d, hold_d = subset(d, "fit"), subset(d, "holdout")
    cands, skipped = single_candidates(d)
    out = robust.none_flagged(fit_d, hold_d)
    rounds = 0
    while True:
        rounds += 1
        s = (_screened if method == "screened" else _exhaustive)(fit_d, hold_d, cands, skipped,
                                                                 out, jac)
        ref = decide(s).chosen or next((r for r in s.ranking if r.identifiable and r.success
                                        and not r.approx and len(r.candidate) == 1), None)
        new = robust.flag(fit_d, hold_d, ref.effects if ref else [],
                          ref.path_temp_c if ref else None)
        if np.array_equal(new.fit, out.fit) or rounds > OUTLIER_ROUNDS:
            if not np.array_equal(new.fit, out.fit):
                out.notes.append(f"outlier flags still changing after {rounds} rounds; the "
                                 "last fits left out the flags of the round before")
                new = out
            break
        out = new
    s.outliers = new
    s.spread = robust.spread(fit_d, max(screen.ORDERS))
    s.stats["outlier_rounds"] = rounds
    s.stats["method"] = method
    return s


def _order_layout(B: screen.Basis, cands) -> dict:
    out = {}
    for c in cands:
        (name, joints), = c
        if name == "cyclic_error":
            out[joints[0]] = screen.order_separation(B, joints[0])
    return out


def _screened(fit_d, hold_d, cands, skipped, out: robust.Outliers, jac) -> Search:
    keep = out.keep_fit
    n_total = 2 * int(keep.sum())
    nominal = nominal_result(fit_d, hold_d, keep)
    fold_of, _, n_places = crossval.folds(fit_d)
    B = screen.basis(fit_d, hold_d, cands, keep, None, fold_of)
    hold_rows = (hold_d.n_points, hold_d.n_path)
    pcands = _pairs_of(cands)
    scs = screen.screen_all(B, cands + pcands)
    res = {c: _approx(B, sc, hold_rows) for c, sc in scs.items()}
    tries = (sum(len(screen.keys_of(c)) for c in cands),
             sum(len(screen.keys_of(c)) for c in pcands))
    n_full = 0
    while True:
        s = Search(nominal, [res[c] for c in cands], [res[c] for c in pcands], skipped,
                   fit_d, hold_d, tries=tries)
        s.ranking = sorted(s.singles + s.pairs, key=_key)
        todo = {r.candidate: r for r in decide(s).touched if r.approx}
        if not todo:
            break
        for r in todo.values():
            sc = scs[r.candidate]
            full = fit_candidate(r.candidate, fit_d, hold_d, n_total, rounds=2,
                                 x0=screen.start_params(B, sc), jac=jac, keep=keep,
                                 weights=sc.weights)
            full.extras["order_dev"] = sc.order_dev
            res[r.candidate] = full
            n_full += 1
    s.order_layout = _order_layout(B, cands)
    s.stats = {"screened": len(scs), "full_fits": n_full}
    s.basis, s.screened, s.n_places = B, scs, n_places
    return s


def _exhaustive(fit_d, hold_d, cands, skipped, out: robust.Outliers, jac) -> Search:
    """The search before the screening: every single fitted in full (a cyclic error once
    per harmonic order, the best kept), pairs of the best :data:`PAIR_TOPS` singles with
    every other single, a second round for the best :data:`REFINE`."""
    keep = out.keep_fit
    n_total = 2 * int(keep.sum())
    nominal = nominal_result(fit_d, hold_d, keep)
    n_full = 0

    def fit(c, orders=None, rounds=1, start=None):
        nonlocal n_full
        n_full += 1
        return fit_candidate(c, fit_d, hold_d, n_total, rounds=rounds, start=start,
                             orders=orders, jac=jac, keep=keep)
    singles = []
    for c in cands:
        (name, joints), = c
        if name != "cyclic_error":
            singles.append(fit(c))
            continue
        variants = [fit(c, {joints[0]: k}) for k in screen.ORDERS]
        best = min(variants, key=lambda r: (not r.identifiable, r.neg2ll))
        best.extras["order_dev"] = {joints[0]: {v.orders[joints[0]]: v.neg2ll - best.neg2ll
                                                for v in variants}}
        singles.append(best)
    order = sorted(singles, key=_key)
    orders_of = {r.candidate: r.orders for r in singles}
    pair_cands, seen = [], set()
    for top in [r.candidate for r in order[:PAIR_TOPS]]:
        for other in singles:
            c = merge(top, other.candidate) if other.candidate != top else None
            if c is not None and c not in seen:
                seen.add(c)
                pair_cands.append((c, {**orders_of[top], **orders_of[other.candidate]}))
    pairs = [fit(c, o or None) for c, o in pair_cands]
    everything = sorted(singles + pairs, key=_key)
    refined = {id(r): fit(r.candidate, rounds=1, start=r) for r in everything[:REFINE]
               if r.success}
    for r in everything[:REFINE]:
        if id(r) in refined:
            refined[id(r)].extras.update(r.extras)
    singles = [refined.get(id(r), r) for r in singles]
    pairs = [refined.get(id(r), r) for r in pairs]
    tries = (sum(len(screen.keys_of(c)) for c in cands), len(pairs))
    s = Search(nominal, singles, pairs, skipped, fit_d, hold_d, tries=tries)
    s.ranking = sorted(singles + pairs, key=_key)
    B = screen.basis(fit_d, hold_d, [c for c in cands if c[0][0] == "cyclic_error"], keep, None)
    s.order_layout = _order_layout(B, [c for c in cands if c[0][0] == "cyclic_error"])
    s.stats = {"screened": 0, "full_fits": n_full}
    return s


@dataclass
class Decision:
    """``chosen`` FitResult or None (``none``); ``p_value`` of the effect-vs-nominal test
    (Bonferroni-adjusted), ``delta_bic`` (nominal − chosen), ``pair_p_value`` if a pair was
    weighed, ``runner_up`` the best rival naming a different effect and its BIC margin;
    ``touched`` every result the decision looked at (the search fits those in full)."""

    chosen: FitResult | None
    p_value: float
    delta_bic: float
    pair_p_value: float | None = None
    runner_up: str | None = None
    margin_bic: float | None = None
    touched: list = field(default_factory=list)
    rival: FitResult | None = None


def _lr_p(null: FitResult, alt: FitResult, m: int) -> float:
    stat = max(null.neg2ll - alt.neg2ll, 0.0)
    dof = max(alt.k - null.k, 1)
    return min(1.0, float(chi2_sf(stat, dof)) * max(m, 1))


def decide(s: Search) -> Decision:
    """Apply the none / pair rules of the module docstring."""
    ok_singles = sorted([r for r in s.singles if r.identifiable and r.success], key=_key)
    if not ok_singles:
        return Decision(None, 1.0, 0.0)
    best = ok_singles[0]
    touched = [best]
    p = _lr_p(s.nominal, best, s.tries[0] or len(s.singles))
    dbic = s.nominal.bic - best.bic
    if p >= ALPHA or dbic <= 0:
        return Decision(None, p, dbic, touched=touched)
    chosen, pair_p = best, None
    ok_pairs = sorted([r for r in s.pairs if r.identifiable and r.success], key=_key)
    if ok_pairs and ok_pairs[0].bic < best.bic:
        pr = ok_pairs[0]
        touched.append(pr)
        nested = [r for r in s.singles if _nested(r.candidate, pr.candidate)]
        if nested:
            sub = min(nested, key=lambda r: r.bic)
            touched.append(sub)
            pair_p = _lr_p(sub, pr, s.tries[1] or len(s.pairs))
            if pair_p < ALPHA:
                chosen = pr
    names = {e for e, _ in chosen.candidate}
    rival = next((r for r in s.ranking if r.identifiable and r is not chosen
                  and not ({e for e, _ in r.candidate} & names)), None)
    if rival is not None and (not rival.approx or rival.bic - chosen.bic < RIVAL_FULL_FIT):
        touched.append(rival)
    return Decision(chosen, p, s.nominal.bic - chosen.bic, pair_p,
                    rival.label if rival else None, (rival.bic - chosen.bic) if rival else None,
                    touched, rival)


def judge(s: Search, dec: Decision, jac: str = "analytic") -> tuple[Decision, "crossval.Judgement | None"]:
    """The out-of-sample choice of :mod:`.crossval` on top of :func:`decide`: when the
    decision names a cause, the simplest candidate that predicts left-out places as well
    as the best is named instead (fitted in full if it was only screened), and the
    candidates the places cannot tell from it are its rivals. ``none`` stays ``none``.
    Returns the (possibly new) decision and the judgement (None without folds, e.g. the
    exhaustive search)."""
    B = s.basis
    if B is None or not B.n_folds:
        return dec, None
    ref = s.screened.get(dec.chosen.candidate) if dec.chosen is not None else None
    w = ref.weights if ref is not None else (1.0, 1.0)
    j = crossval.judge(B, s.screened, dec.chosen.candidate if dec.chosen else None, w,
                       s.n_places, lambda c: label(c))
    if dec.chosen is None or j.named is None:
        return dec, j
    j.rivals += crossval.untestable_rivals([j.named] + [r.candidate for r in j.rivals], s.skipped)
    if j.named == dec.chosen.candidate:
        return dec, j
    new = next((r for r in s.ranking if r.candidate == j.named and not r.approx), None)
    if new is None:
        sc = s.screened[j.named]
        keep = s.outliers.keep_fit if s.outliers is not None else None
        n_total = 2 * int(np.sum(keep)) if keep is not None else s.basis.n_total
        new = fit_candidate(j.named, s.fit_d, s.hold_d, n_total, rounds=2,
                            x0=screen.start_params(B, sc), jac=jac, keep=keep,
                            weights=sc.weights)
        new.extras["order_dev"] = sc.order_dev
        s.stats["full_fits"] = s.stats.get("full_fits", 0) + 1
    if not (new.identifiable and new.success):
        return dec, j
    m = s.tries[0] if len(j.named) == 1 else s.tries[1]
    rival = j.rivals[0].label if j.rivals else dec.runner_up
    return Decision(new, _lr_p(s.nominal, new, m or 1), s.nominal.bic - new.bic, None, rival,
                    None, dec.touched + [new]), j


def _nested(single, pair) -> bool:
    (e, js), = single
    return any(e == pe and set(js) <= set(pj) for pe, pj in pair)


def order_report(s: Search, r: FitResult) -> dict:
    """Per cyclic joint of ``r``: the harmonic order, Δ(−2 ln L) of every order screened,
    the orders in the 95 % likelihood set (Δ ≤ χ²₁(0.95)), whether the layout separates the
    orders (largest canonical correlation ≤ MAX_CORR) and why not."""
    out = {}
    lim = CHI2_95_1
    dev = r.extras.get("order_dev", {})
    for j, k in r.orders.items():
        dj = dev.get(j, {k: 0.0})
        rho, pair = s.order_layout.get(j, (0.0, (0, 0)))
        sep = rho <= MAX_CORR
        out[j] = {"order": int(k), "period_deg": 360.0 / k,
                  "delta_neg2ll": {int(o): round(float(v), 3) for o, v in sorted(dj.items())},
                  "set95": sorted(int(o) for o, v in dj.items() if v <= lim),
                  "layout_separates": bool(sep), "max_canonical_corr": round(float(rho), 6)}
        if not sep:
            out[j]["reason"] = (f"the angles of {j} in the fit rows cannot separate {pair[0]} "
                                f"from {pair[1]} cycles per revolution (canonical correlation "
                                f"{rho:.4f} > {MAX_CORR})")
    return out


def assess(s: Search, dec: Decision) -> tuple[str, list[str]]:
    """(confidence ``high`` / ``low``, warnings) of the decision: a runner-up of another
    effect within :data:`BIC_STRONG` (less than "very strong" evidence, Kass & Raftery
    1995), fit rows on too few places (:func:`.robust.spread`), a harmonic order the layout
    or the data cannot pin down, outliers too many to set aside."""
    warn = []
    if dec.chosen is not None and dec.margin_bic is not None and dec.margin_bic < BIC_STRONG:
        warn.append(f"runner-up {dec.runner_up} is only ΔBIC {dec.margin_bic:.1f} worse "
                    f"(< {BIC_STRONG:g}: not strong evidence for the cause over it)")
    sp = s.spread
    if sp.get("few"):
        warn.append(f"the fit rows cover {sp['places']} places ({sp['distinct_poses']} distinct "
                    f"poses, {sp['cell_deg']:.1f}° cells): too few to tell causes apart or to "
                    "check the remainder")
    if dec.chosen is not None:
        for j, o in order_report(s, dec.chosen).items():
            if not o["layout_separates"]:
                warn.append(f"cyclic error on {j}: harmonic order not identifiable from this "
                            f"layout ({o['reason']})")
            elif len(o["set95"]) > 1:
                warn.append(f"cyclic error on {j}: harmonic orders {o['set95']} all fit (95 % "
                            "likelihood set); the order is not pinned down")
    if s.outliers is not None and not all(s.outliers.set_aside):
        warn.append("many rows far off: " + "; ".join(s.outliers.notes))
    return ("low" if warn else "high"), warn


@dataclass
class Remainder:
    """What the chosen model leaves: ``systematic_share`` of the holdout points' remainder a
    smooth field predicts, ``path_noise_ratio`` (holdout path rms / (√2·path σ)),
    ``point_noise_ratio`` (holdout point rms / (√2·point noise bound)), ``unexplained`` and
    the reasons, ``where`` of the remainder (all rows but outliers)."""

    unexplained: bool
    reasons: list[str]
    systematic_share: float | None
    path_noise_ratio: float | None
    where: where_mod.Where | None = None
    notes: list[str] = field(default_factory=list)
    point_noise_ratio: float | None = None


def unexplained(d: DiagData, s: Search, dec: Decision, shrink: float,
                path_sigma: float | None, point_noise=None) -> Remainder:
    """The unexplained test of the module docstring, on the rows that are not outliers.
    ``shrink`` the holdout shrink on those rows; ``point_noise`` a :class:`.noise.Noise`
    (σ per axis of a static point measurement and where it came from) or None."""
    effects = dec.chosen.effects if dec.chosen else []
    tp = dec.chosen.path_temp_c if dec.chosen else None
    out = s.outliers or robust.none_flagged(s.fit_d, s.hold_d)
    reasons: list[str] = []
    if dec.chosen is not None and shrink < MIN_SHRINK:
        reasons.append(f"holdout shrink {shrink:.2f} < {MIN_SHRINK}")
    rf_all, rfq = hold_residuals(s.fit_d, effects, tp)
    rh_all, rhq = hold_residuals(s.hold_d, effects, tp)
    kf = out.keep_fit[:len(rf_all)]
    kh = out.keep_hold[:len(rh_all)]
    share = None
    if s.fit_d.points is not None and s.hold_d.points is not None and kh.any():
        rf, rh = rf_all[kf], rh_all[kh]
        xy = np.vstack([s.fit_d.points.xy[kf] - rf, s.hold_d.points.xy[kh] - rh])
        X = where_mod._poly3(xy)
        X = np.column_stack([X, np.tile(np.eye(2), (len(rf) + len(rh), 1))])
        nf = 2 * len(rf)
        if nf > X.shape[1] + 10:
            b = where_mod.lstsq(X[:nf], rf.ravel())
            before = float(np.mean(rh.ravel() ** 2))
            after = float(np.mean((rh.ravel() - X[nf:] @ b) ** 2))
            share = 1.0 - after / before if before > 0 else 0.0
            if share > MAX_SYSTEMATIC:
                reasons.append(f"a smooth field predicts {share:.0%} of the remainder on "
                               "unseen points: it is systematic, not noise")
    pn = point_noise
    limit = None
    if pn is not None:
        limit = MAX_POINT_NOISE_RATIO_PATHS if pn.source == "paths" else MAX_POINT_NOISE_RATIO_GIVEN
    hp = TableStats.of(rh_all[kh])
    pr = None
    if pn is not None and hp.n:
        pr = hp.rms / (math.sqrt(2) * pn.upper95_mm)
        if pr > limit:
            what = {"given": "the given noise", "paths": "the path noise",
                    "repeats": "the noise of revisited poses",
                    "residual": "the noise the remainder's structure shows"}[pn.source]
            bound = "" if pn.source == "given" else f", 95 % upper bound {pn.upper95_mm:.4f} mm"
            reasons.append(f"point remainder {hp.rms:.4f} mm is {pr:.1f}× {what} "
                           f"(σ {pn.sigma_mm:.4f} mm per axis{bound})")
    ratio = None
    kq = out.keep_hold[len(rh_all):]
    if path_sigma and s.hold_d.moves and kq.any():
        hq = TableStats.of(rhq[kq]).rms
        ratio = hq / (math.sqrt(2) * path_sigma)
        if ratio > MAX_PATH_NOISE_RATIO:
            reasons.append(f"path remainder {hq:.4f} mm is {ratio:.1f}× the path noise")
    rem = Remainder(bool(reasons), reasons, share, ratio, point_noise_ratio=pr)
    if pn is None:
        rem.notes.append("noise level unknown (no paths, no --noise-mm, too few points to "
                         "estimate it): a gap that is not smooth over the workspace cannot be "
                         "told from noise")
    elif pn.source == "residual":
        rem.notes.append(f"point noise estimated from the remainder itself ({pn.method}): a "
                         "remainder that varies from pose to pose without pattern in joints "
                         "or time cannot be told from noise")
    if rem.unexplained:
        rp, rq = hold_residuals(d, effects, tp)
        rem.where = where_mod.analyse(d, rp, rq, robust.keep_all(d, out))
    return rem


__all__ = ["ALPHA", "Decision", "Remainder", "Search", "decide", "judge", "label", "search",
           "unexplained"]
