"""Outliers (misdetections) and the spread of the fit rows. Pure numerics.

**Outliers.** A camera that now and then locks onto the wrong blob gives a few rows that
are off by far more than the noise. They are found on the remainder of a model (the
decision's cause, else the best identifiable single, else the nominal model), per table
(points, path samples), at a threshold the data set:

* what is compared: each row's remainder minus the leave-one-out local plane through its
  :data:`NEIGHBOURS` nearest neighbours (points: in joint space; path samples: in time
  along their move), scaled by √(1 + ΣW²) to the noise's σ. A misdetection stands out
  from its neighbours; a remainder that varies smoothly (an effect the model lacks) does
  not, and is left to the unexplained test. A flagged row is left out of the others'
  planes and the flags computed again (at most :data:`PASSES` times);
* scale: σ per axis = 1.4826 × the median absolute deviation of those values (both axes,
  fit and holdout rows pooled; unaffected by up to half the rows being outliers), taken at
  its 95 % upper bound (:func:`.noise.upper95`) so that few rows do not make a tight scale;
* threshold: a row is an outlier when its squared distance from the median exceeds
  σ² × the χ²₂ quantile at :data:`ALPHA` / (rows in the table), i.e. over the whole table
  a Gaussian row is flagged with probability ≤ :data:`ALPHA` (about 4.5 σ for 300 rows);
* outliers must be a minority: when more than :data:`MAX_SHARE` of a table's fit rows lie
  beyond the threshold, the remainder is heavy-tailed or systematic (an effect the model
  lacks), not a few misdetections, and nothing in that table is set aside (a note says so).

The search (:mod:`.rank`) refits without the flagged fit rows and flags again from the new
model (a row set aside earlier can come back) until the flags no longer change. Holdout
rows are flagged with the same scale and threshold; the holdout figures of the report stay
on all rows, the honesty tests use the rows that are not outliers.

**Spread.** A cause is only as well supported as the places it was measured at. Poses
closer in joint space than the angle over which the fastest response of the vocabulary
turns by a radian are one place for telling causes apart; the fit rows must cover at least
half as many places as the smooth displacement field of the unexplained test (:mod:`.rank`:
a cubic in (x, y) per axis, 20 columns) has columns, and determine that field (column-scaled
condition number at most :data:`cell.diagnosis.screen.MAX_COND`). Fewer (clustered poses)
and the report warns that causes cannot be told apart reliably nor the remainder checked.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cell.diagnosis import noise as noise_mod
from cell.diagnosis import where as where_mod
from cell.diagnosis.jacobian import evaluate, rows_of
from cell.diagnosis.replay import DiagData
from cell.kinematics import planar_xy
from cell.numerics.stats import chi2_isf, distinct, median

ALPHA = 0.01
MAX_SHARE = 0.25
MIN_ROWS = 10
NEIGHBOURS = 16
PASSES = 4


@dataclass
class Outliers:
    """Flags of one model's remainder: ``fit`` / ``hold`` (rows,) bool (True = outlier), in
    the row order of :func:`.jacobian.rows_of` (points, then path samples); per table
    (points, paths): robust ``sigma`` per axis mm, ``threshold`` in σ, ``cut_mm`` the
    distance from the local plane beyond which a row is flagged (threshold × σ's 95 %
    upper bound), ``set_aside``
    (False when the table's share exceeded :data:`MAX_SHARE`); ``notes``."""

    fit: np.ndarray
    hold: np.ndarray
    sigma: tuple = (None, None)
    threshold: tuple = (None, None)
    cut_mm: tuple = (None, None)
    set_aside: tuple = (True, True)
    notes: list = field(default_factory=list)

    @property
    def keep_fit(self) -> np.ndarray:
        return ~self.fit

    @property
    def keep_hold(self) -> np.ndarray:
        return ~self.hold


def none_flagged(fit_d: DiagData, hold_d: DiagData) -> Outliers:
    return Outliers(np.zeros(rows_of(fit_d).n, bool), np.zeros(rows_of(hold_d).n, bool))


def _local_residual(coords: np.ndarray, r: np.ndarray, use: np.ndarray) -> np.ndarray:
    """r (n,2) minus its leave-one-out local plane through :data:`NEIGHBOURS` neighbours
    at ``coords`` taken among the rows ``use`` marks, scaled to the noise's σ
    (÷ √(1 + ΣW²))."""
    nb = noise_mod.neighbours(coords, min(NEIGHBOURS, int(np.sum(use)) - 1), use)
    W = noise_mod.plane_weights(coords, nb)
    e = r - np.einsum("nk,nkc->nc", W, r[nb])
    return e / np.sqrt(1.0 + np.sum(W ** 2, axis=1))[:, None]


def _path_coords(d: DiagData) -> np.ndarray:
    """(n_path, 1): time along each move, the moves far apart (neighbours stay in a move)."""
    if not d.moves:
        return np.zeros((0, 1))
    span = max(float(m.t[-1] - m.t[0]) for m in d.moves if len(m.t)) + 1.0
    return np.concatenate([m.t - m.t[0] + 10.0 * span * i for i, m in enumerate(d.moves)])[:, None]


def flag(fit_d: DiagData, hold_d: DiagData, effects, path_temp_c=None) -> Outliers:
    """The outliers of the remainder of ``effects`` (module docstring)."""
    rf, rh = rows_of(fit_d), rows_of(hold_d)
    ef = rf.meas - evaluate(rf, effects, path_temp_c)[0]
    eh = rh.meas - evaluate(rh, effects, path_temp_c)[0]
    out = none_flagged(fit_d, hold_d)
    sig, thr, cut, aside = [None, None], [None, None], [None, None], [True, True]
    coords = ((np.vstack([rf.cmd[:rf.n_points], rh.cmd[:rh.n_points]]),
               np.vstack([_path_coords(fit_d), _path_coords(hold_d) + 1e9])))
    for t, (sf, sh, name) in enumerate(((slice(0, rf.n_points), slice(0, rh.n_points), "points"),
                                        (slice(rf.n_points, rf.n), slice(rh.n_points, rh.n),
                                         "path samples"))):
        a, b = ef[sf], eh[sh]
        if len(a) < MIN_ROWS or len(a) + len(b) <= NEIGHBOURS + 1:
            continue
        r = np.vstack([a, b])
        q = math.sqrt(float(chi2_isf(ALPHA / len(r), 2)))
        far = np.zeros(len(r), bool)
        for _ in range(PASSES):   # a spike spoils its neighbours' planes: leave it out of them
            z = _local_residual(coords[t], r, ~far)
            zk = z[~far]
            med = median(zk, axis=0)
            s = noise_mod.mad(zk)
            if not s > 0:
                break
            su = noise_mod.upper95(s, noise_mod.MAD_EFFICIENCY * zk.size)
            new = np.sum((z - med) ** 2, axis=1) > (q * su) ** 2
            if np.array_equal(new, far):
                break
            far = new
        if not s > 0:
            continue
        fa, fb = far[:len(a)], far[len(a):]
        sig[t], thr[t], cut[t] = s, q, q * su
        if fa.mean() > MAX_SHARE:
            aside[t] = False
            out.notes.append(f"{100 * fa.mean():.0f} % of the fit {name} lie beyond {q:.1f} σ "
                             f"(σ {s:.4f} mm): heavy tails or an effect the model lacks, not a "
                             "few misdetections; none set aside")
            continue
        out.fit[sf] = fa
        out.hold[sh] = fb
    out.sigma, out.threshold, out.set_aside = tuple(sig), tuple(thr), tuple(aside)
    out.cut_mm = tuple(cut)
    return out


def describe(o: Outliers, fit_d: DiagData, hold_d: DiagData) -> dict:
    """JSON-ready summary: counts, the sample ids of outlying points, (move, time_s) of
    outlying path samples, the scale, threshold and cut per table."""
    pts, path = [], []
    for d, mask in ((fit_d, o.fit), (hold_d, o.hold)):
        rows = rows_of(d)
        if d.points is not None:
            pts += [int(s) for s in np.asarray(d.points.sample)[mask[:rows.n_points]]]
        k = rows.n_points
        for m in d.moves:
            sel = mask[k:k + len(m.t)]
            path += [[int(m.move), round(float(t), 6)] for t in m.t[sel]]
            k += len(m.t)
    return {"n": len(pts) + len(path),
            "points": {"n": len(pts), "samples": sorted(pts),
                       "sigma_mm": _r(o.sigma[0]), "threshold_sigma": _r(o.threshold[0], 3),
                       "cut_mm": _r(o.cut_mm[0]),
                       "set_aside": o.set_aside[0]},
            "paths": {"n": len(path), "samples": sorted(path),
                      "sigma_mm": _r(o.sigma[1]), "threshold_sigma": _r(o.threshold[1], 3),
                      "cut_mm": _r(o.cut_mm[1]),
                      "set_aside": o.set_aside[1]},
            "alpha": ALPHA, "max_share": MAX_SHARE, "notes": list(o.notes)}


def _r(v, nd: int = 6):
    return None if v is None else round(float(v), nd)


def spread(fit_d: DiagData, max_order: int = 4) -> dict:
    """How many distinct places the fit rows cover (module docstring): ``places`` occupied
    cells of a grid of ``cell_deg`` = 360°/(2π·``max_order``) in (θ1, θ2) (the angle over
    which the fastest response of the vocabulary, the highest harmonic screened, turns by a
    radian: closer poses are one place for telling causes apart), ``distinct_poses``
    (distinct commanded joint pairs), ``cond`` (column-scaled condition number of the
    20-column smooth field at the rows' nominal positions), ``rows``, and ``few`` (True
    when the places cannot determine that field: fewer than 10, or ``cond`` above
    :data:`cell.diagnosis.screen.MAX_COND`)."""
    from cell.diagnosis.screen import MAX_COND
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


def keep_all(d: DiagData, o: Outliers) -> tuple[np.ndarray, np.ndarray]:
    """(points (N,), path samples (n_path,)) bool masks over all rows of ``d`` (fit and
    holdout, in ``d``'s order): True for the rows that are not outliers."""
    kp = np.ones(d.n_points, bool)
    n_fit_pts = int(d.points.fit.sum()) if d.points is not None else 0
    n_hold_pts = d.n_points - n_fit_pts
    if d.points is not None:
        kp[d.points.fit] = o.keep_fit[:n_fit_pts]
        kp[~d.points.fit] = o.keep_hold[:n_hold_pts]
    parts, kf, kh = [], n_fit_pts, n_hold_pts
    for m in d.moves:
        n = len(m.t)
        if m.fit:
            parts.append(o.keep_fit[kf:kf + n])
            kf += n
        else:
            parts.append(o.keep_hold[kh:kh + n])
            kh += n
    kq = np.concatenate(parts) if parts else np.zeros(0, bool)
    return kp, kq
