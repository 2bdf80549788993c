"""The replay of :mod:`.replay` with its exact Jacobian: what the per-station lags' fit of a
planar campaign evaluates (:mod:`.delay`, a v1 figure of its report). Pure numerics.

:func:`evaluate` gives the simulated measurements of a campaign's rows (points, then path
samples) under a list of vocabulary effects and, on request, their derivatives with respect
to the fitted parameters, in :func:`cell.effects.stack_vectors` order, plus the path
temperature nuisance last when asked for. Values come from the
vocabulary's own functions (:mod:`cell.effects`), so they are those of
:func:`.replay.predict`; the derivatives are the chain rule through the composition order
of :mod:`cell.effects`:

    comms (λ_j = σ·k_j delay of the commanded path) → joint stage θ = a + Σ Δθ(a, dir)
    → link stage L = l + Σ Δl(T) → FK (seed 000 eq. 4) → camera similarity about c

with, per effect, the derivatives its definition carries (``Effect.deriv``, see
:class:`cell.effects.Effect`): ∂Δθ/∂x and ∂Δθ/∂a (joint stage), ∂Δl/∂x and ∂Δl/∂T (link
stage), the camera map and its derivative, the per-joint lags and theirs (comms); this
module composes them and knows no effect by name. Backlash directions along a path follow the delayed
command; they are piecewise constant in σ (derivative 0, as finite differences see it away
from a reversal). The delayed command is the linear interpolation of the commanded samples,
so ∂a/∂σ = −k_j·10⁻³·(slope of the segment that t − λ_j falls in), 0 where the command is
held before the first sample; at λ = 0 exactly the one-sided derivative for λ → 0⁺ (the
segment ending at t) is used. ``tests/cell/test_diagnosis_jacobian.py`` holds every
derivative to finite differences.

Bad input is not checked here (the rows come from a validated campaign and the effects from
:func:`cell.effects.make_effect`); an effect without a derivative raises TypeError.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cell import effects as fx
from cell.diagnosis.replay import DiagData

DEG = math.pi / 180.0


@dataclass
class Rows:
    """The rows one evaluation covers, as flat arrays: the ``n_points`` points first, then
    the path samples. ``cmd`` (n,2) deg commanded, ``dirs`` (n,2) the nominal directions (a
    path's follow its undelayed command), ``temp`` (n_points,) °C or None, ``meas`` (n,2)
    mm measured; ``moves`` (start row, t, cmd, dirs0) per move; ``order`` (2,) station
    positions, ``links`` (2,) nominal mm, ``center`` (2,) mm."""

    n_points: int
    cmd: np.ndarray
    dirs: np.ndarray
    temp: np.ndarray | None
    meas: np.ndarray
    moves: list
    order: np.ndarray
    links: np.ndarray
    center: np.ndarray

    @property
    def n(self) -> int:
        return len(self.cmd)

    @property
    def n_path(self) -> int:
        return self.n - self.n_points


def rows_of(d: DiagData) -> Rows:
    """The :class:`Rows` of ``d`` (cached in ``d.cache``)."""
    r = d.cache.get("rows")
    if r is not None:
        return r
    cmd, dirs, meas = [], [], []
    if d.points is not None:
        cmd.append(d.points.cmd)
        dirs.append(d.points.dirs)
        meas.append(d.points.xy)
    moves, k = [], d.n_points
    for m in d.moves:
        cmd.append(m.cmd)
        dirs.append(fx.path_directions(m.cmd, m.dirs0))
        meas.append(m.xy)
        moves.append((k, m.t, m.cmd, m.dirs0))
        k += len(m.t)
    cat = (lambda a: np.concatenate(a)) if cmd else (lambda a: np.zeros((0, 2)))
    temp = None if d.points is None or d.points.temp is None else np.asarray(d.points.temp, float)
    r = Rows(d.n_points, cat(cmd), cat(dirs), temp, cat(meas), moves, np.asarray(d.order, float),
             np.array([d.geometry.l1_mm, d.geometry.l2_mm], float),
             np.zeros(2) if d.center is None else np.asarray(d.center, float))
    d.cache["rows"] = r
    return r


def _vision_map(e: fx.EffectInstance) -> tuple[np.ndarray, np.ndarray]:
    """(M, ∂M/∂x) of one camera effect: m = c + M·(p − c) (its definition's ``deriv``)."""
    return e.spec.deriv(e.full_vector())


def _delay(r: Rows, lam_ms, want: bool):
    """Path commands delayed by ``lam_ms`` (2,) ms per joint (n_path,2), their directions
    and ∂a_j/∂λ_j in deg/ms (n_path,2) (None if not ``want``)."""
    lam = np.asarray(lam_ms, float) * 1e-3
    if not r.moves:
        z = np.zeros((0, 2))
        return z, z, (z if want else None)
    npt = r.n_points
    if not lam.any():
        a, dirs = r.cmd[npt:], r.dirs[npt:]
    else:
        acts, dl = [], []
        for _, t, cmd, d0 in r.moves:
            a = np.array(cmd, float)
            for j in range(2):
                if lam[j]:
                    a[:, j] = np.interp(t - lam[j], t, cmd[:, j])
            acts.append(a)
            dl.append(fx.path_directions(a, d0))
        a, dirs = np.concatenate(acts), np.concatenate(dl)
    if not want:
        return a, dirs, None
    der = []
    for _, t, cmd, d0 in r.moves:
        da = np.zeros((len(t), 2))
        if len(t) > 1:
            for j in range(2):
                q = t - lam[j]
                seg = np.searchsorted(t, q, side="left") - 1   # q in (t[seg], t[seg+1]]
                ok = (seg >= 0) & (seg < len(t) - 1)
                s = np.clip(seg, 0, len(t) - 2)
                slope = (cmd[s + 1, j] - cmd[s, j]) / (t[s + 1] - t[s])
                da[:, j] = np.where(ok, -slope * 1e-3, 0.0)
        der.append(da)
    return a, dirs, np.concatenate(der)


def evaluate(r: Rows, effects: Sequence[fx.EffectInstance], path_temp_c: float | None = None,
             jac: bool = False, with_path_temp: bool = False, lags_ms=None):
    """Simulated measurements (n,2) mm of rows ``r`` under ``effects`` and, with ``jac``,
    ∂/∂(fitted parameters) as (n, 2, m) (m = fitted parameters, +1 for ``path_temp_c``
    when ``with_path_temp``, +2 for ``lags_ms``, in that order, last). ``path_temp_c`` as
    in :func:`.replay.predict`. ``lags_ms`` (2,): instead of a comm_delay effect, joint j
    runs its path command λ_j ms late (the per-station lags of :mod:`.delay`)."""
    effects = list(effects)
    n, npt = r.n, r.n_points
    m = sum(len(e.fit_names) for e in effects) + int(with_path_temp) + 2 * (lags_ms is not None)
    # stage 1: comms (path rows only)
    a, dirs = r.cmd, r.dirs
    comms = [e for e in effects if e.spec.stage == fx.Stage.COMMS]
    da_dlam = None
    if (comms or lags_ms is not None) and r.n_path:
        if len(comms) + (lags_ms is not None) > 1:
            raise ValueError("at most one comms effect (or lags)")
        if lags_ms is not None:
            lam = np.asarray(lags_ms, float)
        else:
            lam, dlam_dx = comms[0].spec.deriv(comms[0].full_vector(), r.order)
        ap, dp, dd = _delay(r, lam, jac)
        a = np.vstack([r.cmd[:npt], ap])
        dirs = np.vstack([r.dirs[:npt], dp])
        if jac:
            da_dlam = np.vstack([np.zeros((npt, 2)), dd])
    # stage 2: joints
    theta = np.array(a, float)
    dth_da = np.ones((n, 2)) if jac else None
    col: dict[int, tuple[str, np.ndarray]] = {}     # param index -> (stage, array)
    k = 0
    starts = []
    for e in effects:
        starts.append(k)
        k += len(e.fit_names)
    for e, k0 in zip(effects, starts):
        if e.spec.stage != fx.Stage.JOINT:
            continue
        x = e.full_vector()
        theta += e.spec.fn(x, e.jidx, a, dirs)
        if jac:
            cols, dda = e.spec.deriv(x, e.jidx, a, dirs)
            for i, c in enumerate(cols):
                col[k0 + i] = ("theta", c)
            if dda is not None:
                dth_da += dda
    # stage 3: links
    t_ref = fx.reference_temp_c(effects)
    temp = np.empty(n)
    temp[:npt] = r.temp if r.temp is not None else t_ref
    temp[npt:] = t_ref if path_temp_c is None else path_temp_c
    L = np.tile(r.links, (n, 1))
    dL_dT = np.zeros((n, 2)) if jac else None
    for e, k0 in zip(effects, starts):
        if e.spec.stage != fx.Stage.LINK:
            continue
        x = e.full_vector()
        L += e.spec.fn(x, e.jidx, r.links, temp)
        if jac:
            cols, dT = e.spec.deriv(x, e.jidx, r.links, temp)
            for i, c in enumerate(cols):
                col[k0 + i] = ("link", c)
            if dT is not None:
                dL_dT += dT
    # stage 4: FK
    t1 = np.radians(theta[:, 0])
    t12 = t1 + np.radians(theta[:, 1])
    c1, s1, c12, s12 = np.cos(t1), np.sin(t1), np.cos(t12), np.sin(t12)
    p = np.column_stack([L[:, 0] * c1 + L[:, 1] * c12, L[:, 0] * s1 + L[:, 1] * s12])
    # stage 5: camera
    vis = [(e, k0) for e, k0 in zip(effects, starts) if e.spec.stage == fx.Stage.VISION]
    M = np.eye(2)
    vis_cols: dict[int, np.ndarray] = {}
    out = p
    for e, k0 in vis:
        Mi, dMi = _vision_map(e)
        rel = out - r.center
        if jac:
            for kk in vis_cols:                      # earlier camera columns pass through Mi
                vis_cols[kk] = vis_cols[kk] @ Mi.T
            vis_cols[k0] = rel @ dMi.T
        out = r.center + rel @ Mi.T
        M = Mi @ M
    if not jac:
        return out, None
    J = np.zeros((n, 2, m))
    # FK partials, then through the camera map M
    dp_dt1 = DEG * np.column_stack([-L[:, 0] * s1 - L[:, 1] * s12, L[:, 0] * c1 + L[:, 1] * c12])
    dp_dt2 = DEG * np.column_stack([-L[:, 1] * s12, L[:, 1] * c12])
    dp_dl1 = np.column_stack([c1, s1])
    dp_dl2 = np.column_stack([c12, s12])

    def through_theta(dth):
        return (dp_dt1 * dth[:, :1] + dp_dt2 * dth[:, 1:]) @ M.T

    def through_links(dl):
        return (dp_dl1 * dl[:, :1] + dp_dl2 * dl[:, 1:]) @ M.T

    for i, (stage, c) in col.items():
        J[:, :, i] = through_theta(c) if stage == "theta" else through_links(c)
    for i, c in vis_cols.items():
        J[:, :, i] = c
    for e, k0 in zip(effects, starts):
        if e.spec.stage == fx.Stage.COMMS and da_dlam is not None:
            J[:, :, k0] = through_theta(dth_da * da_dlam * dlam_dx)
    nxt = k
    if with_path_temp:
        dT = np.zeros((n, 2))
        dT[npt:] = dL_dT[npt:]
        J[:, :, nxt] = through_links(dT)
        nxt += 1
    if lags_ms is not None and da_dlam is not None:
        for j in range(2):
            dl = np.zeros((n, 2))
            dl[:, j] = dth_da[:, j] * da_dlam[:, j]
            J[:, :, nxt + j] = through_theta(dl)
    return out, J


def coverage_check() -> list[str]:
    """Planar vocabulary effects without a derivative (a test keeps this empty)."""
    return [n for n, e in fx.EFFECTS.items() if e.deriv is None]
