"""The validation's accuracy, asserted on enough trials to fail when it drops.

Realistic campaigns (cell/truth: poses clustered at 3–12 stations, optional columns often
missing, gross outliers; cell/diagnosis/validate.py and cell/diagnosis/chain/validate.py), judged
right / ambiguous (truth among the rivals) / ambiguous, truth missing / unexplained /
wrong. Every golden number below was measured at the commit that set them (the cause chosen
by predicting left-out places, untestable effects as rivals, pairs of the best three chain
effects and the best with every other) with ``.venv/bin/python`` running exactly these runs:

* planar, 120 vocabulary trials (seed 1, 200 poses), by ``cellctl diagnose validate
  --trials 120 --seed 1 --points 200``, measured when the planar campaigns went to the one
  diagnosis (each read as the chain campaign it is): right 59, ambiguous 33, ambiguous
  with the truth missing 2, unexplained 26, wrong 0; 65 of 69 true values inside their
  95 % intervals (the planar engine before it: 58 / 39 / 2 / 21 / 0, 78 of 81);
* planar, 30 trials outside the vocabulary (seed 1, ``--out-of-vocabulary 1``): unexplained
  28, ambiguous with the truth missing 1, right (none) 1, wrong 0;
* chain, 80 vocabulary trials (seed 1, 60 poses), by ``cellctl diagnose validate --chain
  --trials 80 --seed 1``, measured when motor_cyclic_error joined the chain vocabulary (the
  validation arm states its motor gear ratios), then again when the chain search learnt
  to trim a joint left-out places do not need and untestable rivals came per candidate:
  right 30, ambiguous 48, ambiguous with the truth missing 2, unexplained 0, wrong 0;
  34 of 35 intervals cover (the earlier goldens and what moved them are in the history of
  this file);
* chain, 24 trials outside the vocabulary (seed 1, ``--out-of-vocabulary 1``): unexplained
  11, ambiguous with the truth missing 11, right (none) 1, ambiguous 1, wrong 0;

Margins: the counts of right answers may fall by 7 (planar) / 5 (chain) trials and the
truth named or among the rivals by 5, so the decision logic can move a few answers between
``right`` and ``ambiguous``; the ``wrong`` counts may not grow at all (0 everywhere).
Coverage must lie in the two-sided 99 % band of a binomial with p = 0.95 over
the intervals checked. These bounds fail for the sign flips tried, each measured with the
planar run above (120 trials, seed 1, 200 poses) where it applies: the moves' approach
direction (``first_step`` in cell/measurements/campaign.py, the format's convention the
planar reading gives each move's samples): right 50, unexplained 35; the sign of the joint
effects in the one robot model (cell/kinematics/evaluate.py forward(), ``qm + dq``): planar
right 25, unexplained 79, wrong 2, chain right 14, unexplained 43; the twist in
cell/kinematics/evaluate.py: chain right 11, unexplained 53, wrong 3.
"""
import math

import pytest

from cell.diagnosis import validate as planar
from cell.diagnosis.chain import validate as chain

# about a minute of CPU per family: the slow tier (tests/conftest.py); on a loaded 2-core
# host beside the rest of the suite a run may take several, beyond the default time-out
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

SEED = 1


def binomial_band(n: int, p: float = 0.95, level: float = 0.99) -> tuple[int, int]:
    """The two-sided ``level`` band (lo, hi) of hits of a binomial(n, p): P(X < lo) and
    P(X > hi) are each at most (1 − level)/2."""
    tail = (1.0 - level) / 2.0
    pmf = [math.comb(n, k) * p ** k * (1 - p) ** (n - k) for k in range(n + 1)]
    lo, acc = 0, 0.0
    while acc + pmf[lo] <= tail:
        acc += pmf[lo]
        lo += 1
    hi, acc = n, 0.0
    while acc + pmf[hi] <= tail:
        acc += pmf[hi]
        hi -= 1
    return lo, hi


def test_binomial_band():
    # scipy.stats.binom.ppf(0.005, n, 0.95) and .ppf(0.995, n, 0.95) give the same bands
    assert binomial_band(100) == (89, 100)
    assert binomial_band(79) == (69, 79)
    lo, hi = binomial_band(20)
    assert lo <= 19 <= hi and hi == 20


def _coverage_in_band(s: dict) -> None:
    n = s["coverage_n"]
    hits = round(s["coverage"] * n)
    lo, hi = binomial_band(n)
    assert n >= 15, f"only {n} intervals checked"
    assert lo <= hits <= hi, f"{hits} of {n} intervals cover the truth; 99 % band {lo}–{hi}"


@pytest.fixture(scope="module")
def planar_vocab():
    return planar.summarise(planar.run(120, SEED, points=200))


@pytest.fixture(scope="module")
def chain_vocab():
    return chain.summarise(chain.run(80, SEED))


def test_planar_vocabulary_accuracy(planar_vocab):
    v = planar_vocab["verdicts"]
    assert sum(v.values()) == 120
    assert v["right"] >= 59 - 7, v
    assert v["right"] + v["ambiguous"] >= 92 - 5, v
    assert v["unexplained"] <= 26 + 5, v
    assert v["wrong"] == 0, planar_vocab["wrong"]


def test_planar_interval_coverage_is_near_95_percent(planar_vocab):
    _coverage_in_band(planar_vocab)


def test_planar_outside_the_vocabulary():
    s = planar.summarise(planar.run(30, SEED, points=200, outside_share=1.0))
    v = s["outside_verdicts"]
    assert sum(v.values()) == 30 and v["wrong"] == 0, s["wrong"]
    assert v["unexplained"] >= 28 - 3, v


def test_chain_vocabulary_accuracy(chain_vocab):
    v = chain_vocab["verdicts"]
    assert sum(v.values()) == 80
    assert v["right"] >= 30 - 5, v
    assert v["right"] + v["ambiguous"] >= 78 - 5, v
    assert v["unexplained"] <= 0 + 5, v
    assert v["wrong"] == 0, chain_vocab["wrong"]


def test_chain_interval_coverage_is_near_95_percent(chain_vocab):
    _coverage_in_band(chain_vocab)


def test_chain_outside_the_vocabulary():
    s = chain.summarise(chain.run(24, SEED, outside_share=1.0))
    v = s["outside_verdicts"]
    assert sum(v.values()) == 24 and v["wrong"] == 0, s["wrong"]
    assert v["unexplained"] >= 11 - 3, v
