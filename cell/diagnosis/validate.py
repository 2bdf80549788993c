"""Validation: campaigns with a hidden effect, diagnosed and scored. The run time per
campaign is measured with ``time.perf_counter`` and only reported; each campaign goes
through a temporary directory in the exchange format (written, read back, diagnosed).

The truth is the **independent forward model** :mod:`cell.truth`, not :mod:`cell.effects`
(which the diagnosis fits with): ``tests/cell/test_truth.py`` holds the two to 1e-9 mm,
so a sign, unit or composition mistake shows there instead of cancelling out here.

Each trial draws the truth from ``seed``: an effect uniformly from the vocabulary plus
``none``, a joint uniformly from those it acts on, a size uniform in the vocabulary's
``typical`` range (:func:`cell.truth.parts.draw`; a cyclic error also gets 1–4 cycles per
revolution). With ``combos`` the truth is a main effect plus a *smaller* second effect of
another kind: the second is drawn the same way, then scaled down (never up) so the rms
displacement it makes over the campaign's rows is at most 20–40 % of the main one's. The
campaign is :func:`cell.truth.campaign.make_campaign` (the design of
:class:`.synth.Design`: 300 poses, 6 moves by default). The diagnosis sees only the campaign.

**Outside the vocabulary**: with ``outside_share`` > 0 that share of the trials (drawn from
a stream of its own, so the other trials keep their truths) carries instead one effect of
``outside_kinds`` (:data:`cell.truth.parts.OUTSIDE`: radial lens distortion, reach-dependent
sag, a joint-offset bump halfway through, joint 2 coupled to joint 1), alone, also with
``combos``. The right answer is ``unexplained`` or ``none``: a vocabulary cause reported
without ``unexplained`` (and not marked ``confidence: low``) is a confident wrong cause.

Scores (:func:`summarise`): confusion matrix (true effect × named effect, ``unexplained``
as its own column since the report then names no supported cause; rows for the effects
outside the vocabulary too), effect / joint / subsystem accuracy (a cyclic error's joint
is right only with its true number of cycles per revolution), how often the ``where``
analysis's ``depends_on`` matches the true effect's, median holdout shrink (effect trials),
coverage of the true parameters by the 95 % intervals (trials named right, fitted
parameters only; cyclic phase compared modulo 360°), and the run time per campaign. These
are over the vocabulary trials (and ``none``); the trials outside it are counted apart: how
many were named as a confident cause.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from cell import effects as fx
from cell.diagnosis.report import diagnose
from cell.diagnosis.synth import Design
from cell.measurements import read_campaign, write_campaign
from cell.truth import campaign as truth_campaign
from cell.truth import parts as tp

TRUTHS = tuple(fx.EFFECTS) + ("none",)
OUTSIDE = tp.OUTSIDE


@dataclass
class Trial:
    """One scored trial. ``true_*`` the hidden truth (main effect for combos), ``named`` /
    ``named_joints`` what the report's cause says, ``covered`` / ``n_params`` the interval
    coverage count, ``seconds`` the diagnosis run time."""

    index: int
    true_effect: str           # a vocabulary effect, "none" or a kind outside the vocabulary
    true_joints: tuple[str, ...]
    second: str | None
    named: str
    named_joints: tuple[str, ...]
    unexplained: bool
    shrink: float
    depends_on: str
    covered: int
    n_params: int
    seconds: float
    truth_params: dict = field(default_factory=dict)
    confidence: str | None = None   # the report's cause.confidence, if it gives one
    order_ok: bool = True           # a cyclic error named with the true cycles per revolution

    @property
    def outside(self) -> bool:
        """The truth is an effect outside the vocabulary."""
        return self.true_effect in OUTSIDE

    @property
    def confident_cause(self) -> bool:
        """The report names a vocabulary cause, does not call it unexplained and does not
        mark it low confidence."""
        return not self.unexplained and self.named != "none" and self.confidence != "low"

    @property
    def named_or_unexplained(self) -> str:
        return "unexplained" if self.unexplained else self.named

    @property
    def effect_ok(self) -> bool:
        return not self.unexplained and self.named == self.true_effect

    @property
    def joint_ok(self) -> bool:
        """Right effect on the right joints (a cyclic error: with the right order too)."""
        return self.effect_ok and tuple(self.named_joints) == tuple(self.true_joints) \
            and self.order_ok


def _subsystem(name: str) -> str:
    return "none" if name in ("none", "unexplained") else fx.EFFECTS[name].subsystem


def _draw(rng: np.random.Generator, exclude=()) -> list[tp.Part]:
    name = str(rng.choice([t for t in TRUTHS if t not in exclude]))
    return [] if name == "none" else [tp.draw(rng, name)]


def expected(p: tp.Part) -> fx.EffectInstance:
    """What the diagnosis should answer for vocabulary part ``p``, as the vocabulary's
    instance (built by :func:`cell.effects.make_effect`, which checks names and bounds)."""
    a = tp.answer(p)
    if a is None:
        raise ValueError(f"{p.kind} lies outside the vocabulary: it has no expected answer")
    return fx.make_effect(a.effect, a.joints, a.params)


def draw_truth(rng: np.random.Generator, combos: bool, rows: truth_campaign.Rows,
               design: Design) -> list[tp.Part]:
    """The hidden vocabulary effects of one trial (see module docstring); [] for ``none``.
    ``rows`` are the trial's campaign rows (combos size the second effect on them)."""
    if not combos:
        return _draw(rng)
    main = _draw(rng, exclude=("none",))
    second = _draw(rng, exclude=("none", main[0].kind))[0]
    m = truth_campaign.rms_displacement(main, rows, design)
    s = truth_campaign.rms_displacement([second], rows, design)
    target = rng.uniform(0.2, 0.4) * m
    return main + [tp.scaled(second, min(1.0, target / s) if s > 0 else 1.0)]


def draw_outside(tseed: int, share: float, kinds: Sequence[str]) -> tp.Part | None:
    """The effect outside the vocabulary of trial seed ``tseed``, or None (a vocabulary
    trial): with probability ``share``, one of ``kinds`` uniformly. Its own stream."""
    if share <= 0 or not kinds:
        return None
    rng = np.random.default_rng([tseed, 7])
    if rng.random() >= share:
        return None
    return tp.draw(rng, str(rng.choice(list(kinds))))


def _covered(truth: fx.EffectInstance, ci95: dict) -> tuple[int, int]:
    hit = n = 0
    for name in truth.fit_names:
        if name not in ci95:
            continue
        lo, hi = ci95[name]
        v = truth.params[name]
        n += 1
        if name.endswith("phase_deg"):
            mid, half = (lo + hi) / 2, (hi - lo) / 2
            hit += abs((v - mid + 180.0) % 360.0 - 180.0) <= half
        else:
            hit += lo <= v <= hi
    return hit, n


def _same_order(truth: fx.EffectInstance, named: dict) -> bool:
    """For a cyclic error: the report's period for each true joint is the true one (a
    report without ``jK_cyclic_period_deg`` fitted the vocabulary's default, 360°)."""
    if truth.effect != "cyclic_error":
        return True
    default = fx.EFFECTS["cyclic_error"].spec_of("j1_cyclic_period_deg").default
    return all(abs(float(named.get(f"{j}_cyclic_period_deg", default))
                   - truth.params[f"{j}_cyclic_period_deg"]) < 1e-6 for j in truth.joints)


def _through_the_format(camp) -> object:
    """``camp`` written to a temporary campaign directory and read back (the format path)."""
    with tempfile.TemporaryDirectory(prefix="cell-validate-") as tmp:
        return read_campaign(write_campaign(camp, Path(tmp) / "campaign"))


def run_trial(i: int, seed: int, combos: bool = False, design: Design = Design(),
              outside_share: float = 0.0, outside_kinds: Sequence[str] = OUTSIDE) -> Trial:
    """Draw, measure, diagnose and score trial ``i`` of validation run ``seed``."""
    tseed = seed * 100_003 + i
    rng = np.random.default_rng(tseed)
    rows = truth_campaign.draw_rows(tseed, design)
    odd = draw_outside(tseed, outside_share, outside_kinds)
    truth = [odd] if odd is not None else draw_truth(rng, combos, rows, design)
    camp = _through_the_format(truth_campaign.make_campaign(truth, tseed, design, rows))
    t0 = time.perf_counter()
    dg = diagnose(camp)
    secs = time.perf_counter() - t0
    rep = dg.report
    c = rep["cause"]
    hit = n = 0
    order_ok = True
    if odd is not None:
        true_name, true_joints = odd.kind, ((f"j{odd.joint}",) if odd.joint else ())
        params = dict(odd.values)
    elif truth:
        main = expected(truth[0])
        true_name, true_joints, params = main.effect, main.joints, dict(main.params)
        order_ok = _same_order(main, c["params"])
        if c["effect"] == true_name and tuple(c["joints"]) == main.joints and order_ok:
            hit, n = _covered(main, c["ci95"])
    else:
        true_name, true_joints, params = "none", (), {}
    return Trial(i, true_name, true_joints,
                 truth[1].kind if len(truth) > 1 else None, c["effect"], tuple(c["joints"]),
                 bool(rep["unexplained"]), float(rep["holdout"]["shrink"]),
                 rep["gap"]["where"]["depends_on"], hit, n, secs, params,
                 c.get("confidence"), order_ok)


def run(trials: int, seed: int, combos: bool = False, points: int = 300,
        progress=None, outside_share: float = 0.0,
        outside_kinds: Sequence[str] = OUTSIDE) -> list[Trial]:
    """``trials`` scored trials; ``progress(i, trial)`` is called after each. Raises
    ValueError for an ``outside_share`` outside [0, 1] or an unknown kind."""
    if not 0.0 <= outside_share <= 1.0:
        raise ValueError(f"outside_share {outside_share} must lie in [0, 1]")
    bad = [k for k in outside_kinds if k not in OUTSIDE]
    if bad:
        raise ValueError(f"unknown kinds {bad}; known: {list(OUTSIDE)}")
    design = Design(n_points=points)
    out = []
    for i in range(trials):
        t = run_trial(i, seed, combos, design, outside_share, tuple(outside_kinds))
        out.append(t)
        if progress:
            progress(i, t)
    return out


def summarise(ts: list[Trial]) -> dict:
    """The scores of the module docstring as a dict (JSON-ready). The vocabulary scores
    are over the vocabulary trials (``none`` included); ``outside_*`` count the trials
    outside it: all of them, named as a confident cause, unexplained, none."""
    voc = [t for t in ts if not t.outside]
    out = [t for t in ts if t.outside]
    eff = [t for t in voc if t.true_effect != "none"]
    none = [t for t in voc if t.true_effect == "none"]
    secs = np.array([t.seconds for t in ts]) if ts else np.zeros(1)
    cov_hit = sum(t.covered for t in voc)
    cov_n = sum(t.n_params for t in voc)
    dep = [t for t in eff if t.effect_ok]
    return {
        "trials": len(ts),
        "effect_accuracy": _share([t.effect_ok or (t.true_effect == "none" and t.named == "none"
                                                   and not t.unexplained) for t in voc]),
        "joint_accuracy_effects": _share([t.joint_ok for t in eff]),
        "effect_accuracy_effects": _share([t.effect_ok for t in eff]),
        "subsystem_accuracy": _share([_subsystem(t.named_or_unexplained) == _subsystem(t.true_effect)
                                      for t in voc]),
        "none_named_as_effect": sum(t.named != "none" for t in none),
        "none_trials": len(none),
        "effects_called_none": sum(t.named == "none" for t in eff),
        "unexplained": sum(t.unexplained for t in voc),
        "median_shrink": float(np.median([t.shrink for t in eff])) if eff else math.nan,
        "depends_on_agreement": _share([t.depends_on == fx.EFFECTS[t.true_effect].depends_on
                                        for t in dep]),
        "coverage": (cov_hit / cov_n) if cov_n else math.nan,
        "coverage_n": cov_n,
        "seconds_median": float(np.median(secs)), "seconds_max": float(np.max(secs)),
        "outside_trials": len(out),
        "outside_named_as_cause": sum(t.confident_cause for t in out),
        "outside_unexplained": sum(t.unexplained for t in out),
        "outside_none": sum(t.named == "none" and not t.unexplained for t in out),
    }


def _share(xs) -> float:
    xs = list(xs)
    return sum(map(bool, xs)) / len(xs) if xs else math.nan


def _label(name: str, spaced: bool = False) -> str:
    return (name.replace("_", " ") if spaced else name) + (" (outside)" if name in OUTSIDE else "")


def markdown(ts: list[Trial], title: str) -> str:
    """Markdown tables: summary, per-effect scores, confusion matrix. Rows for effects
    outside the vocabulary are marked "(outside)"; their "named right" counts trials that
    named no confident cause (unexplained or none)."""
    s = summarise(ts)
    outside = (f"{s['outside_named_as_cause']}/{s['outside_trials']}" if s["outside_trials"]
               else "–")
    out = [f"### {title}", "",
           "| trials | effect acc. | effect+joint acc. (effects) | subsystem acc. | none named as effect "
           "| effects called none | unexplained | median holdout shrink | depends_on agrees "
           "| 95 % CI coverage | s/campaign median (max) | outside vocab. named as cause |",
           "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
           f"| {s['trials']} | {_pct(s['effect_accuracy'])} | {_pct(s['joint_accuracy_effects'])} "
           f"| {_pct(s['subsystem_accuracy'])} | {s['none_named_as_effect']}/{s['none_trials']} "
           f"| {s['effects_called_none']} | {s['unexplained']} | {_num(s['median_shrink'])} "
           f"| {_pct(s['depends_on_agreement'])} | {_pct(s['coverage'])} ({s['coverage_n']}) "
           f"| {s['seconds_median']:.2f} ({s['seconds_max']:.2f}) | {outside} |", "",
           "| true effect | trials | named right | right joint | median shrink | CI coverage "
           "| median s |", "|---|---:|---:|---:|---:|---:|---:|"]
    rows = list(TRUTHS) + list(OUTSIDE)
    for name in rows:
        g = [t for t in ts if t.true_effect == name]
        if not g:
            continue
        if name in OUTSIDE:
            right, jr = sum(not t.confident_cause for t in g), "–"
        else:
            right = sum(t.effect_ok or (name == "none" and t.named == "none"
                                        and not t.unexplained) for t in g)
            jr = sum(t.joint_ok or (name == "none" and t.named == "none" and not t.unexplained)
                     for t in g)
        ch, cn = sum(t.covered for t in g), sum(t.n_params for t in g)
        sh = f"{np.median([t.shrink for t in g]):.3f}" if name != "none" else "–"
        out.append(f"| {_label(name)} | {len(g)} | {right} | {jr} | {sh} | "
                   f"{(f'{ch}/{cn}') if cn else '–'} | {np.median([t.seconds for t in g]):.2f} |")
    cols = list(TRUTHS) + ["unexplained"]
    short = {c: c.replace("_", " ") for c in cols}
    out += ["", "Confusion matrix (rows: true effect, columns: named cause):", "",
            "| true \\ named | " + " | ".join(short[c] for c in cols) + " |",
            "|---|" + "---:|" * len(cols)]
    for name in rows:
        g = [t for t in ts if t.true_effect == name]
        if not g:
            continue
        cells = [sum(t.named_or_unexplained == c for t in g) for c in cols]
        out.append(f"| {_label(name, True)} | "
                   + " | ".join(str(v) if v else "·" for v in cells) + " |")
    return "\n".join(out)


def _num(v: float) -> str:
    return "–" if math.isnan(v) else f"{v:.3f}"


def _pct(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.1f} %"
