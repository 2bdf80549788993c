"""Which effect explains a chain campaign's gap: screening, fits, decision. Pure numerics.

1. **Registration only** (:func:`cell.diagnosis.chain.fit.fit` with no parameters): the nominal.
2. **Identifiability** per effect: its per-joint parameters the data can see beside the
   registration; the rest is reported (absorbed by registration, or seen only as a sum).
3. **Linearised screening**: per effect, forward selection of its parameters on the
   registration-only Jacobian (forward while the leave-one-pose-out prediction error
   drops, then backward while a removal costs nothing significant over poses). Cheap:
   one linear solve per try.
4. **Full non-linear fits** of each effect's selection, of every pair of the best
   :data:`PAIR_TOPS` effects, and of the best effect paired with every other effect the
   campaign can see (their pools screened jointly: a second effect too small to rank
   alone still joins the first), and of the best pair with one effect swapped for one that
   can stand in for it (:attr:`cell.effects.Effect.mimics`). Where poses sit at places, a
   candidate close to the best with an effect on several joints is fitted again without
   that effect on the joint left-out places need least, when they do not need it
   (:func:`_places_trim`): the test over poses counts the samples of a measured move one
   by one, and can keep a joint that only absorbs what the moves share.
5. **Decision**: an effect exists when the candidate with the lowest leave-out error
   predicts poses left out one at a time better than registration alone, by a one-sided
   Wilcoxon signed-rank test over poses at :data:`ALPHA`; otherwise ``none``. Which effect:
   the candidates that predict left-out **places** (poses at one station left out
   together, :mod:`cell.diagnosis.places`) as well as the best (:func:`choose`) are
   tied, and the one with the fewest parameters is named. It is ``unexplained`` when it
   leaves most of the holdout gap (shrink < :data:`MIN_SHRINK`) or, with a noise
   reference, a fit error well above the noise.
6. **Confidence**: ``ambiguous`` when a tied candidate is another explanation (its
   ``rivals``, with :func:`separating_poses`); ``low`` when the named cause predicts
   left-out poses to more than :data:`PREDICT_FACTOR` × the noise (it fits, but does not
   carry over: an effect outside the vocabulary that a flexible enough candidate imitates
   at the campaign's places), when a scale error of the measuring
   instrument (:func:`instrument_scale`: a uniform and a radial scale of the sensor's
   readings, not an arm effect, so never named; a tracker's scale and a uniform stretch of
   the arm's links look alike from outside) predicts as well, when the fit poses lie at
   fewer than :data:`MIN_FOLDS` places, or when the gap is left unexplained.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis import tie
from cell.diagnosis.chain import drift, ripple
from cell.diagnosis.chain import fit as F
from cell.diagnosis.leaveout import Folds
from cell.diagnosis.places import separating
from cell.diagnosis.tie import ALPHA, RIVAL_RATIO
from cell.numerics.sums import squares_last

STEP_ALPHA = 0.05     # the same test for keeping one more parameter during screening
MIN_SHRINK = 0.5      # below: the best candidate leaves most of the holdout gap
NOISE_FACTOR = 2.0    # fit rms above this many noise rms (3-D) is more than noise
PREDICT_FACTOR = 1.5  # a named cause predicting left-out poses worse than this × noise: doubt
PAIR_TOPS = 3         # pairs of the best this many single effects are fitted together
MIN_FOLDS = 3         # fewer places: nothing is predicted out of sample
UP = ", 95 % upper bound"   # what the noise figures of the decision's messages are
HINT_ALPHA = 0.05     # no cause named, but the best one's test below this: `none` is not sure


@dataclass
class Candidate:
    label: str
    effects: tuple[str, ...]
    fit: F.Fit
    hold_rms: float
    hold_max: float
    ident: F.Identifiability | None = None
    hold_in_rms: float = math.nan     # the same on the holdout points not set aside
    hold_in_max: float = math.nan

    @property
    def joints(self) -> list[str]:
        return [f"j{k + 1}" for k in sorted({p.joint for p in self.fit.params if p.on_joint})]


@dataclass
class Search:
    fit_d: F.Data
    hold_d: F.Data
    nominal: Candidate
    ranking: list[Candidate]
    idents: dict[str, F.Identifiability] = field(default_factory=dict)
    hold_keep: np.ndarray | None = None   # holdout points that are not outliers (None: all)
    beyond: dict[str, tuple[F.Param, float]] = field(default_factory=dict)  # left out, value wanted


class Screen:
    """The linearised model at the registration-only solution ``f0`` with the columns of
    every parameter of ``pool`` (column-scaled), stacked for leave-one-pose-out and
    leave-one-place-out fits of any subset (:class:`cell.diagnosis.leaveout.Folds`)."""

    def __init__(self, d: F.Data, f0: F.Fit, pool: list[F.Param]):
        _, J = F.model(d, f0.reg, list(pool), np.zeros(len(pool)), jac=True)
        self.nr = F.n_registration(d)
        self.index = {p.name: self.nr + i for i, p in enumerate(pool)}
        Js, _ = F.scaled(J)
        r0 = f0.resid.ravel()
        self.poses = Folds(Js, r0, d.obs_pose, d.n_poses, self.nr, dims=d.dims)
        fold, n = d.folds()
        self.places = self.poses if n >= d.n_poses else Folds(Js, r0, fold, n, self.nr, dims=d.dims)

    def cols(self, params) -> list[int]:
        return list(range(self.nr)) + [self.index[p.name] for p in params]


def screen(d: F.Data, f0: F.Fit, pool: list[F.Param], start: list[F.Param] = (),
           design: Screen | None = None) -> list[F.Param]:
    """Stepwise selection on the linearised model at the registration-only solution
    ``f0``. Forward: add the parameter that most lowers the leave-one-pose-out error while
    it drops (parameters needed only together, like offsets of parallel axes, get in).
    Backward: drop the parameter whose removal costs least while that cost is not
    significant over poses (one-sided Wilcoxon, :data:`STEP_ALPHA`). ``design`` holds the
    columns of ``pool`` (and ``start``) when already built. Returns the chosen parameters
    (``start`` first)."""
    chosen = list(start)
    design = design or Screen(d, f0, list(start) + [p for p in pool if p not in start])
    folds = design.poses

    def cv(params: list[F.Param]) -> float:
        return design.poses.loo(design.cols(params))[0]

    best = cv(chosen)
    while True:                        # forward: while the left-out error still drops
        rest = [p for p in pool if p not in chosen]
        if not rest:
            break
        scores = folds.loo_each([design.cols(chosen + [p]) for p in rest])
        tries = [(sc[0], p) for sc, p in zip(scores, rest)]
        score, p = min(tries, key=lambda t: t[0])
        if not score < best:
            break
        chosen.append(p)
        best = score
    best_fold = folds.loo(design.cols(chosen))[1]
    while len(chosen) > len(start):    # backward: drop what the poses do not need
        out = chosen[len(start):]
        drops = list(zip(folds.loo_each([design.cols([c for c in chosen if c is not p]) for p in out]),
                         out))
        (score, per), p = min(drops, key=lambda t: t[0][0])
        if tie.p_worse(per, best_fold) < STEP_ALPHA:
            break
        chosen.remove(p)
        best_fold = per
    return chosen


def one_alternative(design: Screen, pool: list[F.Param]) -> list[F.Param]:
    """``pool`` with, where its effect gives alternatives (:attr:`cell.effects.OnChain.choice`:
    a ripple's orders), only the alternative per joint whose parameters alone predict
    left-out poses best (``design`` holds the pool's columns)."""
    groups: dict = {}
    for p in pool:
        n = fx.CHAIN_EFFECTS[p.effect].chain.choice
        groups.setdefault((p.effect, p.joint) if n else p.name, {}).setdefault(
            p.part // n if n else 0, []).append(p)
    if all(len(g) == 1 for g in groups.values()):
        return list(pool)
    best = {key: min(g.values(), key=lambda ps: design.poses.loo(design.cols(ps))[0])
            for key, g in groups.items()}
    keep = {p.name for ps in best.values() for p in ps}
    return [p for p in pool if p.name in keep]


def _held(label, effects, f: F.Fit, hold_d: F.Data, keep, ident=None) -> Candidate:
    y, _ = F.model(hold_d, f.reg, f.params, f.values)
    e = hold_d.xyz - y
    n = np.sqrt(squares_last(e))
    c = Candidate(label, effects, f, F.rms3(e), float(n.max()) if len(n) else math.nan, ident)
    if keep is not None:
        e, n = e[keep], n[keep]
    c.hold_in_rms, c.hold_in_max = F.rms3(e), float(n.max()) if len(n) else math.nan
    return c


def _candidate(label, effects, fit_d, hold_d, params, f0, ident=None, keep=None,
               beyond: dict | None = None) -> Candidate | None:
    """``params`` fitted on ``fit_d`` and judged on ``hold_d``, within their physical bounds
    (:attr:`cell.effects.OnChain.bounds`): while the fit wants a parameter beyond its
    bounds, the one furthest beyond (in standard errors) is left out and the rest fitted
    again (``beyond`` collects, by name, each such parameter and the value its fit wanted).
    None when an effect of ``effects`` is left without a parameter (the campaign shows it
    only with a value it cannot have)."""
    params = list(params)
    while True:
        f = F.fit(fit_d, params, f0.reg)
        out = [(far / max(se, 1e-300), p, v) for p, v, se in zip(params, f.values, f.se)
               if (far := _beyond(p, v)) > 0]
        if not out:
            return _held(label, effects, f, hold_d, keep, ident)
        _, worst, wanted = max(out, key=lambda t: t[0])
        if beyond is not None:
            beyond.setdefault(worst.name, (worst, float(wanted)))
        params.remove(worst)
        if _own_effects(params) != set(effects):
            return None


def _own_effects(params) -> set[str]:
    """The effects ``params`` hold a parameter of their own of (not only a nuisance)."""
    return {p.effect for p in params if not p.nuisance}


def _beyond(p: F.Param, v: float) -> float:
    """How far ``v`` lies outside parameter ``p``'s physical bounds (0 within; a nuisance
    has none)."""
    if p.nuisance:
        return 0.0
    lo, hi = fx.CHAIN_EFFECTS[p.effect].chain.bounds
    return max(0.0 if lo is None else lo - v, 0.0 if hi is None else v - hi)


def _beyond_note(p: F.Param, v: float) -> str:
    """Says that parameter ``p`` wanted ``v``, beyond its physical bounds."""
    unit = "" if p.unit == "1" else f" {p.unit}"
    lo, hi = fx.CHAIN_EFFECTS[p.effect].chain.bounds
    span = f"{lo:g} … {hi:g}" if lo is not None and hi is not None else \
        f"≥ {lo:g}" if lo is not None else f"≤ {hi:g}"
    return (f"{p.name} fitted to {v:.4g}{unit}, beyond what its effect can physically be "
            f"({span}{unit}), so no candidate carries it: check the part and the model's "
            "units rather than calibrating it in")


def _confounded_offsets(idents: dict[str, F.Identifiability], offsets: list[F.Param]) -> None:
    """A joint effect of joint K seen only as a sum with K's offset (K never moves, so its
    gear ratio acts as a constant angle): the data cannot tell which of the two it is, so
    the offset is not identifiable either and no cause is named on it."""
    if "joint_offset" not in idents:
        return
    off = idents["joint_offset"]
    for e, ident in idents.items():
        for name, why in ident.dropped.items():
            if e in ("joint_offset", "link_length") or not why.startswith("seen only as a sum with"):
                continue
            for p in offsets:
                if p.name in why and any(q is p for q in off.kept) and name.startswith(f"j{p.joint + 1}_"):
                    off.kept = [q for q in off.kept if q is not p]
                    off.dropped[p.name] = f"seen only as a sum with {name}"


def search(fit_d: F.Data, hold_d: F.Data, effects=F.EFFECTS, hold_keep: np.ndarray | None = None
           ) -> Search:
    """Screen and fit the candidates on ``fit_d`` (module docstring), predicting ``hold_d``;
    ``hold_keep`` marks the holdout points that are not outliers (:mod:`cell.diagnosis.chain.robust`)."""
    f0 = F.fit(fit_d, [])
    nominal = _held("registration only", (), f0, hold_d, hold_keep)
    voc = F.vocabulary(fit_d.chain)
    idents, picks, ranking, beyond = {}, {}, [], {}
    offsets = [p for p in voc if p.effect == "joint_offset"]
    for e in effects:
        pool = [p for p in voc if p.effect == e]
        if not pool:
            continue
        # a parameter that only repeats a joint offset (a link along the axis, a gear ratio
        # at a reading that never changes) is the offset, not an effect of its own
        first = offsets if e != "joint_offset" else []
        idents[e] = F.identifiability(fit_d, pool, f0.reg, keep_first=first)
        idents[e].kept = [p for p in idents[e].kept if p.effect == e]
    # one linearised design holds every column the singles and the pairs screen: a subset's
    # leave-out fit is exact on it (registration eliminated once, then any columns)
    design = Screen(fit_d, f0, [p for i in idents.values() for p in i.kept])
    for e, ident in idents.items():
        kept = one_alternative(design, ident.kept)
        if len(kept) < len(ident.kept):   # what is kept of the alternatives, judged on its own:
            again = F.identifiability(fit_d, kept, f0.reg,  # not against the orders left out
                                      keep_first=offsets if e != "joint_offset" else [])
            ident.dropped.update(again.dropped)
            ident.warnings = {n: w for n, w in again.warnings.items() if n in {p.name for p in kept}}
            kept = [p for p in again.kept if p.effect == e]
        ident.kept = kept
    _confounded_offsets(idents, offsets)
    for e in effects:
        if e not in idents:
            continue
        picks[e] = screen(fit_d, f0, idents[e].kept, design=design)
        if not _own_effects(picks[e]):     # a nuisance alone is no cause
            picks[e] = []
        c = _candidate(e, (e,), fit_d, hold_d, picks[e], f0, idents[e], hold_keep, beyond) \
            if picks[e] else None
        if c is not None:
            ranking.append(c)
    ranking.sort(key=lambda c: c.fit.cv_rms)
    # singles by their leave-out error, then the effects that picked nothing alone
    order = [c.effects[0] for c in ranking]
    order += [e for e in effects if e in idents and idents[e].kept and e not in order]
    pairs = {tuple(sorted((a, b), key=order.index)) for a in order[:PAIR_TOPS]
             for b in order[:PAIR_TOPS] if b != a}
    pairs |= {(order[0], b) for b in order[1:]}

    def pair(a: str, b: str) -> None:
        ident = F.identifiability(fit_d, idents[a].kept + idents[b].kept, f0.reg)
        both = screen(fit_d, f0, ident.kept, design=design)
        c = _candidate(f"{a} + {b}", (a, b), fit_d, hold_d, both, f0, ident, hold_keep, beyond) \
            if _own_effects(both) == {a, b} else None
        if c is not None:
            ranking.append(c)

    for a, b in sorted(pairs, key=lambda ab: (order.index(ab[0]), order.index(ab[1]))):
        pair(a, b)
    # the best pair with one effect swapped for one that can stand in for it (a thermal
    # growth for link lengths): the pairs above need not hold that one, and the tie rule
    # can only weigh rivals that were fitted
    ranking.sort(key=lambda c: c.fit.cv_rms)
    top = ranking[0].effects if ranking else ()
    for x, other in ((top[0], top[1]), (top[1], top[0])) if len(top) == 2 else ():
        for e in order:
            swap = tuple(sorted((e, other), key=order.index))
            if e not in top and swap not in pairs and (x in fx.CHAIN_EFFECTS[e].mimics
                                                        or e in fx.CHAIN_EFFECTS[x].mimics):
                pairs.add(swap)
                pair(*swap)
    ranking.sort(key=lambda c: c.fit.cv_rms)
    # a trimmed candidate predicts about as its parent: it can be named only beside the best
    for c in [c for c in ranking if tie.close(c.fit.cv_rms, ranking[0].fit.cv_rms)]:
        trimmed = _places_trim(fit_d, design, c.fit.params)
        if trimmed is not None:
            label = " + ".join(e + (f" on {', '.join(js)}" if (js := sorted(
                {f"j{p.joint + 1}" for p in trimmed if p.effect == e and p.on_joint and not p.nuisance},
                key=lambda j: int(j[1:]))) else "") for e in c.effects)
            t = _candidate(label, c.effects, fit_d, hold_d, trimmed, f0,
                           idents[c.effects[0]] if len(c.effects) == 1 else c.ident, hold_keep, beyond)
            if t is not None:
                ranking.append(t)
    ranking.sort(key=lambda c: c.fit.cv_rms)
    return Search(fit_d, hold_d, nominal, ranking, idents, hold_keep, beyond)


def _places_trim(d: F.Data, design: Screen, params: list[F.Param]) -> list[F.Param] | None:
    """``params`` (a candidate's) without one effect's parameters on one joint (the pair
    left-out places need least), when the linearised model without them is tied with the
    full one over places (the rule of :func:`cell.diagnosis.tie.tied`) and every effect
    keeps a parameter of its own on a joint; None when each such pair is needed, or the
    poses do not sit at :data:`MIN_FOLDS` places or more."""
    n = d.folds()[1]
    units = sorted({(p.effect, p.joint) for p in params if p.on_joint and not p.nuisance})
    if n >= d.n_poses or n < MIN_FOLDS or len(units) < 2:
        return None
    full = design.places.loo(design.cols(params))[1]
    best = None
    for e, k in units:
        if not any(u != (e, k) and u[0] == e for u in units):
            continue                      # the effect's only joint: that is another candidate
        rest = [q for q in params if not (q.on_joint and q.effect == e and q.joint == k)]
        per = design.places.loo(design.cols(rest))[1]
        pv = tie.p_worse(per, full)
        if tie.tied(pv, math.sqrt(float(np.mean(per))), math.sqrt(float(np.mean(full)))) \
                and (best is None or pv > best[0]):
            best = (pv, rest)
    return None if best is None else best[1]


def instrument_scale(d: F.Data, f0: F.Fit) -> tuple[float, np.ndarray]:
    """Leave-out error (total rms, per-fold mean square; folds of :meth:`F.Data.folds`) of
    registration plus a scale error of the measuring instrument, linearised at the registration-only fit
    ``f0``: a uniform scale of the readings ``y`` and a radial one ``y·|y|`` (|y| in m)
    about the sensor origin. A rival hypothesis outside the arm's vocabulary: when it
    predicts left-out poses as well as a named cause, the data cannot tell the two apart."""
    y = F.model(d, f0.reg, [], np.zeros(0))[0]
    radius_m = np.linalg.norm(y, axis=1, keepdims=True) / 1000.0
    return F.loo_with(d, f0, np.column_stack([y.ravel(), (y * radius_m).ravel()]))


@dataclass
class Decision:
    chosen: Candidate | None
    p_value: float
    runner_up: Candidate | None
    runner_up_p: float | None
    unexplained: bool
    reasons: list[str]
    notes: list[str]
    warnings: list[str] = field(default_factory=list)
    rivals: list = field(default_factory=list)
    tied: list = field(default_factory=list)
    drift_rivals: list[dict] = field(default_factory=list)
    untestable: list[dict] = field(default_factory=list)

    @property
    def confidence(self) -> str:
        """``ambiguous`` when :attr:`rivals` (or a drifting sensor frame,
        :attr:`drift_rivals`) predict left-out poses as well as the named cause (the
        campaign cannot tell them apart), or an effect the campaign cannot test may stand
        behind it (:attr:`untestable`, :func:`untestable_rivals`); ``low`` when
        :attr:`warnings` says something else to check before acting, or the cause leaves
        most of the gap unexplained, else ``high``."""
        if self.rivals or self.drift_rivals or self.untestable:
            return "ambiguous"
        return "low" if self.warnings or self.unexplained else "high"


def _components(c: Candidate) -> set:
    return {(p.effect, p.joint) for p in c.fit.params}


def untestable_rivals(s: Search, shown: list[Candidate]) -> list[dict]:
    """Effects the campaign cannot test that a candidate of ``shown`` (the named cause and
    its rivals) can stand in for (:attr:`cell.effects.Effect.mimics`, on a shared joint):
    rivals no prediction can rule out until the missing variable is measured. Untestable
    is a parameter dropped because the campaign lacks its column (its effect's
    :attr:`~cell.effects.OnChain.unseen`), because the column hardly varies
    (:attr:`~cell.effects.OnChain.still`), or because it is seen only as a sum with
    another (a backlash always approached from one side is an offset). One rival entry
    (``label``, ``effects``, ``joints``, ``testable`` false and ``why``, as the planar
    report's untestable rivals) per effect and candidate it could stand behind, on the
    joints it would replace there (a gear ratio of j2 named, a cyclic error of j1 a rival:
    backlash on j2, and backlash on j1), the same entry once. When the named cause
    (``shown[0]``) joins several effects and the untestable one stands in for some of them
    only, also the cause with those swapped for it (a link length beside a camera scale,
    where the poses' temperature is unknown: thermal drift beside the camera scale), since
    the truth may be that pair rather than either alone."""
    voc = {p.name: p for p in F.vocabulary(s.fit_d.chain)}
    out, seen = [], set()

    def add(on: dict[str, set], why: str) -> None:
        def js(ks) -> list[str]:
            return [f"j{k + 1}" for k in sorted(j for j in ks if j >= 0)]
        key = tuple((m, tuple(sorted(ks))) for m, ks in on.items())
        if key in seen:
            return
        seen.add(key)
        out.append({"label": " + ".join(m + (f" on {', '.join(js(ks))}" if js(ks) else "")
                                        for m, ks in on.items()),
                    "effects": list(on), "joints": js(set().union(*on.values())),
                    "testable": False, "why": f"not testable: {why}"})

    for e, ident in s.idents.items():
        eff = fx.CHAIN_EFFECTS[e]
        use = eff.chain
        untested = [(voc[n], r) for n, r in ident.dropped.items()
                    if n in voc and voc[n].effect == e
                    and (r in (use.unseen, use.still) or r.startswith("seen only as a sum"))]
        for i, c in enumerate(shown):
            comps = _components(c)
            behind, why = set(), ""         # (effect, joint, on a joint) it would replace
            for p, reason in untested:
                hit = {(m, k) for m, k in comps if m in eff.mimics and (not p.on_joint or k == p.joint)}
                behind |= {(m, k, p.on_joint) for m, k in hit}
                why = why or (reason if hit else "")
            if not behind:
                continue
            add({e: {k for _, k, joint in behind if joint}}, why)
            rest = {(m, k) for m, k in comps if m != e} - {(m, k) for m, k, _ in behind}
            if i == 0 and rest and len({m for m, _ in comps}) > 1:
                on = {e: {k for _, k, joint in behind if joint}}
                for m, k in sorted(rest):
                    on.setdefault(m, set()).add(k)
                add(on, why)
    return out


def lacking(s: Search) -> list[str]:
    """The effects the campaign cannot test for what it lacks, not for the arm's geometry
    (:attr:`cell.diagnosis.chain.fit.Identifiability.lacking`), one phrase each: the effect,
    its joints and the first reason."""
    out = []
    for e, ident in s.idents.items():
        names = [n for n in ident.dropped if n in ident.lacking]
        if names:
            voc = {p.name: p for p in F.vocabulary(s.fit_d.chain)}
            js = sorted({voc[n].joint for n in names if n in voc and voc[n].on_joint})
            on = f" on {', '.join(f'j{k + 1}' for k in js)}" if js else ""
            out.append(f"{e}{on} ({ident.dropped[names[0]]})")
    return out


def choose(s: Search) -> tie.Choice:
    """The naming rule (:func:`cell.diagnosis.tie.choose`) over the ranking:
    tied with the best over left-out folds, and of the tied candidates that predict
    left-out poses better than registration alone (one-sided Wilcoxon over poses at
    :data:`ALPHA`) the simplest named."""
    f0 = s.nominal.fit
    return tie.choose(s.ranking, lambda c: c.fit.cv_fold, lambda c: c.fit.cv_rms,
                      lambda c: len(c.fit.params), _components,
                      passes=lambda c: tie.p_worse(f0.cv_pose, c.fit.cv_pose) < ALPHA)


def unsupported(s: Search, chosen: Candidate) -> list[tuple[str, float]]:
    """The parameters of ``chosen`` that left-out places do not need: (name, p) where the
    linearised model without the parameter is tied with it over places by the tie rule
    (:func:`cell.diagnosis.tie.tied`): the campaign
    cannot tell whether the parameter is part of the cause. Empty when the poses do not
    sit at places, or at fewer than :data:`MIN_FOLDS` (screening has already asked the
    same over poses)."""
    d = s.fit_d
    n = d.folds()[1]
    if n >= d.n_poses or n < MIN_FOLDS or not chosen.fit.params:
        return []
    ps = chosen.fit.params
    design = Screen(d, s.nominal.fit, ps)
    full = design.places.loo(design.cols(ps))[1]
    out = []
    for p in ps:
        per = design.places.loo(design.cols([q for q in ps if q is not p]))[1]
        pv = tie.p_worse(per, full)
        if tie.tied(pv, math.sqrt(float(np.mean(per))), math.sqrt(float(np.mean(full)))):
            out.append((p.name, pv))
    return out


def decide(s: Search, noise_mm: float | None, noise_est: float | None = None) -> Decision:
    """Name a cause, ``none``, and whether most of the gap is left unexplained.
    ``noise_mm`` is what σ per axis of one point measurement may be, at most (the 95 %
    upper bound of its estimate, :func:`cell.diagnosis.noise.upper95`; None: unknown),
    ``noise_est`` the estimate itself (None: take ``noise_mm``).

    The candidate with the lowest leave-out error is tested against registration alone
    (over poses, each left out alone: is there an effect at all);
    if it passes, the simplest candidate (fewest parameters) among those it cannot be told
    from over places (:func:`choose`) that also passes is named: a cause with more parameters must
    predict left-out poses better, not fit the fit poses better. Tied candidates that are
    neither the named cause nor a larger model containing it are its ``rivals``; so is a
    scale error of the measuring instrument that predicts as well. A named cause with a
    parameter that the registration and the other parameters almost absorb (variance
    inflation above :data:`cell.diagnosis.chain.fit.MAX_VIF`) is not confident: the
    campaign hardly sees it apart from them. Neither is ``none`` when the best candidate's
    test falls short of ``ALPHA`` but not of :data:`HINT_ALPHA`: the campaign hints at it;
    nor when the gap, though within what the noise may be, is above :data:`NOISE_FACTOR` ×
    its estimate while effects the campaign cannot test (:func:`lacking`) could hide there."""
    f0 = s.nominal.fit
    notes: list[str] = []
    best = s.ranking[0] if s.ranking else None
    p = tie.p_worse(f0.cv_pose, best.fit.cv_pose) if best else 1.0
    chosen, rivals, tied = None, [], []
    if best is not None and p < ALPHA:
        ch = choose(s)
        tied = [c for c, t in zip(s.ranking, ch.tied) if t]
        chosen, rivals = ch.named, ch.rivals
        p = tie.p_worse(f0.cv_pose, chosen.fit.cv_pose)
        if chosen is not best:
            notes.append(f"{best.label} predicts left-out poses best, but not significantly "
                         f"better than the simpler {chosen.label} ({len(best.fit.params)} "
                         f"parameters against {len(chosen.fit.params)}): the simpler is named")
    runner = next((c for c in s.ranking if c is not chosen), None) if chosen is not None else None
    rp = tie.p_worse(runner.fit.cv_fold, chosen.fit.cv_fold) if runner else None
    warnings: list[str] = []
    if chosen is None and best is not None and p < HINT_ALPHA:
        warnings.append(f"{best.label} predicts left-out poses better than registration alone "
                        f"(p = {p:.2g}), though not clearly enough to be named (p < {ALPHA:g}): "
                        "the campaign may be too small to show it; measure more places before "
                        "concluding there is no effect")
    untested = untestable_rivals(s, [chosen] + list(rivals)) if chosen is not None else []
    by_effect: dict[str, tuple[set, str]] = {}   # one warning per effect, its joints together
    for u in untested:
        if len(u["effects"]) == 1:       # the cause with a part swapped: its effect warns alone
            js, why = by_effect.setdefault(u["effects"][0], (set(), u["why"]))
            js.update(u["joints"])
    for e, (js, why) in by_effect.items():
        on = f" on {', '.join(sorted(js, key=lambda j: int(j[1:])))}" if js else ""
        warnings.append(f"the cause may be {e}{on}, which this campaign cannot test "
                        f"({why.removeprefix('not testable: ')}): measure what it lacks "
                        "and diagnose again")
    if rivals:
        warnings.append("the campaign cannot tell the cause from " + ", ".join(
            c.label for c in rivals) + ": they predict left-out poses as well (cause.rivals; "
            "cause.separating_poses says where to measure next)")
    n_folds = s.fit_d.folds()[1]
    for name, pv in unsupported(s, chosen) if chosen is not None else []:
        warnings.append(f"{name} is not needed to predict left-out places (p = {pv:.2g} over "
                        f"{n_folds} places): the campaign cannot tell whether it is part of the cause")
    if chosen is not None and chosen.ident is not None:       # a parameter hardly seen
        warnings += [chosen.ident.warnings[p.name] for p in chosen.fit.params
                     if p.name in chosen.ident.warnings]
    if chosen is not None and n_folds < MIN_FOLDS:
        warnings.append(f"the fit poses lie at {n_folds} place(s): no cause can be checked on "
                        "places it was not fitted on")
    if chosen is not None:
        scale_rms, scale_pose = instrument_scale(s.fit_d, f0)
        sp = tie.p_worse(scale_pose, chosen.fit.cv_fold)
        if sp >= ALPHA:
            warnings.append(f"a scale error of the measuring instrument predicts left-out poses "
                            f"as well as {chosen.label} (p = {sp:.2g}): check the sensor's scale "
                            "before changing the arm's model")
    if chosen is not None and s.hold_d.n_poses and not chosen.hold_in_rms < s.nominal.hold_in_rms:
        warnings.append(f"{chosen.label} does not predict the holdout poses better than registration "
                        f"alone ({s.nominal.hold_in_rms:.4f} -> {chosen.hold_in_rms:.4f} mm rms)")
    notes += [_beyond_note(p, v) for p, v in s.beyond.values()]
    reasons: list[str] = []
    mine = _components(chosen) if chosen is not None else set()
    smaller = [s.nominal] + [c for c in s.ranking if c is not chosen and _components(c) < mine] \
        if chosen is not None else []
    dr = drift.check(s.fit_d, chosen or s.nominal, smaller, ALPHA, RIVAL_RATIO)
    if dr.present:
        reasons.append(dr.present)
    wave = ripple.check(s.fit_d, chosen, ALPHA) if chosen is not None and not dr.present else ""
    if wave:
        reasons.append(wave)
    if dr.rivals:
        warnings.append("the campaign cannot tell the cause from "
                        + ", ".join(r["label"] for r in dr.rivals)
                        + ": measure the poses in another order, or fix the sensor")
    noise3 = None if noise_mm is None else noise_mm * math.sqrt(s.fit_d.dims)
    if noise3 is not None and chosen is not None and chosen.fit.cv_rms > PREDICT_FACTOR * noise3:
        warnings.append(f"{chosen.label} predicts left-out poses only to {chosen.fit.cv_rms:.3f} mm "
                        f"rms, {chosen.fit.cv_rms / noise3:.1f}× the noise ({noise3:.3f} mm {s.fit_d.dims}-D{UP}): "
                        "part of the gap is something it does not hold, or the noise is larger "
                        "than measured")
    gap = f0.rms
    if noise3 is not None and gap <= NOISE_FACTOR * noise3:
        est3 = noise3 if noise_est is None else noise_est * math.sqrt(s.fit_d.dims)
        hidden = lacking(s) if chosen is None and gap > NOISE_FACTOR * est3 else []
        if hidden:
            warnings.append(f"the gap ({gap:.3f} mm) is {gap / est3:.1f}× the noise estimate "
                            f"({est3:.3f} mm {s.fit_d.dims}-D), within what the noise may be, and "
                            f"this campaign cannot test {'; '.join(hidden)}: measure what they "
                            "lack before concluding there is no effect")
        if chosen is not None:
            notes.append(f"the gap ({gap:.3f} mm) is within {NOISE_FACTOR:g}× the noise "
                         f"({noise3:.3f} mm {s.fit_d.dims}-D{UP}); the named cause is small")
        return Decision(chosen, p, runner, rp, bool(reasons), reasons, notes, warnings, rivals,
                        tied, dr.rivals, untested)
    before = s.nominal.hold_in_rms
    after = chosen.hold_in_rms if chosen else before
    shrink = 1 - after / before if before > 0 else 0.0
    if chosen is None:
        if noise3 is None:
            notes.append("no noise reference (no repeated poses, no --noise-mm): the gap cannot "
                         "be compared with the measurement noise")
            reasons.append("no effect of the chain vocabulary predicts left-out poses better than "
                           "registration alone")
        else:
            reasons.append(f"the gap ({gap:.3f} mm) is {gap / noise3:.1f}× the noise, and no effect "
                           "of the chain vocabulary predicts left-out poses better than registration alone")
        return Decision(None, p, None, None, True, reasons, notes, drift_rivals=dr.rivals)
    if shrink < MIN_SHRINK:
        reasons.append(f"the best candidate ({chosen.label}) shrinks the holdout error by only "
                       f"{100 * shrink:.0f} %: most of the gap is left")
    if noise3 is not None and chosen.fit.rms > NOISE_FACTOR * noise3:
        reasons.append(f"after {chosen.label} the fit error ({chosen.fit.rms:.3f} mm) is still "
                       f"{chosen.fit.rms / noise3:.1f}× the noise ({noise3:.3f} mm {s.fit_d.dims}-D{UP})")
    return Decision(chosen, p, runner, rp, bool(reasons), reasons, notes, warnings, rivals, tied,
                    dr.rivals, untested)


POSE_DRAWS = 4000     # configurations drawn inside the limits to choose them from


def separating_poses(s: Search, chosen: Candidate, rivals: list[Candidate],
                     noise_mm: float | None, seed: int = 0) -> list[dict]:
    """Up to :data:`cell.diagnosis.places.N_POSES` joint configurations where ``chosen`` and its ``rivals``
    (each with its own registration) predict the measured points most differently:
    drawn inside each joint's limits (the campaign's own range where the model gives
    none), the pose whose smallest difference to any rival is largest first, then the
    next at least a fifth of the joints' ranges away. Per pose the readings (``jK``), the
    approach directions (``dirs``, for the joints whose ``jK_dir`` the campaign records,
    drawn ±1), the expected largest point difference (mm) per rival and, with a noise
    reference, that difference over σ per axis."""
    if not rivals or chosen is None:
        return []
    d = s.fit_d
    rng = np.random.default_rng(seed)
    lo = d.readings.min(axis=0).astype(float)
    hi = d.readings.max(axis=0).astype(float)
    for k, j in enumerate(d.chain.joints):
        if j.lower is not None and j.upper is not None:
            lo[k], hi[k] = j.lower, j.upper
    span = np.where(hi > lo, hi - lo, 1.0)
    q = lo + rng.random((POSE_DRAWS, len(lo))) * (hi - lo)
    seen = np.any(d.dirs != 0, axis=0)            # joints whose approach the campaign records
    dirs = np.where(seen, rng.choice((-1.0, 1.0), q.shape), 0.0) if seen.any() else None
    syn = d.at(q, dirs)
    m = max(d.n_markers, 1)

    def predict(c: Candidate) -> np.ndarray:
        y, _ = F.model(syn, c.fit.reg, c.fit.params, c.fit.values)
        return y.reshape(len(q), m, d.dims)
    base = predict(chosen)
    diffs = np.stack([np.linalg.norm(base - predict(c), axis=2).max(axis=1) for c in rivals], 1)
    def where(i: int) -> dict:
        e = {"readings": {j.column: round(float(v), 3) for j, v in zip(d.chain.joints, q[i])}}
        if dirs is not None:
            e["dirs"] = {j.column: int(dirs[i, k]) for k, j in enumerate(d.chain.joints) if seen[k]}
        return e
    return separating(q / span, diffs, [c.label for c in rivals], noise_mm, 0.2, where)
