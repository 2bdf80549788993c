"""The v1 report's figures of a planar campaign, from any model's residual on its rows
(``cell/measurements.md``, "Format version 1.3"): the per-table summaries, how many places
the fit rows cover, the point noise estimates, and what the gap or a remainder varies with.
:mod:`cell.diagnosis.chain.planar` computes them from the one diagnosis's fits. Pure
numerics.

**Spread.** A cause is only as well supported as the places it was measured at. Poses
closer in joint space than the angle over which the fastest response of the vocabulary
turns by a radian are one place for telling causes apart; the fit rows must cover at least
half as many places as a smooth displacement field (a cubic in (x, y) per axis, 20
columns) has columns, and determine that field (column-scaled condition number at most
:data:`MAX_COND`). Fewer (clustered poses) and the campaign cannot tell causes apart
reliably nor check the remainder.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.diagnosis import noise as noise_mod
from cell.diagnosis import where as where_mod
from cell.diagnosis.jacobian import rows_of
from cell.diagnosis.replay import DiagData, PointsData
from cell.kinematics import planar_xy
from cell.numerics.stats import distinct

MAX_COND = 1e4       #: a column-scaled condition number beyond: the field is not determined
Z95 = 1.959963984540054


def _r(v, nd: int = 6):
    if v is None:
        return None
    return float(round(v, nd)) if math.isfinite(v) else v


def subset(d: DiagData, which: str) -> DiagData:
    """The fit (``which="fit"``) or holdout rows of ``d`` as a DiagData of their own."""
    want = which == "fit"
    pts = None
    if d.points is not None:
        p, m = d.points, d.points.fit == want
        if m.any():
            pts = PointsData(p.cmd[m], p.dirs[m], p.time[m],
                             None if p.temp is None else p.temp[m],
                             None if p.payload is None else p.payload[m], p.xy[m], p.fit[m],
                             p.sample[m], p.has_dirs)
    moves = [mv for mv in d.moves if mv.fit == want]
    return DiagData(d.geometry, d.center, d.stations, d.order, pts, moves, d.split_source,
                    d.source)


@dataclass
class TableStats:
    """Per-table residual summary: ``n`` rows, ``rms`` / ``max`` of the residual norm, mm."""

    n: int
    rms: float
    max: float

    @staticmethod
    def of(r: np.ndarray) -> "TableStats":
        if len(r) == 0:
            return TableStats(0, 0.0, 0.0)
        nrm = np.hypot(r[:, 0], r[:, 1])
        return TableStats(len(r), float(np.sqrt(np.mean(nrm ** 2))), float(nrm.max()))


def combined(a: TableStats, b: TableStats) -> TableStats:
    """The summary of two tables' rows together."""
    n = a.n + b.n
    if n == 0:
        return TableStats(0, 0.0, 0.0)
    return TableStats(n, math.sqrt((a.n * a.rms ** 2 + b.n * b.rms ** 2) / n), max(a.max, b.max))


def table_stats(t: TableStats) -> dict:
    """``n``, ``rms_mm``, ``max_mm`` of one table's residual (``gap.points``, ``gap.paths``)."""
    return {"n": t.n, "rms_mm": _r(t.rms), "max_mm": _r(t.max)}


def spread(fit_d: DiagData, max_order: int = 4) -> dict:
    """How many distinct places the fit rows cover (module docstring): ``places`` occupied
    cells of a grid of ``cell_deg`` = 360°/(2π·``max_order``) in (θ1, θ2) (the angle over
    which the fastest response of the vocabulary, the highest harmonic order, turns by a
    radian: closer poses are one place for telling causes apart), ``distinct_poses``
    (distinct commanded joint pairs), ``cond`` (column-scaled condition number of the
    20-column smooth field at the rows' nominal positions), ``rows``, and ``few`` (True
    when the places cannot determine that field: fewer than 10, or ``cond`` above
    :data:`MAX_COND`)."""
    rows = rows_of(fit_d)
    cell = 360.0 / (2 * math.pi * max_order)
    if rows.n == 0:
        return {"places": 0, "cell_deg": cell, "cond": math.inf, "distinct_poses": 0,
                "rows": 0, "few": True}
    cmd = rows.cmd
    xy = planar_xy(rows.links[0], rows.links[1], cmd)
    X = np.column_stack([where_mod._poly3(xy), np.tile(np.eye(2), (len(xy), 1))])
    nrm = np.sqrt(np.einsum("ij,ij->j", X, X))
    if np.any(nrm <= 0) or X.shape[0] < X.shape[1]:
        cond = math.inf
    else:
        Xn = X / nrm
        ev = np.linalg.eigvalsh(np.einsum("ij,ik->jk", Xn, Xn))     # σ² of Xn (no threads)
        cond = math.sqrt(ev[-1] / ev[0]) if ev[0] > 0 else math.inf
    places = len(distinct(np.floor(cmd / cell), axis=0))
    n_distinct = len(distinct(np.round(cmd, 6), axis=0))
    few = places < X.shape[1] // 2 or not cond <= MAX_COND
    return {"places": int(places), "cell_deg": round(cell, 4), "cond": cond,
            "distinct_poses": int(n_distinct), "rows": int(rows.n), "few": bool(few)}


def point_estimates(d: DiagData, r_points: np.ndarray | None, keep_points,
                    noise_mm: float | None, path_sigma: float | None
                    ) -> tuple[noise_mod.Noise | None, dict]:
    """(the best point noise, every estimate by source) from the remainder ``r_points``
    (N, 2) mm of a model on ``d``'s static points, those ``keep_points`` marks (not
    outliers); ``noise_mm`` the given σ, ``path_sigma`` the paths' (:mod:`.noise`)."""
    est: dict = {}
    if noise_mm:
        est["given"] = noise_mod.given(noise_mm)
    p = d.points
    if p is not None:
        k = np.asarray(keep_points, bool)
        r = r_points[k]
        rep = noise_mod.repeats(p.cmd[k], p.dirs[k] if p.has_dirs else None, r)
        res = noise_mod.residual(p.cmd[k], p.time[k], r, (d.geometry.l1_mm, d.geometry.l2_mm))
        if rep is not None:
            est["repeats"] = rep
        if res is not None:
            est["residual"] = res
    pth = noise_mod.from_paths(path_sigma, d.n_path)
    if pth is not None:
        est["paths"] = pth
    return noise_mod.best(*est.values()), est


def remainder_where(w: where_mod.Where | None) -> dict:
    """``remainder``'s ``depends_on``, ``joint``, ``rms_mm``: what the remainder of the named
    cause varies with (:func:`.where.analyse`), all None when it was not analysed."""
    return {"depends_on": w.depends_on if w else None, "joint": w.joint if w else None,
            "rms_mm": _r(w.rms_mm) if w else None}


def where_figures(wh: where_mod.Where) -> dict:
    """The ``gap.where`` figures beyond the spec's: ``depends_on_joint``, ``effect_sizes``
    and ``per_joint_rms_deg`` of :func:`.where.analyse`."""
    return {"depends_on_joint": wh.joint,
            "effect_sizes": {k: {kk: (_r(vv) if isinstance(vv, float) else vv)
                                 for kk, vv in v.items() if kk != "explained_ms"}
                             for k, v in wh.effect_sizes.items()},
            "per_joint_rms_deg": {k: (None if v is None else _r(v, 7))
                                  for k, v in wh.per_joint_rms_deg.items()}}
