"""Which effect: fit every candidate, rank them, decide. Pure numerics.

Search (:func:`search`):

1. every identifiable single candidate (:func:`.candidates.single_candidates`) is fitted;
2. pairs: each of the :data:`PAIR_TOPS` best singles with every other single (same effect
   on both joints merges into one component). A single that mimics a pair (a cyclic error
   standing in for gear ratio + offset on one joint) tends to rank first, so the partners
   of the runners-up are tried as well;
3. the best :data:`REFINE` candidates by BIC get a second, reweighted round (see
   :mod:`.fit`) — their BIC, intervals and holdout numbers are the final ones.

Ranking: identifiable candidates by BIC on the fit rows (lower is better), then the ones
that failed the identifiability check (listed, never chosen).

Decision (:func:`decide`), with family-wise error rate :data:`ALPHA`:

* **none**: the best single is compared with the nominal model by a likelihood-ratio test
  (2·Δln L ~ χ²_k under "no effect"), Bonferroni-corrected over the singles tried. Not
  significant -> ``none``: the gap is what noise alone would leave.
* **pair**: the best pair replaces the best single only if its BIC is lower *and* the
  likelihood-ratio test against its better nested single is significant (Bonferroni over
  the pairs tried).
* **unexplained** (:func:`unexplained`): the chosen model leaves most of the holdout gap
  (shrink < :data:`MIN_SHRINK`), or what it leaves is still systematic: a smooth cubic
  field in (x, y) fitted to the remainder on the fit points predicts more than
  :data:`MAX_SYSTEMATIC` of the remainder's mean square on the holdout points, or the
  paths' holdout remainder is more than :data:`MAX_PATH_NOISE_RATIO` × the model-free path
  noise (second differences along each move), or the points' holdout remainder is more
  than :data:`MAX_POINT_NOISE_RATIO_GIVEN` × a noise level the user gives, else more than
  :data:`MAX_POINT_NOISE_RATIO_PATHS` × the path noise (points also carry repeatability,
  which a path does not show; 5× leaves room for a repeatability up to ~4× the camera
  noise). Without paths and without a given noise level, "none" means "no candidate is
  supported", not "within noise": a non-smooth gap (e.g. backlash without direction
  columns) cannot be told from noise, and the report says so in ``remainder.notes``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from cell.diagnosis import where as where_mod
from cell.diagnosis.candidates import merge, single_candidates
from cell.diagnosis.fit import FitResult, fit_candidate, label, nominal_result, subset
from cell.diagnosis.replay import DiagData
from cell.diagnosis.replay import residuals as resid

ALPHA = 1e-3
REFINE = 4
PAIR_TOPS = 3
MIN_SHRINK = 0.5
MAX_SYSTEMATIC = 0.5
MAX_PATH_NOISE_RATIO = 2.0
MAX_POINT_NOISE_RATIO_GIVEN = 3.0
MAX_POINT_NOISE_RATIO_PATHS = 5.0


@dataclass
class Search:
    """All fits of one campaign: ``nominal``, ``singles``, ``pairs``, ``skipped``
    {label: reason}, ``ranking`` (identifiable by BIC, then the rest)."""

    nominal: FitResult
    singles: list[FitResult]
    pairs: list[FitResult]
    skipped: dict[str, str]
    fit_d: DiagData
    hold_d: DiagData
    ranking: list[FitResult] = field(default_factory=list)


def _key(r: FitResult):
    return (not r.identifiable, r.bic)


def search(d: DiagData) -> Search:
    """Fit the candidates of ``d`` (module docstring) and rank them."""
    fit_d, hold_d = subset(d, "fit"), subset(d, "holdout")
    n_total = 2 * (fit_d.n_points + fit_d.n_path)
    nominal = nominal_result(fit_d, hold_d)
    cands, skipped = single_candidates(d)
    singles = [fit_candidate(c, fit_d, hold_d, n_total, rounds=1) for c in cands]
    order = sorted(singles, key=_key)
    pair_cands: list = []
    for top in [r.candidate for r in order[:PAIR_TOPS]]:
        for other in singles:
            if other.candidate != top:
                pair_cands.append(merge(top, other.candidate))
    seen, uniq = set(), []
    for c in pair_cands:
        if c is not None and c not in seen:
            seen.add(c)
            uniq.append(c)
    pairs = [fit_candidate(c, fit_d, hold_d, n_total, rounds=1) for c in uniq]
    everything = sorted(singles + pairs, key=_key)
    refined = {id(r): fit_candidate(r.candidate, fit_d, hold_d, n_total, rounds=1, start=r)
               for r in everything[:REFINE] if r.success}
    singles = [refined.get(id(r), r) for r in singles]
    pairs = [refined.get(id(r), r) for r in pairs]
    s = Search(nominal, singles, pairs, skipped, fit_d, hold_d)
    s.ranking = sorted(singles + pairs, key=_key)
    return s


@dataclass
class Decision:
    """``chosen`` FitResult or None (``none``); ``p_value`` of the effect-vs-nominal test
    (Bonferroni-adjusted), ``delta_bic`` (nominal − chosen), ``pair_p_value`` if a pair was
    weighed, ``runner_up`` the best rival naming a different effect and its BIC margin."""

    chosen: FitResult | None
    p_value: float
    delta_bic: float
    pair_p_value: float | None = None
    runner_up: str | None = None
    margin_bic: float | None = None


def _lr_p(null: FitResult, alt: FitResult, m: int) -> float:
    stat = max(null.neg2ll - alt.neg2ll, 0.0)
    dof = max(alt.k - null.k, 1)
    return min(1.0, float(chi2.sf(stat, dof)) * max(m, 1))


def decide(s: Search) -> Decision:
    """Apply the none / pair rules of the module docstring."""
    ok_singles = sorted([r for r in s.singles if r.identifiable and r.success], key=_key)
    if not ok_singles:
        return Decision(None, 1.0, 0.0)
    best = ok_singles[0]
    p = _lr_p(s.nominal, best, len(s.singles))
    dbic = s.nominal.bic - best.bic
    if p >= ALPHA or dbic <= 0:
        return Decision(None, p, dbic)
    chosen, pair_p = best, None
    ok_pairs = sorted([r for r in s.pairs if r.identifiable and r.success], key=_key)
    if ok_pairs and ok_pairs[0].bic < best.bic:
        pr = ok_pairs[0]
        nested = [r for r in s.singles if _nested(r.candidate, pr.candidate)]
        if nested:
            sub = min(nested, key=lambda r: r.bic)
            pair_p = _lr_p(sub, pr, len(s.pairs))
            if pair_p < ALPHA:
                chosen = pr
    names = {e for e, _ in chosen.candidate}
    rival = next((r for r in s.ranking if r.identifiable and r is not chosen
                  and not ({e for e, _ in r.candidate} & names)), None)
    return Decision(chosen, p, s.nominal.bic - chosen.bic, pair_p,
                    rival.label if rival else None, (rival.bic - chosen.bic) if rival else None)


def _nested(single, pair) -> bool:
    (e, js), = single
    return any(e == pe and set(js) <= set(pj) for pe, pj in pair)


@dataclass
class Remainder:
    """What the chosen model leaves: ``systematic_share`` of the holdout points' remainder a
    smooth field predicts, ``path_noise_ratio`` (holdout path rms / (√2·path σ)),
    ``unexplained`` and the reasons, ``where`` of the remainder (all rows)."""

    unexplained: bool
    reasons: list[str]
    systematic_share: float | None
    path_noise_ratio: float | None
    where: where_mod.Where | None = None
    notes: list[str] = field(default_factory=list)


def unexplained(d: DiagData, s: Search, dec: Decision, shrink: float,
                path_sigma: float | None, noise_mm: float | None = None) -> Remainder:
    """The unexplained test of the module docstring. ``noise_mm`` is the expected σ per axis
    of a static point measurement (repeatability and measurement noise together), if known."""
    effects = dec.chosen.effects if dec.chosen else []
    tp = dec.chosen.path_temp_c if dec.chosen else None
    reasons: list[str] = []
    if dec.chosen is not None and shrink < MIN_SHRINK:
        reasons.append(f"holdout shrink {shrink:.2f} < {MIN_SHRINK}")
    share = None
    if s.fit_d.points is not None and s.hold_d.points is not None:
        rf, _ = resid(s.fit_d, effects, tp)
        rh, _ = resid(s.hold_d, effects, tp)
        X = where_mod._poly3(np.vstack([s.fit_d.points.xy - rf, s.hold_d.points.xy - rh]))
        X = np.column_stack([X, np.tile(np.eye(2), (len(rf) + len(rh), 1))])
        nf = 2 * len(rf)
        if nf > X.shape[1] + 10:
            b, *_ = np.linalg.lstsq(X[:nf], rf.ravel(), rcond=None)
            before = float(np.mean(rh.ravel() ** 2))
            after = float(np.mean((rh.ravel() - X[nf:] @ b) ** 2))
            share = 1.0 - after / before if before > 0 else 0.0
            if share > MAX_SYSTEMATIC:
                reasons.append(f"a smooth field predicts {share:.0%} of the remainder on "
                               "unseen points: it is systematic, not noise")
    ref = (noise_mm, MAX_POINT_NOISE_RATIO_GIVEN, "the given noise") if noise_mm else \
        (path_sigma, MAX_POINT_NOISE_RATIO_PATHS, "the path noise") if path_sigma else None
    hp = (dec.chosen or s.nominal).hold_points
    if ref is not None and hp.n:
        pr = hp.rms / (math.sqrt(2) * ref[0])
        if pr > ref[1]:
            reasons.append(f"point remainder {hp.rms:.4f} mm is {pr:.1f}× {ref[2]} "
                           f"(σ {ref[0]:.4f} mm per axis)")
    ratio = None
    if path_sigma and s.hold_d.moves:
        hq = (dec.chosen or s.nominal).hold_paths.rms
        ratio = hq / (math.sqrt(2) * path_sigma)
        if ratio > MAX_PATH_NOISE_RATIO:
            reasons.append(f"path remainder {hq:.4f} mm is {ratio:.1f}× the path noise")
    rem = Remainder(bool(reasons), reasons, share, ratio)
    if ref is None:
        rem.notes.append("noise level unknown (no paths, no --noise-mm): a gap that is not "
                         "smooth over the workspace cannot be told from noise")
    if rem.unexplained:
        rp, rq = resid(d, effects, tp)
        rem.where = where_mod.analyse(d, rp, rq)
    return rem


__all__ = ["ALPHA", "Decision", "Remainder", "Search", "decide", "label", "search", "unexplained"]
