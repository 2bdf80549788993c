"""Seed 004's joint terms in the robot calibration file: what a joint's sweep measured,
which terms the cell's model applies, and why the others are not.

The file's ``joints`` section (absent in files written before it: nothing applied) holds
one entry per joint swept (j1, j2, j4)::

    "j2": {"backlash_deg":   {"value": 0.0198, "low": 0.0194, "high": 0.0202},
           "gear_ratio_rel": {"value": 1.8e-05, "low": -7.9e-04, "high": 8.2e-04},
           "harmonics": [{"period_deg": 7.2, "amplitude_deg": 0.006, "phase_deg": -60.0}],
           "sweep_deg": [-2.2, 2.2],
           "applied": [],
           "why": "gear_ratio: its 95 % interval holds 0"}

Signs and units are the effect vocabulary's (``cell/measurements.md``): ``gear_ratio``
θ_true = θ_cmd·(1 + ε), ``cyclic_error`` θ_true = θ_cmd + a·sin(2π·θ_cmd/P + φ). Seed 004's
model e = c − dir·b/2 + ε·θ + Σ a·sin(2πθ/P + φ) (:mod:`cell.calibration.joint`) uses the
same ε, a, P and φ.

What the cell does with them:

* **backlash** is measured directly, so it is always used: every arrival's via point lies
  beyond the measured band (:func:`cell.compensation.lattice.margin_units`).
* **gear ratio and cyclic error** are measured over the sweep only (about ±1–2°, where the
  hand camera keeps its target in view), while the cell turns its joints over tens of
  degrees; a short-period ripple over the sweep also looks like a slope. So a term is a
  candidate only when its estimate is significant (its 95 % interval leaves out 0, or a
  harmonic was accepted), and it is applied only when the kinematic fit with it predicts
  the held-out poses better, rms and max each, than without it (:func:`weigh`). The terms
  are applied to the commanded joint angles in the fit too, so the joint zeros do not
  absorb them a second time.
* **the gear ratio seed 001 sees.** The kinematic calibration's poses span most of each
  joint's range, so its fit can carry a gear-ratio error that seed 004's sweep cannot: ε of
  j1 and j2 fitted beside the DH errors (:func:`fit_gear_ratios`). The file's top-level
  ``gear_ratio`` section holds the estimates; one whose interval leaves out 0 is applied
  under the same held-out rule, on top of the seed 004 terms chosen::

    "gear_ratio": {"j1": {"value": 3.1e-04, "low": 2.8e-04, "high": 3.4e-04},
                   "j2": {"value": -4.9e-04, "low": -5.3e-04, "high": -4.5e-04},
                   "applied": ["j1", "j2"], "why": ""}
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Mapping, Sequence

import numpy as np

from cell.effects.backlash import WIDTH
from cell.effects.base import PLANAR_JOINTS
from cell.effects.cyclic_error import EFFECT as CYCLIC
from cell.effects.gear_ratio import RATIO
from cell.effects.instances import EffectInstance, make_effect

if TYPE_CHECKING:
    from cell.calibration.joint import JointResult
    from cell.calibration.kinematic import HoldoutCheck, Identification
    from cell.kinematics import Scara

SWEPT = ("j1", "j2", "j4")                     #: joints seed 004 calibrates (j3 is prismatic)
TERMS = ("gear_ratio", "cyclic_error")         #: terms a model may apply (backlash always is)
AMPLITUDE_BOUNDS = CYCLIC.spec_of("j1_cyclic_amp_deg").bounds
PERIOD_BOUNDS = CYCLIC.spec_of("j1_cyclic_period_deg").bounds


def entry(result: "JointResult") -> dict:
    """The ``joints`` entry for one seed 004 result, nothing applied yet. Lost motion is
    never negative: a backlash estimate below 0 (noise about none) is stored as 0, its
    interval cut at 0."""
    def est(e, floor=-math.inf):
        return {k: max(floor, float(getattr(e, k))) for k in ("value", "low", "high")}
    nominal = np.asarray(result.nominal_deg, dtype=float)
    return {"backlash_deg": est(result.backlash_deg, 0.0), "gear_ratio_rel": est(result.gear_ratio_error),
            "harmonics": [{"period_deg": float(h.period_deg), "amplitude_deg": float(h.amplitude.value),
                           "phase_deg": float(h.phase.value)} for h in result.harmonics],
            "sweep_deg": [float(nominal.min()), float(nominal.max())], "applied": [], "why": ""}


def check(section) -> None:
    """Refuse a ``joints`` section that does not fit the robot or the vocabulary.

    :raises ValueError: naming the key, e.g. ``joints.j5: not a joint seed 004 calibrates
        (j1, j2, j4)`` or ``joints.j2.gear_ratio_rel.value = 0.09: outside [-0.05, 0.05]``.
    """
    if not isinstance(section, dict):
        raise ValueError(f"joints: must be a mapping of joint → terms, got {type(section).__name__}")
    for joint, e in section.items():
        where = f"joints.{joint}"
        if joint not in SWEPT:
            raise ValueError(f"{where}: not a joint seed 004 calibrates ({', '.join(SWEPT)})")
        if not isinstance(e, dict):
            raise ValueError(f"{where}: must be a mapping, got {type(e).__name__}")
        _estimate(e, "backlash_deg", where, WIDTH.bounds)
        _estimate(e, "gear_ratio_rel", where, RATIO.bounds)
        harmonics = e.get("harmonics", [])
        if not isinstance(harmonics, list):
            raise ValueError(f"{where}.harmonics: must be a list")
        for i, h in enumerate(harmonics):
            if not isinstance(h, dict):
                raise ValueError(f"{where}.harmonics[{i}]: must be a mapping")
            _number(h, "amplitude_deg", f"{where}.harmonics[{i}]", AMPLITUDE_BOUNDS)
            _number(h, "period_deg", f"{where}.harmonics[{i}]", PERIOD_BOUNDS, open_low=True)
            _number(h, "phase_deg", f"{where}.harmonics[{i}]", (-math.inf, math.inf))
        sweep = e.get("sweep_deg")
        if (not isinstance(sweep, list) or len(sweep) != 2
                or not all(_finite(v) for v in sweep) or sweep[0] > sweep[1]):
            raise ValueError(f"{where}.sweep_deg = {sweep!r}: must be [low, high], finite, low ≤ high")
        applied = e.get("applied", [])
        if not isinstance(applied, list) or any(t not in TERMS for t in applied):
            raise ValueError(f"{where}.applied = {applied!r}: terms must be among {', '.join(TERMS)}")
        if applied and joint not in PLANAR_JOINTS:
            raise ValueError(f"{where}.applied = {applied!r}: {joint} does not move the tool's x, y, "
                             "so no term of it can be applied")
        if "cyclic_error" in applied and not harmonics:
            raise ValueError(f"{where}.applied: cyclic_error applied but no harmonic measured")


def check_gear_ratio(section) -> None:
    """Refuse a top-level ``gear_ratio`` section that does not fit the robot.

    :raises ValueError: naming the key (``gear_ratio.j3: ...``)."""
    if not isinstance(section, dict):
        raise ValueError(f"gear_ratio: must be a mapping, got {type(section).__name__}")
    for joint, e in section.items():
        if joint in ("applied", "why"):
            continue
        if joint not in PLANAR_JOINTS:
            raise ValueError(f"gear_ratio.{joint}: not a joint the kinematic fit gives a gear ratio "
                             f"({', '.join(PLANAR_JOINTS)})")
        _estimate(section, joint, "gear_ratio", RATIO.bounds)
    applied = section.get("applied", [])
    if not isinstance(applied, list) or any(j not in section or j in ("applied", "why") for j in applied):
        raise ValueError(f"gear_ratio.applied = {applied!r}: must list joints the section estimates")


def gear_effects(section: Mapping | None) -> list[EffectInstance]:
    """The gear-ratio effects of the kinematic fit's applied estimates."""
    s = section or {}
    return [_gear(j, s[j]["value"]) for j in s.get("applied", [])]


def _gear(joint: str, ratio: float) -> EffectInstance:
    """The vocabulary's gear-ratio effect of ``joint`` with ε = ``ratio``."""
    return make_effect("gear_ratio", [joint], {f"{joint}_gear_ratio_rel": float(ratio)})


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _number(d: dict, key: str, where: str, bounds, open_low: bool = False) -> float:
    v = d.get(key)
    if not _finite(v):
        raise ValueError(f"{where}.{key} = {v!r}: must be a finite number")
    lo, hi = bounds
    if v > hi or v < lo or (open_low and v == lo):
        raise ValueError(f"{where}.{key} = {v!r}: outside [{lo:g}, {hi:g}]")
    return float(v)


def _estimate(e: dict, key: str, where: str, bounds) -> None:
    est = e.get(key)
    if not isinstance(est, dict):
        raise ValueError(f"{where}.{key}: must be {{value, low, high}}")
    v, lo, hi = (_number(est, k, f"{where}.{key}", bounds if k == "value" else (-math.inf, math.inf))
                 for k in ("value", "low", "high"))
    if not lo <= v <= hi:
        raise ValueError(f"{where}.{key}: value {v:g} outside its interval [{lo:g}, {hi:g}]")


def effects(section: Mapping | None, applied: Mapping[str, Sequence[str]] | None = None
            ) -> list[EffectInstance]:
    """The joint-stage effects of the applied terms (``applied``: joint → terms, default the
    section's own ``applied``), in the vocabulary's terms, for j1 and j2."""
    out = []
    for joint, e in (section or {}).items():
        terms = e.get("applied", ()) if applied is None else applied.get(joint, ())
        if joint not in PLANAR_JOINTS:
            continue
        if "gear_ratio" in terms:
            out.append(_gear(joint, e["gear_ratio_rel"]["value"]))
        if "cyclic_error" in terms:
            out += [make_effect("cyclic_error", [joint], {
                f"{joint}_cyclic_amp_deg": h["amplitude_deg"], f"{joint}_cyclic_phase_deg": h["phase_deg"],
                f"{joint}_cyclic_period_deg": h["period_deg"]}) for h in e["harmonics"]]
    return out


def joint_delta(effects: Sequence[EffectInstance], q_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Δθ, ∂Δθ/∂θ_cmd), each (N, 2), of ``effects`` at commanded angles ``q_deg`` (N, 2) of
    j1, j2: θ_true = θ_cmd + Δθ, per the vocabulary's own functions and derivatives."""
    q = np.asarray(q_deg, dtype=float)
    delta, slope = np.zeros_like(q), np.zeros_like(q)
    dirs = np.ones_like(q)
    for e in effects:
        x = e.full_vector()
        delta += e.spec.fn(x, e.jidx, q, dirs)
        slope += e.spec.deriv(x, e.jidx, q, dirs)[1]
    return delta, slope


def corrected(effects: Sequence[EffectInstance], q) -> np.ndarray:
    """Joint configurations (N, ≥2) with the terms added to θ1, θ2 (what the joints turn to
    when commanded ``q``); a copy, ``q`` itself when there are no terms."""
    if not effects:
        return q
    q = np.array(q, dtype=float)
    q[:, :2] += joint_delta(effects, q[:, :2])[0]
    return q


def backlash_deg(section: Mapping | None) -> tuple[float, float]:
    """The measured backlash of j1 and j2 (upper end of the 95 % interval; 0: not measured)."""
    s = section or {}
    return tuple(max(0.0, float(s[j]["backlash_deg"]["high"])) if j in s else 0.0
                 for j in PLANAR_JOINTS)


@dataclass(frozen=True)
class FitData:
    """The kinematic calibration's own measurements, as its file stores them: commanded
    joints and measured x, y (mm) of the fit poses (``in_base``: the anchors) and of the
    held-out poses; ``lever_fit`` / ``lever_hold`` (N, 3) how the hand camera's board poses
    were reduced (:func:`cell.calibration.procedure.board_lever`; None: the measurements
    are taken as tool positions whatever the model's tool orientation)."""
    q_fit: np.ndarray
    m_fit: np.ndarray
    in_base: np.ndarray
    q_hold: np.ndarray
    m_hold: np.ndarray
    lever_fit: np.ndarray | None = None
    lever_hold: np.ndarray | None = None

    @classmethod
    def of(cls, doc: dict, nominal: "Scara | None" = None) -> "FitData | None":
        """From a calibration document's ``data`` (None when it holds no kinematic fit).
        With the ``nominal`` robot and the document's board, the levers too (each pose's
        ``point``). Raises CalibrationError for a board point the board does not have."""
        data = doc.get("data") or {}
        fit, hold = data.get("fit"), data.get("holdout")
        if not fit or not hold:
            return None
        qf, mf = (np.array([f[k] for f in fit], dtype=float) for k in ("q", "measured_mm"))
        qh, mh = (np.array([h[k] for h in hold], dtype=float) for k in ("q", "measured_mm"))
        pf, ph = [f.get("point", 0) for f in fit], [h.get("point", 0) for h in hold]
        lf = lh = None
        if nominal is not None and data.get("board"):
            from cell.calibration.procedure import board_lever
            from cell.vision.calibration import board_from_dict
            board = board_from_dict(dict(data["board"]))
            lf, lh = board_lever(nominal, board, qf, mf, pf), board_lever(nominal, board, qh, mh, ph)
        return cls(qf, mf, np.array([k < 0 for k in pf], dtype=bool), qh, mh, lf, lh)


@dataclass(frozen=True)
class Weighing:
    """What :func:`weigh` chose: the terms applied per joint, the fit and held-out check
    with them, and one line per candidate the model leaves out."""
    applied: dict[str, list[str]]
    identification: "Identification"
    holdout: "HoldoutCheck"
    why: dict[str, str]
    #: the file's ``gear_ratio`` section: seed 001's estimates, which it applies and why
    gear_ratio: dict | None = None


def candidates(section: Mapping | None) -> list[tuple[str, str]]:
    """(joint, term) pairs of j1 and j2 worth trying: a gear ratio whose interval leaves
    out 0, the harmonics the sweep accepted."""
    out = []
    for joint, e in (section or {}).items():
        if joint not in PLANAR_JOINTS:
            continue
        g = e["gear_ratio_rel"]
        if g["low"] > 0 or g["high"] < 0:
            out.append((joint, "gear_ratio"))
        if e["harmonics"]:
            out.append((joint, "cyclic_error"))
    return out


def weigh(nominal: "Scara", data: FitData, section: Mapping | None, *, min_gain: float) -> Weighing:
    """Fit the kinematic calibration with each subset of the candidate terms applied to
    the commanded angles, and keep the subset whose held-out rms is lowest among those
    that pass the held-out check and beat none in rms without a worse max (none when no
    subset does). Deterministic: same data, same choice. A subset whose fit fails
    (singular) is not chosen. Then seed 001's own gear ratios, on top of the subset chosen
    (:func:`fit_gear_ratios`, under the same rule; :attr:`Weighing.gear_ratio`).

    :raises CalibrationError: the fit without any term fails."""
    from cell.calibration.dh import scara_chain
    from cell.errors import CalibrationError
    chain = scara_chain(nominal.g)
    cands = candidates(section)

    def fit(subset):
        applied: dict[str, list[str]] = {}
        for joint, term in subset:
            applied.setdefault(joint, []).append(term)
        return (applied, *_fit_with(chain, data, effects(section, applied), min_gain))

    trials = {subset: fit(subset) for n in range(len(cands) + 1)
              for subset in itertools.combinations(cands, n)}
    base = trials[()]
    if base[1] is None:
        raise CalibrationError(f"the kinematic fit failed: {base[2]}", "fit")
    b = base[2]
    best = base
    for subset, trial in trials.items():
        h = trial[2]
        if trial[1] is not None and _better(h, b) and h.rms_xy_after_mm < best[2].rms_xy_after_mm:
            best = trial
    best, gear = _with_gear_ratios(nominal, data, section, best, min_gain=min_gain)
    why = {}
    for joint, term in cands:
        if term in best[0].get(joint, ()):
            continue
        _, ident, h = trials[((joint, term),)]
        reach = max(abs(v) for v in section[joint]["sweep_deg"])
        why[f"{joint}.{term}"] = (f"the fit with it failed: {h}" if ident is None else
                                  f"held-out poses with it alone: rms {b.rms_xy_after_mm:.4f} → "
                                  f"{h.rms_xy_after_mm:.4f} mm, max {b.max_xy_after_mm:.4f} → "
                                  f"{h.max_xy_after_mm:.4f} mm (measured over ±{reach:.1f}° only)")
    return Weighing(best[0], best[1], best[2], why, gear)


def fit_gear_ratios(nominal: "Scara", data: FitData, fixed: Sequence[EffectInstance] = (),
                    joints: Sequence[str] = PLANAR_JOINTS, iterations: int = 8) -> dict[str, dict]:
    """Seed 001's own estimate of the gear-ratio error ε of ``joints``, with 95 % intervals:
    ε and the DH errors fitted together on the kinematic poses, with the ``fixed`` terms
    applied to the commanded angles. Each step refits the DH errors at the current ε, then
    takes one Gauss–Newton step in ε with the DH columns beside it (∂/∂ε_j is the column
    of j's zero times the commanded angle). Intervals from that last design, Student's t.

    :raises CalibrationError: the fit without ε fails (singular design)."""
    from cell.calibration.dh import scara_chain
    from cell.calibration.kinematic import _as_measured, _weighted, identify, jacobian, residuals
    from cell.numerics.stats import t_ppf
    chain = scara_chain(nominal.g)
    cols = [PLANAR_JOINTS.index(j) for j in joints]
    eps = np.zeros(len(joints))
    for _ in range(iterations):
        fx = [*fixed, *(_gear(j, e) for j, e in zip(joints, eps))]
        qf = corrected(fx, data.q_fit)
        ident = identify(chain, qf, data.m_fit, position_only=True, in_base=data.in_base,
                         lever=data.lever_fit)
        J = jacobian(chain, qf, ident.p, w=0.0, in_base=data.in_base, lever=data.lever_fit)
        extra = [J[:, chain.index(f"{j}.theta")] * np.repeat(data.q_fit[:, c], 3)
                 for j, c in zip(joints, cols)]
        A = np.column_stack([J[:, [chain.index(n) for n in ident.kept]], *extra])
        r = _weighted(residuals(chain, qf, _as_measured(chain, qf, data.m_fit, True), ident.p,
                                data.in_base, data.lever_fit), 0.0)
        step = np.linalg.lstsq(A, r, rcond=None)[0][-len(joints):]
        eps = eps + step
        if np.max(np.abs(step)) < 1e-9:
            break
    dof = 2 * len(data.q_fit) - A.shape[1]
    s2 = float(np.sum(r ** 2)) / dof
    se = np.sqrt(np.diag(np.linalg.pinv(A.T @ A))[-len(joints):] * s2)
    half = t_ppf(0.975, dof) * se
    return {j: {"value": float(e), "low": float(e - h), "high": float(e + h)}
            for j, e, h in zip(joints, eps, half)}


def _with_gear_ratios(nominal, data, section, best, *, min_gain):
    """Stage two of :func:`weigh`: seed 001's gear ratios on top of the seed 004 terms
    chosen (``best``); applied when significant and when they predict the held-out poses
    better, as a seed 004 term must. Returns (best, the ``gear_ratio`` section)."""
    from cell.calibration.dh import scara_chain
    from cell.errors import CalibrationError
    fixed = effects(section, best[0])
    try:
        est = fit_gear_ratios(nominal, data, fixed)
    except CalibrationError as exc:
        return best, {"applied": [], "why": f"the fit with gear ratios failed: {exc}"}
    sig = [j for j, e in est.items() if e["low"] > 0 or e["high"] < 0]
    gear = {**est, "applied": [], "why": ""}
    if not sig:
        gear["why"] = "no joint's gear ratio is told from 0 by its 95 % interval"
        return best, gear
    ident, h = _fit_with(scara_chain(nominal.g), data, [*fixed, *(_gear(j, est[j]["value"]) for j in sig)],
                         min_gain)
    if ident is None:
        gear["why"] = f"the fit with them failed: {h}"
        return best, gear
    b = best[2]
    if _better(h, b):
        gear["applied"] = sig
        return (best[0], ident, h), gear
    gear["why"] = (f"held-out poses with {', '.join(sig)}'s: rms {b.rms_xy_after_mm:.4f} → "
                   f"{h.rms_xy_after_mm:.4f} mm, max {b.max_xy_after_mm:.4f} → {h.max_xy_after_mm:.4f} mm")
    return best, gear


def _fit_with(chain, data: FitData, fx: Sequence[EffectInstance], min_gain: float):
    """(identification, held-out check) of the kinematic fit with the terms ``fx`` applied
    to the commanded angles, "before" on the commands; (None, the reason) when the fit
    fails."""
    from cell.calibration.kinematic import holdout_check, identify
    from cell.errors import CalibrationError
    qf, qh = corrected(fx, data.q_fit), corrected(fx, data.q_hold)
    try:
        ident = identify(chain, qf, data.m_fit, position_only=True, in_base=data.in_base,
                         lever=data.lever_fit)
    except CalibrationError as exc:
        return None, str(exc)
    return ident, holdout_check(chain, ident.p, qh, data.m_hold, q_fit=qf, measured_fit=data.m_fit,
                                min_gain=min_gain, position_only=True, in_base_fit=data.in_base,
                                commanded=(data.q_fit, data.q_hold), lever_fit=data.lever_fit,
                                lever_hold=data.lever_hold)


def _better(h: "HoldoutCheck", than: "HoldoutCheck") -> bool:
    """The rule for applying a term: the check passes, the held-out rms falls, the max does
    not grow."""
    return h.passed and h.rms_xy_after_mm < than.rms_xy_after_mm and h.max_xy_after_mm <= than.max_xy_after_mm


def annotate(section: Mapping | None, weighing: Weighing | None, reason: str = "") -> dict:
    """The section with each joint's ``applied`` and ``why`` set: from ``weighing``, or none
    applied for ``reason`` (e.g. no kinematic calibration to weigh the terms against)."""
    out = {}
    for joint, e in (section or {}).items():
        e = dict(e)
        if weighing is None:
            e["applied"], e["why"] = [], reason if joint in PLANAR_JOINTS else \
                f"{joint} does not move the tool's x, y"
        else:
            e["applied"] = list(weighing.applied.get(joint, []))
            notes = [f"{t}: {w}" for k, w in weighing.why.items() for j, t in [k.split(".", 1)] if j == joint]
            g = e["gear_ratio_rel"]
            if joint in PLANAR_JOINTS and not g["low"] > 0 and not g["high"] < 0:
                notes.append("gear_ratio: its 95 % interval holds 0")
            if joint in PLANAR_JOINTS and not e["harmonics"]:
                notes.append("cyclic_error: no harmonic accepted by the sweep")
            if joint not in PLANAR_JOINTS:
                notes.append(f"{joint} does not move the tool's x, y")
            e["why"] = "; ".join(notes)
        out[joint] = e
    return out
