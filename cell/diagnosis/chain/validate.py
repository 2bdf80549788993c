"""Blind validation of the chain diagnosis: campaigns with a hidden effect drawn from the
independent forward model (:mod:`cell.truth.chain`), written in the exchange format by
:func:`cell.truth.chain_campaign.make` (the truth's own writer), read back with the
project's reader, diagnosed by :func:`cell.diagnosis.chain.report.diagnose_chain` with no noise given
(it must estimate the noise itself) and judged (:mod:`cell.truth.verdict`).

The arm is the UR5 of :mod:`cell.truth.chain_campaign` (6 joints, standard DH), measured by a
tracker at a random unknown pose, at 3 markers at unknown places on the hand; ``poses``
poses (default 60) of which a tenth (at least 3) revisit earlier ones; σ per axis uniform
in 0.02–0.05 mm. **Layouts**: ``realistic`` (default; its own stream per trial): the poses
cluster at 3–12 stations with ±3° jitter per joint, and 0–2 marker readings are gross
outliers (1–5 mm); ``uniform``: readings uniform over ±150°, no outliers. Either way half
of the campaigns (by a stream of their own) record the approach directions ``jK_dir``,
each pose approached from a random side per joint; every campaign whose truth holds a
backlash does. Likewise, by a stream of their own, half of the campaigns record the
arm's temperature (``temp_c``) while it warms up by 8–15 °C
(:func:`cell.truth.chain_campaign.warm_up`); every campaign whose truth holds a thermal
growth does.

**Truths**, from each trial's own seed, uniformly among ``none`` and the vocabulary:

* ``joint_offset``: one or two of j2…j5 (j1 and j6 are absorbed by the sensor frame and the
  free markers), 0.02–0.2° each, either sign;
* ``link_length``: one of the DH parameters this arm's layout separates from the
  registration and from each other (a of j2, j3; α of j2, j3, j4; d of j5), 0.2–2 mm or
  0.02–0.2°;
* ``gear_ratio``: j2 or j3, 3·10⁻⁴–2·10⁻³ relative;
* ``backlash``: j2 or j3, a lost-motion width of 0.02–0.1° (its campaign records every
  joint's approach direction, ``jK_dir``: without them the format places each joint at the
  centre of its band and there is no backlash to see);
* ``gravity_compliance``: j2, or j2 and j3, 0.1–0.5 °/m each;
* ``cyclic_error``: j2 or j3, a ripple of 0.02–0.08° with 1–4 cycles per revolution at a
  random phase (the truth's ``cyclic``; its true coefficients are
  ``jK_cyclicN_sin_deg`` = a·cos φ and ``jK_cyclicN_cos_deg`` = a·sin φ);
* ``motor_cyclic_error``: j2 or j3, a ripple of the motor-side gear of 0.01–0.05° at the
  joint (the v1 effect's range) with :data:`MOTOR_RATIO` cycles per revolution, at a random
  phase (the truth's ``motor``; true coefficients ``jK_motor_cyclic_sin_deg`` = a·cos φ,
  ``jK_motor_cyclic_cos_deg`` = a·sin φ). Every campaign's model.yaml states that ratio for
  every joint (``motor_gear_ratio``), as a user who knows the drives would;
* ``thermal_drift``: every length of the arm grows by 1.5–3·10⁻⁵ /K (an aluminium arm
  such as the UR5 has about 2.3·10⁻⁵). With the warm-up's 8–15 °C that moves the tool by
  0.07–0.3 mm at the arm's reach, above the tracker's noise as every other drawn effect is;
  a 1·10⁻⁵ /K arm warming by 5 °C moves it by 0.03 mm, within the noise, and the
  diagnosis rightly sees nothing there.

In the realistic layout a quarter of the effect trials carry a second effect of another
kind (drawn the same way; a joint offset then on j4 or j5 only, so the two act on
different joints).

**Outside the vocabulary** (with ``outside_share``: that share of trials, drawn from a
stream of its own): ``lens`` (radial scale of the sensor, 1–3·10⁻³ /m), ``reach_sag``
(1–3 mm/m²), ``bump`` (an offset of 0.1–0.2° on j2 or j3 from the middle pose on),
``couple`` (j3 turns by 0.5–3·10⁻³ × j2's reading), ``cyclic`` (a transmission ripple of
0.02–0.08° with 5–8 cycles per revolution on j2 or j3: the vocabulary's ``cyclic_error``
holds 1–4), ``plane_bump`` (a smooth local displacement of 0.1–0.4 mm, width
150–300 mm, centred near the arm's reach). A vocabulary cause named with high confidence
and without ``unexplained`` is a confident wrong cause.

The trial, the scores (verdict counts, confident wrong answers, accuracy, confusion
matrix, holdout shrink, coverage of the true parameters by the 95 % intervals, CPU seconds)
and the tables are the one harness of planar and chain campaigns, :mod:`cell.diagnosis.harness`; this
module draws the chain truths and campaigns.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from cell.diagnosis import harness
from cell import effects as fx
from cell.diagnosis.chain.report import diagnose_chain
from cell.diagnosis.harness import Trial, summarise  # noqa: F401 (this family's scores)
from cell.measurements import read_campaign
from cell.truth import verdict as vd
from cell.truth.chain_campaign import MARKERS, UR5, make

# the chain vocabulary (cell.diagnosis.chain.fit.EFFECTS) but the sensor's own maps and the
# drives' bus: the campaigns drawn here give no sensor_center_mm and no measured moves (a
# planar campaign read as a chain one does: cell/diagnosis/validate.py)
VOCABULARY = ("none",) + tuple(n for n, e in fx.CHAIN_EFFECTS.items()
                               if e.chain.joints not in ("sensor", "bus"))
OUTSIDE = ("lens", "reach_sag", "bump", "couple", "cyclic", "plane_bump")
LAYOUTS = ("realistic", "uniform")
TWO_SHARE = 0.25
MOTOR_RATIO = 100.0    # motor turns per joint turn the validation arm states: a strain-wave
                       # gear's usual order (a 3.6° period at the joint)
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
    if kind == "backlash":
        j = str(rng.choice(["j2", "j3"]))
        x = float(rng.uniform(0.02, 0.1))
        return Truth(kind, (j,), {"backlash": {j: x}}, 0.0, {f"{j}_backlash_deg": x})
    if kind == "motor_cyclic_error":
        j = str(rng.choice(["j2", "j3"]))
        a, ph = float(rng.uniform(0.01, 0.05)), float(rng.uniform(0, 360))
        return Truth(kind, (j,), {"motor": {j: (a, MOTOR_RATIO, ph)}}, 0.0,
                     {f"{j}_motor_cyclic_sin_deg": a * math.cos(math.radians(ph)),
                      f"{j}_motor_cyclic_cos_deg": a * math.sin(math.radians(ph))})
    if kind == "thermal_drift":
        x = float(rng.uniform(1.5e-5, 3e-5))
        return Truth(kind, (), {"grow": x}, 0.0, {"thermal_expansion_per_k": x})
    if kind == "gravity_compliance":
        js = ["j2"] if rng.random() < 0.5 else ["j2", "j3"]
        v = {j: float(rng.uniform(0.1, 0.5)) for j in js}
        return Truth(kind, tuple(js), {"sag": v}, 0.0, {f"{j}_compliance_deg_per_m": x for j, x in v.items()})
    if kind == "cyclic_error":
        j = str(rng.choice(["j2", "j3"]))
        return ripple(j, float(rng.uniform(0.02, 0.08)), int(rng.integers(1, 5)),
                      float(rng.uniform(0, 360)))
    if kind == "lens":
        x = float(rng.uniform(1e-3, 3e-3))
        return Truth(kind, (), {}, x, {"lens_per_m": x})
    if kind == "cyclic":
        j = str(rng.choice(["j2", "j3"]))
        a, n, ph = float(rng.uniform(0.02, 0.08)), int(rng.integers(5, 9)), float(rng.uniform(0, 360))
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


def ripple(joint: str, amp_deg: float, cycles: int, phase_deg: float) -> Truth:
    """A ``cyclic_error`` truth: a·sin(n·q + φ) on ``joint`` (the truth's ``cyclic``), its
    true parameters the report's coefficients s = a·cos φ, c = a·sin φ of order n."""
    ph = math.radians(phase_deg)
    return Truth("cyclic_error", (joint,), {"cyclic": {joint: (amp_deg, cycles, phase_deg)}}, 0.0,
                 {f"{joint}_cyclic{cycles}_sin_deg": amp_deg * math.cos(ph),
                  f"{joint}_cyclic{cycles}_cos_deg": amp_deg * math.sin(ph)})


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
        effects[k] = {**effects.get(k, {}), **v} if isinstance(v, dict) else v
    comps = ((first.kind, first.joints), (second.kind, second.joints))
    return Truth(first.kind, first.joints, effects, 0.0, {**first.params, **second.params}, comps)


def draw_layout(tseed: int, layout: str) -> dict:
    """Keyword arguments of :func:`cell.truth.chain_campaign.make` for trial seed ``tseed``'s
    layout (module docstring), from streams of its own."""
    dirs = bool(np.random.default_rng([tseed, 4]).random() < 0.5)
    temps = bool(np.random.default_rng([tseed, 8]).random() < 0.5)
    if layout == "uniform":
        return {"dirs": dirs, "temps": temps}
    rng = np.random.default_rng([tseed, 3])
    return {"places": int(rng.integers(3, 13)), "jitter_deg": 3.0,
            "outliers": int(rng.integers(0, 3)), "dirs": dirs, "temps": temps}


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
    return judge_truth(i, tseed, truth, noise, draw_layout(tseed, layout), poses)


def judge_truth(i: int, tseed: int, truth: Truth, noise: float, lay: dict, poses: int = 60) -> Trial:
    """Measure ``truth`` on a campaign of trial seed ``tseed`` (σ ``noise`` mm per axis,
    layout ``lay``: :func:`draw_layout`'s keywords), diagnose it through the format and judge
    it as trial ``i``. The campaign records the approach directions when the truth holds a
    backlash, and the temperatures when it holds a thermal growth."""
    lay = {**lay, "dirs": lay.get("dirs", False) or "backlash" in truth.effects,
           "temps": lay.get("temps", False) or "grow" in truth.effects}
    with tempfile.TemporaryDirectory(prefix="cell-chain-validate-") as tmp:
        d = make(Path(tmp) / "campaign", truth.effects, poses=poses, noise_mm=noise, seed=tseed,
                 markers=MARKERS, lens=truth.lens, repeats=max(3, poses // 10),
                 model_extra={"motor_gear_ratio": {r["name"]: MOTOR_RATIO for r in UR5}}, **lay)
        t0 = time.process_time()
        rep = diagnose_chain(read_campaign(d))
        secs = time.process_time() - t0
    return harness.judge(i, tseed, rep, truth.expected, true_effect=truth.kind,
                         true_joints=truth.joints, truth_label=truth.label, seconds=secs,
                         covered=lambda ci95: _covered(truth, ci95), layout=lay,
                         second=truth.components[1][0] if truth.components else None,
                         truth_params=truth.params)


def run(trials: int, seed: int, poses: int = 60, outside_share: float = 0.0,
        outside_kinds: Sequence[str] = OUTSIDE, progress=None, layout: str = "realistic",
        start: int = 0) -> list[Trial]:
    """Trials ``start`` … ``start + trials − 1``, judged. Raises ValueError for a share
    outside [0, 1], an unknown kind or layout, or fewer than 20 poses."""
    if poses < 20:
        raise ValueError(f"poses {poses} must be ≥ 20")
    harness.check_outside(outside_share, outside_kinds, OUTSIDE, layout, LAYOUTS)
    return harness.run(lambda i: run_trial(i, seed, poses, outside_share, tuple(outside_kinds),
                                           layout), trials, start, progress)


def markdown(ts: list[Trial], title: str) -> str:
    """The harness's four tables (:func:`cell.diagnosis.harness.markdown`) for chain trials."""
    return harness.markdown(ts, title, "chain", VOCABULARY, OUTSIDE)
