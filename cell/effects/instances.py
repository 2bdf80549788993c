"""Sized effects: :class:`EffectInstance` (one effect on chosen joints with every parameter)
and the vectors a fitter works with. Pure; no I/O. Bad input raises
:class:`~cell.errors.ConfigError` naming the effect and the field."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np

from cell.effects.base import PLANAR_JOINTS, Effect
from cell.effects.vocabulary import EFFECTS
from cell.errors import ConfigError


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




def reference_temp_c(effects: Sequence[EffectInstance], default: float = 20.0) -> float:
    """The reference temperature (°C) of the first effect among ``effects`` that states one
    (a ``thermal_ref_temp_c`` constant: thermal drift), else ``default``: the temperature at
    which no effect of temperature acts (rows without a temperature are taken there)."""
    for e in effects:
        if "thermal_ref_temp_c" in e.params:
            return float(e.params["thermal_ref_temp_c"])
    return default
