"""Validation: campaigns with a hidden effect, diagnosed and scored. Pure numerics (the run
time per campaign is measured with ``time.perf_counter`` and only reported).

Each trial draws the truth from ``seed``: an effect uniformly from the vocabulary plus
``none``, a joint uniformly from those it acts on, a size with :meth:`Effect.draw` (each
parameter uniform in its ``typical`` range, random sign where signed). With ``combos`` the
truth is a main effect plus a *smaller* second effect of another kind: the second is drawn
the same way, then scaled down (never up) so the rms displacement it makes over the
campaign's rows is at most 20–40 % of the main one's. The campaign is :func:`.synth.make_campaign` (300 poses, 6
moves by default). The diagnosis sees only the campaign.

Scores (:func:`summarise`): confusion matrix (true effect × named effect, ``unexplained``
as its own column since the report then names no supported cause), effect / joint /
subsystem accuracy, how often the ``where`` analysis's ``depends_on`` matches the true
effect's, median holdout shrink (effect trials), coverage of the true parameters by the
95 % intervals (trials named right, fitted parameters only; cyclic phase compared modulo
360°), and the run time per campaign.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis.replay import predict, prepare
from cell.diagnosis.report import diagnose
from cell.diagnosis.synth import Design, make_campaign

TRUTHS = tuple(fx.EFFECTS) + ("none",)


@dataclass
class Trial:
    """One scored trial. ``true_*`` the hidden truth (main effect for combos), ``named`` /
    ``named_joints`` what the report's cause says, ``covered`` / ``n_params`` the interval
    coverage count, ``seconds`` the diagnosis run time."""

    index: int
    true_effect: str
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

    @property
    def named_or_unexplained(self) -> str:
        return "unexplained" if self.unexplained else self.named

    @property
    def effect_ok(self) -> bool:
        return not self.unexplained and self.named == self.true_effect

    @property
    def joint_ok(self) -> bool:
        return self.effect_ok and tuple(self.named_joints) == tuple(self.true_joints)


def _subsystem(name: str) -> str:
    return "none" if name in ("none", "unexplained") else fx.EFFECTS[name].subsystem


def _draw(rng: np.random.Generator, exclude=()) -> list[fx.EffectInstance]:
    name = str(rng.choice([t for t in TRUTHS if t not in exclude]))
    if name == "none":
        return []
    eff = fx.EFFECTS[name]
    joints = (str(rng.choice(eff.joints)),) if eff.per_joint else ()
    return [eff.draw(rng, joints)]


def _scaled(e: fx.EffectInstance, k: float) -> fx.EffectInstance:
    params = {n: (v * k if e.spec.spec_of(n).fitted and "phase" not in n else v)
              for n, v in e.params.items()}
    return fx.make_effect(e.effect, e.joints, params)


def _rms_displacement(d, e: fx.EffectInstance) -> float:
    base = np.concatenate([x.ravel() for x in predict(d, [])])
    sim = np.concatenate([x.ravel() for x in predict(d, [e])])
    return float(np.sqrt(np.mean((sim - base) ** 2) * 2))


def draw_truth(rng: np.random.Generator, combos: bool, design: Design, seed: int
               ) -> list[fx.EffectInstance]:
    """The hidden effects of one trial (see module docstring); [] for ``none``."""
    if not combos:
        return _draw(rng)
    main = _draw(rng, exclude=("none",))
    second = _draw(rng, exclude=("none", main[0].effect))[0]
    d = prepare(make_campaign([], seed, design))     # the trial's rows, noise-free sizes
    m, s = _rms_displacement(d, main[0]), _rms_displacement(d, second)
    target = rng.uniform(0.2, 0.4) * m
    return main + [_scaled(second, min(1.0, target / s) if s > 0 else 1.0)]


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


def run_trial(i: int, seed: int, combos: bool = False, design: Design = Design()) -> Trial:
    """Draw, measure, diagnose and score trial ``i`` of validation run ``seed``."""
    tseed = seed * 100_003 + i
    rng = np.random.default_rng(tseed)
    truth = draw_truth(rng, combos, design, tseed)
    camp = make_campaign(truth, tseed, design)
    t0 = time.perf_counter()
    dg = diagnose(camp)
    secs = time.perf_counter() - t0
    rep = dg.report
    c = rep["cause"]
    main = truth[0] if truth else None
    true_name = main.effect if main else "none"
    hit = n = 0
    if main is not None and c["effect"] == true_name and tuple(c["joints"]) == main.joints:
        hit, n = _covered(main, c["ci95"])
    return Trial(i, true_name, main.joints if main else (),
                 truth[1].effect if len(truth) > 1 else None, c["effect"], tuple(c["joints"]),
                 bool(rep["unexplained"]), float(rep["holdout"]["shrink"]),
                 rep["gap"]["where"]["depends_on"], hit, n, secs,
                 dict(main.params) if main else {})


def run(trials: int, seed: int, combos: bool = False, points: int = 300,
        progress=None) -> list[Trial]:
    """``trials`` scored trials; ``progress(i, trial)`` is called after each."""
    design = Design(n_points=points)
    out = []
    for i in range(trials):
        t = run_trial(i, seed, combos, design)
        out.append(t)
        if progress:
            progress(i, t)
    return out


def summarise(ts: list[Trial]) -> dict:
    """The scores of the module docstring as a dict (JSON-ready)."""
    eff = [t for t in ts if t.true_effect != "none"]
    none = [t for t in ts if t.true_effect == "none"]
    secs = np.array([t.seconds for t in ts]) if ts else np.zeros(1)
    cov_hit = sum(t.covered for t in ts)
    cov_n = sum(t.n_params for t in ts)
    dep = [t for t in eff if t.effect_ok]
    return {
        "trials": len(ts),
        "effect_accuracy": _share([t.effect_ok or (t.true_effect == "none" and t.named == "none"
                                                   and not t.unexplained) for t in ts]),
        "joint_accuracy_effects": _share([t.joint_ok for t in eff]),
        "effect_accuracy_effects": _share([t.effect_ok for t in eff]),
        "subsystem_accuracy": _share([_subsystem(t.named_or_unexplained) == _subsystem(t.true_effect)
                                      for t in ts]),
        "none_named_as_effect": sum(t.named != "none" for t in none),
        "none_trials": len(none),
        "effects_called_none": sum(t.named == "none" for t in eff),
        "unexplained": sum(t.unexplained for t in ts),
        "median_shrink": float(np.median([t.shrink for t in eff])) if eff else math.nan,
        "depends_on_agreement": _share([t.depends_on == fx.EFFECTS[t.true_effect].depends_on
                                        for t in dep]),
        "coverage": (cov_hit / cov_n) if cov_n else math.nan,
        "coverage_n": cov_n,
        "seconds_median": float(np.median(secs)), "seconds_max": float(np.max(secs)),
    }


def _share(xs) -> float:
    xs = list(xs)
    return sum(map(bool, xs)) / len(xs) if xs else math.nan


def markdown(ts: list[Trial], title: str) -> str:
    """Markdown tables: summary, per-effect scores, confusion matrix."""
    s = summarise(ts)
    out = [f"### {title}", "",
           "| trials | effect acc. | effect+joint acc. (effects) | subsystem acc. | none named as effect "
           "| effects called none | unexplained | median holdout shrink | depends_on agrees "
           "| 95 % CI coverage | s/campaign median (max) |",
           "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
           f"| {s['trials']} | {_pct(s['effect_accuracy'])} | {_pct(s['joint_accuracy_effects'])} "
           f"| {_pct(s['subsystem_accuracy'])} | {s['none_named_as_effect']}/{s['none_trials']} "
           f"| {s['effects_called_none']} | {s['unexplained']} | {s['median_shrink']:.3f} "
           f"| {_pct(s['depends_on_agreement'])} | {_pct(s['coverage'])} ({s['coverage_n']}) "
           f"| {s['seconds_median']:.2f} ({s['seconds_max']:.2f}) |", "",
           "| true effect | trials | named right | right joint | median shrink | CI coverage "
           "| median s |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name in TRUTHS:
        g = [t for t in ts if t.true_effect == name]
        if not g:
            continue
        right = sum(t.effect_ok or (name == "none" and t.named == "none" and not t.unexplained)
                    for t in g)
        jr = sum(t.joint_ok or (name == "none" and t.named == "none" and not t.unexplained)
                 for t in g)
        ch, cn = sum(t.covered for t in g), sum(t.n_params for t in g)
        sh = f"{np.median([t.shrink for t in g]):.3f}" if name != "none" else "–"
        out.append(f"| {name} | {len(g)} | {right} | {jr} | {sh} | "
                   f"{(f'{ch}/{cn}') if cn else '–'} | {np.median([t.seconds for t in g]):.2f} |")
    cols = list(TRUTHS) + ["unexplained"]
    short = {c: c.replace("_", " ") for c in cols}
    out += ["", "Confusion matrix (rows: true effect, columns: named cause):", "",
            "| true \\ named | " + " | ".join(short[c] for c in cols) + " |",
            "|---|" + "---:|" * len(cols)]
    for name in TRUTHS:
        g = [t for t in ts if t.true_effect == name]
        if not g:
            continue
        cells = [sum(t.named_or_unexplained == c for t in g) for c in cols]
        out.append(f"| {short[name]} | " + " | ".join(str(v) if v else "·" for v in cells) + " |")
    return "\n".join(out)


def _pct(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.1f} %"
