"""The effect vocabulary shared by the plant (which makes the truth) and the sim-to-real
diagnosis (which fits it). Pure, vectorised numerics; no I/O.

Each effect of :data:`EFFECTS` is a pure function of an explicit parameter vector, so a
fitter can hand candidate vectors to :func:`simulate_points` / :func:`simulate_path` (e.g.
inside ``scipy.optimize.least_squares``) exactly as the plant does with its true values.
Names, subsystems and ``depends_on`` follow the measurement format, ``cell/measurements.md``.

Composition order (one order, used everywhere)::

    1. comms   (paths only) comm_delay: joint i runs its command λ_i = σ·k_i late,
               k_i = its 1-based position in the CAN station order (seed 002)
    2. joint   θ_true = θ_cmd + Σ Δθ(θ_cmd, dir): joint_offset, gear_ratio, backlash,
               cyclic_error; every term is evaluated at the commanded (drive-side) angle,
               so the joint terms add and their order among themselves does not matter
    3. link    l_true = l_nominal + Σ Δl(T): link_length, thermal_drift
    4. FK      seed 000 eq. 4 with l_true, θ_true        -> true tool centre (x, y)
    5. vision  camera_scale, camera_rotation about the camera centre -> what the camera
               measures (a similarity about one centre: the two commute)

Units: angles in degrees, lengths in mm, time in s, temperature in °C, relative sizes
dimensionless. Per-joint parameters are named ``<joint>_<stem>`` (``j2_backlash_deg``);
``link_length`` on ``j1``/``j2`` means link 1/2. Bad input raises
:class:`~cell.errors.ConfigError` (effects and their parameters),
:class:`~cell.errors.KinematicsError` (joint and direction arrays) or
:class:`~cell.errors.TrajectoryError` (time arrays), naming the value.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from cell.errors import ConfigError, KinematicsError, TrajectoryError
from cell.kinematics import planar_xy

PLANAR_JOINTS = ("j1", "j2")
STATION_NAMES = ("j1", "j2", "j3", "j4")
DEFAULT_STATIONS = STATION_NAMES
SUBSYSTEMS = ("kinematics", "transmission", "thermal", "vision", "comms")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    ``stem`` is the full name for effects on no joint and gets a ``<joint>_`` prefix for
    per-joint effects. ``bounds`` are hard limits (outside: ConfigError; a fitter can pass
    them to least_squares). ``typical`` is the magnitude range for random draws; ``signed``
    draws take a random sign. ``fitted=False`` marks a known constant (``default``) that a
    fitter holds fixed.
    """

    stem: str
    unit: str
    doc: str
    bounds: tuple[float, float]
    typical: tuple[float, float]
    signed: bool = True
    fitted: bool = True
    default: float | None = None


@dataclass(frozen=True)
class Effect:
    """One effect of the vocabulary.

    ``joints`` lists the joints it may act on (``()`` for none); ``per_joint`` effects take
    one set of ``params`` per chosen joint. ``stage`` says which signature ``fn`` has:

    * ``joint``:  ``fn(x, jidx, cmd_deg (N,2), dirs (N,2)) -> Δθ_deg (N,2)``
    * ``link``:   ``fn(x, jidx, links_mm (2,), temp_c (N,)) -> Δl_mm (N,2)``
    * ``vision``: ``fn(x, xy_mm (N,2), center_mm (2,)) -> measured xy_mm (N,2)``
    * ``comms``:  ``fn(x, order (2,), time_s (N,), cmd_deg (N,2)) -> cmd the joints had (N,2)``

    ``x`` is the instance's full parameter vector (fixed ones included) in
    :meth:`param_names` order; ``jidx`` the 0-based joint indices.

    ``mimics``: the effects whose fit stands in for this one when the campaign lacks what
    identifies it (thermal drift without a temperature column looks like longer links;
    backlash without directions like any error of its joint). Such an effect cannot be
    tested, but it stays a rival of a cause that names one of them on its joints.
    """

    name: str
    subsystem: str
    stage: str
    joints: tuple[str, ...]
    per_joint: bool
    params: tuple[ParamSpec, ...]
    depends_on: str
    summary: str
    fn: Callable[..., np.ndarray] = field(repr=False)
    mimics: tuple[str, ...] = ()

    def param_names(self, joints: Sequence[str] = ()) -> list[str]:
        """Full parameter names for ``joints`` (joint-major, then spec order)."""
        if not self.per_joint:
            return [p.stem for p in self.params]
        return [f"{j}_{p.stem}" for j in joints for p in self.params]

    def spec_of(self, name: str) -> ParamSpec:
        """The :class:`ParamSpec` behind full parameter ``name``."""
        stem = name.split("_", 1)[1] if self.per_joint else name
        return next(p for p in self.params if p.stem == stem)

    def zero(self, joints: Sequence[str] = ()) -> "EffectInstance":
        """A zero-sized instance (fitted parameters 0, constants at their default): no effect."""
        return self._build(joints, lambda s: 0.0)

    def guess(self, joints: Sequence[str] = ()) -> "EffectInstance":
        """A starting point for a bounded fit: signed parameters 0, unsigned ones at the low
        end of their typical range (strictly inside the bounds: least_squares' trf stalls
        when x0 sits on a bound), constants at their default."""
        return self._build(joints, lambda s: 0.0 if s.signed else s.typical[0])

    def draw(self, rng: np.random.Generator, joints: Sequence[str] = ()) -> "EffectInstance":
        """A random instance: each fitted parameter uniform in its ``typical`` range, with a
        random sign if ``signed``; constants at their default."""
        def pick(s: ParamSpec) -> float:
            v = float(rng.uniform(*s.typical))
            return v * float(rng.choice((-1.0, 1.0))) if s.signed else v
        return self._build(joints, pick)

    def _build(self, joints, pick) -> "EffectInstance":
        specs = {n: self.spec_of(n) for n in self.param_names(joints)}
        return make_effect(self.name, joints,
                           {n: (pick(s) if s.fitted else s.default) for n, s in specs.items()})


# ------------------------------------------------------------------ effect functions
def _grid(x: np.ndarray, jidx: Sequence[int], n_stems: int) -> np.ndarray:
    return np.asarray(x, dtype=float).reshape(len(jidx), n_stems)


def joint_offset(x, jidx, cmd_deg, dirs):
    """Zero-position error: Δθ_j = o_j (deg), the same at every angle and direction."""
    out = np.zeros_like(cmd_deg, dtype=float)
    out[:, list(jidx)] += _grid(x, jidx, 1)[:, 0]
    return out


def gear_ratio(x, jidx, cmd_deg, dirs):
    """Gear ratio error: θ_true = θ_cmd·(1 + ε_j), i.e. Δθ_j = ε_j·θ_cmd,j, where
    ε = N_nominal/N_true − 1 (the drive converts joint angle to motor angle with the
    nominal ratio). Zero at the joint's zero, growing with the angle."""
    out = np.zeros_like(cmd_deg, dtype=float)
    out[:, list(jidx)] = _grid(x, jidx, 1)[:, 0] * cmd_deg[:, list(jidx)]
    return out


def backlash(x, jidx, cmd_deg, dirs):
    """Lost motion of total width b_j (deg): the output trails the drive by half the band,
    Δθ_j = −dir_j·b_j/2, so a reversal moves the joint by b_j. Depends on the direction of
    the last motion only (dir 0 = unknown, centre of the band); not on the angle. The
    traversal of the band at a reversal (≤ b/speed, ms) is not modelled."""
    out = np.zeros_like(cmd_deg, dtype=float)
    out[:, list(jidx)] = -0.5 * _grid(x, jidx, 1)[:, 0] * dirs[:, list(jidx)]
    return out


def cyclic_error(x, jidx, cmd_deg, dirs):
    """Periodic transmission error: Δθ_j = a_j·sin(2π·θ_cmd,j/P_j + φ_j), amplitude a (deg),
    phase φ (deg), period P (joint deg). P is a known constant of the drive (default 360°:
    once per revolution of the output gear); a and φ are fitted."""
    g = _grid(x, jidx, 3)
    out = np.zeros_like(cmd_deg, dtype=float)
    arg = 2 * np.pi * cmd_deg[:, list(jidx)] / g[:, 2] + np.radians(g[:, 1])
    out[:, list(jidx)] = g[:, 0] * np.sin(arg)
    return out


def link_length(x, jidx, links_mm, temp_c):
    """Link length error: Δl_k = d_k (mm), constant (``j1``/``j2`` = link 1/2)."""
    out = np.zeros((len(temp_c), 2))
    out[:, list(jidx)] += _grid(x, jidx, 1)[:, 0]
    return out


def thermal_drift(x, jidx, links_mm, temp_c):
    """Thermal expansion of both links: Δl_k = α·l_k·(T − T_ref), α in 1/K, T_ref (°C) the
    known temperature the nominal lengths hold at (default 20 °C, ISO 1). Acts on no single
    joint (``joints = []``); T comes from the temperature model (plant) or the log."""
    alpha, t_ref = np.asarray(x, dtype=float)
    return alpha * (np.asarray(temp_c, dtype=float)[:, None] - t_ref) * np.asarray(links_mm)[None, :]


def camera_scale(x, xy_mm, center_mm):
    """Camera scale error s (relative) about the camera centre c: m = c + (1 + s)·(p − c)."""
    c = np.asarray(center_mm, dtype=float)
    return c + (1.0 + float(x[0])) * (xy_mm - c)


def camera_rotation(x, xy_mm, center_mm):
    """Camera rotation error φ (deg) about the camera centre c: m = c + R(φ)·(p − c)."""
    c = np.asarray(center_mm, dtype=float)
    a = math.radians(float(x[0]))
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return c + (xy_mm - c) @ rot.T


def comm_delay(x, order, time_s, cmd_deg):
    """Per-frame CAN delay σ (ms, seed 002): joint j receives its command λ_j = σ·k_j late
    (k_j = 1-based station position), so at time t it has the command of t − λ_j. The
    commanded trajectory is interpolated linearly between its samples and held at its
    first value before the first one. σ = 0 is the identity."""
    lam = float(x[0]) * 1e-3 * np.asarray(order, dtype=float)
    out = np.array(cmd_deg, dtype=float)
    for j in range(2):
        if lam[j]:
            out[:, j] = np.interp(time_s - lam[j], time_s, cmd_deg[:, j])
    return out


_PS, _INF, _J = ParamSpec, math.inf, PLANAR_JOINTS
EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("joint_offset", "kinematics", "joint", _J, True, (
        _PS("offset_deg", "deg", "joint zero error", (-5.0, 5.0), (0.02, 0.2)),),
        "constant", "joint zero differs from the nominal zero", joint_offset),
    Effect("link_length", "kinematics", "link", _J, True, (
        _PS("link_delta_mm", "mm", "true − nominal link length", (-50.0, 50.0), (0.1, 1.0)),),
        "position", "a link is longer or shorter than nominal", link_length),
    Effect("gear_ratio", "transmission", "joint", _J, True, (
        _PS("gear_ratio_rel", "1", "ε = N_nominal/N_true − 1", (-0.05, 0.05), (2e-4, 2e-3)),),
        "angle", "joint angle scaled by a wrong gear ratio", gear_ratio),
    Effect("backlash", "transmission", "joint", _J, True, (
        _PS("backlash_deg", "deg", "total lost-motion width", (0.0, 2.0), (0.01, 0.1), False),),
        "direction", "lost motion: the joint depends on the approach direction", backlash,
        ("joint_offset", "gear_ratio", "cyclic_error")),
    Effect("cyclic_error", "transmission", "joint", _J, True, (
        _PS("cyclic_amp_deg", "deg", "amplitude", (0.0, 1.0), (0.01, 0.08), False),
        _PS("cyclic_phase_deg", "deg", "phase at θ = 0", (-_INF, _INF), (0.0, 360.0), False),
        _PS("cyclic_period_deg", "deg", "period in joint deg (known)", (1e-3, 3600.0),
            (360.0, 360.0), False, fitted=False, default=360.0)),
        "angle", "periodic transmission error of the drive", cyclic_error),
    Effect("thermal_drift", "thermal", "link", (), False, (
        _PS("thermal_expansion_per_k", "1/K", "linear expansion of both links", (-2e-5, 2e-4),
            (10e-6, 30e-6), False),
        _PS("thermal_ref_temp_c", "°C", "temperature of the nominal lengths (known)",
            (-50.0, 100.0), (20.0, 20.0), False, fitted=False, default=20.0)),
        "temperature", "both links grow with temperature", thermal_drift, ("link_length",)),
    Effect("camera_scale", "vision", "vision", (), False, (
        _PS("camera_scale_rel", "1", "scale about the camera centre", (-0.05, 0.05), (2e-4, 2e-3)),),
        "position", "camera scale error about its centre", camera_scale),
    Effect("camera_rotation", "vision", "vision", (), False, (
        _PS("camera_rotation_deg", "deg", "rotation about the camera centre", (-5.0, 5.0),
            (0.01, 0.1)),),
        "position", "camera rotated about its centre", camera_rotation),
    Effect("comm_delay", "comms", "comms", (), False, (
        _PS("comm_delay_sigma_ms", "ms", "per-frame delay σ; station k is σ·k late", (0.0, 50.0),
            (0.5, 4.0), False),),
        "speed", "joints receive their commands one after another", comm_delay),
)}


# ------------------------------------------------------------------ instances
def _located(msg: str, *loc) -> ConfigError:
    exc = ConfigError(msg)
    exc.loc = tuple(loc)  # where in the effect entry the problem is (used for file:line)
    return exc


@dataclass(frozen=True)
class EffectInstance:
    """One sized effect on chosen joints; build with :func:`make_effect` (validates).

    ``params`` holds every parameter by full name, constants included.
    """

    effect: str
    joints: tuple[str, ...]
    params: Mapping[str, float]

    @property
    def spec(self) -> Effect:
        return EFFECTS[self.effect]

    @property
    def jidx(self) -> tuple[int, ...]:
        return tuple(PLANAR_JOINTS.index(j) for j in self.joints)

    @property
    def param_names(self) -> list[str]:
        return self.spec.param_names(self.joints)

    @property
    def fit_names(self) -> list[str]:
        """Names of the fitted parameters (constants left out), in vector order."""
        return [n for n in self.param_names if self.spec.spec_of(n).fitted]

    def full_vector(self) -> np.ndarray:
        """Every parameter, in :attr:`param_names` order (what ``spec.fn`` takes)."""
        return np.array([self.params[n] for n in self.param_names], dtype=float)

    def vector(self) -> np.ndarray:
        """The fitted parameters, in :attr:`fit_names` order."""
        return np.array([self.params[n] for n in self.fit_names], dtype=float)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of the fitted parameters, for ``least_squares(bounds=...)``."""
        b = np.array([self.spec.spec_of(n).bounds for n in self.fit_names], dtype=float)
        return b[:, 0], b[:, 1]

    def with_vector(self, x) -> "EffectInstance":
        """A copy with the fitted parameters replaced by ``x`` (no bounds check, so a
        fitter may probe freely; only length and finiteness are checked)."""
        x = np.asarray(x, dtype=float).ravel()
        if x.shape != (len(self.fit_names),) or not np.all(np.isfinite(x)):
            raise ConfigError(f"{self.effect}: vector {x.tolist()} must hold "
                              f"{len(self.fit_names)} finite values {self.fit_names}")
        params = dict(self.params)
        params.update(zip(self.fit_names, map(float, x)))
        return EffectInstance(self.effect, self.joints, params)


def make_effect(effect: str, joints: Iterable[str] = (), params: Mapping[str, float] | None = None
                ) -> EffectInstance:
    """Validated :class:`EffectInstance`. Constants (``fitted=False``) may be omitted and take
    their default; every fitted parameter must be given.

    Raises ConfigError naming the effect and the field (``exc.loc`` = ``("effect",)``,
    ``("joints",)`` or ``("params", name)``) for an unknown effect, joints it cannot act on,
    a missing/unknown/non-finite parameter or one outside its bounds.
    """
    if effect not in EFFECTS:
        raise _located(f"unknown effect {effect!r}; known: {sorted(EFFECTS)}", "effect")
    spec = EFFECTS[effect]
    joints = tuple(joints)
    if spec.per_joint:
        bad = [j for j in joints if j not in spec.joints]
        if not joints or bad or len(set(joints)) != len(joints):
            raise _located(f"{effect}: joints {list(joints)} invalid; give one or more distinct "
                           f"of {list(spec.joints)}", "joints")
    elif joints:
        raise _located(f"{effect} acts on no joint; joints must be empty, got {list(joints)}",
                       "joints")
    params = dict(params or {})
    names = spec.param_names(joints)
    for n in params:
        if n not in names:
            raise _located(f"{effect}: unknown parameter {n!r}; expected {names}", "params", n)
    out = {}
    for n in names:
        ps = spec.spec_of(n)
        if n not in params:
            if ps.fitted:
                raise _located(f"{effect}: parameter {n!r} ({ps.unit}, {ps.doc}) is missing",
                               "params")
            out[n] = float(ps.default)
            continue
        v = params[n]
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(v)):
            raise _located(f"{effect}: {n} = {v!r} is not a finite number", "params", n)
        lo, hi = ps.bounds
        if not lo <= float(v) <= hi:
            raise _located(f"{effect}: {n} = {v!r} {ps.unit} is outside [{lo}, {hi}]",
                           "params", n)
        out[n] = float(v)
    return EffectInstance(effect, joints, out)


def stack_vectors(effects: Sequence[EffectInstance]) -> tuple[np.ndarray, list[str]]:
    """All fitted parameters of ``effects`` as one vector, with their names (for a fitter)."""
    vec = [e.vector() for e in effects]
    return (np.concatenate(vec) if vec else np.zeros(0)), [n for e in effects for n in e.fit_names]


def split_vector(effects: Sequence[EffectInstance], x) -> list[EffectInstance]:
    """Inverse of :func:`stack_vectors`: ``effects`` with their fitted parameters from ``x``."""
    x = np.asarray(x, dtype=float).ravel()
    sizes = [len(e.fit_names) for e in effects]
    if x.size != sum(sizes):
        raise ConfigError(f"vector of {x.size} values; the effects need {sum(sizes)}")
    parts = np.split(x, np.cumsum(sizes)[:-1]) if effects else []
    return [e.with_vector(p) for e, p in zip(effects, parts)]


# ------------------------------------------------------------------ composition
def _joint_batch(name: str, a, n: int | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 2 or (n is not None and a.shape[0] != n):
        want = "(N, 2)" if n is None else f"({n}, 2)"
        raise KinematicsError(f"{name} must have shape {want} (j1, j2 per row), got {a.shape}")
    is_dir = name.startswith("dirs")
    ok = np.isin(a, (-1.0, 0.0, 1.0)) if is_dir else np.isfinite(a)
    if not ok.all():
        r, c = np.argwhere(~ok)[0]
        raise KinematicsError(f"{name}[{r}, {c}] = {float(a[r, c])!r} is not "
                              + ("-1, 0 or +1" if is_dir else "a finite number"))
    return a


def _series(name: str, a, n: int, effects=()) -> np.ndarray:
    if a is None:  # only temp_c may be left out, and only without thermal_drift
        if name != "temp_c" or any(e.effect == "thermal_drift" for e in effects):
            raise ConfigError(f"{name} is required" + (": thermal_drift is among the effects"
                                                       if name == "temp_c" else ""))
        return np.zeros(n)
    a = np.asarray(a, dtype=float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,):
        raise TrajectoryError(f"{name} must have shape ({n},), got {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise TrajectoryError(f"{name}[{bad[0]}] = {float(a[bad[0]])!r} is not a finite number")
    return a


def _check_effects(effects) -> list[EffectInstance]:
    effects = list(effects)
    for i, e in enumerate(effects):
        if not isinstance(e, EffectInstance):
            raise ConfigError(f"effects[{i}] = {e!r} is not an EffectInstance (use make_effect)")
    return effects


def _links(geometry) -> np.ndarray:
    g = getattr(geometry, "g", geometry)  # a Scara or its Geometry
    return np.array([g.l1_mm, g.l2_mm], dtype=float)


def true_joints(effects: Sequence[EffectInstance], cmd_deg: np.ndarray, dirs: np.ndarray
                ) -> np.ndarray:
    """Stage 2: true joint angles (N,2) deg from commanded angles and last-motion directions."""
    q = np.array(cmd_deg, dtype=float)
    for e in effects:
        if e.spec.stage == "joint":
            q += e.spec.fn(e.full_vector(), e.jidx, cmd_deg, dirs)
    return q


def true_links(geometry, effects: Sequence[EffectInstance], temp_c: np.ndarray) -> np.ndarray:
    """Stage 3: true link lengths (N,2) mm at temperatures ``temp_c`` (N,) °C."""
    nominal = _links(geometry)
    links = np.tile(nominal, (len(temp_c), 1))
    for e in effects:
        if e.spec.stage == "link":
            links += e.spec.fn(e.full_vector(), e.jidx, nominal, temp_c)
    return links


def planar_fk(links_mm: np.ndarray, q_deg: np.ndarray) -> np.ndarray:
    """Stage 4: seed 000 eq. 4, vectorised: (x, y) mm (N,2) for links (N,2) mm, joints (N,2) deg."""
    return planar_xy(links_mm[:, 0], links_mm[:, 1], q_deg)


def camera_view(effects: Sequence[EffectInstance], xy_mm: np.ndarray, camera_center_mm
                ) -> np.ndarray:
    """Stage 5: what the camera measures (N,2) mm for true points ``xy_mm`` (N,2)."""
    c = np.asarray(camera_center_mm, dtype=float)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ConfigError(f"camera_center_mm = {camera_center_mm!r} must be 2 finite mm values")
    out = np.asarray(xy_mm, dtype=float)
    for e in effects:
        if e.spec.stage == "vision":
            out = e.spec.fn(e.full_vector(), out, c)
    return out


def simulate_points(nominal_geometry, effects: Sequence[EffectInstance], cmd_deg, dirs,
                    time_s=None, temp_c=None, camera_center_mm=(0.0, 0.0)) -> np.ndarray:
    """What the camera measures (x, y) mm (N,2) for static poses, through stages 2–5.

    ``nominal_geometry`` is a :class:`~cell.kinematics.Geometry` (or a Scara);
    ``cmd_deg`` (N,2) commanded θ1, θ2 in deg; ``dirs`` (N,2) sign of each joint's last
    motion (−1, 0, +1); ``time_s`` (N,) s (checked, no static effect uses it yet);
    ``temp_c`` (N,) or scalar °C (required only with thermal_drift); ``camera_center_mm``
    where the camera's optical axis meets the work plane. comm_delay has no effect on
    static poses. Raises as the module docstring says; nothing is stored.
    """
    effects = _check_effects(effects)
    cmd = _joint_batch("cmd_deg", cmd_deg)
    n = len(cmd)
    d = _joint_batch("dirs", dirs, n)
    if time_s is not None:
        _series("time_s", time_s, n)
    temp = _series("temp_c", temp_c, n, effects)
    xy = planar_fk(true_links(nominal_geometry, effects, temp), true_joints(effects, cmd, d))
    return camera_view(effects, xy, camera_center_mm)


def station_order(stations: Sequence[str]) -> np.ndarray:
    """1-based bus positions (k_j1, k_j2) from a CAN station order such as ``[j2, j1, j3]``."""
    st = list(stations)
    if len(set(st)) != len(st) or any(s not in STATION_NAMES for s in st) \
            or not set(PLANAR_JOINTS) <= set(st):
        raise ConfigError(f"stations = {st!r}: list distinct names of {list(STATION_NAMES)} "
                          f"including j1 and j2")
    return np.array([st.index(j) + 1 for j in PLANAR_JOINTS], dtype=float)


def path_directions(q_deg: np.ndarray, dirs0) -> np.ndarray:
    """Sign of each joint's last motion along a sampled path (N,2); ``dirs0`` (2,) before it."""
    step = np.sign(np.diff(q_deg, axis=0))
    signs = np.vstack([np.asarray(dirs0, dtype=float)[None, :], step])
    # forward-fill zeros (joint at rest keeps its last direction)
    idx = np.where(signs != 0, np.arange(len(signs))[:, None], 0)
    idx = np.maximum.accumulate(idx, axis=0)
    return np.take_along_axis(signs, idx, axis=0)


def simulate_path(nominal_geometry, effects: Sequence[EffectInstance], cmd_deg, time_s,
                  temp_c=None, camera_center_mm=(0.0, 0.0), stations=DEFAULT_STATIONS,
                  dirs0=(0, 0)) -> np.ndarray:
    """What the camera measures (x, y) mm (N,2) along one move, through stages 1–5.

    ``cmd_deg`` (N,2) is where the controller meant θ1, θ2 to be at ``time_s`` (N,), s,
    strictly increasing (paths.csv's j*_cmd_deg, time_s). comm_delay gives each joint the
    command of t − λ_j (linear interpolation in the commanded samples); the directions for
    backlash follow the delayed command, starting from ``dirs0`` (−1/0/+1 per joint).
    ``stations`` is the CAN station order. Raises as the module docstring says.
    """
    effects = _check_effects(effects)
    cmd = _joint_batch("cmd_deg", cmd_deg)
    n = len(cmd)
    t = _series("time_s", time_s, n)
    if n > 1 and not np.all(np.diff(t) > 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise TrajectoryError(f"time_s must increase strictly: time_s[{k}] = {float(t[k])!r} "
                              f"after {float(t[k - 1])!r}")
    d0 = _joint_batch("dirs0", np.asarray(dirs0, dtype=float).reshape(1, -1), 1)[0]
    order = station_order(stations)
    if n == 0:
        return np.zeros((0, 2))
    actual = cmd
    for e in effects:
        if e.spec.stage == "comms":
            actual = e.spec.fn(e.full_vector(), order, t, actual)
    dirs = path_directions(actual, d0)
    temp = _series("temp_c", temp_c, n, effects)
    xy = planar_fk(true_links(nominal_geometry, effects, temp), true_joints(effects, actual, dirs))
    return camera_view(effects, xy, camera_center_mm)
