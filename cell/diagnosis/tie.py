"""The one rule by which the diagnosis, planar and chain, calls a candidate cause **tied**
with the best one: the campaign's left-out folds (places, or poses where they do not
cluster) cannot tell the two apart. Pure numerics.

A candidate is tied with the best when both hold:

* it does not predict the left-out folds worse by a margin that matters: the one-sided
  Wilcoxon signed-rank test over folds (its per-fold error minus the best's) gives
  p ≥ :data:`ALPHA`, or its prediction rms is within :data:`MARGIN` of the best's (a
  candidate that is worse on every fold by a hair is still as good an explanation: a
  spurious extra parameter of 0.002° must not beat the simpler cause);
* its prediction rms is within :data:`RIVAL_RATIO` of the best's. A fold count too small
  for the test to reach :data:`ALPHA` (at most 6 folds: 0.5⁶ > 0.01) must not make a poor
  candidate a rival.

Of the tied candidates the simplest (fewest parameters) is named; the others that are
other explanations are its rivals, and the answer is ``ambiguous``. The same test, the
other way round, says whether a candidate predicts better than the nominal model at all.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Generic, Sequence, TypeVar

import numpy as np

from cell.numerics.stats import wilcoxon_greater

T = TypeVar("T")
ALPHA = 0.01          # one-sided test over folds
RIVAL_RATIO = 1.25    # a tied candidate's prediction rms is within this factor of the best's
MARGIN = 0.05         # a candidate predicting worse by less than this share is tied anyway


def p_worse(errors, best_errors) -> float:
    """One-sided p that ``errors`` (per fold) lie above ``best_errors`` (paired); 1.0 when
    a difference is not finite (nothing can be concluded)."""
    with np.errstate(invalid="ignore"):          # inf − inf (a fold that cannot be left out)
        diff = np.asarray(errors, dtype=float) - np.asarray(best_errors, dtype=float)
    if not np.all(np.isfinite(diff)):
        return 1.0
    return wilcoxon_greater(diff)


def close(rms: float, best_rms: float) -> bool:
    """The prediction rms ``rms`` is within :data:`RIVAL_RATIO` of ``best_rms``."""
    return rms <= RIVAL_RATIO * best_rms


def tied(p: float, rms: float, best_rms: float) -> bool:
    """Tied with the best: :func:`close`, and either not worse at :data:`ALPHA` (``p``
    from :func:`p_worse`) or worse by less than :data:`MARGIN` of the best's prediction
    rms (a difference too small to matter, however consistent over the folds)."""
    return close(rms, best_rms) and (p >= ALPHA or rms <= (1.0 + MARGIN) * best_rms)


def testable(n_folds: int) -> bool:
    """Whether ``n_folds`` folds can reach :data:`ALPHA` at all (the smallest one-sided
    Wilcoxon p over n folds is 0.5ⁿ)."""
    return 0.5 ** n_folds < ALPHA


def simplest(candidates: Sequence[T], k: Callable[[T], int], rms: Callable[[T], float],
             effects: Callable[[T], int] = lambda c: 0) -> T:
    """The candidate to name among ``candidates`` (tied ones): the fewest parameters ``k``,
    then the fewest ``effects`` (one effect on two joints is a simpler story than two
    effects on one, at as many parameters), then the lowest prediction ``rms``. A cause
    with more parameters is named only when it predicts the left-out folds better, not
    when it fits the fit rows better."""
    return min(candidates, key=lambda c: (k(c), effects(c), rms(c)))


def rivals(named: T, tied: Sequence[T], components: Callable[[T], set]) -> list[T]:
    """The tied candidates that are other explanations of the gap than ``named``: neither
    ``named`` itself nor a larger model that contains all of its ``components``."""
    mine = components(named)
    return [c for c in tied if c is not named and not components(c) >= mine]


@dataclass
class Choice(Generic[T]):
    """The rule applied to candidates ranked best first: ``p`` (one-sided p that each
    predicts worse than the best, 1.0 where not computed) and ``tied`` per candidate, in
    the ranking's order; ``named`` the simplest tied candidate that passes; ``rivals`` the
    tied other explanations of it."""

    best: T
    p: list[float]
    tied: list[bool]
    named: T
    rivals: list[T]


def choose(ranked: Sequence[T], errors: Callable[[T], np.ndarray], rms: Callable[[T], float],
           k: Callable[[T], int], components: Callable[[T], set],
           passes: Callable[[T], bool] = lambda c: True, reported: int = 0) -> Choice[T]:
    """Apply the rule of this module to ``ranked`` (non-empty, lowest prediction ``rms``
    first; ``errors`` per fold, ``k`` parameters, ``components`` what the candidate
    claims): the tied candidates, the simplest of those that ``passes`` (the best must
    pass) and its rivals. ``p`` is computed for the candidates close enough to be tied
    and for the first ``reported`` (a report's table reads them)."""
    best = ranked[0]
    p = [1.0] * len(ranked)
    flags = [False] * len(ranked)
    for i, c in enumerate(ranked):
        if c is not best and (close(rms(c), rms(best)) or i < reported):
            p[i] = p_worse(errors(c), errors(best))
        flags[i] = c is best or tied(p[i], rms(c), rms(best))
    ties = [c for c, f in zip(ranked, flags) if f]
    named = simplest([c for c in ties if passes(c)] or [best], k, rms,
                     lambda c: len({e for e, _ in components(c)}))
    return Choice(best, p, flags, named, rivals(named, ties, components))
