"""The tie rule both diagnosis families use (cell/diagnosis/tie.py)."""
import numpy as np

from cell.diagnosis import tie


def test_a_candidate_worse_on_every_fold_is_not_tied():
    best = np.linspace(1.0, 2.0, 12)
    worse = best * 1.2                      # within the rms ratio, but worse on all 12 folds
    p = tie.p_worse(worse, best)
    assert p < tie.ALPHA and not tie.tied(p, 1.2, 1.0)


def test_a_candidate_the_folds_cannot_tell_apart_is_tied():
    rng = np.random.default_rng(0)
    best = rng.uniform(1.0, 2.0, 12)
    other = best + rng.normal(0.0, 0.05, 12)
    p = tie.p_worse(other, best)
    assert p >= tie.ALPHA and tie.tied(p, 1.02, 1.0)


def test_a_poor_candidate_is_never_tied_however_few_the_folds():
    p = tie.p_worse([3.0, 2.0, 4.0], [1.0, 1.0, 1.0])     # 3 folds: the test cannot reach α
    assert p >= tie.ALPHA and not tie.testable(3)
    assert not tie.tied(p, 1.8, 1.0)                       # but 1.8× the best's rms


def test_non_finite_errors_conclude_nothing():
    assert tie.p_worse([np.nan, 1.0], [0.5, 0.5]) == 1.0
    assert tie.testable(7) and not tie.testable(6)


def test_the_simplest_tied_cause_is_named_and_other_explanations_are_its_rivals():
    offset = ("offset", 2, 1.00, {("joint_offset", "j1")})
    bigger = ("offset + link", 3, 0.98, {("joint_offset", "j1"), ("link_length", "j1")})
    other = ("gear", 2, 1.01, {("gear_ratio", "j2")})
    tied = [bigger, offset, other]
    named = tie.simplest(tied, lambda c: c[1], lambda c: c[2])
    assert named is offset                       # 2 parameters beat 3 that predict as well
    assert tie.rivals(named, tied, lambda c: c[3]) == [other]   # the larger model is no rival


def _ranked():
    rng = np.random.default_rng(3)
    base = rng.uniform(1.0, 2.0, 12)
    # (label, k, per-fold errors, components), lowest rms first
    big = ("offset + link", 3, base, {("joint_offset", "j1"), ("link_length", "j1")})
    offset = ("offset", 2, base + rng.normal(0.0, 0.02, 12), {("joint_offset", "j1")})
    gear = ("gear", 2, base + rng.normal(0.0, 0.05, 12), {("gear_ratio", "j2")})
    poor = ("backlash", 1, base * 1.6, {("backlash", "j2")})
    ranked = sorted([big, offset, gear, poor], key=lambda c: float(np.sqrt(np.mean(c[2]))))
    return ranked


def _choose(ranked, passes=lambda c: True, reported=0):
    return tie.choose(ranked, lambda c: c[2], lambda c: float(np.sqrt(np.mean(c[2]))),
                      lambda c: c[1], lambda c: c[3], passes=passes, reported=reported)


def test_choose_names_the_simplest_tied_cause_that_passes_and_keeps_its_rivals():
    ranked = _ranked()
    ch = _choose(ranked)
    labels = [c[0] for c, t in zip(ranked, ch.tied) if t]
    assert "backlash" not in labels                       # 1.6× worse on every fold
    assert ch.named[0] in ("offset", "gear") and ch.named[1] == 2
    assert {r[0] for r in ch.rivals} == {"offset", "gear"} - {ch.named[0]}
    # a candidate that fails the family's own test is never named, only tied
    ch2 = _choose(ranked, passes=lambda c: c[0] == "offset + link")
    assert ch2.named[0] == "offset + link"
    assert {r[0] for r in ch2.rivals} == {"offset", "gear"}   # a part of it is a rival too


def test_choose_tests_only_the_candidates_it_reads():
    ranked = _ranked()
    poor = next(i for i, c in enumerate(ranked) if c[0] == "backlash")
    assert _choose(ranked).p[poor] == 1.0                  # far from the best: not tested
    assert _choose(ranked, reported=len(ranked)).p[poor] < tie.ALPHA


def test_a_candidate_worse_by_a_hair_on_every_fold_is_still_tied():
    best = np.linspace(1.0, 2.0, 12)
    hair = best * 1.02                      # worse on all 12 folds, by 2 %
    p = tie.p_worse(hair, best)
    assert p < tie.ALPHA and tie.tied(p, 1.02, 1.0)
    assert not tie.tied(p, 1.06, 1.0)        # by 6 %: that matters
