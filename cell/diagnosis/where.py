"""Where the gap lies, and what it varies with. Pure numerics.

The residual (measured − simulated, mm) is regressed, one variable at a time, on small
linear models that each express "the gap varies with X" (N rows, both axes stacked, no
intercept outside the model; J_j = ∂(x,y)/∂θ_j in mm/deg, u_k = ∂(x,y)/∂l_k,
B = [J_1, J_2, u_1, u_2, e_x, e_y] the six small rigid-body/kinematic displacements):

==============  ============================================  ============
label           regressors                                    columns
==============  ============================================  ============
constant        J_j                    (one joint off by a constant angle)   1
angle           J_j·[1, θ_j/100, sin kθ_j, cos kθ_j], k ≤ 4   4 (best k)
direction       J_j·[1, dir_j]                                               2
position        B  (a fixed kinematic/rigid error)                           6
position        B + a cubic field in (x, y) per axis (any smooth map)       24
temperature     B·[1, T]                                                    12
time            B·[1, t, t²]                                                18
payload         B·[1, payload]   (reported, not a spec ``depends_on``)      12
speed (paths)   smooth field + J_j·θ̇_j  — the part beyond the field          2
                (paths-only campaign: B + J_j·θ̇_j, competing by BIC)       8
==============  ============================================  ============

Effect size = the fraction of the residual's mean square the model explains (R²,
uncentred, in [0, 1]) and the rms it explains, mm. ``depends_on`` is the variable of the
model with the lowest BIC (``2N·ln(RSS/2N) + m·ln 2N``), so a richer model has to pay for
its columns; with points and paths, "speed" wins when the paths' velocity-following part
explains more mean square than the best static model does on the points (the static
models are fitted on the points; a paths-only campaign fits all of them on the path
samples).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis.replay import DiagData
from cell.numerics.stats import distinct

ANGLE_ORDERS = (1, 2, 3, 4)     # the harmonic orders the cyclic error is screened at
SPEC_DEPENDS = ("constant", "angle", "direction", "time", "temperature", "position", "speed")


@dataclass
class Where:
    """Result of :func:`analyse`: ``depends_on`` (spec vocabulary), ``joint`` (``"j1"``,
    ``"j2"`` or None), ``effect_sizes`` {variable: {"r2", "rms_mm", "joint"}},
    ``per_joint_rms_deg`` {j1, j2} (residual mapped through the inverse Jacobian)."""

    depends_on: str
    joint: str | None
    effect_sizes: dict = field(default_factory=dict)
    per_joint_rms_deg: dict = field(default_factory=dict)
    rms_mm: float = 0.0


def jacobian_cols(l1: float, l2: float, cmd: np.ndarray) -> tuple[np.ndarray, ...]:
    """(J1, J2, u1, u2), each (N,2): ∂(x,y)/∂θ_j in mm/deg and ∂(x,y)/∂l_k (unitless)."""
    a = np.radians(cmd[:, 0])
    ab = a + np.radians(cmd[:, 1])
    u1 = np.column_stack([np.cos(a), np.sin(a)])
    u2 = np.column_stack([np.cos(ab), np.sin(ab)])
    k = math.pi / 180.0
    j2 = l2 * k * np.column_stack([-np.sin(ab), np.cos(ab)])
    j1 = l1 * k * np.column_stack([-np.sin(a), np.cos(a)]) + j2
    return j1, j2, u1, u2


def _stack(vec2: np.ndarray, f: np.ndarray | None = None) -> np.ndarray:
    """(2N, m): a (N,2) displacement column times each feature column of f (N,m)."""
    if f is None:
        return vec2.reshape(-1, 1)
    return (vec2[:, :, None] * f[:, None, :]).reshape(-1, f.shape[1])


def _base(d: DiagData, cmd: np.ndarray) -> tuple[np.ndarray, tuple]:
    j1, j2, u1, u2 = jacobian_cols(d.geometry.l1_mm, d.geometry.l2_mm, cmd)
    n = len(cmd)
    ex = np.tile([1.0, 0.0], (n, 1))
    ey = np.tile([0.0, 1.0], (n, 1))
    return np.column_stack([_stack(v) for v in (j1, j2, u1, u2, ex, ey)]), (j1, j2)


def _scaled(x: np.ndarray) -> np.ndarray:
    s = float(np.std(x))
    return (x - float(np.mean(x))) / (s if s > 0 else 1.0)


def lstsq(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares b of y ≈ X·b for a tall X of a few dozen columns (minimum-norm when
    the columns are dependent): the normal equations of the column-scaled X, formed with
    einsum and solved through the eigen-decomposition of the small Gram matrix, directions
    below 1e-12 of the largest eigenvalue left out. Only the Gram matrix (at most a few
    dozen columns square) goes to LAPACK: a tall matrix handed to numpy's lstsq runs
    threaded BLAS kernels whose idle threads spin when more than one BLAS thread is
    allowed (:mod:`cell` allows one unless the environment says otherwise)."""
    s = np.sqrt(np.einsum("ij,ij->j", X, X))
    s = np.where(s > 0, s, 1.0)
    Xs = X / s
    lam, V = np.linalg.eigh(np.einsum("ij,ik->jk", Xs, Xs))
    keep = lam > 1e-12 * max(lam[-1], 1e-300)
    g = V.T @ np.einsum("ij,i->j", Xs, y)
    b = V[:, keep] @ (g[keep] / lam[keep])
    return b / s


def _fit(X: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(RSS, R²) of the least-squares fit y ≈ X·b."""
    tot = float(y @ y)
    b = lstsq(X, y)
    e = y - np.einsum("ij,j->i", X, b)
    rss = float(e @ e)
    return rss, (1.0 - rss / tot) if tot > 0 else 0.0


def _poly3(xy: np.ndarray) -> np.ndarray:
    x, y = _scaled(xy[:, 0]), _scaled(xy[:, 1])
    f = np.column_stack([x, y, x * x, x * y, y * y, x ** 3, x * x * y, x * y * y, y ** 3])
    n = len(xy)
    ex = np.tile([1.0, 0.0], (n, 1))
    ey = np.tile([0.0, 1.0], (n, 1))
    return np.column_stack([_stack(ex, f), _stack(ey, f)])


def static_view(d: DiagData, r_points: np.ndarray, r_paths: np.ndarray):
    """(cmd, dirs, xy_nominal, time, temp, payload, residual) of the static rows: the points,
    or, for a paths-only campaign, the path samples."""
    if d.points is not None:
        p = d.points
        return p.cmd, p.dirs, p.xy - r_points, p.time, p.temp, p.payload, r_points
    cmd = d.path_cat("cmd")
    dirs = np.concatenate([fx.path_directions(m.cmd, m.dirs0) for m in d.moves])
    return cmd, dirs, d.path_cat("xy") - r_paths, d.path_cat("t"), None, None, r_paths


def analyse(d: DiagData, r_points: np.ndarray, r_paths: np.ndarray, keep=None) -> Where:
    """Effect sizes and ``depends_on`` of the residual (module docstring); all rows, or
    those ``keep`` = (points mask, path samples mask) marks (outliers left out)."""
    cmd, dirs, xy, t, temp, payload, r = static_view(d, r_points, r_paths)
    kq = None
    if keep is not None:
        kp, kq = (np.asarray(k, bool) for k in keep)
        m = kp if d.points is not None else kq
        cmd, dirs, xy, t, r = cmd[m], dirs[m], xy[m], t[m], r[m]
        temp = None if temp is None else np.asarray(temp)[m]
        payload = None if payload is None else np.asarray(payload)[m]
    y = r.ravel()
    n2 = y.size
    ms = float(np.mean(np.sum(r ** 2, axis=1))) if len(r) else 0.0
    B, (j1, j2) = _base(d, cmd)
    models: list[tuple[str, str | None, np.ndarray]] = []
    for jn, J in (("j1", j1), ("j2", j2)):
        ji = 0 if jn == "j1" else 1
        th = cmd[:, ji]
        models.append(("constant", jn, _stack(J)))
        for k in ANGLE_ORDERS:            # a harmonic of k cycles per revolution
            models.append(("angle", jn, _stack(J, np.column_stack(
                [np.ones(len(th)), th / 100.0, np.sin(k * np.radians(th)),
                 np.cos(k * np.radians(th))]))))
        if set(distinct(dirs[:, ji])) >= {-1.0, 1.0}:
            models.append(("direction", jn, _stack(J, np.column_stack([np.ones(len(th)),
                                                                      dirs[:, ji]]))))
    models.append(("position", None, B))
    models.append(("position", None, np.column_stack([B, _poly3(xy)])))

    def scalar_model(name, v, powers):
        if v is not None and np.std(v) > 0:
            vs = _scaled(v)
            models.append((name, None, np.column_stack([B] + [B * np.repeat(vs ** p, 2)[:, None]
                                                              for p in powers])))
    scalar_model("temperature", temp, (1,))
    scalar_model("time", t, (1, 2))
    scalar_model("payload", payload, (1,))
    if d.points is None and d.moves:   # paths-only: speed competes on the same rows
        vel = _velocities(d) if kq is None else _velocities(d)[kq]
        models.append(("speed", None, np.column_stack([B, _stack(j1 * vel[:, :1]),
                                                       _stack(j2 * vel[:, 1:])])))
    sizes: dict[str, dict] = {}
    best = None
    for name, jn, X in models:
        if X.shape[0] <= X.shape[1] + 1:
            continue
        rss, r2 = _fit(X, y)
        bic = n2 * math.log(max(rss / n2, 1e-30)) + X.shape[1] * math.log(n2)
        if name not in sizes or r2 > sizes[name]["r2"]:
            sizes[name] = {"r2": round(max(r2, 0.0), 4), "rms_mm": math.sqrt(max(r2, 0.0) * ms),
                           "joint": jn}
        if name in SPEC_DEPENDS and (best is None or bic < best[0]):
            best = (bic, name, jn, r2 * ms)
    depends, joint = (best[1], best[2]) if best else ("constant", None)
    sp = speed_effect(d, r_paths, kq) if d.points is not None else None
    if sp is not None:
        sizes["speed"] = sp
        if best is None or sp["explained_ms"] > best[3]:
            depends, joint = "speed", None
    return Where(depends, joint, sizes, per_joint_rms(d, cmd, r), math.sqrt(ms))


def speed_effect(d: DiagData, r_paths: np.ndarray, keep=None) -> dict | None:
    """R² of the path residual explained by J_j·θ̇_j beyond a smooth static field (on the
    samples ``keep`` marks, all by default)."""
    m = np.ones(len(r_paths), bool) if keep is None else np.asarray(keep, bool)
    if not d.moves or int(m.sum()) < 30:
        return None
    cmd = d.path_cat("cmd")[m]
    vel = _velocities(d)[m]
    B, (j1, j2) = _base(d, cmd)
    r_paths = r_paths[m]
    xy = d.path_cat("xy")[m] - r_paths
    X0 = np.column_stack([B, _poly3(xy)])
    X1 = np.column_stack([X0, _stack(j1 * vel[:, :1]), _stack(j2 * vel[:, 1:])])
    y = r_paths.ravel()
    rss0, _ = _fit(X0, y)
    rss1, _ = _fit(X1, y)
    tot = float(y @ y)
    inc = (rss0 - rss1) / tot if tot > 0 else 0.0
    ms = tot / len(r_paths)
    return {"r2": round(max(inc, 0.0), 4), "rms_mm": math.sqrt(max(inc, 0.0) * ms), "joint": None,
            "explained_ms": max(inc, 0.0) * ms}


def _velocities(d: DiagData) -> np.ndarray:
    """Commanded joint velocities (n_path, 2) deg/s along the moves."""
    return np.concatenate([np.gradient(m.cmd, m.t, axis=0) if len(m.t) > 1
                           else np.zeros((len(m.t), 2)) for m in d.moves])


def per_joint_rms(d: DiagData, cmd: np.ndarray, r: np.ndarray) -> dict:
    """rms (deg) of the residual mapped to joint space, rows at |sin θ2| > 0.15 only."""
    j1, j2, _, _ = jacobian_cols(d.geometry.l1_mm, d.geometry.l2_mm, cmd)
    ok = np.abs(np.sin(np.radians(cmd[:, 1]))) > 0.15
    if not ok.any():
        return {"j1": None, "j2": None}
    J = np.stack([j1[ok], j2[ok]], axis=2)          # (n, 2 axes, 2 joints)
    dq = np.linalg.solve(J, r[ok][:, :, None])[:, :, 0]
    return {"j1": float(np.sqrt(np.mean(dq[:, 0] ** 2))), "j2": float(np.sqrt(np.mean(dq[:, 1] ** 2)))}
