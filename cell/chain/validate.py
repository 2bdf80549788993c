"""Blind validation of the chain diagnosis: campaigns with a hidden effect drawn from the
independent forward model (:mod:`cell.truth.chain`), written in the exchange format by
:func:`cell.truth.chain_campaign.make` (the truth's own writer), read back with the
project's reader, diagnosed by :func:`cell.chain.report.diagnose_chain` with no noise given
(it must estimate the noise itself) and judged (:mod:`cell.truth.verdict`).

The arm is the UR5 of :mod:`cell.truth.chain_campaign` (6 joints, standard DH), measured by a
tracker at a random unknown pose, at 3 markers at unknown places on the hand; ``poses``
poses (default 60) of which a tenth (at least 3) revisit earlier ones; σ per axis uniform
in 0.02–0.05 mm. **Layouts**: ``realistic`` (default; its own stream per trial): the poses
cluster at 3–12 stations with ±3° jitter per joint, and 0–2 marker readings are gross
outliers (1–5 mm); ``uniform``: readings uniform over ±150°, no outliers.

**Truths**, from each trial's own seed, uniformly among ``none`` and the vocabulary:

* ``joint_offset``: one or two of j2…j5 (j1 and j6 are absorbed by the sensor frame and the
  free markers), 0.02–0.2° each, either sign;
* ``link_length``: one of the DH parameters this arm's layout separates from the
  registration and from each other (a of j2, j3; α of j2, j3, j4; d of j5), 0.2–2 mm or
  0.02–0.2°;
* ``gear_ratio``: j2 or j3, 3·10⁻⁴–2·10⁻³ relative;
* ``gravity_compliance``: j2, or j2 and j3, 0.1–0.5 °/m each.

In the realistic layout a quarter of the effect trials carry a second effect of another
kind (drawn the same way; a joint offset then on j4 or j5 only, so the two act on
different joints).

**Outside the vocabulary** (with ``outside_share``: that share of trials, drawn from a
stream of its own): ``lens`` (radial scale of the sensor, 1–3·10⁻³ /m), ``reach_sag``
(1–3 mm/m²), ``bump`` (an offset of 0.1–0.2° on j2 or j3 from the middle pose on),
``couple`` (j3 turns by 0.5–3·10⁻³ × j2's reading), ``cyclic`` (a transmission ripple of
0.02–0.08° with 2–4 cycles per revolution on j2 or j3, joint-dependent and not in the
chain vocabulary), ``plane_bump`` (a smooth local displacement of 0.1–0.4 mm, width
150–300 mm, centred near the arm's reach). A vocabulary cause named with high confidence
and without ``unexplained`` is a confident wrong cause.

Scores (:func:`summarise`): verdict counts (in and outside the vocabulary), the confident
wrong answers, effect and effect+joint accuracy, confusion matrix, ``none`` named as an
effect, effects called ``none``, median holdout shrink, coverage of the true parameters by
the 95 % intervals (trials judged right), CPU seconds per campaign.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from cell.chain.fit import EFFECTS
from cell.chain.report import diagnose_chain
from cell.measurements import read_campaign
from cell.truth import verdict as vd
from cell.truth.chain_campaign import MARKERS, make

VOCABULARY = ("none",) + EFFECTS    # the chain vocabulary, cell.chain.fit.EFFECTS
OUTSIDE = ("lens", "reach_sag", "bump", "couple", "cyclic", "plane_bump")
LAYOUTS = ("realistic", "uniform")
TWO_SHARE = 0.25
LINKS = (("j2", "a", "a_mm"), ("j3", "a", "a_mm"), ("j2", "alpha", "alpha_deg"),
         ("j3", "alpha", "alpha_deg"), ("j4", "alpha", "alpha_deg"), ("j5", "d", "d_mm"))


@dataclass
class Truth:
    """One drawn truth: the kind, the joints it acts on, the forward model's ``effects``
    dict, the campaign's ``lens`` and the true values under the report's parameter names."""

    kind: str
    joints: tuple[str, ...]
    effects: dict
    lens: float
    params: dict
    components: tuple | None = None    # (effect, joints) pairs; None: just (kind, joints)

    @property
    def expected(self) -> vd.Expected:
        """What the report should name (:class:`cell.truth.verdict.Expected`)."""
        if self.kind in OUTSIDE:
            return vd.Expected((), True)
        if self.kind == "none":
            return vd.Expected(())
        return vd.Expected(self.components or ((self.kind, self.joints),))

    @property
    def label(self) -> str:
        return f"{self.kind} (outside)" if self.kind in OUTSIDE else self.expected.label


@dataclass
class Trial:
    index: int
    truth: Truth
    named: str
    named_joints: tuple[str, ...]
    unexplained: bool
    low_confidence: bool
    shrink: float
    covered: int
    n_params: int
    seconds: float
    verdict: str = ""
    confidence: str | None = None
    answer_label: str = ""
    layout: dict | None = None
    seed: int = 0

    @property
    def truth_label(self) -> str:
        return self.truth.label

    @property
    def outside(self) -> bool:
        return self.truth.kind in OUTSIDE

    @property
    def answer(self) -> str:
        return "unexplained" if self.unexplained else self.named

    @property
    def effect_ok(self) -> bool:
        if self.truth.kind == "none":
            return self.answer == "none"
        return self.answer == self.truth.kind

    @property
    def joint_ok(self) -> bool:
        return self.effect_ok and (self.truth.kind == "none"
                                   or tuple(self.named_joints) == self.truth.joints)

    @property
    def confident_cause(self) -> bool:
        return not self.unexplained and self.named != "none" and not self.low_confidence


def _size(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.choice((-1.0, 1.0)) * rng.uniform(lo, hi))


def draw(rng: np.random.Generator, kind: str) -> Truth:
    """A truth of ``kind`` (module docstring) drawn from ``rng``."""
    if kind == "none":
        return Truth(kind, (), {}, 0.0, {})
    if kind == "joint_offset":
        js = sorted(rng.choice(["j2", "j3", "j4", "j5"], int(rng.integers(1, 3)), replace=False).tolist())
        v = {j: _size(rng, 0.02, 0.2) for j in js}
        return Truth(kind, tuple(js), {"offset": v}, 0.0, {f"{j}_offset_deg": x for j, x in v.items()})
    if kind == "link_length":
        j, key, name = LINKS[int(rng.integers(len(LINKS)))]
        x = _size(rng, 0.2, 2.0) if key in ("a", "d") else _size(rng, 0.02, 0.2)
        return Truth(kind, (j,), {key: {j: x}}, 0.0, {f"{j}_{name}": x})
    if kind == "gear_ratio":
        j = str(rng.choice(["j2", "j3"]))
        x = _size(rng, 3e-4, 2e-3)
        return Truth(kind, (j,), {"ratio": {j: x}}, 0.0, {f"{j}_gear_ratio_rel": x})
    if kind == "gravity_compliance":
        js = ["j2"] if rng.random() < 0.5 else ["j2", "j3"]
        v = {j: float(rng.uniform(0.1, 0.5)) for j in js}
        return Truth(kind, tuple(js), {"sag": v}, 0.0, {f"{j}_compliance_deg_per_m": x for j, x in v.items()})
    if kind == "lens":
        x = float(rng.uniform(1e-3, 3e-3))
        return Truth(kind, (), {}, x, {"lens_per_m": x})
    if kind == "cyclic":
        j = str(rng.choice(["j2", "j3"]))
        a, n, ph = float(rng.uniform(0.02, 0.08)), int(rng.integers(2, 5)), float(rng.uniform(0, 360))
        return Truth(kind, (j,), {"cyclic": {j: (a, n, ph)}}, 0.0,
                     {f"{j}_cyclic_amp_deg": a, f"{j}_cyclic_cycles": n})
    if kind == "plane_bump":
        a, w = float(rng.uniform(0.1, 0.4)), float(rng.uniform(150, 300))
        ang = rng.uniform(0, 2 * math.pi)
        at = (600 * math.cos(ang), 600 * math.sin(ang), float(rng.uniform(0, 400)))
        u = rng.normal(size=3)
        return Truth(kind, (), {"plane_bump": (a, at, w, tuple(u / np.linalg.norm(u)))}, 0.0,
                     {"plane_bump_mm": a})
    if kind == "reach_sag":
        x = float(rng.uniform(1.0, 3.0))
        return Truth(kind, (), {"reach_sag": x}, 0.0, {"reach_sag_mm_per_m2": x})
    if kind == "bump":
        j = str(rng.choice(["j2", "j3"]))
        x = _size(rng, 0.1, 0.2)
        return Truth(kind, (j,), {"bump": {j: x}}, 0.0, {f"{j}_bump_deg": x})
    if kind == "couple":
        x = _size(rng, 5e-4, 3e-3)
        return Truth(kind, ("j3",), {"couple": x}, 0.0, {"j3_from_j2": x})
    raise ValueError(f"unknown kind {kind!r}; known: {', '.join(VOCABULARY + OUTSIDE)}")


def draw_second(rng: np.random.Generator, first: Truth) -> Truth:
    """``first`` plus a second effect of another kind (module docstring)."""
    kind = str(rng.choice([k for k in VOCABULARY[1:] if k != first.kind]))
    if kind == "joint_offset":
        j = str(rng.choice([j for j in ("j4", "j5") if j not in first.joints]))
        v = _size(rng, 0.02, 0.2)
        second = Truth(kind, (j,), {"offset": {j: v}}, 0.0, {f"{j}_offset_deg": v})
    else:
        second = draw(rng, kind)
    effects = {**first.effects}
    for k, v in second.effects.items():
        effects[k] = {**effects.get(k, {}), **v}
    comps = ((first.kind, first.joints), (second.kind, second.joints))
    return Truth(first.kind, first.joints, effects, 0.0, {**first.params, **second.params}, comps)


def draw_layout(tseed: int, layout: str) -> dict:
    """Keyword arguments of :func:`cell.truth.chain_campaign.make` for trial seed ``tseed``'s
    layout (module docstring), from a stream of its own."""
    if layout == "uniform":
        return {}
    rng = np.random.default_rng([tseed, 3])
    return {"places": int(rng.integers(3, 13)), "jitter_deg": 3.0,
            "outliers": int(rng.integers(0, 3))}


def _covered(truth: Truth, ci95: dict) -> tuple[int, int]:
    hit = n = 0
    for name, v in truth.params.items():
        if name in ci95 and None not in ci95[name]:
            lo, hi = ci95[name]
            n += 1
            hit += lo <= v <= hi
    return hit, n


def run_trial(i: int, seed: int, poses: int = 60, outside_share: float = 0.0,
              outside_kinds: Sequence[str] = OUTSIDE, layout: str = "realistic") -> Trial:
    """Draw, measure (through the format), diagnose and judge trial ``i`` of run ``seed``."""
    tseed = seed * 100_003 + i
    rng = np.random.default_rng(tseed)
    odd = np.random.default_rng([tseed, 7])
    if outside_share > 0 and odd.random() < outside_share:
        truth = draw(odd, str(odd.choice(list(outside_kinds))))
    else:
        truth = draw(rng, str(rng.choice(VOCABULARY)))
    noise = float(rng.uniform(0.02, 0.05))
    if layout == "realistic" and truth.kind in VOCABULARY[1:] \
            and np.random.default_rng([tseed, 5]).random() < TWO_SHARE:
        truth = draw_second(np.random.default_rng([tseed, 6]), truth)
    lay = draw_layout(tseed, layout)
    with tempfile.TemporaryDirectory(prefix="cell-chain-validate-") as tmp:
        d = make(Path(tmp) / "campaign", truth.effects, poses=poses, noise_mm=noise, seed=tseed,
                 markers=MARKERS, lens=truth.lens, repeats=max(3, poses // 10), **lay)
        t0 = time.process_time()
        rep = diagnose_chain(read_campaign(d))
        secs = time.process_time() - t0
    c = rep["cause"]
    verdict = vd.classify(truth.expected, rep)
    hit = n = 0
    if verdict == "right":
        hit, n = _covered(truth, c["ci95"])
    named = vd.cause_components(c)
    answer = " + ".join(f"{e}[{','.join(j)}]" if j else e for e, j in named) or "none"
    return Trial(i, truth, c["effect"], tuple(c["joints"]), bool(rep["unexplained"]),
                 c.get("confidence") in ("low", "ambiguous"),
                 float(rep["holdout"]["shrink"] or 0.0), hit, n, secs, verdict,
                 c.get("confidence"), answer, lay, tseed)


def run(trials: int, seed: int, poses: int = 60, outside_share: float = 0.0,
        outside_kinds: Sequence[str] = OUTSIDE, progress=None, layout: str = "realistic",
        start: int = 0) -> list[Trial]:
    """Trials ``start`` … ``start + trials − 1``, judged. Raises ValueError for a share
    outside [0, 1], an unknown kind or layout, or fewer than 20 poses."""
    if not 0.0 <= outside_share <= 1.0:
        raise ValueError(f"outside_share {outside_share} must lie in [0, 1]")
    bad = [k for k in outside_kinds if k not in OUTSIDE]
    if bad or not outside_kinds:
        raise ValueError(f"unknown kinds {bad}; known: {list(OUTSIDE)}")
    if poses < 20:
        raise ValueError(f"poses {poses} must be ≥ 20")
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; known: {list(LAYOUTS)}")
    out = []
    for i in range(start, start + trials):
        out.append(run_trial(i, seed, poses, outside_share, tuple(outside_kinds), layout))
        if progress:
            progress(i, out[-1])
    return out


def _share(xs) -> float:
    xs = list(xs)
    return sum(map(bool, xs)) / len(xs) if xs else math.nan


def summarise(ts: list[Trial]) -> dict:
    """The scores of the module docstring (JSON-ready)."""
    voc = [t for t in ts if not t.outside]
    out = [t for t in ts if t.outside]
    eff = [t for t in voc if t.truth.kind != "none"]
    none = [t for t in voc if t.truth.kind == "none"]
    cov_hit, cov_n = sum(t.covered for t in voc), sum(t.n_params for t in voc)
    secs = [t.seconds for t in ts] or [math.nan]
    return {
        "trials": len(ts),
        "verdicts": vd.counts(t.verdict for t in voc),
        "outside_verdicts": vd.counts(t.verdict for t in out),
        "wrong": [{"seed": t.seed, "truth": t.truth_label, "answer": t.answer_label,
                   "confidence": t.confidence, "layout": t.layout}
                  for t in ts if t.verdict == "wrong"],
        "effect_accuracy": _share(t.effect_ok for t in voc),
        "joint_accuracy_effects": _share(t.joint_ok for t in eff),
        "none_named_as_effect": sum(t.answer != "none" for t in none),
        "none_trials": len(none),
        "effects_called_none": sum(t.answer == "none" for t in eff),
        "unexplained": sum(t.unexplained for t in voc),
        "median_shrink": float(np.median([t.shrink for t in eff])) if eff else math.nan,
        "coverage": cov_hit / cov_n if cov_n else math.nan,
        "coverage_n": cov_n,
        "cpu_s_median": float(np.median(secs)), "cpu_s_max": float(np.max(secs)),
        "outside_trials": len(out),
        "outside_named_as_cause": sum(t.confident_cause for t in out),
        "outside_unexplained": sum(t.unexplained for t in out),
        "outside_none": sum(t.answer == "none" for t in out),
    }


def _num(v: float) -> str:
    return "–" if math.isnan(v) else f"{v:.3f}"


def _pct(v: float) -> str:
    return "–" if math.isnan(v) else f"{100 * v:.1f} %"


def markdown(ts: list[Trial], title: str) -> str:
    """Markdown tables: verdicts, confident wrong answers, summary, per truth, confusion
    matrix (rows outside the vocabulary marked; for them "named right" counts trials with
    no confident cause)."""
    s = summarise(ts)
    wrong = vd.wrong_lines(ts)
    out = [f"### {title}", "", *vd.TABLE_HEAD, *vd.table_lines("chain", ts, lambda t: t.outside), "",
           *(["Confident wrong answers:", "", *wrong, ""] if wrong else []),
           "| trials | effect acc. | effect+joint acc. (effects) | none named as effect | effects called none "
           "| unexplained (vocab.) | median holdout shrink | 95 % CI coverage | CPU s/campaign median (max) "
           "| outside vocab. named as cause |",
           "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
           f"| {s['trials']} | {_pct(s['effect_accuracy'])} | {_pct(s['joint_accuracy_effects'])} "
           f"| {s['none_named_as_effect']}/{s['none_trials']} | {s['effects_called_none']} "
           f"| {s['unexplained']} | {_num(s['median_shrink'])} | {_pct(s['coverage'])} ({s['coverage_n']}) "
           f"| {s['cpu_s_median']:.2f} ({s['cpu_s_max']:.2f}) "
           f"| {s['outside_named_as_cause']}/{s['outside_trials']} |", "",
           "| true effect | trials | named right | right joints | median shrink |",
           "|---|---:|---:|---:|---:|"]
    kinds = [k for k in VOCABULARY + OUTSIDE if any(t.truth.kind == k for t in ts)]
    for k in kinds:
        g = [t for t in ts if t.truth.kind == k]
        if k in OUTSIDE:
            right, jr = sum(not t.confident_cause for t in g), "–"
        else:
            right, jr = sum(t.effect_ok for t in g), sum(t.joint_ok for t in g)
        sh = f"{np.median([t.shrink for t in g]):.3f}" if k != "none" else "–"
        out.append(f"| {k}{' (outside)' if k in OUTSIDE else ''} | {len(g)} | {right} | {jr} | {sh} |")
    cols = list(VOCABULARY) + ["unexplained"]
    out += ["", "Confusion matrix (rows: true effect, columns: answer):", "",
            "| true \\ answer | " + " | ".join(c.replace("_", " ") for c in cols) + " |",
            "|---|" + "---:|" * len(cols)]
    for k in kinds:
        g = [t for t in ts if t.truth.kind == k]
        cells = [sum(t.answer == c for t in g) for c in cols]
        out.append(f"| {k.replace('_', ' ')}{' (outside)' if k in OUTSIDE else ''} | "
                   + " | ".join(str(v) if v else "·" for v in cells) + " |")
    return "\n".join(out)
