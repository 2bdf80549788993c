"""Validation: campaigns with a hidden effect, diagnosed and judged. Each campaign is
written as files in the exchange format by the truth's own writer
(:func:`cell.truth.campaign.write_campaign`), read back with the project's reader
(:func:`cell.measurements.read_campaign`) and diagnosed; the run time of the diagnosis is
measured with ``time.process_time`` and only reported.

The truth is the **independent forward model** :mod:`cell.truth`, which imports nothing
from the fitter's side (``tests/cell/test_truth_independence.py`` checks every module):
its robot numbers, poses, moves and approach directions are its own, and it follows the
conventions of ``cell/measurements.md``, not :mod:`cell.effects`.

**Layouts.** ``realistic`` (the default) draws, per trial and from a stream of its own, a
production-like campaign (:class:`cell.truth.campaign.Design`): the poses cluster at 3–12
stations with ±1° jitter; points.csv carries direction columns half of the time, a
temperature column half of the time, a split column half of the time; 4 moves in 60 % of
the campaigns (none otherwise); 0–3 gross outliers (0.5–3 mm). ``uniform`` is the earlier
design: poses spread over the workspace, 6 moves, every column.

**Truths.** An effect uniformly from the vocabulary plus ``none`` (``comm_delay`` only in
campaigns with moves: static poses cannot show it), a joint uniformly from those it acts
on, a size uniform in the range ``cell/measurements.md`` gives (:func:`cell.truth.parts.draw`;
a cyclic error also 1–4 cycles per revolution). A share ``two_share`` of the effect trials
(realistic: 0.25; ``combos``: all) carries a second effect of another kind, scaled down
(never up) so its rms displacement over the campaign is 40–100 % of the main one's. With
``outside_share`` > 0 that share of the trials (its own stream) carries instead one effect
outside the vocabulary (:data:`cell.truth.parts.OUTSIDE`).

**Verdicts** (:mod:`cell.truth.verdict`): ``right``, ``ambiguous`` (the truth among the
named cause and its rivals), ``ambiguous_missing``, ``unexplained``, ``wrong``; a cause
matches only with every true effect on its joints (a cyclic error also with its number of
cycles per revolution). **Coverage**: share of the true fitted parameters inside the 95 %
intervals, over the trials judged ``right`` (cyclic phase compared modulo 360°).
:func:`summarise` also keeps the earlier scores (effect / joint / subsystem accuracy,
``depends_on`` agreement, median holdout shrink, run time).
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
from cell.measurements import read_campaign
from cell.truth import campaign as truth_campaign
from cell.truth import parts as tp
from cell.truth import verdict as vd
from cell.truth.campaign import Design

TRUTHS = tuple(fx.EFFECTS) + ("none",)
OUTSIDE = tp.OUTSIDE
LAYOUTS = ("realistic", "uniform")
TWO_SHARE = 0.25            # realistic layout: share of effect trials with a second effect


@dataclass
class Trial:
    """One judged trial. ``true_*`` the hidden truth (main effect for two), ``named`` /
    ``named_joints`` what the report's cause says, ``verdict`` one of
    :data:`cell.truth.verdict.VERDICTS`, ``covered`` / ``n_params`` the interval coverage
    count (trials judged right), ``seconds`` the diagnosis CPU time, ``layout`` the
    campaign's design choices, ``seed`` the trial's seed."""

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
    verdict: str = ""
    truth_label: str = ""
    answer_label: str = ""
    rivals: tuple[str, ...] = ()
    layout: dict = field(default_factory=dict)
    seed: int = 0

    @property
    def outside(self) -> bool:
        """The truth is an effect outside the vocabulary."""
        return self.true_effect in OUTSIDE

    @property
    def confident_cause(self) -> bool:
        """The report names a vocabulary cause, does not call it unexplained and says it
        with high confidence (or gives no confidence)."""
        return not self.unexplained and self.named != "none" \
            and self.confidence in (None, "high")

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


def draw_layout(tseed: int, layout: str, points: int) -> Design:
    """The campaign design of trial seed ``tseed`` (module docstring), its own stream."""
    if layout == "uniform":
        return Design(n_points=points)
    rng = np.random.default_rng([tseed, 3])
    return Design(n_points=points, places=int(rng.integers(3, 13)),
                  directions=bool(rng.random() < 0.5), temperature=bool(rng.random() < 0.5),
                  n_moves=4 if rng.random() < 0.6 else 0, outliers=int(rng.integers(0, 4)),
                  split_column=bool(rng.random() < 0.5))


def draw_truth(rng: np.random.Generator, combos: bool, rows: truth_campaign.Rows,
               design: Design, two_share: float = 0.0) -> list[tp.Part]:
    """The hidden vocabulary effects of one trial (see module docstring); [] for ``none``.
    ``rows`` are the trial's campaign rows (a second effect is sized on them)."""
    design = truth_campaign.as_design(design)
    static = () if design.n_moves else ("comm_delay",)
    if not combos:
        main = _draw(rng, exclude=static)
        if not main or rng.random() >= two_share:
            return main
    else:
        main = _draw(rng, exclude=("none",) + static)
    second = _draw(rng, exclude=("none", main[0].kind) + static)[0]
    m = truth_campaign.rms_displacement(main, rows, design)
    s = truth_campaign.rms_displacement([second], rows, design)
    target = rng.uniform(0.4, 1.0) * m
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


def run_trial(i: int, seed: int, combos: bool = False, design: Design | None = None,
              outside_share: float = 0.0, outside_kinds: Sequence[str] = OUTSIDE,
              layout: str = "realistic", points: int = 300) -> Trial:
    """Draw, write, read, diagnose and judge trial ``i`` of validation run ``seed``.
    ``design`` fixes the campaign design (else :func:`draw_layout` draws it)."""
    tseed = seed * 100_003 + i
    rng = np.random.default_rng(tseed)
    design = draw_layout(tseed, layout, points) if design is None \
        else truth_campaign.as_design(design)
    rows = truth_campaign.draw_rows(tseed, design)
    odd = draw_outside(tseed, outside_share, outside_kinds)
    two = 1.0 if combos else (TWO_SHARE if layout == "realistic" else 0.0)
    truth = [odd] if odd is not None else draw_truth(rng, combos, rows, design, two)
    with tempfile.TemporaryDirectory(prefix="cell-validate-") as tmp:
        camp = read_campaign(truth_campaign.write_campaign(Path(tmp) / "campaign", truth,
                                                           tseed, design, rows))
        t0 = time.process_time()
        rep = diagnose(camp).report
        secs = time.process_time() - t0
    c = rep["cause"]
    wants = [] if odd is not None else [expected(p) for p in truth]
    want = vd.Expected(tuple((e.effect, tuple(e.joints)) for e in wants), odd is not None)
    orders_ok = lambda cause: all(_same_order(e, cause.get("params", {})) for e in wants)  # noqa: E731
    verdict = vd.classify(want, rep, orders_ok)
    hit = n = 0
    if verdict == "right":
        for e in wants:
            h, k = _covered(e, c.get("ci95", {}))
            hit, n = hit + h, n + k
    if odd is not None:
        true_name, true_joints = odd.kind, ((f"j{odd.joint}",) if odd.joint else ())
        params = dict(odd.values)
    elif wants:
        true_name, true_joints, params = wants[0].effect, wants[0].joints, dict(wants[0].params)
    else:
        true_name, true_joints, params = "none", (), {}
    named = vd.cause_components(c)
    answer = " + ".join(f"{e}[{','.join(j)}]" if j else e for e, j in named) or "none"
    lay = {"places": design.places, "directions": design.directions,
           "temperature": design.temperature, "moves": design.n_moves,
           "outliers": design.outliers, "split": design.split_column}
    return Trial(i, true_name, tuple(true_joints), truth[1].kind if len(truth) > 1 else None,
                 c["effect"], tuple(c["joints"]), bool(rep["unexplained"]),
                 float(rep["holdout"]["shrink"]), rep["gap"]["where"]["depends_on"], hit, n,
                 secs, params, c.get("confidence"), orders_ok(c) if wants else True,
                 verdict, (odd.kind + " (outside)") if odd is not None else want.label,
                 answer, tuple(r.get("label", "?") for r in c.get("rivals") or []), lay, tseed)


def run(trials: int, seed: int, combos: bool = False, points: int = 300,
        progress=None, outside_share: float = 0.0,
        outside_kinds: Sequence[str] = OUTSIDE, layout: str = "realistic",
        start: int = 0) -> list[Trial]:
    """Trials ``start`` … ``start + trials − 1`` of run ``seed``; ``progress(i, trial)`` is
    called after each. Raises ValueError for an ``outside_share`` outside [0, 1], an
    unknown kind or layout."""
    if not 0.0 <= outside_share <= 1.0:
        raise ValueError(f"outside_share {outside_share} must lie in [0, 1]")
    bad = [k for k in outside_kinds if k not in OUTSIDE]
    if bad:
        raise ValueError(f"unknown kinds {bad}; known: {list(OUTSIDE)}")
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; known: {list(LAYOUTS)}")
    out = []
    for i in range(start, start + trials):
        t = run_trial(i, seed, combos, None, outside_share, tuple(outside_kinds), layout, points)
        out.append(t)
        if progress:
            progress(i, t)
    return out


def summarise(ts: list[Trial]) -> dict:
    """The scores of the module docstring as a dict (JSON-ready). ``verdicts`` /
    ``outside_verdicts`` count the verdicts of the vocabulary trials (``none`` included)
    and of those outside it; ``coverage`` is over the trials judged right; the other
    vocabulary scores are over the vocabulary trials; ``outside_*`` count the trials
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
        "verdicts": vd.counts(t.verdict for t in voc),
        "outside_verdicts": vd.counts(t.verdict for t in out),
        "wrong": [{"seed": t.seed, "truth": t.truth_label, "answer": t.answer_label,
                   "confidence": t.confidence, "layout": t.layout}
                  for t in ts if t.verdict == "wrong"],
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
    """Markdown tables: verdicts (vocabulary trials and those outside it), the confident
    wrong answers, summary, per-effect scores, confusion matrix. Rows for effects outside
    the vocabulary are marked "(outside)"; their "named right" counts trials that named no
    confident cause (unexplained or none)."""
    s = summarise(ts)
    outside = (f"{s['outside_named_as_cause']}/{s['outside_trials']}" if s["outside_trials"]
               else "–")
    wrong = vd.wrong_lines(ts)
    out = [f"### {title}", "", *vd.TABLE_HEAD, *vd.table_lines("planar", ts, lambda t: t.outside),
           "", *(["Confident wrong answers:", "", *wrong, ""] if wrong else []),
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
