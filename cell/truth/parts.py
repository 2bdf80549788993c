"""The effects a validation truth is made of, in the forward model's own parameters, how
they are drawn, and what the diagnosis should answer for each. Pure numerics.

A :class:`Part` is one effect on one joint (or on none) with its own parameters;
:func:`compose` turns parts into a :class:`~cell.truth.model.Truth`. Two families:

* **vocabulary** (:data:`VOCABULARY`): the ten effects of ``cell/measurements.md``.
  :func:`answer` gives the expected answer in the vocabulary's names and units
  (effect, joints, parameters), e.g. a gear with N_true/N_nominal = 1 + g is
  ``gear_ratio_rel`` = 1/(1 + g) − 1; a ripple (c, s, n) is amplitude √(c² + s²),
  phase atan2(c, s) and period 360°/n; a motor-side ripple is a ripple of
  :data:`MOTOR_GEAR_RATIO` cycles per joint revolution (the format's default N), answered
  as amplitude, phase and N.
* **outside the vocabulary** (:data:`OUTSIDE`): effects no candidate describes;
  :func:`answer` is None: the right diagnosis is ``unexplained`` (or no cause).

  ============================ ===========================================================
  ``radial_distortion``        the camera's lens: m = c + d·(1 + K·|d|²), |K·d³| 0.1–0.5 mm
                               at 800 mm from the camera centre, either sign
  ``reach_sag``                the tool droops in −y by g·(r / 1 m)², g 0.2–0.6 mm
  ``offset_bump``              halfway through the static poses (in time) a knock moves a
                               joint's zero by 0.02–0.2° (either sign); the moves come after
  ``joint_coupling``           joint 2's true angle gains κ·θ1 (joint 1's command),
                               |κ| 2·10⁻⁴–2·10⁻³
  ``plane_bump``               a smooth local bump of the work plane: the tool centre moves
                               by A·exp(−|p − p₀|²/(2w²)) in a fixed direction, A 0.1–0.4 mm,
                               w 150–300 mm, p₀ at 300–900 mm from the base within ±150°
  ============================ ===========================================================

Draw ranges of the vocabulary effects are the ``typical`` ranges of :mod:`cell.effects`,
restated here in the model's own units (so the truth does not depend on that module):
uniform magnitude, random sign where the effect has one. A cyclic error gets
:data:`CYCLIC_ORDERS` cycles per revolution, uniformly, and a uniform phase; a motor cyclic
error :data:`MOTOR_GEAR_RATIO` cycles and a uniform phase.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from cell.truth.model import Bump, PlaneBump, Ripple, Truth

VOCABULARY = ("joint_offset", "link_length", "gear_ratio", "backlash", "cyclic_error",
              "thermal_drift", "camera_scale", "camera_rotation", "comm_delay",
              "motor_cyclic_error")
OUTSIDE = ("radial_distortion", "reach_sag", "offset_bump", "joint_coupling", "plane_bump")
CYCLIC_ORDERS = (1, 2, 3, 4)
MOTOR_GEAR_RATIO = 50     # motor turns per joint turn: the format's default N


@dataclass(frozen=True)
class Size:
    """One drawn parameter: magnitude uniform in [low, high], a random sign if ``signed``."""

    name: str
    unit: str
    low: float
    high: float
    signed: bool = True


@dataclass(frozen=True)
class Kind:
    """An effect kind: the joints it may act on (() = none) and its sized parameters."""

    name: str
    joints: tuple[int, ...]
    sizes: tuple[Size, ...]


_R = math.radians
KINDS: dict[str, Kind] = {k.name: k for k in (
    Kind("joint_offset", (1, 2), (Size("zero_deg", "deg", 0.02, 0.2),)),
    Kind("link_length", (1, 2), (Size("error_mm", "mm", 0.1, 1.0),)),
    Kind("gear_ratio", (1, 2), (Size("teeth_excess", "1", 2e-4, 2e-3),)),   # N_true/N_nom − 1
    Kind("backlash", (1, 2), (Size("play_deg", "deg", 0.01, 0.1, False),)),
    Kind("cyclic_error", (1, 2), (Size("amp_deg", "deg", 0.01, 0.08, False),)),
    Kind("thermal_drift", (), (Size("expansion_per_k", "1/K", 10e-6, 30e-6, False),)),
    Kind("camera_scale", (), (Size("gain_excess", "1", 2e-4, 2e-3),)),
    Kind("camera_rotation", (), (Size("turn_rad", "rad", _R(0.01), _R(0.1)),)),
    Kind("comm_delay", (), (Size("frame_delay_s", "s", 0.5e-3, 4e-3, False),)),
    Kind("motor_cyclic_error", (1, 2), (Size("amp_deg", "deg", 0.01, 0.05, False),)),
    Kind("radial_distortion", (), (Size("lens_k_per_mm2", "1/mm²", 0.1 / 800 ** 3,
                                        0.5 / 800 ** 3),)),
    Kind("reach_sag", (), (Size("sag_mm_at_1m", "mm", 0.2, 0.6, False),)),
    Kind("offset_bump", (1, 2), (Size("step_deg", "deg", 0.02, 0.2),)),
    Kind("joint_coupling", (), (Size("coupling_21", "1", 2e-4, 2e-3),)),
    Kind("plane_bump", (), (Size("amp_mm", "mm", 0.1, 0.4, False),
                            Size("width_mm", "mm", 150.0, 300.0, False),
                            Size("at_r_mm", "mm", 300.0, 900.0, False),
                            Size("at_deg", "deg", 0.0, 150.0),
                            Size("dir_deg", "deg", 0.0, 180.0))),
)}


@dataclass(frozen=True)
class Part:
    """One effect of a truth: ``kind`` (a key of :data:`KINDS`), ``joint`` (1, 2 or None)
    and its parameters ``values`` in the model's own units. A cyclic error (either) holds
    ``cycles``, ``cos_deg`` and ``sin_deg``; a thermal drift also ``ref_temp_c``."""

    kind: str
    joint: int | None
    values: Mapping[str, float] = field(default_factory=dict)

    @property
    def outside(self) -> bool:
        return self.kind in OUTSIDE


def draw(rng: np.random.Generator, kind: str, joint: int | None = None) -> Part:
    """A random part of ``kind`` (module docstring); ``joint`` is drawn if not given."""
    k = KINDS[kind]
    if k.joints:
        joint = int(rng.choice(k.joints)) if joint is None else joint
    else:
        joint = None
    vals: dict[str, float] = {}
    for s in k.sizes:
        v = float(rng.uniform(s.low, s.high))
        vals[s.name] = v * float(rng.choice((-1.0, 1.0))) if s.signed else v
    if kind in ("cyclic_error", "motor_cyclic_error"):
        amp, phase = vals.pop("amp_deg"), float(rng.uniform(0.0, 2 * math.pi))
        cycles = int(rng.choice(CYCLIC_ORDERS)) if kind == "cyclic_error" else MOTOR_GEAR_RATIO
        vals = {"cycles": cycles, "cos_deg": amp * math.sin(phase),
                "sin_deg": amp * math.cos(phase)}
    if kind == "thermal_drift":
        vals["ref_temp_c"] = 20.0
    return Part(kind, joint, vals)


def scaled(p: Part, k: float) -> Part:
    """``p`` with its size multiplied by ``k`` (order, phase, reference and a bump's place,
    width and direction kept)."""
    fixed = ("cycles", "ref_temp_c", "width_mm", "at_r_mm", "at_deg", "dir_deg")
    return Part(p.kind, p.joint, {n: (v if n in fixed else v * k) for n, v in p.values.items()})


def compose(parts: Sequence[Part], bump_at_s: float = 0.0) -> Truth:
    """The :class:`Truth` carrying every part (at most one part per kind and joint; a
    cyclic error adds its ripple). ``bump_at_s`` is when an ``offset_bump`` happens."""
    f: dict = {"zero_deg": [0.0, 0.0], "link_error_mm": [0.0, 0.0], "teeth_ratio": [1.0, 1.0],
               "play_deg": [0.0, 0.0], "ripples": [[], []]}
    other: dict = {}
    for p in parts:
        v, j = p.values, (p.joint or 1) - 1
        if p.kind == "joint_offset":
            f["zero_deg"][j] += v["zero_deg"]
        elif p.kind == "link_length":
            f["link_error_mm"][j] += v["error_mm"]
        elif p.kind == "gear_ratio":
            f["teeth_ratio"][j] *= 1.0 + v["teeth_excess"]
        elif p.kind == "backlash":
            f["play_deg"][j] += v["play_deg"]
        elif p.kind in ("cyclic_error", "motor_cyclic_error"):
            f["ripples"][j].append(Ripple(int(v["cycles"]), v["cos_deg"], v["sin_deg"]))
        elif p.kind == "thermal_drift":
            other.update(expansion_per_k=v["expansion_per_k"], ref_temp_c=v["ref_temp_c"])
        elif p.kind == "camera_scale":
            other["camera_gain"] = 1.0 + v["gain_excess"]
        elif p.kind == "camera_rotation":
            other["camera_turn_rad"] = v["turn_rad"]
        elif p.kind == "comm_delay":
            other["frame_delay_s"] = v["frame_delay_s"]
        elif p.kind == "radial_distortion":
            other["lens_k_per_mm2"] = v["lens_k_per_mm2"]
        elif p.kind == "reach_sag":
            other["sag_mm_at_1m"] = v["sag_mm_at_1m"]
        elif p.kind == "offset_bump":
            other["bump"] = Bump(int(p.joint), v["step_deg"], float(bump_at_s))
        elif p.kind == "joint_coupling":
            other["coupling_21"] = v["coupling_21"]
        elif p.kind == "plane_bump":
            at = math.radians(v["at_deg"])
            other["plane_bump"] = PlaneBump(v["amp_mm"], (v["at_r_mm"] * math.cos(at),
                                                          v["at_r_mm"] * math.sin(at)),
                                            v["width_mm"], math.radians(v["dir_deg"]))
        else:
            raise ValueError(f"unknown kind {p.kind!r}; known: {sorted(KINDS)}")
    return Truth(zero_deg=tuple(f["zero_deg"]), link_error_mm=tuple(f["link_error_mm"]),
                 teeth_ratio=tuple(f["teeth_ratio"]), play_deg=tuple(f["play_deg"]),
                 ripples=(tuple(f["ripples"][0]), tuple(f["ripples"][1])), **other)


@dataclass(frozen=True)
class Answer:
    """What the diagnosis should report for a vocabulary part: the effect's name, its
    joints and every parameter by the vocabulary's full name, in its units."""

    effect: str
    joints: tuple[str, ...]
    params: dict[str, float]


def answer(p: Part) -> Answer | None:
    """The expected answer for ``p`` (None outside the vocabulary)."""
    if p.outside:
        return None
    v = p.values
    joints = (f"j{p.joint}",) if p.joint else ()
    pre = f"j{p.joint}_" if p.joint else ""
    if p.kind == "joint_offset":
        params = {"offset_deg": v["zero_deg"]}
    elif p.kind == "link_length":
        params = {"link_delta_mm": v["error_mm"]}
    elif p.kind == "gear_ratio":
        params = {"gear_ratio_rel": 1.0 / (1.0 + v["teeth_excess"]) - 1.0}
    elif p.kind == "backlash":
        params = {"backlash_deg": v["play_deg"]}
    elif p.kind == "cyclic_error":
        phase = math.degrees(math.atan2(v["cos_deg"], v["sin_deg"])) % 360.0
        params = {"cyclic_amp_deg": math.hypot(v["cos_deg"], v["sin_deg"]),
                  "cyclic_phase_deg": phase, "cyclic_period_deg": 360.0 / v["cycles"]}
    elif p.kind == "motor_cyclic_error":
        phase = math.degrees(math.atan2(v["cos_deg"], v["sin_deg"])) % 360.0
        params = {"motor_cyclic_amp_deg": math.hypot(v["cos_deg"], v["sin_deg"]),
                  "motor_cyclic_phase_deg": phase, "motor_gear_ratio": float(v["cycles"])}
    elif p.kind == "thermal_drift":
        params = {"thermal_expansion_per_k": v["expansion_per_k"],
                  "thermal_ref_temp_c": v["ref_temp_c"]}
    elif p.kind == "camera_scale":
        params = {"camera_scale_rel": v["gain_excess"]}
    elif p.kind == "camera_rotation":
        params = {"camera_rotation_deg": math.degrees(v["turn_rad"])}
    elif p.kind == "comm_delay":
        params = {"comm_delay_sigma_ms": v["frame_delay_s"] * 1e3}
    else:  # pragma: no cover - KINDS and this list are kept together
        raise ValueError(f"no answer for {p.kind!r}")
    return Answer(p.kind, joints, {pre + n: float(x) for n, x in params.items()})
