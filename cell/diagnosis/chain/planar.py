"""The v1 (SCARA) report's figures in the chain diagnosis of a planar campaign read as a
chain (:func:`cell.measurements.chain.planar_as_chain`), so that the report of a planar
campaign carries the v1 report's keys with their v1 meaning (``cell/measurements.md``,
"Format version 1.3").

Every figure is computed from the chain diagnosis's own fits: the registration-only fit
(the nominal model: a planar reading's registration has no parameters) and the named
cause, evaluated on every pose, whose residuals are split back into the campaign's
points and path samples by :class:`~cell.measurements.chain.PlanarRows`. The planar
helpers that work on any residual do the rest, on the planar campaign's own arrays
(:func:`cell.diagnosis.replay.prepare`): where the gap lies (:mod:`cell.diagnosis.where`),
the per-station lags (:mod:`cell.diagnosis.delay`, on the path samples less the named
cause's static part), the point noise estimates (:mod:`cell.diagnosis.noise`), the spread
of the fit rows. What cannot mean the same (the BIC-based test, the counts of the planar
search this diagnosis replaced, its unexplained test's ratios) is left out;
``cell/measurements.md`` lists it. Pure numerics.
"""
from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from cell.diagnosis import delay as delay_mod
from cell.diagnosis import where as where_mod
from cell.diagnosis.chain import fit as F
from cell.diagnosis.chain import rank
from cell.diagnosis.chain.robust import Outliers
from cell.diagnosis.figures import (TableStats, combined, point_estimates, remainder_where,
                                    spread as fit_spread, subset, table_stats)
from cell.diagnosis.replay import DiagData, path_noise_mm, prepare
from cell.measurements import CampaignFormatError
from cell.measurements.chain import ChainCampaign, PlanarRows

COMMS = "comm_delay"     # the chain effect whose parameters are the lags, not a static part
#: a chain harmonic's coefficient: joint, stem (``cyclic{n}`` or ``motor_cyclic``), n, part
HARMONIC = re.compile(r"^(j\d+)_(cyclic(\d+)|motor_cyclic)_(sin|cos)_deg$")


@dataclass
class Reading:
    """A planar campaign's rows beside the chain fits: ``d`` its planar arrays, ``rows``
    the pose → row map, ``fit`` (P,) fit poses, ``keep`` (P,) poses not set aside as
    outliers, ``nominal`` / ``named`` (P, 2) residuals (measured − model, mm) of the
    registration-only fit and of the named cause (the nominal one when none is named)."""

    d: DiagData
    rows: PlanarRows
    fit: np.ndarray
    keep: np.ndarray
    nominal: np.ndarray
    named: np.ndarray

    def tables(self, per_pose: np.ndarray, mask: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """(points, path samples) of ``per_pose`` rows, those ``mask`` marks if given."""
        if mask is None:
            return self.rows.points(per_pose), self.rows.paths(per_pose)
        return (self.rows.points(per_pose)[self.rows.points(mask)],
                self.rows.paths(per_pose)[self.rows.paths(mask)])


def residuals(d_all: F.Data, f: F.Fit, values: np.ndarray | None = None) -> np.ndarray:
    """(P, 2) measured − model of fit ``f`` (its values, or ``values``) on every point of
    ``d_all``, registration kept."""
    y, _ = F.model(d_all, f.reg, f.params, f.values if values is None else values)
    return d_all.xyz - y


def reading(cc: ChainCampaign, d_all: F.Data, fit_mask: np.ndarray, keep: np.ndarray,
            s: rank.Search, dec: rank.Decision) -> Reading | None:
    """The rows of planar campaign ``cc`` beside the chain fits; None when ``cc`` is no
    planar reading, or its planar arrays do not line up with the poses (a split the
    planar reader would refuse: then there is no v1 report to match)."""
    rows = cc.planar
    if rows is None or len(cc.markers) != 1 or d_all.dims != 2:
        return None
    try:
        d = rows.arrays if rows.arrays is not None else prepare(rows.campaign)
    except CampaignFormatError:
        return None
    fit_rows = np.concatenate([d.points.fit if d.points is not None else np.zeros(0, bool),
                               d.path_fit_mask()])
    if len(fit_rows) != cc.n_poses or not np.array_equal(fit_rows, fit_mask):
        return None
    nominal = residuals(d_all, s.nominal.fit)
    named = nominal if dec.chosen is None else residuals(d_all, dec.chosen.fit)
    return Reading(d, rows, fit_mask, keep, nominal, named)


def _holdout_table(r: Reading, take) -> dict:
    hold = ~r.fit
    before, after = TableStats.of(take(r.nominal)[take(hold)]), TableStats.of(take(r.named)[take(hold)])
    return {"n": before.n, "rms_before_mm": _r(before.rms), "rms_after_mm": _r(after.rms)}


def _r(v, nd: int = 6):
    return None if v is None or not math.isfinite(v) else round(float(v), nd)


def gap(r: Reading) -> tuple[dict, where_mod.Where]:
    """The v1 ``gap`` (every row of the campaign, nominal model) with ``points`` /
    ``paths``, and where it lies (outliers left out), as the planar report has them."""
    gp, gq = (TableStats.of(t) for t in r.tables(r.nominal))
    g = combined(gp, gq)
    wh = where_mod.analyse(r.d, *r.tables(r.nominal), r.tables(r.keep))
    return ({"rms_mm": _r(g.rms), "max_mm": _r(g.max), "n": g.n, "poses": g.n,
             "points": table_stats(gp), "paths": table_stats(gq)}, wh)


def holdout_tables(r: Reading) -> dict:
    """``holdout.points`` / ``holdout.paths``: every holdout row, nominal and named."""
    return {"points": _holdout_table(r, r.rows.points), "paths": _holdout_table(r, r.rows.paths)}


def station_lags(r: Reading, d_all: F.Data, dec: rank.Decision) -> dict | None:
    """The per-station lags of :func:`cell.diagnosis.delay.station_lags` on the fit moves'
    samples not set aside, less the named cause's static part (its parameters other than
    the lag's; only when it explains the gap, as the planar report does): the chain fit's
    static displacement is taken off the measured path and the lags fitted to what is
    left with the nominal planar model (the two add to first order; the lags are
    microseconds to milliseconds, the static effects tenths of a millimetre)."""
    d = r.d
    if dec.chosen is not None and not dec.unexplained:
        f = dec.chosen.fit
        static = np.array([0.0 if p.effect == COMMS else v for p, v in zip(f.params, f.values)])
        shift = r.rows.paths(residuals(d_all, f, np.zeros(len(f.params)))
                             - residuals(d_all, f, static))
        moves, k = [], 0
        for m in d.moves:
            moves.append(replace(m, xy=m.xy - shift[k:k + len(m.t)]))
            k += len(m.t)
        d = replace(d, moves=moves, cache={})
    keep_fit = r.rows.paths(r.keep)[r.rows.paths(r.fit)]
    return delay_mod.station_lags(d, (), None, keep_fit)


def noise(r: Reading, noise_mm: float | None) -> dict:
    """``noise``'s v1 figures: the paths' σ (model-free), the named cause's fit rms per
    table (rows not set aside), and every point noise estimate of the named cause's
    remainder on the points (:func:`cell.diagnosis.figures.point_estimates`)."""
    sigma_q = path_noise_mm(r.d)
    fp, fq = r.tables(r.named, r.fit & r.keep)
    _, est = point_estimates(r.d, r.rows.points(r.named), r.rows.points(r.keep), noise_mm, sigma_q)
    return {"path_sigma_mm": None if sigma_q is None else _r(sigma_q, 7),
            "fit_rms_points_mm": _r(TableStats.of(fp).rms), "fit_rms_paths_mm": _r(TableStats.of(fq).rms),
            "estimates": {k: v.as_dict() for k, v in est.items()}}


def outlier_tables(r: Reading, outl: Outliers) -> dict:
    """``outliers.points`` / ``outliers.paths`` in the v1 shape: per table the flagged
    rows (points: their ``sample``; path samples: ``[move, time_s]``), the table's robust
    scale, threshold and cut (:func:`cell.diagnosis.chain.robust.flag`: static poses and
    moves apart), and ``set_aside`` (the fit set's: the flags the fit left out)."""
    out = ~r.keep
    sample = np.asarray(r.d.points.sample) if r.d.points is not None else np.zeros(0)
    pts = sorted(int(x) for x in sample[r.rows.points(out)])
    moves = np.concatenate([np.full(len(m.t), m.move) for m in r.d.moves]) if r.d.moves else np.zeros(0)
    t = r.d.path_cat("t")
    pq = r.rows.paths(out)
    path = sorted([int(m), round(float(x), 6)] for m, x in zip(moves[pq], t[pq]))
    def scale(table: str) -> dict:
        s, q, cut = outl.scales.get(table, (None, None, None))
        return {"sigma_mm": _r(s), "threshold_sigma": _r(q, 3), "cut_mm": _r(cut),
                "set_aside": bool(outl.set_aside[0])}
    return {"points": {"n": len(pts), "samples": pts} | scale("static"),
            "paths": {"n": len(path), "samples": path} | scale("moves")}


def remainder(r: Reading, dec: rank.Decision) -> dict:
    """``remainder``'s ``depends_on`` / ``joint`` / ``rms_mm``: what the named cause's
    remainder varies with (outliers left out), when the gap is unexplained (as v1)."""
    w = where_mod.analyse(r.d, *r.tables(r.named), r.tables(r.keep)) if dec.unexplained else None
    return remainder_where(w)


def split_source(r: Reading) -> dict:
    """``split.source`` as v1 has it: per table, the file's column or the seeded draw."""
    return dict(r.d.split_source)


def spread(r: Reading) -> dict:
    """``spread``: the places the fit rows cover (:func:`cell.diagnosis.figures.spread`)."""
    return {k: (_r(v, 3) if isinstance(v, float) else v)
            for k, v in fit_spread(subset(r.d, "fit")).items()}


def _box(s: float, c: float, s_ci, c_ci) -> tuple[list, list]:
    """Amplitude and phase intervals (deg) of s·sin x + c·cos x = a·sin(x + φ) over the box
    of the two coefficients' 95 % intervals: conservative (the box is wider than their
    joint 95 % region); the phase is anything when the box holds the origin."""
    corners = [(x, y) for x in s_ci for y in c_ci]
    inside = s_ci[0] <= 0 <= s_ci[1] and c_ci[0] <= 0 <= c_ci[1]
    lo = 0.0 if inside else math.hypot(min(max(0.0, s_ci[0]), s_ci[1]), min(max(0.0, c_ci[0]), c_ci[1]))
    amp = [_r(lo, 9), _r(max(math.hypot(x, y) for x, y in corners), 9)]
    phi = math.degrees(math.atan2(c, s)) % 360.0
    if inside:
        return amp, [0.0, 360.0]
    d = [(math.degrees(math.atan2(y, x)) - phi + 180.0) % 360.0 - 180.0 for x, y in corners]
    return amp, [_r(phi + min(d), 9), _r(phi + max(d), 9)]


LINK = re.compile(r"^(j\d+)_a_mm$")


def v1_params(params: dict, ci95: dict) -> tuple[dict, dict]:
    """The v1 names of a planar reading's parameters, to add beside the chain's: a link's
    DH ``jK_a_mm`` (the length change of link K, the planar reading's a) as
    ``jK_link_delta_mm``, and a cyclic error's by :func:`harmonic_params`."""
    out, ci = harmonic_params(params, ci95)
    for name, v in params.items():
        if (m := LINK.match(name)) and name in ci95:
            out[f"{m[1]}_link_delta_mm"], ci[f"{m[1]}_link_delta_mm"] = v, list(ci95[name])
    return out, ci


def harmonic_params(params: dict, ci95: dict) -> tuple[dict, dict]:
    """The v1 names of a chain's harmonic parameters, to add beside them: a joint's
    ``jK_cyclic{n}_sin_deg`` / ``_cos_deg`` (one order n only: v1 has one per joint) as
    ``jK_cyclic_amp_deg``, ``jK_cyclic_phase_deg`` (a·sin(n·θ + φ)), ``jK_cyclic_order``
    and ``jK_cyclic_period_deg`` (their intervals the one order: the chain does not report
    a likelihood set of orders), and ``jK_motor_cyclic_sin_deg`` / ``_cos_deg`` as
    ``jK_motor_cyclic_amp_deg``, ``jK_motor_cyclic_phase_deg``; amplitude and phase
    intervals by :func:`_box`. A coefficient the chain's selection left out (fixed at 0)
    counts as 0 with the interval [0, 0]."""
    out, ci = {}, {}
    found = {(m[1], m[2], m[3]): None for n in params if (m := HARMONIC.match(n))}
    orders = Counter(j for j, _, order in found if order)
    for j, stem, order in found:
        sin, cos = f"{j}_{stem}_sin_deg", f"{j}_{stem}_cos_deg"
        if (order and orders[j] > 1) or any(n in params and n not in ci95 for n in (sin, cos)):
            continue
        s, c = params.get(sin, 0.0), params.get(cos, 0.0)
        if s is None or c is None:
            continue
        base = "cyclic" if order else "motor_cyclic"
        out[f"{j}_{base}_amp_deg"] = _r(math.hypot(s, c), 9)
        out[f"{j}_{base}_phase_deg"] = _r(math.degrees(math.atan2(c, s)) % 360.0, 9)
        ci[f"{j}_{base}_amp_deg"], ci[f"{j}_{base}_phase_deg"] = _box(
            s, c, ci95.get(sin, [0.0, 0.0]), ci95.get(cos, [0.0, 0.0]))
        if order:
            n = int(order)
            out[f"{j}_cyclic_order"], ci[f"{j}_cyclic_order"] = n, [n, n]
            out[f"{j}_cyclic_period_deg"] = _r(360.0 / n, 9)
            ci[f"{j}_cyclic_period_deg"] = [_r(360.0 / n, 9)] * 2
    return out, ci
