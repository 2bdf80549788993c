"""Bounded nonlinear least squares: a small damped Gauss–Newton (Levenberg–Marquardt) in
numpy, for the few-parameter fits of the diagnosis. Pure numerics.

:func:`least_squares` minimises ``cost(x) = ½·‖f(x)‖²`` over the box ``lo ≤ x ≤ hi``
(either side may be infinite) for a residual ``f`` of m rows and a few (n ≲ 20)
parameters, with the Jacobian ``J = ∂f/∂x`` the caller gives (exact, e.g. from
:mod:`cell.diagnosis.jacobian`) or forward differences. It stands in for
``scipy.optimize.least_squares(method="trf", x_scale="jac")``, whose import alone costs about
0.3 s of CPU, more than the fits themselves.

One iteration, at an accepted point x with residual r and Jacobian J:

1. **Scaling.** D = diag(d), d_i the largest Euclidean norm column i of J has had so far
   (zero columns count as 1), as MINPACK's ``lmder`` and scipy's ``x_scale="jac"``: the
   steps, the damping and the tests below do not depend on the parameters' units.
2. **Active set.** g = Jᵀr is the cost's gradient. A parameter on its lower bound with
   g_i > 0, or on its upper bound with g_i < 0 (descent would leave the box), is held
   there for this step; the others are free.
3. **Damped step.** On the free parameters, (JᵀJ + μ·D²)·δ = −g (a Cholesky solve of a
   small n×n system; μ raised tenfold until it factors). The trial point is the projection
   of x + δ on the box, s = P(x + δ) − x, so a step is never refused for crossing a bound:
   the parameter stops on it and the next step's active set decides whether it stays.
4. **Gain ratio.** ρ = (cost(x) − cost(x + s)) / (−gᵀs − ½‖Js‖²): actual over the
   Gauss–Newton model's predicted decrease, for the projected step actually taken. A trial
   point whose residual is not finite has ρ = −1.
5. **Damping update** (Nielsen's rule, Madsen, Nielsen & Tingleff, *Methods for
   non-linear least squares problems*, 2004, §3.2): ρ > 0 accepts the step, evaluates J
   there and sets μ ← μ·max(⅓, 1 − (2ρ − 1)³), ν ← 2; ρ ≤ 0 refuses it and sets
   μ ← μ·ν, ν ← 2ν. The first μ is 10⁻³·max_i (JᵀJ)_ii / d_i² (10⁻³ of the scaled
   curvature): near Gauss–Newton when the model is good, a short scaled gradient step when
   it is not.

Convergence (``status`` as scipy's): **1** the scaled projected gradient
max_i |g_i| / (d_i·‖r‖) on the free parameters is at most ``gtol`` (the cosine of the
largest angle between r and a free column of J: nothing left to explain); **2** an accepted
step lowered the cost by less than ``ftol`` of it, and the model predicted no more;
**3** the scaled step ‖D·s‖ is at most ``xtol``·(``xtol`` + ‖D·x‖); **4** both 2 and 3;
**0** ``max_nfev`` residual evaluations were spent first (forward-difference columns count
too). The solution is the best accepted point; its residual and Jacobian come with it, so
a caller forms ``JᵀJ`` at the solution for intervals without evaluating again.

Raises ValueError when x0 is outside the box, the bounds are crossed, or the residual at x0
is not finite; exceptions of ``fun``/``jac`` pass through.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

STATUS = {0: "the number of residual evaluations reached max_nfev",
          1: "gtol: the projected gradient is at most gtol",
          2: "ftol: the cost changed by less than ftol of it",
          3: "xtol: the step is at most xtol of x",
          4: "ftol and xtol both satisfied"}
EPS = np.finfo(float).eps


@dataclass
class Solution:
    """What :func:`least_squares` found: ``x`` (n,), ``fun`` (m,) the residual there,
    ``jac`` (m, n) its Jacobian there, ``cost`` ½‖fun‖², ``status`` (module docstring,
    > 0 converged), ``nfev`` / ``njev`` evaluations of the residual / Jacobian,
    ``active`` (n,) −1 on the lower bound, +1 on the upper, 0 inside."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    status: int
    nfev: int
    njev: int
    active: np.ndarray

    @property
    def success(self) -> bool:
        return self.status > 0

    @property
    def message(self) -> str:
        return STATUS[self.status]


def forward_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, r: np.ndarray,
                     lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Forward differences (m, n) of ``fun`` at ``x`` (``r`` = fun(x)), step
    √eps·max(1, |x_i|), taken backwards where the forward point would leave the box."""
    J = np.empty((r.size, x.size))
    for i in range(x.size):
        h = np.sqrt(EPS) * max(1.0, abs(x[i]))
        if x[i] + h > hi[i]:
            h = -h
        xp = x.copy()
        xp[i] += h
        J[:, i] = (fun(xp) - r) / (xp[i] - x[i])
    return J


def least_squares(fun: Callable[[np.ndarray], np.ndarray], x0, jac="2-point", lo=None, hi=None,
                  ftol: float = 1e-8, xtol: float = 1e-8, gtol: float = 1e-8,
                  max_nfev: int = 200) -> Solution:
    """Minimise ½‖fun(x)‖² on ``lo ≤ x ≤ hi`` (module docstring). ``fun(x)`` → (m,)
    residual; ``jac(x)`` → (m, n) its Jacobian, or ``"2-point"`` for forward differences;
    ``lo`` / ``hi`` (n,) bounds (default unbounded; ±inf allowed). Returns a
    :class:`Solution`; raises ValueError as the module docstring says."""
    x = np.array(x0, dtype=float).ravel()
    n = x.size
    lo = np.full(n, -np.inf) if lo is None else np.broadcast_to(np.asarray(lo, float), (n,))
    hi = np.full(n, np.inf) if hi is None else np.broadcast_to(np.asarray(hi, float), (n,))
    if np.any(lo >= hi):
        raise ValueError("each lower bound must be below its upper bound")
    if np.any((x < lo) | (x > hi)):
        raise ValueError("x0 is outside the bounds")
    r = np.asarray(fun(x), dtype=float).ravel()
    nfev, njev = 1, 0
    if not np.all(np.isfinite(r)):
        raise ValueError("the residual is not finite at x0")

    def jacobian(x, r):
        nonlocal nfev, njev
        if jac == "2-point":
            nfev += n
            return forward_jacobian(fun, x, r, lo, hi)
        njev += 1
        return np.asarray(jac(x), dtype=float).reshape(r.size, n)

    J = jacobian(x, r)
    cost = 0.5 * float(r @ r)
    d = np.zeros(n)
    boxed = bool(np.any(lo != -np.inf) or np.any(hi != np.inf))     # a bound that is not ±inf
    mu, nu, status = None, 2.0, 0
    while True:
        d = np.maximum(d, np.sqrt(np.einsum("ij,ij->j", J, J)))
        dd = np.where(d > 0, d, 1.0)
        g = J.T @ r
        A = J.T @ J
        if mu is None:
            mu = 1e-3 * float(np.max(np.diag(A) / dd ** 2)) if n else 0.0
            mu = mu if mu > 0 else 1e-3
        # without bounds a finite x is free in every parameter, and the projection is the identity
        F = None if not boxed and np.isfinite(x).all() else \
            np.flatnonzero(~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0))))
        gf, df = (g, dd) if F is None else (g[F], dd[F])
        rn = math.sqrt(2.0 * cost)
        if n == 0 or rn == 0 or (np.abs(gf) / df).max(initial=0.0) <= gtol * rn:
            status = 1
            break
        if nfev >= max_nfev:
            break
        Af = A if F is None else A[np.ix_(F, F)]
        damp = np.diag(df ** 2)
        while True:
            try:
                L = np.linalg.cholesky(Af + mu * damp)
                break
            except np.linalg.LinAlgError:
                mu *= 10.0
        step = -np.linalg.solve(L.T, np.linalg.solve(L, gf))
        if F is None:
            xt = x + step
        else:
            delta = np.zeros(n)
            delta[F] = step
            xt = np.clip(x + delta, lo, hi)
        s = xt - x
        Js = J @ s
        pred = -float(g @ s) - 0.5 * float(Js @ Js)
        rt = np.asarray(fun(xt), dtype=float).ravel()
        nfev += 1
        cost_t = 0.5 * float(rt @ rt)         # inf or nan iff some rt is (or the sum overflows)
        if not math.isfinite(cost_t):
            cost_t = math.inf
        rho = (cost - cost_t) / pred if pred > 0 and cost_t < math.inf else -1.0
        ds = dd * s
        dx = dd * x
        small_step = math.sqrt(ds @ ds) <= xtol * (xtol + math.sqrt(dx @ dx))
        if rho > 0:
            small_cost = cost - cost_t <= ftol * cost and pred <= ftol * cost
            x, r, cost = xt, rt, cost_t
            J = jacobian(x, r)
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small_cost or small_step:
                status = 4 if small_cost and small_step else (2 if small_cost else 3)
                break
        else:
            if small_step:
                status = 3
                break
            mu *= nu
            nu *= 2.0
    active = np.where(x <= lo, -1, np.where(x >= hi, 1, 0))
    return Solution(x, r, J, cost, status, nfev, njev, active)
