"""Blind validation of the chain diagnosis: campaigns with a hidden effect drawn from the
independent forward model (:mod:`cell.truth.chain`, via :mod:`cell.truth.chain_campaign`),
written in the exchange format, read back, diagnosed by :func:`cell.chain.report.diagnose_chain`
with no noise given (it must estimate the noise from the revisited poses), and scored.

The arm is the UR5 of :mod:`cell.truth.chain_campaign` (6 joints, standard DH), measured by a
tracker at a random unknown pose, at 3 markers at unknown places on the hand; ``poses``
poses (default 60) of which a tenth (at least 3) revisit earlier ones; σ per axis uniform
in 0.02–0.05 mm. Each trial draws the truth from its own seed, uniformly among ``none`` and
the vocabulary:

* ``joint_offset``: one or two of j2…j5 (j1 and j6 are absorbed by the sensor frame and the
  free markers), 0.02–0.2° each, either sign;
* ``link_length``: one of the DH parameters this arm's layout separates from the
  registration and from each other (a of j2, j3; α of j2, j3, j4; d of j5), 0.2–2 mm or
  0.02–0.2°;
* ``gear_ratio``: j2 or j3, 3·10⁻⁴–2·10⁻³ relative;
* ``gravity_compliance``: j2, or j2 and j3, 0.1–0.5 °/m each.

**Outside the vocabulary** (with ``outside_share``: that share of trials, drawn from a
stream of its own): ``lens`` (radial scale of the sensor, 1–3·10⁻³ /m), ``reach_sag``
(1–3 mm/m²), ``bump`` (an offset of 0.1–0.2° on j2 or j3 from the middle pose on),
``couple`` (j3 turns by 0.5–3·10⁻³ × j2's reading). The right answer is ``unexplained``
or ``none``: a vocabulary cause named without ``unexplained`` is a confident wrong cause.

Scores (:func:`summarise`): effect and effect+joint accuracy, confusion matrix, ``none``
named as an effect, effects called ``none``, median holdout shrink, coverage of the true
parameters by the 95 % intervals (trials named right), CPU seconds per campaign, and for
the trials outside the vocabulary how many were named as a confident cause.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from cell.chain.report import diagnose_chain
from cell.measurements import read_campaign
from cell.truth.chain_campaign import MARKERS, make

VOCABULARY = ("none", "joint_offset", "link_length", "gear_ratio", "gravity_compliance")
OUTSIDE = ("lens", "reach_sag", "bump", "couple")
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


def _covered(truth: Truth, ci95: dict) -> tuple[int, int]:
    hit = n = 0
    for name, v in truth.params.items():
        if name in ci95 and None not in ci95[name]:
            lo, hi = ci95[name]
            n += 1
            hit += lo <= v <= hi
    return hit, n


def run_trial(i: int, seed: int, poses: int = 60, outside_share: float = 0.0,
              outside_kinds: Sequence[str] = OUTSIDE) -> Trial:
    """Draw, measure (through the format), diagnose and score trial ``i`` of run ``seed``."""
    tseed = seed * 100_003 + i
    rng = np.random.default_rng(tseed)
    odd = np.random.default_rng([tseed, 7])
    if outside_share > 0 and odd.random() < outside_share:
        truth = draw(odd, str(odd.choice(list(outside_kinds))))
    else:
        truth = draw(rng, str(rng.choice(VOCABULARY)))
    noise = float(rng.uniform(0.02, 0.05))
    with tempfile.TemporaryDirectory(prefix="cell-chain-validate-") as tmp:
        d = make(Path(tmp) / "campaign", truth.effects, poses=poses, noise_mm=noise, seed=tseed,
                 markers=MARKERS, lens=truth.lens, repeats=max(3, poses // 10))
        t0 = time.process_time()
        rep = diagnose_chain(read_campaign(d))
        secs = time.process_time() - t0
    c = rep["cause"]
    hit = n = 0
    if truth.kind not in OUTSIDE and c["effect"] == truth.kind and tuple(c["joints"]) == truth.joints:
        hit, n = _covered(truth, c["ci95"])
    return Trial(i, truth, c["effect"], tuple(c["joints"]), bool(rep["unexplained"]),
                 c.get("confidence") == "low", float(rep["holdout"]["shrink"] or 0.0), hit, n, secs)


def run(trials: int, seed: int, poses: int = 60, outside_share: float = 0.0,
        outside_kinds: Sequence[str] = OUTSIDE, progress=None) -> list[Trial]:
    """``trials`` scored trials. Raises ValueError for a share outside [0, 1], an unknown
    kind or fewer than 20 poses."""
    if not 0.0 <= outside_share <= 1.0:
        raise ValueError(f"outside_share {outside_share} must lie in [0, 1]")
    bad = [k for k in outside_kinds if k not in OUTSIDE]
    if bad or not outside_kinds:
        raise ValueError(f"unknown kinds {bad}; known: {list(OUTSIDE)}")
    if poses < 20:
        raise ValueError(f"poses {poses} must be ≥ 20")
    out = []
    for i in range(trials):
        out.append(run_trial(i, seed, poses, outside_share, tuple(outside_kinds)))
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
    """Markdown tables: summary, per truth, confusion matrix (rows outside the vocabulary
    marked; for them "named right" counts trials with no confident cause)."""
    s = summarise(ts)
    out = [f"### {title}", "",
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
