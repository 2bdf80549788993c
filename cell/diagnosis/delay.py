"""Per-station communication lag from the measured moves. Pure numerics.

Each joint's lag λ_j (ms) is fitted on its own: the joint is taken to follow its commanded
trajectory shifted by λ_j (linear interpolation, held at the first command before it,
exactly as the comm_delay stage does, with the joint's own lag in place of σ·k_j), the
static part of the diagnosed cause stays in the model (only
when the cause explains the gap; otherwise the nominal model is used), and
:func:`cell.numerics.lsq.least_squares` fits (λ_1, λ_2) on the fit moves (exact Jacobian,
:mod:`.jacobian`; path samples flagged as outliers left out). 95 % intervals: ±1.96·SE from
the Jacobian at the solution.

Seed 002's pattern is λ_j = σ·k_j with k_j the joint's 1-based position in the CAN station
order (model.yaml ``stations``). The check fits σ through the origin (weighted by the lags'
standard errors) and calls the lags proportional when the χ² of the misfit (1 degree of
freedom) has p > 0.001 or the largest deviation is under 5 % of the largest lag (at ms
sampling the lags are so precise that a purely statistical test would reject tiny model
differences that do not matter). With no lag detected, ``proportional`` is None.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from cell import effects as fx
from cell.diagnosis.figures import Z95, subset
from cell.diagnosis.jacobian import evaluate, rows_of
from cell.diagnosis.replay import DiagData
from cell.numerics.lsq import least_squares
from cell.numerics.stats import chi2_sf

LAG_BOUNDS_MS = (-20.0, 200.0)


class LagFit:
    """The residual (measured − modelled path samples ``m`` marks) and its Jacobian in the
    two lags (ms) of the lag fit of :func:`station_lags`. The model's Jacobian comes with
    its residual, so the residual keeps it, and :meth:`jacobian` at the same lags (where
    the solver asks after an accepted step) takes it instead of evaluating again; at other
    lags it evaluates afresh."""

    def __init__(self, rows, static, path_temp_c, meas: np.ndarray, m: np.ndarray):
        self.rows, self.static, self.path_temp_c, self.meas, self.m = rows, static, path_temp_c, meas, m
        self._at: np.ndarray | None = None       # the lags of the last residual
        self._J: np.ndarray | None = None        # the model's Jacobian there

    def residual(self, x) -> np.ndarray:
        y, self._J = evaluate(self.rows, self.static, self.path_temp_c, jac=True, lags_ms=x)
        self._at = np.array(x, float)
        return self.meas - y[self.m].ravel()

    def jacobian(self, x) -> np.ndarray:
        J = self._J if self._at is not None and np.array_equal(self._at, x) else \
            evaluate(self.rows, self.static, self.path_temp_c, jac=True, lags_ms=x)[1]
        return -J[self.m][:, :, -2:].reshape(-1, 2)


def station_lags(d: DiagData, static: Sequence[fx.EffectInstance] = (),
                 path_temp_c: float | None = None, keep=None) -> dict | None:
    """Per-joint lags and the proportionality check, as a JSON-ready dict::

        {"lags_ms": {"j1": .., "j2": ..}, "ci95_ms": {"j1": [lo, hi], ..},
         "stations": [...], "station_position": {"j1": k1, "j2": k2},
         "sigma_ms": σ̂, "detected": bool, "proportional": bool | None,
         "p_value": .., "max_deviation_ms": .., "moves": n}

    None when the campaign has no moves with motion in the fit rows. ``keep`` (fit path
    samples,) bool marks the samples to fit on (outliers left out; default all).
    """
    fd = subset(d, "fit")
    if not fd.moves or not any(np.ptp(m.cmd, axis=0).max() > 0 for m in fd.moves):
        return None
    m = np.ones(fd.n_path, bool) if keep is None else np.asarray(keep, bool)
    rows = rows_of(replace(fd, points=None, cache={}))
    meas = rows.meas[m].ravel()
    static = [e for e in static if e.spec.stage != fx.Stage.COMMS]

    lag = LagFit(rows, static, path_temp_c, meas, m)
    res = least_squares(lag.residual, np.array([0.5, 0.5]), lag.jacobian, *LAG_BOUNDS_MS,
                        max_nfev=200)
    J = res.jac
    s2 = float(np.sum(res.fun ** 2)) / max(len(res.fun) - 2, 1)
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        se = np.sqrt(np.maximum(np.diag(cov), 1e-18))
    except np.linalg.LinAlgError:
        se = np.full(2, math.inf)
    lam = res.x
    k = d.order
    detected = bool(np.any((np.abs(lam) > Z95 * 2.5 * se) & (np.abs(lam) > 0.05)))
    w = 1.0 / se ** 2
    sigma = float(np.sum(w * k * lam) / np.sum(w * k * k))
    dev = lam - sigma * k
    stat = float(np.sum(dev ** 2 * w))
    p = float(chi2_sf(stat, 1))
    max_dev = float(np.max(np.abs(dev)))
    prop = None
    if detected:
        prop = bool(p > 1e-3 or max_dev < 0.05 * float(np.max(np.abs(lam))))
    return {"lags_ms": {"j1": float(lam[0]), "j2": float(lam[1])},
            "ci95_ms": {j: [float(lam[i] - Z95 * se[i]), float(lam[i] + Z95 * se[i])]
                        for i, j in enumerate(("j1", "j2"))},
            "stations": list(d.stations),
            "station_position": {"j1": int(k[0]), "j2": int(k[1])},
            "sigma_ms": sigma, "detected": detected, "proportional": prop,
            "p_value": p, "max_deviation_ms": max_dev, "moves": len(fd.moves)}
