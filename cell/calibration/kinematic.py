"""Seed 001: identify the SCARA's DH errors from planar poses over a calibration board,
by the differential error model of :mod:`cell.calibration.dh`. Pure numerics; no I/O.

Steps: :func:`identifiability` (which errors the measurement can separate, which merge,
which it cannot see), :func:`select_poses` (greedy D-optimal pose plan), :func:`identify`
(iterated linear least squares = Gauss–Newton, standard errors, 95 % intervals) and
:func:`holdout_check` (does the calibrated model beat the nominal one on unseen poses).

**Weighting.** φ rows (deg) are made commensurate with x, y rows (mm) by one scale
``w`` (mm per deg): residual and Jacobian rows of φ are multiplied by w. The first pass
uses the arm-reach scale ``w0 = reach·π/180`` (a 1° tool rotation moves a point at the
reach by w0 mm). :func:`identify` then estimates σ_xy (mm) and σ_φ (deg) from its own
residuals and refits once with ``w = σ_xy/σ_φ`` (each row weighted by 1/its noise),
clipped to [w0/1000, 1000·w0]; a caller's ``phi_weight_mm_per_deg`` disables that.

**Position only.** A camera that sees one known point per pose measures x, y but not φ
(a disc looks the same turned). ``position_only=True`` gives φ rows zero weight: they add
neither information nor degrees of freedom (dof = 2N − K), the design and the kept set
are those of x, y alone, and ``measured`` may be (N, 2).

**Anchors.** Rows flagged ``in_base`` were measured in the robot base frame itself (the
cell's fixed camera seeing the tool), not in the board's: the board placement
(``base.*``) does not act on them. A few such rows separate the board's rotation from
θ1's zero, which board rows alone see only as a sum.

**Lever (the hand camera's reduction).** A board pose's measured tool position is
``m = b − R(φ₀)·h``: the known point ``b`` less where the hand camera saw it, ``h`` (hand
frame), turned into the board frame by the tool orientation φ₀ the nominal robot gives the
commanded joints (:func:`cell.calibration.procedure.measure_board`). The camera turns with
the TRUE tool, so ``m`` is the tool's position only when φ₀ is right. The robot's own zero
errors turn the tool by Δφ (random-4: 0.38°), and the reduction then errs by Δφ × the few mm
``b − m``; that error is systematic: ``b − m`` is itself mostly the zeros' tangential error,
turned by Δφ it is radial, and the links absorbed it (0.002–0.014 mm long). ``lever``
(N, 3) rows ``(b_x − m_x, b_y − m_y, φ₀)`` (mm, mm, deg; all 0 for a pose measured
directly, e.g. an anchor) let the fit redo the reduction with each model's own tool
orientation φ(q, p): the measurement compared with the model is then
``b − R(φ − φ₀)·(b − m)``, and the Jacobian carries its derivative.

Every failure raises :class:`~cell.errors.CalibrationError` naming the cause.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg as sla

from cell.calibration.dh import D2R, DHChain, check_measured, error_jacobian, wrap_deg
from cell.errors import CalibrationError
from cell.kinematics import identifiable
from cell.numerics.stats import t_ppf

RANK_TOL = 1e-4        # share of a unit column outside the kept span it needs (and the rank cut)
ZERO_TOL = 1e-9        # column norm / largest column norm below which a parameter is unseen
UNOBSERVABLE = "not observable from planar measurements"


def phi_weight_default(chain: DHChain) -> float:
    """The reach length scale w0 = reach_mm·π/180 (mm per deg) for φ rows."""
    return chain.reach_mm * D2R


def design_matrix(chain: DHChain, q, p=None, *, phi_weight_mm_per_deg: float | None = None) -> np.ndarray:
    """:func:`~cell.calibration.dh.error_jacobian` with its φ rows multiplied by
    ``phi_weight_mm_per_deg`` (default :func:`phi_weight_default`): every row in mm."""
    J = error_jacobian(chain, q, p)
    J[2::3] *= phi_weight_default(chain) if phi_weight_mm_per_deg is None else phi_weight_mm_per_deg
    return J


BASE_PARAMS = ("base.x", "base.y", "base.rz")


def _base_free(chain: DHChain, p: np.ndarray) -> np.ndarray:
    out = p.copy()
    out[[chain.index(n) for n in BASE_PARAMS]] = 0.0
    return out


def _mask(in_base, n: int) -> np.ndarray | None:
    if in_base is None:
        return None
    m = np.asarray(in_base, dtype=bool)
    if m.shape != (n,):
        raise CalibrationError(f"in_base must flag each of the {n} poses, got shape {m.shape}")
    return m if m.any() else None


def check_lever(lever, n: int, what: str = "lever") -> np.ndarray | None:
    """``lever`` as a float (n, 3) array (see the module doc), or None for None. A wrong
    shape or a non-finite value raise CalibrationError naming the pose."""
    if lever is None:
        return None
    a = np.asarray(lever, dtype=float)
    if a.shape != (n, 3):
        raise CalibrationError(f"{what} must have shape ({n}, 3) (b − m in x, y mm, φ₀ deg), "
                               f"got {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
    if bad.size:
        raise CalibrationError(f"{what} of pose {bad[0]} is not finite: {a[bad[0]].tolist()}")
    return a


def _turned_lever(chain: DHChain, q, p, lever: np.ndarray) -> np.ndarray:
    """R(φ(q, p) − φ₀)·(b − m) (N, 2) mm: each pose's lever turned by how far the model's
    tool orientation lies from the one the reduction used."""
    d = np.radians(wrap_deg(chain.predict(q, p)[:, 2] - lever[:, 2]))
    c, s = np.cos(d), np.sin(d)
    v = lever[:, :2]
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


def residuals(chain: DHChain, q, m, p, in_base=None, lever=None) -> np.ndarray:
    """measured − model (N, 3); rows ``in_base`` without the board placement. With
    ``lever`` (module doc) the measured x, y are those the reduction gives with the model's
    tool orientation: ``b − R(φ − φ₀)·(b − m)``."""
    r = chain.residuals(q, m, p)
    mask = _mask(in_base, len(r))
    if mask is not None:
        r[mask] = chain.residuals(q[mask], m[mask], _base_free(chain, p))
    lv = check_lever(lever, len(r))
    if lv is not None:
        r[:, :2] += lv[:, :2] - _turned_lever(chain, q, p, lv)
    return r


def jacobian(chain: DHChain, q, p=None, *, w: float | None = None, in_base=None,
             lever=None) -> np.ndarray:
    """:func:`design_matrix`; rows of poses ``in_base`` at the placement-free errors and
    with zero board-placement columns. With ``lever`` (module doc) the x, y rows also carry
    the measurement's own dependence on the errors, −∂/∂p of ``b − R(φ − φ₀)·(b − m)``:
    the turned lever's perpendicular times ∂φ/∂p (rad per unit)."""
    J = design_matrix(chain, q, p, phi_weight_mm_per_deg=w)
    mask = _mask(in_base, len(q))
    if mask is not None:
        p_free = _base_free(chain, np.zeros(chain.n_params) if p is None else np.asarray(p, float))
        rows = np.repeat(mask, 3)
        J[rows] = design_matrix(chain, q[mask], p_free, phi_weight_mm_per_deg=w)
        J[np.ix_(rows, [chain.index(n) for n in BASE_PARAMS])] = 0.0
    lv = check_lever(lever, len(q))
    if lv is not None:
        u = _turned_lever(chain, q, p, lv) * D2R
        dphi = error_jacobian(chain, q, p)[2::3]
        J[0::3] -= u[:, 1:2] * dphi
        J[1::3] += u[:, 0:1] * dphi
    return J


def default_priority(chain: DHChain) -> list[str]:
    """Which parameter to keep when several appear only together, first = kept:
    θ of revolute links, a of every link, θ of prismatic links (a fixed twist), α, d, then
    the board placement base.x, base.y, base.rz (so base.rz merges into j1.theta)."""
    links = list(enumerate(chain.links, 1))
    order = [f"j{k}.theta" for k, lk in links if lk.joint_type == "revolute"]
    order += [f"j{k}.a" for k, _ in links]
    order += [f"j{k}.theta" for k, lk in links if lk.joint_type == "prismatic"]
    order += [f"j{k}.alpha" for k, _ in links] + [f"j{k}.d" for k, _ in links]
    return order + ["base.x", "base.y", "base.rz"]


# ---------------------------------------------------------------------- identifiability
@dataclass(frozen=True)
class Identifiability:
    """Which parameters a design J can separate.

    ``singular_values``: of the column-scaled observable columns; ``rank``: how many
    exceed ``rank_threshold`` = ``tol``·σ_max. ``kept``: chosen in priority order, each with
    at least ``tol`` of its unit column outside the span of those kept before it
    (:mod:`cell.kinematics.identifiable`); ``condition_number`` is the kept set's
    σ_max/σ_min. ``fixed``: one dict per other parameter, ``{"param", "reason"}`` with
    reason :data:`UNOBSERVABLE` (zero column) or ``"merged"`` plus ``"merged_into"``
    ({kept name: c}: an error δ of this parameter acts like errors c·δ of those, so they
    absorb it) and ``"fit_residual"`` (relative misfit of that combination; ~0 = exact).
    """

    names: tuple[str, ...]
    rank: int
    tol: float
    rank_threshold: float
    condition_number: float
    kept: tuple[str, ...]
    fixed: tuple[dict, ...]
    singular_values: tuple[float, ...]

    @property
    def unobservable(self) -> list[str]:
        return [f["param"] for f in self.fixed if f["reason"] == UNOBSERVABLE]

    @property
    def merged(self) -> dict[str, dict[str, float]]:
        return {f["param"]: f["merged_into"] for f in self.fixed if f["reason"] == "merged"}

    def as_dict(self) -> dict:
        return {"rank": self.rank, "tol": self.tol, "rank_threshold": self.rank_threshold,
                "condition_number": _num(self.condition_number), "kept": list(self.kept),
                "fixed": [dict(f, merged_into=dict(f["merged_into"])) if "merged_into" in f else dict(f)
                          for f in self.fixed],
                "singular_values": list(self.singular_values), "names": list(self.names)}


def _num(v: float) -> float | None:
    """A float for JSON: non-finite values (an empty design's condition number) → None."""
    return float(v) if math.isfinite(v) else None


def _scaled_sv(Js: np.ndarray) -> np.ndarray:
    return sla.svdvals(Js) if Js.size else np.zeros(0)


def identifiability(J, names: Sequence[str], *, priority: Sequence[str] | None = None,
                    tol: float = RANK_TOL, zero_tol: float = ZERO_TOL) -> Identifiability:
    """Identifiability report of the design J (M, P) (rows already weighted, e.g.
    :func:`design_matrix`) for parameters ``names`` (P,).

    Columns with norm ≤ zero_tol·(largest norm) are not observable (fixed at 0: all d's,
    since z is not measured). The others are scaled to unit norm; going through them in
    ``priority`` order (unlisted names last, in their order), a column is kept by the rule
    of :mod:`cell.kinematics.identifiable` (at least ``tol`` of it outside the span of the
    columns kept before it), else it is merged: its column is fitted by least squares on
    the kept columns (in parameter units) and reported with the coefficients. Raises
    CalibrationError on a shape mismatch or non-finite J.
    """
    J = np.asarray(J, dtype=float)
    names = tuple(names)
    if J.ndim != 2 or J.shape[1] != len(names):
        raise CalibrationError(f"design matrix shape {J.shape} does not match {len(names)} parameter names")
    if not np.isfinite(J).all():
        raise CalibrationError("design matrix holds non-finite values")
    order = [n for n in (priority or ()) if n in names]
    order += [n for n in names if n not in order]
    norms = np.linalg.norm(J, axis=0)
    top = norms.max() if norms.size else 0.0
    obs = norms > zero_tol * top if top > 0 else np.zeros(len(names), bool)
    Js = np.where(obs, J / np.where(obs, norms, 1.0), 0.0)
    sv = _scaled_sv(Js[:, obs])
    threshold = tol * sv[0] if sv.size else 0.0
    rank = int((sv > threshold).sum()) if sv.size else 0
    kept = identifiable.greedy(Js, [names.index(n) for n in order], tol).kept
    s_kept = _scaled_sv(Js[:, kept])
    cond = float(s_kept[0] / s_kept[-1]) if s_kept.size else math.inf
    fixed = []
    for n, j in ((n, names.index(n)) for n in order if names.index(n) not in kept):
        if not obs[j]:
            fixed.append({"param": n, "reason": UNOBSERVABLE})
            continue
        c, *_ = np.linalg.lstsq(J[:, kept], J[:, j], rcond=None)
        resid = float(np.linalg.norm(J[:, kept] @ c - J[:, j]) / norms[j])
        keep_c = np.abs(c) * norms[kept] / norms[j] > 1e-9
        fixed.append({"param": n, "reason": "merged", "fit_residual": resid,
                      "merged_into": {names[k]: float(v) for k, v, m in zip(kept, c, keep_c) if m}})
    return Identifiability(names, rank, tol, float(threshold), cond,
                           tuple(names[k] for k in kept), tuple(fixed), tuple(float(v) for v in sv))


def _generic_poses(chain: DHChain, q: np.ndarray, n: int = 80) -> np.ndarray:
    """A fixed pseudo-random spread of poses (seed 0): revolute joints uniform in
    [−150°, 150°], prismatic joints drawn from the values q holds (the data's heights)."""
    rng = np.random.default_rng(0)
    g = rng.uniform(-150.0, 150.0, (n, chain.n_joints))
    for lk in chain.links:
        if lk.joint_type == "prismatic":
            g[:, lk.joint] = rng.choice(q[:, lk.joint], n)
    return g


def structural_kept(chain: DHChain, q, *, tol: float = RANK_TOL,
                    position_only: bool = False, anchored: bool = False) -> tuple[str, ...]:
    """The parameters the planar measurement can identify *in principle* for this chain:
    the kept set of :func:`identifiability` on a generic spread of poses at the heights
    (prismatic joint values) that ``q`` uses. The default target of :func:`identify`."""
    q = chain.check_joints(q)
    g = _generic_poses(chain, q)
    J = jacobian(chain, g, w=0.0 if position_only else None,
                 in_base=(np.arange(len(g)) % 4 == 0) if anchored else None)
    return identifiability(J, chain.param_names, priority=default_priority(chain), tol=tol).kept


def _kept_index(chain: DHChain, kept) -> list[int]:
    if len(set(kept)) != len(kept):
        raise CalibrationError(f"kept parameters listed twice: {list(kept)}")
    return [chain.index(n) for n in kept]


def _check_design(J: np.ndarray, kept: Sequence[str], n_poses: int, tol: float, per_pose: int = 3) -> None:
    """Raise CalibrationError unless J (M, K) determines all K kept parameters."""
    k = J.shape[1]
    m = n_poses * per_pose
    if k == 0:
        raise CalibrationError("singular design matrix: rank 0 (no parameter to identify)")
    if m <= k:
        raise CalibrationError(f"singular design matrix: {n_poses} poses × {per_pose} = {m} equations for "
                               f"{k} parameters (need more equations than parameters)")
    rep = identifiability(J, kept, priority=kept, tol=tol)
    if len(rep.kept) < k:
        lost = [f["param"] for f in rep.fixed]
        raise CalibrationError(f"singular design matrix: rank {len(rep.kept)} < {k} parameters at "
                               f"tol {tol:g} ({', '.join(lost)} not determined by these {n_poses} "
                               f"poses; spread θ1, θ2, θ4 over the workspace)")


# ---------------------------------------------------------------------- identification
@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`. ``p`` (n_params,) errors, parameters outside ``kept`` at
    their starting value (0 unless ``p0`` said otherwise); ``std_err``/``ci95`` (K,)/(K, 2)
    for ``kept`` in its order; ``residuals`` (N, 3) measured − model (x mm, y mm, φ deg);
    ``rms_xy_mm`` = √mean(dx² + dy²), ``rms_phi_deg`` = √mean(dφ²); ``sigma_*`` the
    per-component noise estimates (dof-corrected); ``condition_number`` of the
    column-scaled weighted J of the kept parameters at the solution. A result is only
    returned once converged (else CalibrationError); ``converged`` records it."""

    names: tuple[str, ...]
    p: np.ndarray
    kept: tuple[str, ...]
    std_err: np.ndarray
    ci95: np.ndarray
    residuals: np.ndarray
    rms_xy_mm: float
    rms_phi_deg: float
    sigma_xy_mm: float
    sigma_phi_deg: float
    phi_weight_mm_per_deg: float
    dof: int
    iterations: int
    converged: bool
    condition_number: float
    report: Identifiability = field(repr=False)

    def value(self, name: str) -> float:
        return float(self.p[self.names.index(name)])

    def as_dict(self) -> dict:
        return {"p": {n: float(v) for n, v in zip(self.names, self.p)},
                "kept": {n: {"value": self.value(n), "std_err": float(s), "ci95": [float(lo), float(hi)]}
                         for n, s, (lo, hi) in zip(self.kept, self.std_err, self.ci95)},
                "residuals": self.residuals.tolist(), "rms_xy_mm": self.rms_xy_mm,
                "rms_phi_deg": self.rms_phi_deg, "sigma_xy_mm": self.sigma_xy_mm,
                "sigma_phi_deg": self.sigma_phi_deg, "phi_weight_mm_per_deg": self.phi_weight_mm_per_deg,
                "dof": self.dof, "iterations": self.iterations, "converged": self.converged,
                "condition_number": self.condition_number, "identifiability": self.report.as_dict()}


def _weighted(r: np.ndarray, w: float) -> np.ndarray:
    rw = r.copy()
    rw[:, 2] *= w
    return rw.reshape(-1)


def _gauss_newton(chain, q, m, p, idx, w, max_iter, tol_mm, in_base=None, lever=None):
    """Relinearise and solve until the update changes the weighted predictions by less
    than tol_mm rms; returns (p, iterations)."""
    last = math.inf
    for it in range(1, max_iter + 1):
        J = jacobian(chain, q, p, w=w, in_base=in_base, lever=lever)[:, idx]
        rw = _weighted(residuals(chain, q, m, p, in_base, lever), w)
        dx, *_ = np.linalg.lstsq(J, rw, rcond=None)
        p = p.copy()
        p[idx] += dx
        last = float(np.sqrt(np.mean((J @ dx) ** 2)))
        if last < tol_mm:
            return p, it
    raise CalibrationError(f"identification did not converge after {max_iter} iteration"
                           f"{'s' if max_iter != 1 else ''}: the last "
                           f"update changed the predictions by {last:.3g} mm rms (tol {tol_mm:g} mm)")


def _sigmas(r: np.ndarray, k: int) -> tuple[float, float]:
    """σ_xy (mm), σ_φ (deg): rms per component, the K parameters' dof shared pro rata."""
    dof = 3 * r.shape[0] - k
    s_xy = math.sqrt(float(np.sum(r[:, :2] ** 2)) / max(dof * 2 / 3, 1e-12))
    s_phi = math.sqrt(float(np.sum(r[:, 2] ** 2)) / max(dof / 3, 1e-12))
    return s_xy, s_phi


def _as_measured(chain: DHChain, q: np.ndarray, measured, position_only: bool, what: str = "measured"):
    """(N, 3) measurements; with ``position_only`` an (N, 2) array gets the nominal φ (its
    rows carry zero weight, so the value does not matter)."""
    m = np.asarray(measured, dtype=float)
    if position_only and m.ndim == 2 and m.shape[1] == 2:
        m = np.column_stack([m, chain.predict(q)[: m.shape[0], 2] if m.shape[0] == q.shape[0]
                             else np.zeros(m.shape[0])])
    return check_measured(m, q.shape[0], what)


def identify(chain: DHChain, q, measured, *, p0=None, kept: Sequence[str] | None = None,
             phi_weight_mm_per_deg: float | None = None, max_iter: int = 20,
             tol: float = 1e-6, rank_tol: float = RANK_TOL, position_only: bool = False,
             in_base=None, lever=None) -> Identification:
    """Identify the DH errors from joints q (N, n_joints) and measured planar poses
    (N, 3) (x mm, y mm, φ deg in the board frame) by Gauss–Newton on the differential model.

    ``kept`` (default :func:`structural_kept`: everything the measurement can separate
    in principle) are estimated; all other parameters stay at ``p0`` (default 0). Weighting
    as in the module doc (noise-based reweighting once unless ``phi_weight_mm_per_deg`` is
    given). ``in_base`` (N,) flags the anchor poses; ``lever`` (N, 3) how each board pose
    was reduced (module doc: the measurement then follows the model's tool orientation).
    Converged when an update changes the weighted predictions by < ``tol`` mm rms.
    Standard errors: √diag(s²·(JᵀWJ)⁻¹), s² = weighted residual sum / dof, dof = 3N − K;
    95 % intervals with Student's t(dof).

    Raises CalibrationError for bad shapes, a non-finite joint or measurement (naming the
    pose), 3N ≤ K ("singular design matrix: N poses × 3 = M equations for K parameters"),
    a design that does not determine every kept parameter ("rank r < K"), or no
    convergence within ``max_iter`` iterations (naming the last update size).
    """
    q = chain.check_joints(q)
    m = _as_measured(chain, q, measured, position_only)
    p = np.zeros(chain.n_params) if p0 is None else chain.check_errors(p0).copy()
    mask = _mask(in_base, q.shape[0])
    lever = check_lever(lever, q.shape[0])
    kept = tuple(structural_kept(chain, q, tol=rank_tol, position_only=position_only,
                                 anchored=mask is not None) if kept is None else kept)
    idx = _kept_index(chain, kept)
    w0 = phi_weight_default(chain)
    w = 0.0 if position_only else w0 if phi_weight_mm_per_deg is None else float(phi_weight_mm_per_deg)
    if not (math.isfinite(w) and (w > 0 or position_only)):
        raise CalibrationError(f"phi_weight_mm_per_deg = {w!r} must be a positive number")
    per_pose = 2 if position_only else 3
    J0 = jacobian(chain, q, p, w=w, in_base=mask)
    report = identifiability(J0, chain.param_names, priority=default_priority(chain), tol=rank_tol)
    _check_design(J0[:, idx], kept, q.shape[0], rank_tol, per_pose)
    p, its = _gauss_newton(chain, q, m, p, idx, w, max_iter, tol, mask, lever)
    if phi_weight_mm_per_deg is None and not position_only:
        s_xy, s_phi = _sigmas(residuals(chain, q, m, p, mask, lever), len(idx))
        w = float(np.clip(s_xy / s_phi, w0 / 1e3, w0 * 1e3)) if s_phi > 0 else w0 * 1e3
        p, its2 = _gauss_newton(chain, q, m, p, idx, w, max_iter, tol, mask, lever)
        its += its2
    r = residuals(chain, q, m, p, mask, lever)
    J = jacobian(chain, q, p, w=w, in_base=mask, lever=lever)[:, idx]
    dof = per_pose * q.shape[0] - len(idx)
    s2 = float(np.sum(_weighted(r, w) ** 2)) / dof
    norms = np.linalg.norm(J, axis=0)
    sv, Vt = sla.svd(J / norms, full_matrices=False)[1:]
    cov = (Vt.T / sv ** 2) @ Vt / np.outer(norms, norms) * s2
    se = np.sqrt(np.diag(cov))
    half = t_ppf(0.975, dof) * se
    est = p[idx]
    s_xy, s_phi = _sigmas(r, len(idx))
    if position_only:
        r[:, 2] = np.nan                         # not measured
        s_xy, s_phi = math.sqrt(s2 / 2.0), math.nan
    return Identification(
        chain.param_names, p, kept, se, np.column_stack([est - half, est + half]), r,
        float(np.sqrt(np.mean(np.sum(r[:, :2] ** 2, axis=1)))),
        math.nan if position_only else float(np.sqrt(np.mean(r[:, 2] ** 2))),
        s_xy, s_phi, w, dof, its, True, float(sv[0] / sv[-1]), report)


def fit_base(chain: DHChain, q, measured, **kw) -> Identification:
    """The nominal robot with only the board placement (base.x, base.y, base.rz) fitted:
    the fair "before calibration" model. Keywords as for :func:`identify`."""
    return identify(chain, q, measured, kept=("base.x", "base.y", "base.rz"), **kw)


# ---------------------------------------------------------------------- pose selection
def select_poses(chain: DHChain, candidates_q, n: int, *, kept: Sequence[str] | None = None,
                 p=None, rng: np.random.Generator | None = None, position_only: bool = False) -> np.ndarray:
    """Choose ``n`` of the candidate joint configurations (C, n_joints) for identification;
    returns their indices (n,) in the order chosen.

    Criterion: greedy D-optimal, i.e. each step adds the candidate that most increases
    log det(JᵀJ) of the kept parameters (default: :func:`identifiability` on all candidates),
    J = :func:`design_matrix` at ``p`` (default nominal) with columns scaled by their norms
    over all candidates (so units do not matter). Seed: ⌈K/3⌉ poses spread by farthest-point
    sampling in joint space (joints scaled by their candidate range), starting from the
    candidate farthest from the mean (or a random one if ``rng`` is given). While JᵀJ is
    still singular a ridge of 1e-9·trace keeps log det finite. Raises CalibrationError if
    n > C or 3n ≤ K.
    """
    cq = chain.check_joints(candidates_q, "candidates_q")
    c = cq.shape[0]
    J = design_matrix(chain, cq, p, phi_weight_mm_per_deg=0.0 if position_only else None)
    if kept is None:
        kept = identifiability(J, chain.param_names, priority=default_priority(chain)).kept
    idx = _kept_index(chain, kept)
    k = len(idx)
    per_pose = 2 if position_only else 3
    if not (0 < n <= c) or per_pose * n <= k:
        raise CalibrationError(f"cannot select {n} of {c} candidate poses for {k} parameters "
                               f"(need n <= {c} and {per_pose}·n > {k})")
    J = J[:, idx]
    J = J / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    blocks = J.reshape(c, 3, k)
    span = np.ptp(cq, axis=0)
    z = (cq - cq.mean(axis=0)) / np.where(span > 0, span, 1.0)
    first = int(rng.integers(c)) if rng is not None else int(np.argmax(np.sum(z ** 2, axis=1)))
    chosen = [first]
    dist = np.linalg.norm(z - z[first], axis=1)
    while len(chosen) < min(n, math.ceil(k / 3)):
        dist[chosen] = -np.inf
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(z - z[nxt], axis=1))
    info = sum(blocks[i].T @ blocks[i] for i in chosen)
    free = np.ones(c, bool)
    free[chosen] = False
    while len(chosen) < n:
        A = info + 1e-9 * max(np.trace(info), 1.0) * np.eye(k)
        Ainv = np.linalg.inv(A)
        # det(A + BᵀB) = det(A)·det(I + B A⁻¹ Bᵀ): the gain of each candidate block B (3, K)
        G = np.einsum("cik,kl,cjl->cij", blocks, Ainv, blocks) + np.eye(3)
        gain = np.linalg.slogdet(G)[1]
        gain[~free] = -np.inf
        best = int(np.argmax(gain))
        chosen.append(best)
        free[best] = False
        info = info + blocks[best].T @ blocks[best]
    return np.array(chosen, dtype=int)


# ---------------------------------------------------------------------- held-out check
@dataclass(frozen=True)
class HoldoutCheck:
    """Result of :func:`holdout_check`: before (nominal + fitted board placement) and after
    (calibrated) errors on the held-out poses; xy = √(dx² + dy²) per pose, mm; φ in deg."""

    n_hold: int
    rms_xy_before_mm: float
    rms_xy_after_mm: float
    max_xy_before_mm: float
    max_xy_after_mm: float
    rms_phi_before_deg: float
    rms_phi_after_deg: float
    max_phi_before_deg: float
    max_phi_after_deg: float
    rms_xy_fit_mm: float
    gain: float
    ratio: float
    min_gain: float
    max_ratio: float
    passed: bool
    reason: str
    #: the held-out figures that got worse, in words (empty when none did)
    worse: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        return {k: (_num(v) if isinstance(v, float) else list(v) if isinstance(v, tuple) else v)
                for k, v in ((k, getattr(self, k)) for k in self.__dataclass_fields__)}


def _errors(chain, q, m, p, lever=None):
    r = residuals(chain, q, m, p, lever=lever)
    xy = np.hypot(r[:, 0], r[:, 1])
    phi = np.abs(r[:, 2])
    return float(np.sqrt(np.mean(xy ** 2))), float(xy.max()), float(np.sqrt(np.mean(phi ** 2))), float(phi.max())


def holdout_check(chain: DHChain, p, q_hold, measured_hold, *, q_fit, measured_fit,
                  min_gain: float = 0.1, max_ratio: float = 3.0, position_only: bool = False,
                  in_base_fit=None, commanded=None, lever_fit=None, lever_hold=None) -> HoldoutCheck:
    """Check calibrated errors ``p`` on held-out poses (q_hold, measured_hold) that the fit
    did not use.

    "Before" is the nominal robot with only the board placement fitted (:func:`fit_base`)
    on the same fit data (q_fit, measured_fit) the calibration used: the board's place is
    unknown either way, so only that comparison is fair. Rule: passes iff

    * the held-out xy rms improves by at least ``min_gain`` relative, gain = 1 − after/before
      ≥ min_gain;
    * no held-out figure gets worse (:mod:`cell.calibration.check`): neither the xy rms nor
      the xy max (nor, when φ is measured, the φ rms or max);
    * the held-out xy rms is at most ``max_ratio`` × the calibrated model's xy rms on the
      fit data (ratio). The fit residual is this procedure's measure of the noise (the
      arm's repeatability and the camera; it has no revisited poses): with the model right,
      ratio² follows about F(2·n_hold, dof of the fit), whose 0.999 quantile for the
      default 12 held-out and 24 fit poses is under 3, so 3 in rms (9 in variance) is far
      beyond chance: the model does not generalise.

    ``in_base_fit`` flags the anchor poses among the fit data (held-out poses are board
    poses). ``commanded`` (q_fit, q_hold): the commanded joints when ``q_fit`` and
    ``q_hold`` carry joint terms the calibration applies: "before" is then the nominal robot
    on the commands, as without them. ``lever_fit`` / ``lever_hold`` (N, 3): how the board
    poses were reduced (module doc); each model, "before" and after, is then compared with
    the reduction its own tool orientation gives. Raises CalibrationError for bad shapes or
    non-finite input (naming the pose).
    """
    from cell.calibration import check as C
    p = chain.check_errors(p)
    qh = chain.check_joints(q_hold, "q_hold")
    mh = _as_measured(chain, qh, measured_hold, position_only, "measured_hold")
    qf = chain.check_joints(q_fit, "q_fit")
    mf = _as_measured(chain, qf, measured_fit, position_only, "measured_fit")
    qf0, qh0 = (qf, qh) if commanded is None else (chain.check_joints(commanded[0], "q_fit"),
                                                    chain.check_joints(commanded[1], "q_hold"))
    lf = check_lever(lever_fit, qf.shape[0], "lever_fit")
    lh = check_lever(lever_hold, qh.shape[0], "lever_hold")
    before = fit_base(chain, qf0, mf, position_only=position_only, in_base=in_base_fit, lever=lf).p
    rb, mb, pb, pmb = _errors(chain, qh0, mh, before, lh)
    ra, ma, pa, pma = _errors(chain, qh, mh, p, lh)
    fit_rms = float(np.sqrt(np.mean(np.sum(residuals(chain, qf, mf, p, in_base_fit, lf)[:, :2] ** 2,
                                           axis=1))))
    if position_only:
        pb = pmb = pa = pma = math.nan
    gain = 1.0 - ra / rb if rb > 0 else -math.inf
    ratio = ra / fit_rms if fit_rms > 0 else math.inf
    figures = [C.Figure("xy rms", rb, ra, "mm"), C.Figure("xy max", mb, ma, "mm")]
    if not position_only:
        figures += [C.Figure("φ rms", pb, pa, "deg"), C.Figure("φ max", pmb, pma, "deg")]
    other = []
    if gain < min_gain:
        other.append(f"held-out xy rms {ra:.4g} mm vs {rb:.4g} mm before: gain {gain:.1%} < "
                     f"{min_gain:.0%} required")
    if ratio > max_ratio:
        other.append(f"held-out xy rms {ra:.4g} mm is {ratio:.3g} × the fit rms {fit_rms:.4g} mm "
                     f"(> {max_ratio:g}): the model does not generalise")
    verdict = C.Verdict(tuple(figures), (), tuple(other))
    if verdict.passed:
        reason = (f"held-out xy rms {rb:.4g} → {ra:.4g} mm (gain {gain:.1%}), max {mb:.4g} → {ma:.4g} mm, "
                  f"{ratio:.3g} × the fit rms")
    else:
        reason = "; ".join(verdict.failures())
    return HoldoutCheck(qh.shape[0], rb, ra, mb, ma, pb, pa, pmb, pma, fit_rms, float(gain),
                        float(ratio), float(min_gain), float(max_ratio), verdict.passed, reason,
                        tuple(f.text() for f in verdict.worse))
