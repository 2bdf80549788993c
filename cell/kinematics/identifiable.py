"""Which error parameters of a robot model a set of measurements can tell apart: the one
rule of the calibrations and the diagnosis. Pure numerics.

The parameters are gone through in a priority order (the one a user would rather keep
when several act alike: an offset before a link length that looks the same). Each
parameter's column of the design (its effect on every measured value) is taken at unit
norm, so units and lever lengths do not count. A parameter is **kept** when more than
``tol`` of its unit column lies outside the span of what is already in: a nuisance that
is always fitted (a sensor frame, marker positions) and the parameters kept before it
(Gram–Schmidt). Otherwise the measurements see it only as a sum with those, and it is
left out; a zero column is not seen at all.

``left`` is that share outside the span (1: new, 0: repeats them); 1/left² is its
variance inflation beside what came before, the caller's measure of "kept, but only
just". Two tolerances are in use: :data:`STRUCTURAL_TOL` (the diagnosis: left out only
what the layout cannot see at all, the screening decides the rest) and the calibration's
conditioning tolerance (a kept set it can solve stably).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STRUCTURAL_TOL = 1e-6    # a unit column this close to the span of the others adds nothing


@dataclass
class Span:
    """The result of :func:`greedy`: ``kept`` column indices in the order kept, ``left``
    (n,) each visited column's share outside the span before it (NaN: a zero column, or
    not visited), ``Q`` an orthonormal basis of the nuisance and the kept columns,
    ``Q0`` that of the nuisance alone, and ``unit`` each visited nonzero column at unit
    norm, by index (column / its norm, as the caller would divide it)."""

    kept: list[int]
    left: np.ndarray
    Q: np.ndarray
    Q0: np.ndarray
    unit: dict[int, np.ndarray] = field(default_factory=dict)

    def outside(self, v: np.ndarray, basis: np.ndarray | None = None) -> float:
        """The share of unit vector ``v`` outside the span of ``basis`` (default: all)."""
        B = self.Q if basis is None else basis
        return float(np.linalg.norm(v - B @ (B.T @ v)))


def nuisance_basis(N: np.ndarray, tol: float = STRUCTURAL_TOL) -> np.ndarray:
    """An orthonormal basis of the columns ``N`` (M, k) (unit-scaled first; directions
    they do not span to ``tol`` left out)."""
    if N.shape[1] == 0:
        return np.zeros((N.shape[0], 0))
    Q, R = np.linalg.qr(N / np.maximum(np.linalg.norm(N, axis=0), 1e-300))
    return Q[:, np.abs(np.diag(R)) > tol]


def greedy(J: np.ndarray, order, tol: float = STRUCTURAL_TOL,
           nuisance: np.ndarray | None = None) -> Span:
    """Go through the columns ``order`` of ``J`` (M, n) and keep each whose unit column has
    at least ``tol`` outside the span of ``nuisance`` (an orthonormal basis,
    :func:`nuisance_basis`; None: nothing) and of the columns kept before it."""
    Q0 = np.zeros((J.shape[0], 0)) if nuisance is None else nuisance
    Q = Q0
    left = np.full(J.shape[1], np.nan)
    kept: list[int] = []
    unit: dict[int, np.ndarray] = {}
    for j in order:
        c = J[:, j]
        norm = np.linalg.norm(c)
        if norm == 0:
            continue
        v = unit[j] = c / norm
        perp = v - Q @ (Q.T @ v)
        left[j] = float(np.linalg.norm(perp))
        if left[j] >= tol:
            kept.append(j)
            Q = np.column_stack([Q, perp / left[j]])
    return Span(kept, left, Q, Q0, unit)
