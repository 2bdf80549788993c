"""What one effect definition is made of: :class:`Effect` and the small declarative pieces
it carries (:class:`ParamSpec`, :class:`Remedy`, :class:`OnChain`). Pure; no I/O.

An effect is defined once, in its own module of this package (``cell/effects/<name>.py``),
and listed in :mod:`cell.effects.vocabulary`. Everything else reads the definition: the
plant and the planar replay call ``fn``; the joint calibration and the station lags' fit
(:mod:`cell.diagnosis.jacobian`) call ``deriv``; the recommended action
(:mod:`cell.diagnosis.action`) is ``remedy``; the diagnosis (:mod:`cell.diagnosis.chain.fit`)
takes its vocabulary, subsystems, ``depends_on``, derivatives (``OnChain.term``) and what
makes each effect identifiable (``OnChain.unseen``, ``OnChain.coverage``) from ``chain``.
See ``docs/adding-an-effect.md``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Callable, Sequence

import numpy as np

PLANAR_JOINTS = ("j1", "j2")
SUBSYSTEMS = ("kinematics", "transmission", "thermal", "vision", "comms")


class Stage(StrEnum):
    """Where between command and measurement an effect acts, which fixes the signature of
    its ``fn`` and ``deriv`` (:class:`Effect`)."""

    JOINT = "joint"
    LINK = "link"
    VISION = "vision"
    COMMS = "comms"


STAGES = tuple(Stage)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    ``stem`` is the full name for effects on no joint and gets a ``<joint>_`` prefix for
    per-joint effects. ``bounds`` are hard limits (outside: ConfigError; a fitter can pass
    them to least_squares). ``typical`` is the magnitude range for random draws; ``signed``
    draws take a random sign. ``fitted=False`` marks a known constant (``default``) that a
    fitter holds fixed. ``start`` (optional) is the range a full fit's starting value is
    clipped into (e.g. an amplitude kept off 0 so its phase has a gradient).
    """

    stem: str
    unit: str
    doc: str
    bounds: tuple[float, float]
    typical: tuple[float, float]
    signed: bool = True
    fitted: bool = True
    default: float | None = None
    start: tuple[float, float] | None = None


# ------------------------------------------------------------------ identifiability
def phase_coverage(angles: np.ndarray, per_rev: float, groups: np.ndarray | None, joint: str,
                   min_share: float = 0.5) -> str:
    """'' when ``angles`` (deg) sample a period of 360°/``per_rev`` densely within each of
    their ``groups`` (places; None: one place), else why not. With the phase ψ =
    2π·θ·``per_rev``/360°, the pooled within-place covariance of (sin ψ, cos ψ) (each
    place's mean taken off) must have its smaller eigenvalue at least ``min_share`` × ½ (½
    is what evenly spread phases give): then sin ψ and cos ψ are told from each other, from
    a constant (an offset) and from any error that differs only from place to place. It
    fails for a joint that stays put, for angles that all sit at one phase or at two
    opposite ones (a fixed step of a whole or half period, as a stepped sweep can be), and
    at stations whose jitter spans much less than one period."""
    a = np.asarray(angles, float)
    if len(a) < 3:
        return f"{joint} has {len(a)} fit rows: a period of {360.0 / per_rev:.3g}° needs 3"
    psi = np.radians(a * per_rev)
    sc = np.column_stack([np.sin(psi), np.cos(psi)])
    g = np.zeros(len(a), int) if groups is None else np.asarray(groups)
    _, inv = np.unique(g, return_inverse=True)
    means = np.zeros((inv.max() + 1, 2))
    np.add.at(means, inv, sc)
    sc = sc - (means / np.bincount(inv)[:, None])[inv]
    lam = float(np.linalg.eigvalsh(sc.T @ sc / len(a))[0])
    return "" if lam >= 0.5 * min_share else \
        (f"{joint}'s angles sample the {360.0 / per_rev:.3g}° period too sparsely "
         f"(phase spread {lam / 0.5:.2f} < {min_share})")


# ------------------------------------------------------------------ what to do
@dataclass(frozen=True)
class Remedy:
    """The action to recommend when the effect is the cause: ``kind`` (calibrate_joint,
    calibrate_kinematics, thermal, camera, comms, compliance), ``text`` with ``{what}``
    (the effect's name, spaced) and ``{on}`` (" on j1, j2" or ""), ``commands`` with
    ``{joint}`` (one command per joint ``cellctl calibrate joint`` accepts) or ``{src}``
    (the campaign)."""

    kind: str
    text: str
    commands: tuple[str, ...] = ()


CALIBRATE_JOINT = Remedy("calibrate_joint", "Calibrate the joint: {what}{on}.",
                         ("cellctl calibrate joint {joint}",))   # seed 004, per joint
CALIBRATE_KINEMATICS = Remedy("calibrate_kinematics", "Calibrate the kinematics: {what}{on}.",
                              ("cellctl calibrate kinematics",))
CALIBRATE_CHAIN = Remedy("calibrate_kinematics", "Calibrate the kinematics: {what}{on}.",
                         ("cellctl calibrate kinematics {src}",))


@dataclass(frozen=True)
class ChainPoses:
    """What a chain effect's joint term may read, per pose: ``q`` (P, J) the joints' model
    values (deg or mm: the readings with the model's zero and sign applied), ``levers``
    (P, J) m the gravity lever of each joint at the nominal pose (format, "Chain
    effects"), ``dirs`` (P, J) the sign of each joint's last motion (``jK_dir``; 0
    unknown), ``temp_c`` (P,) the temperature of each pose (``temp_c``; None: not recorded),
    ``motor_ratio`` per joint the motor turns per joint turn the model states (None: not
    stated; ``motor_gear_ratio``), ``rate`` (P, J) deg/s the commanded joint speed at each
    pose (0 at a static one; None: static poses only), ``bus`` per joint its 1-based
    position on the drives' bus (None: not known), ``move`` (P,) the measured move each
    pose is a sample of (−1: static) and ``move_t`` (P,) s its time in the move (None:
    static poses only)."""

    q: np.ndarray
    levers: np.ndarray
    dirs: np.ndarray
    temp_c: np.ndarray | None = None
    motor_ratio: tuple[float | None, ...] = ()
    rate: np.ndarray | None = None
    bus: tuple[int | None, ...] = ()
    move: np.ndarray | None = None
    move_t: np.ndarray | None = None


@dataclass(frozen=True)
class OnChain:
    """How the effect applies to a serial chain (:mod:`cell.diagnosis.chain.fit`): its parameters per
    joint are ``<column>_<stem>`` (``stem`` may hold ``{unit}``, the joint's unit), on
    ``joints`` ``"all"``, ``"revolute"`` or ``"geared"`` (the revolute joints whose motor
    gear ratio the model states); ``"geometric"`` takes the chain's own DH /
    origin parameter names; ``"arm"`` is one parameter for the whole arm, named ``stem``;
    ``"bus"`` one parameter, named ``stem``, of the drives' bus, whose ``term`` acts on every
    joint (k = 0 … J − 1; made only for a chain whose joints' bus positions are known);
    ``"sensor"`` one parameter, named ``stem``, of a linear map the sensor applies about its
    centre c (``sensor_center_mm``): m = c + M·(y − c), ``sensor_map(value) -> (M (3, 3),
    ∂M/∂value (3, 3))`` in the measurement frame. ``unit`` the parameter's unit
    (``{unit}``: the joint's). ``remedy`` replaces the planar one on a chain.

    ``term(poses, k) -> (P,)``: the effect on joint k's value per unit of its parameter,
    Δq_k = value · term (:class:`ChainPoses`); for an ``"arm"`` effect (k = −1) the
    relative change of every length of the arm, so that each point in the base frame moves
    to (1 + value · term) times itself. Either way the chain fitter's forward model and,
    being linear, its exact derivative. A ``"geometric"`` effect has none (its parameter
    is the chain's own op offset), nor a ``"sensor"`` one; every other effect must give
    one. ``unseen``: why the campaign cannot show the effect when its term is zero on every
    pose (what column it lacks; for a sensor map, that the campaign gives no centre);
    ``min_spread``: the least spread (max − min) of the term over the fit poses that tells
    the effect from a constant one, ``still`` what it cannot be told from below it.
    ``bounds``: (least, most) the parameter can physically take (the effect's own hard
    limits, its :attr:`ParamSpec.bounds`; a width or a give that cannot be negative, (0,
    None); None: unbounded on that side): a fit that wants it beyond is left without it.
    ``parts``: several parameters per joint instead of one, each ``(stem, term)`` (a
    ripple's sine and cosine coefficient at each order, Δq_k = Σ value·term); ``stem`` and
    ``term`` are then not given. ``choice``: the parts come in alternatives of this many
    consecutive parts (a ripple's order), of which the search keeps, per joint, the one that
    alone best predicts left-out poses (0: every part is kept). ``coverage(poses, k,
    places) -> str``: why the fit poses cannot show the effect on joint k ('' when they
    can; ``places`` (P,) the station of each pose, :func:`cell.diagnosis.places.stations`), a
    requirement beyond what the parameters' columns tell (a short period sampled densely
    within each place: :func:`phase_coverage`). ``shift(poses, k, value) -> (Δq_k,
    ∂Δq_k/∂value)``: for an effect whose change of the joint is not linear in its parameter
    (the comm delay's time shift of the commands), the exact change at ``value`` and its
    derivative; ``term`` is then that derivative at 0, the screening's linearisation.
    ``nuisance``: parameters ``(stem, unit, term)`` the effect carries beside its own where
    the campaign lacks a variable it depends on (the arm's growth during the measured
    moves, whose temperature paths.csv does not record), fitted only together with them and
    never a cause on their own."""

    joints: str
    stem: str = ""
    unit: str = "{unit}"
    remedy: Remedy | None = None
    term: Callable[[ChainPoses, int], np.ndarray] | None = field(default=None, repr=False)
    unseen: str = ""
    min_spread: float = 0.0
    still: str = ""
    bounds: tuple[float | None, float | None] = (None, None)
    sensor_map: Callable[[float], tuple[np.ndarray, np.ndarray]] | None = field(default=None,
                                                                                 repr=False)
    parts: tuple[tuple[str, Callable[[ChainPoses, int], np.ndarray]], ...] = field(
        default=(), repr=False)
    choice: int = 0
    coverage: Callable[[ChainPoses, int, np.ndarray], str] | None = field(default=None,
                                                                          repr=False)
    shift: Callable[[ChainPoses, int, float], tuple[np.ndarray, np.ndarray]] | None = field(
        default=None, repr=False)
    nuisance: tuple[tuple[str, str, Callable[[ChainPoses, int], np.ndarray]], ...] = field(
        default=(), repr=False)

    def __post_init__(self):
        if self.parts and (self.term is not None or self.stem
                           or self.joints not in ("all", "revolute", "geared")):
            raise ValueError(f"OnChain({self.joints!r}): parts replace the stem and the term, "
                             "on joints 'all', 'revolute' or 'geared'")
        if (self.term is None and not self.parts) != (self.joints in ("geometric", "sensor")):
            raise ValueError(f"OnChain({self.joints!r}): a joint term is given exactly when "
                             "the effect is neither geometric nor the sensor's")
        if (self.sensor_map is None) != (self.joints != "sensor"):
            raise ValueError(f"OnChain({self.joints!r}): a sensor map is given exactly when "
                             "the effect is the sensor's")

    def terms(self) -> tuple[tuple[str, Callable[[ChainPoses, int], np.ndarray] | None], ...]:
        """Per parameter of one joint, ``(stem, term)``: the ``parts``, or the one
        ``(stem, term)``; then the ``nuisance`` parameters'."""
        own = self.parts or ((self.stem, self.term),)
        return own + tuple((stem, term) for stem, _, term in self.nuisance)

    @property
    def n_own(self) -> int:
        """How many of :meth:`terms` are the effect's own parameters (the rest nuisance)."""
        return len(self.parts) or 1


def planar_map(m2: np.ndarray, zz: float) -> np.ndarray:
    """A map of the x–y plane (2, 2) as a map of the measurement frame (3, 3) that
    multiplies z by ``zz``: a camera's map seen by a sensor of any axes."""
    out = np.zeros((3, 3))
    out[:2, :2] = m2
    out[2, 2] = zz
    return out


def constant_term(poses: ChainPoses, k: int) -> np.ndarray:
    """Δq_k = value: a constant addition to the joint (an offset)."""
    return np.ones(len(poses.q))


# ------------------------------------------------------------------ the definition
@dataclass(frozen=True)
class Effect:
    """One effect of the vocabulary.

    ``joints`` lists the joints it may act on (``()`` for none); ``per_joint`` effects take
    one set of ``params`` per chosen joint. ``stage`` says which signature ``fn`` (the
    forward function) and ``deriv`` (its analytic derivative) have:

    * ``joint``:  ``fn(x, jidx, cmd_deg (N,2), dirs (N,2)) -> Δθ_deg (N,2)``;
      ``deriv(...) -> ([∂Δθ/∂x_i (N,2) per fitted parameter], ∂Δθ/∂cmd (N,2) diagonal or None)``
    * ``link``:   ``fn(x, jidx, links_mm (2,), temp_c (N,)) -> Δl_mm (N,2)``;
      ``deriv(...) -> ([∂Δl/∂x_i (N,2)], ∂Δl/∂T (N,2) or None)``
    * ``vision``: ``fn(x, xy_mm (N,2), center_mm (2,)) -> measured xy_mm (N,2)``, a linear map
      about the centre; ``deriv(x) -> (M (2,2), ∂M/∂x (2,2))`` with m = c + M·(p − c)
    * ``comms``:  ``fn(x, order (2,), time_s (N,), cmd_deg (N,2)) -> cmd the joints had (N,2)``;
      ``deriv(x, order) -> (λ_ms (2,), ∂λ/∂x (2,))``: joint j runs λ_j ms late

    ``x`` is the instance's full parameter vector (fixed ones included) in
    :meth:`param_names` order; ``jidx`` the 0-based joint indices. An effect with
    ``fn=None`` is not planar (``chain`` only).

    ``mimics``: the effects whose fit stands in for this one when the campaign lacks what
    identifies it (thermal drift without a temperature column looks like longer links;
    backlash without directions like any error of its joint). Such an effect cannot be
    tested, but it stays a rival of a cause that names one of them on its joints.
    ``remedy`` the recommended action; ``chain`` how it applies to a serial chain (None: it
    does not), which also says what makes it identifiable (:class:`OnChain`: ``unseen``,
    ``coverage``).
    """

    name: str
    subsystem: str
    stage: Stage
    joints: tuple[str, ...]
    per_joint: bool
    params: tuple[ParamSpec, ...]
    depends_on: str
    summary: str
    fn: Callable[..., np.ndarray] | None = field(default=None, repr=False)
    deriv: Callable | None = field(default=None, repr=False)
    mimics: tuple[str, ...] = ()
    remedy: Remedy | None = None
    chain: OnChain | None = None

    def __post_init__(self):
        object.__setattr__(self, "stage", Stage(self.stage))   # an unknown stage fails here, by name

    @property
    def planar(self) -> bool:
        """Part of the planar (SCARA) vocabulary."""
        return self.fn is not None

    def remedy_for(self, chain: bool) -> Remedy | None:
        """The remedy on a chain (its own if it gives one) or on the SCARA."""
        if chain and self.chain is not None and self.chain.remedy is not None:
            return self.chain.remedy
        return self.remedy

    def param_names(self, joints: Sequence[str] = ()) -> list[str]:
        """Full parameter names for ``joints`` (joint-major, then spec order)."""
        if not self.per_joint:
            return [p.stem for p in self.params]
        return [f"{j}_{p.stem}" for j in joints for p in self.params]

    def spec_of(self, name: str) -> ParamSpec:
        """The :class:`ParamSpec` behind full parameter ``name``."""
        stem = name.split("_", 1)[1] if self.per_joint else name
        return next(p for p in self.params if p.stem == stem)

    def constants(self) -> dict[str, float]:
        """The known constants by stem, at their default."""
        return {p.stem: float(p.default) for p in self.params if not p.fitted}

    def zero(self, joints: Sequence[str] = ()):
        """A zero-sized instance (fitted parameters 0, constants at their default): no effect."""
        return self._build(joints, lambda s: 0.0)

    def guess(self, joints: Sequence[str] = ()):
        """A starting point for a bounded fit: signed parameters 0, unsigned ones at the low
        end of their typical range (strictly inside the bounds: least_squares' trf stalls
        when x0 sits on a bound), constants at their default."""
        return self._build(joints, lambda s: 0.0 if s.signed else s.typical[0])

    def draw(self, rng: np.random.Generator, joints: Sequence[str] = ()):
        """A random instance: each fitted parameter uniform in its ``typical`` range, with a
        random sign if ``signed``; constants at their default."""
        def pick(s: ParamSpec) -> float:
            v = float(rng.uniform(*s.typical))
            return v * float(rng.choice((-1.0, 1.0))) if s.signed else v
        return self._build(joints, pick)

    def _build(self, joints, pick):
        from cell.effects.instances import make_effect
        specs = {n: self.spec_of(n) for n in self.param_names(joints)}
        return make_effect(self.name, joints,
                           {n: (pick(s) if s.fitted else s.default) for n, s in specs.items()})


def grid(x, jidx: Sequence[int], n_stems: int) -> np.ndarray:
    """A per-joint effect's full vector as (joints, stems)."""
    return np.asarray(x, dtype=float).reshape(len(jidx), n_stems)


def unit_columns(jidx: Sequence[int], n: int) -> list[np.ndarray]:
    """One (n,2) column per joint of ``jidx``, 1 in that joint's column: ∂/∂(a per-joint
    additive term)."""
    cols = []
    for j in jidx:
        c = np.zeros((n, 2))
        c[:, j] = 1.0
        cols.append(c)
    return cols


INF = math.inf
