"""Gross outliers of a chain campaign, found on the best candidate's residual and set
aside. Pure numerics; no I/O.

A tracker now and then reports one marker millimetres off (a reflection, a marker
swapped for its neighbour). One such point among a few hundred at a few hundredths of a
millimetre makes every fit error look far above the noise, so without this step a
campaign with no error at all comes back ``unexplained``.

* **What is compared**: each measured point's 3-D residual (measured − predicted) under
  the candidate that predicts left-out poses best (:func:`reference`; registration alone
  when no candidate exists), fit and holdout points alike, against the median residual
  of the fit points.
* **Scale**: σ per axis = 1.4826 × the median absolute deviation of the fit points'
  residual components about that median (unaffected by up to half the points being
  outliers), taken at its 95 % upper bound (:func:`cell.diagnosis.noise.upper95`) so that
  few points do not make a tight scale. Static poses and the samples of measured moves
  (:func:`tables`) each have their own median, scale and threshold, as the planar
  diagnosis keeps points and paths apart: a static arrival carries the arm's
  repeatability, a sample of a move at its commanded angles does not.
* **Threshold**: a point is an outlier when its squared distance from the median exceeds
  σ² × the χ²₃ quantile at :data:`ALPHA` / (points of fit and holdout), i.e. a Gaussian
  point is flagged anywhere in the campaign with probability ≤ :data:`ALPHA` (Bonferroni;
  about 5.2 σ for 250 points).
* **A minority only**: when more than :data:`MAX_SHARE` of the fit (or of the holdout)
  points lie beyond the threshold, the residual is heavy-tailed or systematic (an effect
  the vocabulary lacks), not a few glitches; none of that set is set aside and the report
  warns. Points of a free marker are kept when setting them aside would leave the marker
  on fewer than :data:`cell.measurements.chain.MIN_MARKER_POSES` fit poses.

:func:`robust_search` searches (:func:`cell.diagnosis.chain.rank.search`), flags, searches again
without the flagged points and flags again from the new best candidate (a point set aside
earlier can come back), until the flags no longer change, at most :data:`ROUNDS` times.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cell.diagnosis.chain import fit as F
from cell.diagnosis.chain import rank
from cell.diagnosis.noise import MAD_EFFICIENCY, mad, upper95
from cell.measurements.chain import MIN_MARKER_POSES
from cell.numerics.stats import chi2_isf, distinct, median

ALPHA = 0.01          # a Gaussian point is flagged anywhere in the campaign with this probability
MAX_SHARE = 0.05      # more flagged than this share of a set: systematic, none set aside
ROUNDS = 3            # search → flag rounds at most
MIN_POINTS = 12       # fewer fit points: no robust scale


@dataclass
class Outliers:
    """Flags over the points of ``fit_d`` / ``hold_d`` (True = outlier, set aside), their
    distance from the median residual ``dist_fit`` / ``dist_hold`` (mm), robust ``sigma``
    per axis (mm), the ``threshold`` in σ, ``cut_mm`` (threshold × σ's 95 % upper bound),
    whether each set's flags were ``set_aside`` (False: too many, see :data:`MAX_SHARE`),
    the ``rounds`` run, and ``notes`` / ``warnings`` for the report."""

    fit: np.ndarray
    hold: np.ndarray
    dist_fit: np.ndarray | None = None
    dist_hold: np.ndarray | None = None
    sigma: float | None = None
    threshold: float | None = None
    cut_mm: float | None = None
    set_aside: tuple[bool, bool] = (True, True)
    scales: dict = field(default_factory=dict)    # table → (sigma, threshold, cut_mm)
    rounds: int = 0
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return int(self.fit.sum() + self.hold.sum())

    def same_flags(self, other: "Outliers") -> bool:
        return np.array_equal(self.fit, other.fit) and np.array_equal(self.hold, other.hold)


def none_flagged(fit_d: F.Data, hold_d: F.Data) -> Outliers:
    return Outliers(np.zeros(len(fit_d.xyz), bool), np.zeros(len(hold_d.xyz), bool))


def reference(s: rank.Search) -> F.Fit:
    """The fit whose residual is searched for outliers: the candidate with the lowest
    leave-out error of search ``s``, else registration alone."""
    return s.ranking[0].fit if s.ranking else s.nominal.fit


def _keep_markers(d: F.Data, out: np.ndarray) -> np.ndarray:
    """``out`` with the flags of a free marker cleared when setting them aside would
    leave it on fewer than MIN_MARKER_POSES poses."""
    if d.known_markers is not None or not out.any():
        return out
    out = out.copy()
    for m in distinct(d.obs_marker[out]):
        left = distinct(d.obs_pose[(d.obs_marker == m) & ~out])
        if len(left) < MIN_MARKER_POSES:
            out[d.obs_marker == m] = False
    return out


def tables(d: F.Data) -> np.ndarray:
    """Each point's table: 0 a static pose, 1 a sample of a measured move (a planar
    campaign's paths.csv read as poses, which a repeatability that only static arrivals
    carry does not touch)."""
    if d.move is None:
        return np.zeros(len(d.xyz), dtype=np.int64)
    return (d.move[d.obs_pose] >= 0).astype(np.int64)


TABLES = ("static", "moves")


def flag(fit_d: F.Data, hold_d: F.Data, f: F.Fit) -> Outliers:
    """The outliers of the residual of fit ``f`` (module docstring) over every point of
    ``fit_d`` and ``hold_d`` (``f`` may have been fitted without some of them). Static
    poses and the samples of measured moves are judged each on their own median and
    scale (:func:`tables`): the two scatter differently, and one scale would flag the
    wider table's tail."""
    out = none_flagged(fit_d, hold_d)
    if len(fit_d.xyz) < MIN_POINTS:           # no table can have a robust scale
        return out
    ef = fit_d.xyz - F.model(fit_d, f.reg, f.params, f.values)[0]
    eh = hold_d.xyz - F.model(hold_d, f.reg, f.params, f.values)[0] if len(hold_d.xyz) else \
        np.zeros((0, fit_d.dims))
    tf, th = tables(fit_d), tables(hold_d)
    moved = bool(np.any(tf == 1) or np.any(th == 1))
    far_f, far_h = np.zeros(len(ef), bool), np.zeros(len(eh), bool)
    out.dist_fit, out.dist_hold = np.zeros(len(ef)), np.zeros(len(eh))
    aside = [True, True]
    for t, table in enumerate(TABLES):
        mf, mh = tf == t, th == t
        if mf.sum() < MIN_POINTS:
            continue
        med = median(ef[mf], axis=0)
        s = mad(ef[mf] - med)
        if not s > 0:
            continue
        su = upper95(s, MAD_EFFICIENCY * ef[mf].size)
        q = math.sqrt(float(chi2_isf(ALPHA / (mf.sum() + mh.sum()), fit_d.dims)))
        out.dist_fit[mf] = np.linalg.norm(ef[mf] - med, axis=1)
        out.dist_hold[mh] = np.linalg.norm(eh[mh] - med, axis=1)
        out.scales[table] = (s, q, q * su)
        if out.sigma is None:
            out.sigma, out.threshold, out.cut_mm = s, q, q * su
        for k, (mask, dist, far, name) in enumerate(((mf, out.dist_fit, far_f, "fit"),
                                                     (mh, out.dist_hold, far_h, "holdout"))):
            beyond = dist[mask] > q * su
            what = f"{name} points" + (f" of the {'static poses' if t == 0 else 'measured moves'}"
                                       if moved else "")
            if len(beyond) and beyond.mean() > MAX_SHARE:
                aside[k] = False
                out.warnings.append(
                    f"{100 * beyond.mean():.0f} % of the {what} lie beyond {q:.1f} σ of the best "
                    f"candidate's residual (σ {s:.4f} mm per axis): heavy tails or an effect outside the "
                    f"vocabulary, not a few glitches; none set aside (at most {100 * MAX_SHARE:.0f} % are)")
                continue
            far[mask] = beyond
    if aside[0]:
        out.fit = _keep_markers(fit_d, far_f)
    if aside[1]:
        out.hold = far_h
    out.set_aside = (aside[0], aside[1])
    return out


def robust_search(fit_d: F.Data, hold_d: F.Data, **kw) -> tuple[rank.Search, Outliers, rank.Search]:
    """(the search (:func:`cell.diagnosis.chain.rank.search`, ``kw`` passed on) on the points that
    are not outliers, its :class:`Outliers`, the search on every point)."""
    s = first = rank.search(fit_d, hold_d, **kw)
    o = none_flagged(fit_d, hold_d)
    for i in range(ROUNDS):
        new = flag(fit_d, hold_d, reference(s))
        new.rounds = i + 1
        settled = new.same_flags(o)
        o = new
        if settled:
            break
        s = rank.search(fit_d.keep_points(~o.fit), hold_d, hold_keep=~o.hold, **kw)
    else:
        o.notes.append(f"the outlier flags did not settle in {ROUNDS} rounds; the last are used")
    if o.n and first.ranking and s.ranking and first.ranking[0].label != s.ranking[0].label:
        o.notes.append(f"with the outliers kept, {first.ranking[0].label} predicted left-out poses "
                       f"best; without them, {s.ranking[0].label}")
    return s, o, first


def describe(o: Outliers, fit_d: F.Data, hold_d: F.Data, pose_ids, fit_poses, hold_poses,
             markers) -> dict:
    """JSON-ready summary (``cell/measurements.md``, chain ``outliers``): every flagged
    point's ``sample``, ``marker``, ``split`` and distance from the median residual
    (``distance_mm``); the scale, threshold and cut; per set whether its flags were set
    aside. ``fit_poses`` / ``hold_poses`` map each set's pose index to the campaign's."""
    pts = []
    for d, mask, dist, poses, split in ((fit_d, o.fit, o.dist_fit, fit_poses, "fit"),
                                        (hold_d, o.hold, o.dist_hold, hold_poses, "holdout")):
        for i in np.flatnonzero(mask):
            pts.append({"sample": int(pose_ids[poses[d.obs_pose[i]]]),
                        "marker": int(markers[d.obs_marker[i]]), "split": split,
                        "distance_mm": _r(dist[i])})
    pts.sort(key=lambda p: (p["sample"], p["marker"]))
    return {"n": len(pts), "points": pts, "sigma_mm": _r(o.sigma), "threshold_sigma": _r(o.threshold, 3),
            "cut_mm": _r(o.cut_mm), "set_aside": {"fit": o.set_aside[0], "holdout": o.set_aside[1]},
            "alpha": ALPHA, "max_share": MAX_SHARE, "rounds": o.rounds,
            "notes": list(o.notes) + list(o.warnings)}


def _r(v, nd: int = 6):
    return None if v is None or not math.isfinite(v) else round(float(v), nd)
