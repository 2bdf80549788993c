"""Which cause predicts places it was not fitted on, and can the campaign tell the leading
causes apart? Pure numerics.

A diagnosis that chooses by how well a cause fits the rows it was fitted on rewards
parameters: on a campaign whose poses sit at a handful of places, two parameters of any
effect fit a handful of places. Here every candidate is judged by **leave-one-place-out
prediction** of the fit rows:

* **places** (:func:`folds`, :mod:`.places`): fit poses at one station (closer than
  :data:`cell.diagnosis.places.LINK_DEG` in joint space) are left out together; spread
  poses each on their own; more than :data:`MAX_FOLDS` groups are gathered into that many
  regions of the workspace. Every fit move is a fold of its own.
* **prediction error** (:func:`fold_errors`): for each fold, the candidate's linearised fit
  (the screening's response columns at the nominal model, :mod:`.screen`) on all other
  folds predicts the fold's residual; its weighted mean square per scalar residual
  (each table weighed by 1/its noise, so 1 ≈ noise) is the fold's error. Nothing is
  refitted: the fold's Gram pieces are subtracted from the whole fit's
  (:mod:`cell.diagnosis.leaveout`, the yardstick of the chain diagnosis too).
* **the choice** (:func:`judge`): the candidates the folds cannot tell from the best are
  **tied** (the rule of both families, :func:`cell.diagnosis.tie.tied`: within
  :data:`RIVAL_RATIO` of its prediction rms, and not worse by a margin that matters); of
  those, the one with the fewest parameters is named (then the lowest error). A tied
  candidate that is neither the named cause nor a larger model containing it is a
  **rival**: the campaign cannot tell the two apart, the answer is ``ambiguous``.
* **separating poses** (:func:`separating_poses`): configurations inside the joint limits
  where the named cause and its rivals predict most differently, each with the expected
  difference in mm against the campaign's point noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis import leaveout, screen, tie
from cell.diagnosis.jacobian import Rows, rows_of
from cell.diagnosis.places import folds as place_folds
from cell.diagnosis.places import separating
from cell.diagnosis.replay import DiagData
from cell.diagnosis.tie import ALPHA, RIVAL_RATIO

MAX_FOLDS = 24        # more places are gathered into this many regions
MIN_FOLDS = 3         # fewer: nothing can be predicted out of sample
MAX_RIVALS = 4
REPORTED = 12         # candidates the report's selection table lists
POSE_SPACING_DEG = 20.0


def folds(fit_d: DiagData) -> tuple[np.ndarray, int, int]:
    """(fold of every fit row (n_rows,), number of point folds, number of places): the
    points' folds of :func:`cell.diagnosis.places.folds` (at most :data:`MAX_FOLDS`), then
    one fold per fit move."""
    rows = rows_of(fit_d)
    out = np.full(rows.n, -1, int)
    n_pf, n_places = 0, 0
    if rows.n_points:
        group, n_places, _ = place_folds(rows.cmd[:rows.n_points], MAX_FOLDS)
        out[:rows.n_points] = group
        n_pf = int(group.max()) + 1
    k = n_pf
    for start, t, _, _ in rows.moves:
        out[start:start + len(t)] = k
        k += 1
    return out, n_pf, n_places


def fold_errors(B: screen.Basis, w: tuple[float, float]) -> leaveout.Folds:
    """The leave-one-fold-out yardstick (:class:`cell.diagnosis.leaveout.Folds`) of the
    Basis' fit rows, each table weighed by ``w`` (points, path samples): a fold's error is
    its weighted mean square per scalar residual (1 ≈ the noise), of the linear fit on any
    column subset (empty: the nominal model). A fold-out system that leaves a column unseen
    is kept finite by a 1e-10 relative ridge."""
    m = len(B.lo)
    if B.fold_rows is None:
        return leaveout.Folds(np.zeros((0, m)), np.zeros(0), np.zeros(0, int), 0, dims=2,
                              per="scalar")
    A, r, group, table = B.fold_rows
    wr = np.where(table == 0, w[0], w[1])
    return leaveout.Folds((A * wr[:, None, None]).reshape(-1, m), (r * wr[:, None]).ravel(),
                          group, B.n_folds, dims=2, per="scalar", ridge=1e-10)


@dataclass
class Scored:
    """One candidate's out-of-sample record: ``label``, ``candidate``, ``k`` parameters,
    ``errors`` (F,) per fold, ``cv_rms`` (√ of the mean error: 1 ≈ the noise), ``p_worse``
    the one-sided p that it predicts worse than the best (computed for the candidates
    within :data:`RIVAL_RATIO` and the :data:`REPORTED` best, else 1.0), ``tied``;
    ``untestable`` why the campaign cannot fit it at all (then it has no errors: a rival
    by what it mimics, :func:`untestable_rivals`)."""

    label: str
    candidate: tuple
    k: int
    errors: np.ndarray
    cv_rms: float
    p_worse: float = 1.0
    tied: bool = False
    untestable: str = ""


@dataclass
class Judgement:
    """The out-of-sample choice: ``named`` (candidate tuple, None = keep the decision's
    ``none``), ``best`` the lowest prediction error, ``rivals`` the tied candidates that
    are other explanations, ``table`` every scored candidate best first, ``n_folds`` /
    ``n_places``, ``nominal`` the nominal model's record, ``testable`` False when the
    folds are too few for the test to reach :data:`ALPHA`, ``notes``."""

    named: tuple | None
    best: Scored | None
    rivals: list[Scored]
    table: list[Scored]
    n_folds: int
    n_places: int
    nominal: Scored | None
    testable: bool
    notes: list[str] = field(default_factory=list)


def _components(c: tuple) -> set:
    return {(e, j) for e, js in c for j in (js or (None,))}


def judge(B: screen.Basis, screened: dict, chosen: tuple | None, weights: tuple[float, float],
          n_places: int, label) -> Judgement:
    """Score every identifiable screened candidate (``screened`` {candidate: Screened}) out
    of sample and apply the rule of the module docstring. ``chosen`` the in-sample
    decision's candidate (None: ``none``, kept); ``label`` candidate → text."""
    F = B.n_folds
    yardstick = fold_errors(B, weights)
    nom_e = yardstick.loo([])[1]
    nominal = Scored("nominal", (), 0, nom_e, math.sqrt(float(nom_e.mean())) if F else math.nan)
    testable = F >= MIN_FOLDS and tie.testable(F)
    if F < MIN_FOLDS:
        return Judgement(chosen, None, [], [], F, n_places, nominal, False,
                         [f"the fit rows lie at {F} place(s): no cause can be checked on "
                          "places it was not fitted on"])
    table = []
    for c, sc in screened.items():
        if not sc.identifiable:
            continue
        e = yardstick.loo(list(sc.S))[1]
        table.append(Scored(label(c), c, sc.k, e, math.sqrt(float(e.mean()))))
    if not table:
        return Judgement(chosen, None, [], [], F, n_places, nominal, testable)
    table.sort(key=lambda s: s.cv_rms)
    ch = tie.choose(table, lambda s: s.errors, lambda s: s.cv_rms, lambda s: s.k,
                    lambda s: _components(s.candidate), reported=REPORTED)
    for s, p, t in zip(table, ch.p, ch.tied):
        s.p_worse, s.tied = p, t
    if chosen is None:
        return Judgement(None, ch.best, [], table, F, n_places, nominal, testable)
    named, rivals = ch.named, ch.rivals
    notes = []
    if not testable:
        notes.append(f"the fit rows lie at {F} folds: too few for a test over places to "
                     f"reach p < {ALPHA:g}; every cause within {RIVAL_RATIO:g}× the best "
                     "prediction error is a rival")
    return Judgement(named.candidate, ch.best, rivals[:MAX_RIVALS], table, F, n_places, nominal,
                     testable, notes)


def untestable_rivals(tied: list[tuple], skipped: dict) -> list[Scored]:
    """Effects the campaign cannot fit (``skipped`` {label: why}) that the named cause or a
    tied rival (candidate tuples ``tied``) can stand in for
    (:attr:`cell.effects.Effect.mimics`, on a shared joint): rivals that no prediction can
    rule out until the missing variable is measured."""
    out = []
    for lab, why in skipped.items():
        name, _, rest = lab.partition("[")
        joints = tuple(j for j in rest.rstrip("]").split(",") if j)
        eff = fx.EFFECTS.get(name)
        if eff is None:
            continue
        if any(e in eff.mimics and (not joints or not js or set(joints) & set(js))
               for c in tied for e, js in c):
            out.append(Scored(lab, ((name, joints),), len(eff.param_names(joints)),
                              np.zeros(0), math.nan, untestable=why))
    return out


def _grid(limits, n1: int = 25, n2: int = 12) -> np.ndarray:
    (a1, b1), (a2, b2) = limits
    t1 = np.linspace(a1, b1, n1 + 2)[1:-1]
    pos = np.linspace(max(15.0, 0.0), min(150.0, b2 - 1.0), n2)
    neg = -np.linspace(max(15.0, 0.0), min(150.0, -a2 - 1.0), n2)
    t2 = np.concatenate([neg[::-1], pos])
    g = np.array([(x, y) for x in t1 for y in t2 if a2 < y < b2])
    return g


def separating_poses(B: screen.Basis, screened: dict, named: tuple, rivals: list[Scored],
                     fit_d: DiagData, limits, sigma_mm: float | None) -> list[dict]:
    """Up to :data:`cell.diagnosis.places.N_POSES` joint configurations inside ``limits`` (both approach
    directions, the campaign's mean temperature) where the named cause and each rival
    predict most differently, at least :data:`POSE_SPACING_DEG` apart: per pose the joints,
    the directions and, per rival, the expected difference (mm) and that difference over
    the point noise σ (per axis) when known."""
    rivals = [r for r in rivals if not r.untestable]
    if not rivals:
        return []
    q = _grid(limits)
    dirs = np.array([(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)])
    qq = np.repeat(q, len(dirs), axis=0)
    dd = np.tile(dirs, (len(q), 1))
    rf = rows_of(fit_d)
    temp = None if rf.temp is None else np.full(len(qq), float(np.mean(rf.temp)))
    rows = Rows(len(qq), qq, dd, temp, np.zeros_like(qq), [], rf.order, rf.links, rf.center)
    keys = [k for k in B.cols]
    (A,), cols, *_ = screen.responses((rows,), keys, B.has_paths)

    def predict(c) -> np.ndarray:
        sc = screened[c]
        idx = [i for k in sc.keys for i in cols[k]]
        return np.einsum("nak,k->na", A[:, :, idx], sc.x)
    base = predict(named)
    diffs = np.stack([np.linalg.norm(base - predict(r.candidate), axis=1) for r in rivals], axis=1)
    return separating(qq, diffs, [r.label for r in rivals], sigma_mm, POSE_SPACING_DEG,
                      lambda i: {"j1_deg": round(float(qq[i, 0]), 3),
                                 "j2_deg": round(float(qq[i, 1]), 3),
                                 "j1_dir": int(dd[i, 0]), "j2_dir": int(dd[i, 1])})
