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
The trial, the scores and the tables are the one harness of planar and chain campaigns,
:mod:`cell.diagnosis.harness`; this module draws the planar truths and campaigns.
"""
from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from cell import effects as fx
from cell.diagnosis import harness
from cell.diagnosis.harness import Trial, summarise  # noqa: F401 (this family's scores)
from cell.measurements import read_campaign
from cell.truth import campaign as truth_campaign
from cell.truth import parts as tp
from cell.truth import verdict as vd
from cell.truth.campaign import Design

TRUTHS = tuple(fx.EFFECTS) + ("none",)
OUTSIDE = tp.OUTSIDE
LAYOUTS = ("realistic", "uniform")
TWO_SHARE = 0.25            # realistic layout: share of effect trials with a second effect


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


def _covered_all(truths: Sequence[fx.EffectInstance], ci95: dict) -> tuple[int, int]:
    pairs = [_covered(e, ci95) for e in truths]
    return sum(h for h, _ in pairs), sum(n for _, n in pairs)


def _same_order(truth: fx.EffectInstance, named: dict) -> bool:
    """For a cyclic error: the report's period for each true joint is the true one (a
    report without ``jK_cyclic_period_deg`` fitted the vocabulary's default, 360°; a chain
    report names the order n in its coefficients ``jK_cyclicN_sin_deg``, period 360°/n)."""
    if truth.effect != "cyclic_error":
        return True
    default = fx.EFFECTS["cyclic_error"].spec_of("j1_cyclic_period_deg").default

    def period(j: str) -> float:
        coef = re.compile(rf"{j}_cyclic(\d+)_(?:sin|cos)_deg")
        orders = {int(m.group(1)) for k in named if (m := coef.fullmatch(k))}
        if len(orders) == 1:
            return 360.0 / orders.pop()
        return float(named.get(f"{j}_cyclic_period_deg", default))
    return all(abs(period(j) - truth.params[f"{j}_cyclic_period_deg"]) < 1e-6
               for j in truth.joints)


def diagnose_planar(camp) -> dict:
    """The report of planar campaign ``camp``: read as the chain campaign it is
    (:func:`cell.diagnosis.answer.as_chain`, ``cell/measurements.md``, last section) and
    diagnosed by :mod:`cell.diagnosis.chain`."""
    from cell.diagnosis.answer import as_chain
    from cell.diagnosis.chain.report import diagnose_chain
    return diagnose_chain(as_chain(camp))


def run_trial(i: int, seed: int, combos: bool = False, design: Design | None = None,
              outside_share: float = 0.0, outside_kinds: Sequence[str] = OUTSIDE,
              layout: str = "realistic", points: int = 300) -> Trial:
    """Draw, write, read, diagnose (:func:`diagnose_planar`) and judge trial
    ``i`` of validation run ``seed``. ``design`` fixes the campaign design (else
    :func:`draw_layout` draws it)."""
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
        rep = diagnose_planar(camp)
        secs = time.process_time() - t0
    wants = [] if odd is not None else [expected(p) for p in truth]
    want = vd.Expected(tuple((e.effect, tuple(e.joints)) for e in wants), odd is not None)
    if odd is not None:
        true_name, true_joints = odd.kind, ((f"j{odd.joint}",) if odd.joint else ())
        params, label = dict(odd.values), odd.kind + " (outside)"
    elif wants:
        true_name, true_joints, params = wants[0].effect, wants[0].joints, dict(wants[0].params)
        label = want.label
    else:
        true_name, true_joints, params, label = "none", (), {}, want.label
    voc = odd is None
    return harness.judge(
        i, tseed, rep, want, true_effect=true_name, true_joints=true_joints, truth_label=label,
        seconds=secs, layout={"places": design.places, "directions": design.directions,
                              "temperature": design.temperature, "moves": design.n_moves,
                              "outliers": design.outliers, "split": design.split_column},
        covered=lambda ci95: _covered_all(wants, ci95),
        second=truth[1].kind if len(truth) > 1 else None, truth_params=params,
        detail_ok=lambda cause: all(_same_order(e, cause.get("params", {})) for e in wants),
        truth_subsystem=_subsystem(true_name) if voc else "",
        truth_depends_on=fx.EFFECTS[true_name].depends_on if voc and wants else "",
        subsystem_of=_subsystem)


def run(trials: int, seed: int, combos: bool = False, points: int = 300,
        progress=None, outside_share: float = 0.0,
        outside_kinds: Sequence[str] = OUTSIDE, layout: str = "realistic",
        start: int = 0) -> list[Trial]:
    """Trials ``start`` … ``start + trials − 1`` of run ``seed``; ``progress(i, trial)`` is
    called after each. Raises ValueError for an ``outside_share`` outside [0, 1], an unknown
    kind or layout."""
    harness.check_outside(outside_share, tuple(outside_kinds) or OUTSIDE, OUTSIDE, layout, LAYOUTS)
    return harness.run(lambda i: run_trial(i, seed, combos, None, outside_share,
                                           tuple(outside_kinds), layout, points),
                       trials, start, progress)


def markdown(ts: list[Trial], title: str) -> str:
    """The harness's four tables (:func:`cell.diagnosis.harness.markdown`) for planar trials."""
    return harness.markdown(ts, title, "planar", TRUTHS, OUTSIDE)
