"""Single-joint positioning accuracy from a hand-mounted camera (seed 004): the circle fit,
:class:`JointSweep`, the error model and :func:`analyse`. Pure numerics, no I/O. The result
types (:class:`JointResult`, :class:`Estimate`, :class:`Harmonic`, :class:`HarmonicTest`,
:class:`Row`) and :func:`plot` (the only file writer; lazy matplotlib) live in
:mod:`cell.calibration.joint_result` and are re-exported here.

Method: camera on the hand, a circular target on a plane parallel to the joint's rotation
plane, only the joint under test moves. Each run: a zero image (all joints at 0); up to the
+limit; steps of ``step_deg`` down to the −limit, an image at each position, +limit included
(forward pass); steps back up to the +limit, an image at each (return pass). The target
centres (camera plane frame, mm) lie on one circle about the joint axis; the central angle
between two centres is the joint's rotation between them times ``sense`` (−1 for a hand
camera: the image turns against the joint).

Sign conventions (those of :mod:`cell.effects`), angles in deg:

* actual angle = sense·(ψ − ψ_zero), ψ the polar angle of an image's centre about the circle
  centre, ψ_zero that of its run's zero image; error = actual − nominal.
* ``dir`` = sign of the joint's last motion: −1 on the forward pass, +1 on the return pass,
  except the turning points of the plain procedure: the forward +limit image was reached
  moving up (dir +1), the return −limit image is the forward pass's last pose (dir −1);
  there forward − return ≈ 0. A sweep taken with ``pretravel`` (one step beyond each
  pass's first angle before it starts) has every image of a pass arrive in its direction.
* backlash b > 0 when the joint lags the drive: Δθ = −dir·b/2 (forward +b/2, return −b/2).
* gear-ratio error ε: Δθ = ε·θ (dimensionless; ppm = 1e6·ε).
* cyclic harmonic k of the period P: Δθ = A_k·sin(2πkθ/P + φ_k), A_k ≥ 0, φ_k in deg.
* single step = actual rotation between consecutive images in the pass's direction of travel
  (≈ +step_deg); step error = that − step_deg (< 0: fell short, by ≈ b after a reversal).

Model, linear least squares over every pass image of every run (individual errors, not run
means, for honest degrees of freedom; zero images are the reference, left out)::

    e[r, image] = c_r − dir·b/2 + ε·θ + Σ_k (s_k·sin(2πkθ/P) + c_k·cos(2πkθ/P)) + noise

One offset c_r per run: the zero image's noise and approach state shift its run alike. The
joint zero error is NOT observable (angles are measured from the zero image, error 0 there
by construction); ``offset_deg`` = mean c_r is minus the zero image's place relative to the
band centre and cyclic curve. 95 % intervals: ± t(0.975, dof)·se, dof = images − parameters,
se² = σ²(XᵀX)⁻¹ + the propagated circle-centre covariance (a centre error scales the angles:
on a short arc it dominates ε); the offset's from the scatter of c_r (t, R − 1 dof) if
R ≥ 2, else from se²(c_1) + σ² (the zero image's own noise, that of any image).
Failures raise :class:`~cell.errors.CalibrationError` naming joint, run, pass and step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.calibration.joint_result import Estimate, Harmonic, HarmonicTest, JointResult, Row, plot
from cell.errors import CalibrationError
from cell.numerics.stats import f_sf, t_ppf

ALPHA = 0.05            # 95 % intervals; family-wise level of the harmonic F-tests
MAX_COND = 100.0        # column-scaled design condition beyond which a harmonic is not
                        # identifiable (range ≲ P/5: its sin, cos look like slope, offset)
MAX_RADIUS_RATIO = 1e5  # radius / point spread beyond which the points are a straight line
MIN_CURVATURE_T = 5.0   # radius / se(radius) below which an arc cannot be told from a line
ROUNDOFF_DEG = 1e-9     # model rms below which the data fit to round-off (no harmonic added)
PASSES = ("forward", "return")


# ------------------------------------------------------------------ circle fit
@dataclass(frozen=True)
class CircleFit:
    """Least-squares circle: ``center`` (2,) mm, ``radius`` mm, ``rms`` and ``residuals``
    (N,) = |p − c| − r of the geometric fit, mm; ``cov`` (3,3) covariance of (cx, cy, r),
    mm², σ²(JᵀJ)⁻¹ with σ² = Σres²/(N − 3) (NaN for N = 3); ``n`` points; ``iterations``
    of the Gauss–Newton refinement; ``start`` "taubin" or "hint"."""
    center: np.ndarray
    radius: float
    rms: float
    residuals: np.ndarray
    cov: np.ndarray
    n: int
    iterations: int
    start: str


def _points(points) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise CalibrationError(f"circle fit: points have shape {p.shape}, expected (N, 2) mm")
    return p


def _taubin(u: np.ndarray) -> np.ndarray:
    """Taubin's algebraic circle (Chernov's Newton form) of centred points: (a, b, r)."""
    x, y, n = u[:, 0], u[:, 1], len(u)
    z = x * x + y * y
    mxx, myy, mxy, mxz, myz, mzz = x @ x / n, y @ y / n, x @ y / n, x @ z / n, y @ z / n, z @ z / n
    mz, cov_xy = mxx + myy, mxx * myy - mxy ** 2
    var_z = mzz - mz ** 2
    a3, a2 = 4 * mz, -3 * mz ** 2 - mzz
    a1 = var_z * mz + 4 * cov_xy * mz - mxz ** 2 - myz ** 2
    a0 = mxz * (mxz * myy - myz * mxy) + myz * (myz * mxx - mxz * mxy) - var_z * cov_xy
    xn, yv = 0.0, a0
    for _ in range(99):  # Newton from 0 to the characteristic polynomial's smallest root
        dy = a1 + xn * (2 * a2 + 3 * a3 * xn)
        xnew = xn - yv / dy if dy else xn
        ynew = a0 + xnew * (a1 + xnew * (a2 + xnew * a3))
        if not math.isfinite(xnew) or abs(ynew) >= abs(yv):
            break
        xn, yv = xnew, ynew
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.array([mxz * (myy - xn) - myz * mxy, myz * (mxx - xn) - mxz * mxy]) \
            / (2 * (xn * xn - xn * mz + cov_xy))
    return np.array([c[0], c[1], math.sqrt(c @ c + mz)])


def _geometric(u: np.ndarray, x: np.ndarray, max_iter: int = 100, prior=None):
    """Gauss–Newton with step halving on Σ(|u − c| − r)² (+ w²(r − r0)² with ``prior`` =
    (r0, w)): (x, J, residuals, iterations); with a prior its row is the last."""
    def resid(x):
        d = u - x[:2]
        rho = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-300)
        r, j = rho - x[2], np.column_stack([-d / rho[:, None], -np.ones(len(u))])
        if prior is not None:
            r = np.append(r, prior[1] * (x[2] - prior[0]))
            j = np.vstack([j, [0.0, 0.0, prior[1]]])
        return r, j
    res, jac = resid(x)
    for it in range(1, max_iter + 1):
        step, cost, t = np.linalg.lstsq(jac, -res, rcond=None)[0], res @ res, 1.0
        while t > 1e-8:
            res_n, jac_n = resid(x + t * step)
            if res_n @ res_n <= cost:
                break
            t /= 2
        else:
            return x, jac, res, it  # no decrease at all: at the minimum
        x, res, jac = x + t * step, res_n, jac_n
        if np.linalg.norm(t * step) <= 1e-12 * (1 + np.linalg.norm(x)):
            return x, jac, res, it
    raise CalibrationError(f"circle fit: the geometric fit did not converge in {max_iter} iterations")


def fit_circle(points, *, min_points: int = 5, center_hint=None, radius_prior=None) -> CircleFit:
    """Circle through ``points`` (N,2) mm: Taubin's algebraic fit, then the geometric fit
    (min Σ(|p − c| − r)², Gauss–Newton, analytic Jacobian) from it, or from ``center_hint``
    (2,) mm if given (radius = mean distance). Both run on the points centred on their mean
    and scaled by their rms spread, so a short arc (a few degrees of a 1 m circle) stays well
    conditioned; its centre is then uncertain mostly along the radius, as ``cov`` reports.

    ``radius_prior`` = (r0_mm, sigma_mm): the radius is known beforehand to ±sigma (e.g. the
    distance of the target from the joint axis, from the nominal geometry): the geometric
    fit then also minimises ((r − r0)·σ_p/sigma)², σ_p the unconstrained fit's point noise,
    and ``cov`` includes the prior. On a short arc, where the points alone hardly fix the
    radius (and so the angle scale), this is what makes a gear-ratio error measurable.

    Raises CalibrationError: fewer than ``min_points`` (≥ 3) points, a non-finite point (its
    index), fewer than 3 distinct points, points on a line (radius beyond
    :data:`MAX_RADIUS_RATIO` × spread or below :data:`MIN_CURVATURE_T` standard errors:
    the arc is too short/straight to fit a circle)."""
    p = _points(points)
    if min_points < 3:
        raise CalibrationError(f"circle fit: min_points = {min_points} must be at least 3")
    if len(p) < min_points:
        raise CalibrationError(f"circle fit has too few points: {len(p)} < {min_points}")
    bad = np.flatnonzero(~np.all(np.isfinite(p), axis=1))
    if bad.size:
        raise CalibrationError(f"circle fit: point {int(bad[0])} = {p[bad[0]].tolist()} is not finite")
    if (distinct := len(np.unique(p, axis=0))) < 3:
        raise CalibrationError(f"circle fit: only {distinct} distinct point(s) among {len(p)} "
                               "(the rest are duplicates)")
    mean = p.mean(axis=0)
    spread = math.sqrt(np.mean(np.sum((p - mean) ** 2, axis=1)))
    u = (p - mean) / spread
    line = CalibrationError(f"circle fit: the arc is too short/straight to fit a circle ({len(p)} "
                            f"points spanning {np.ptp(p, axis=0).max():.4g} mm)")
    x0, start = _taubin(u), "taubin"
    if not np.all(np.isfinite(x0)) or x0[2] > MAX_RADIUS_RATIO:
        raise line
    if center_hint is not None:
        h = np.asarray(center_hint, dtype=float)
        if h.shape != (2,) or not np.all(np.isfinite(h)):
            raise CalibrationError(f"circle fit: center_hint = {center_hint!r} must be 2 finite mm")
        c = (h - mean) / spread
        x0, start = np.array([*c, np.mean(np.hypot(*(u - c).T))]), "hint"
    x, jac, res, its = _geometric(u, x0)
    dof, cov = len(p) - 3, np.full((3, 3), np.nan)
    s2 = res @ res / dof if dof > 0 else math.nan
    if radius_prior is not None:
        r0, sig = (float(v) for v in radius_prior)
        if not (math.isfinite(r0) and r0 > 0 and math.isfinite(sig) and sig > 0):
            raise CalibrationError(f"circle fit: radius_prior = {radius_prior!r} must be (r0 > 0, sigma > 0) mm")
        if dof <= 0:
            raise CalibrationError(f"circle fit has too few points for a radius prior: {len(p)}")
        w = max(math.sqrt(s2), 1e-12) / (sig / spread)
        x, jac, res, more = _geometric(u, x, prior=(r0 / spread, w))
        its += more
        res = res[:-1]
        dof += 1
    if dof > 0:
        _, sv, vt = np.linalg.svd(jac, full_matrices=False)  # not inv(JᵀJ): squares the condition
        with np.errstate(divide="ignore", invalid="ignore"):
            cov = s2 * (vt.T / sv ** 2) @ vt * spread ** 2
    radius = float(x[2] * spread)
    if not 0 < x[2] <= MAX_RADIUS_RATIO or (dof > 0 and radius_prior is None
                                            and not radius >= MIN_CURVATURE_T * math.sqrt(cov[2, 2])):
        raise line
    res_mm = res * spread
    return CircleFit(x[:2] * spread + mean, radius, float(math.sqrt(np.mean(res_mm ** 2))),
                     res_mm, cov, len(p), its, start)


def _check_sense(sense) -> int:
    if sense not in (1, -1):
        raise CalibrationError(f"sense = {sense!r} must be +1 or -1 (-1 for a hand camera)")
    return int(sense)


def step_angles(points, circle: CircleFit, sense: int = -1) -> np.ndarray:
    """Polar angle (deg) of each point (N,2) mm about ``circle.center``, unwrapped along the
    given order (consecutive points less than 180° apart), times ``sense`` (+1/−1)."""
    s, d = _check_sense(sense), _points(points) - circle.center
    return s * np.degrees(np.unwrap(np.arctan2(d[:, 1], d[:, 0])))


# ------------------------------------------------------------------ the measurement
def _where(r: int, pass_: str, k: int, nominal) -> str:
    return f"run {r} {pass_} pass step {k} (θ = {float(nominal[k]):.6g}°)"


@dataclass(frozen=True)
class JointSweep:
    """One joint's campaign of R runs over M nominal angles, validated on construction.

    ``joint`` name ("j1"); ``step_deg`` the nominal step, in (0, 180); ``nominal_deg`` (M ≥ 2)
    the forward pass's nominal angles from the +limit down to the −limit, ``step_deg`` apart;
    ``zero`` (R,2) mm each run's zero-image centre; ``forward``, ``return_`` (R,M,2) mm the
    pass images' centres. BOTH passes are stored in forward (nominal_deg) order: index k is
    nominal_deg[k] in both, so ``return_[r, 0]`` is the LAST image of the return pass (see
    :meth:`from_visit_order`). A row of NaN marks a lost target (:func:`analyse` refuses it);
    other non-finite values are refused here. Runs and steps are named by 0-based index.
    ``pretravel``: each pass began one step beyond its first angle (see the module doc)."""
    joint: str
    step_deg: float
    nominal_deg: np.ndarray
    zero: np.ndarray
    forward: np.ndarray
    return_: np.ndarray
    pretravel: bool = False

    def __post_init__(self):
        j, s = self.joint, float(self.step_deg)
        if not isinstance(j, str) or not j:
            raise CalibrationError(f"joint = {j!r} must be a non-empty name such as 'j1'")
        if not (math.isfinite(s) and 0 < s < 180):
            raise CalibrationError(f"{j}: step_deg = {self.step_deg!r} must be in (0, 180) deg")
        nom = np.asarray(self.nominal_deg, dtype=float)
        if nom.ndim != 1 or len(nom) < 2 or not np.all(np.isfinite(nom)) \
                or not np.allclose(np.diff(nom), -s, rtol=0, atol=1e-6 * max(1.0, s)):
            raise CalibrationError(f"{j}: nominal_deg {np.round(nom, 6).tolist()} must run from the "
                                   f"+limit down to the −limit in steps of {s:g}°")
        arrays = {n: np.asarray(getattr(self, n), dtype=float) for n in ("zero", "forward", "return_")}
        r = len(arrays["zero"]) if arrays["zero"].ndim == 2 else 0
        for name, want in (("zero", (r, 2)), ("forward", (r, len(nom), 2)), ("return_", (r, len(nom), 2))):
            if arrays[name].shape != want or r == 0:
                raise CalibrationError(f"{j}: {name} has shape {arrays[name].shape}, expected "
                                       f"{want if r else '(R, 2)'} mm with R ≥ 1 runs")
            flat = arrays[name].reshape(-1, 2)
            bad = np.flatnonzero(~np.isfinite(flat).all(1) & ~np.isnan(flat).all(1))
            if bad.size:
                i = int(bad[0])
                where = f"run {i} zero image" if name == "zero" else \
                    _where(i // len(nom), name.rstrip("_"), i % len(nom), nom)
                raise CalibrationError(f"{j}: centre {flat[i].tolist()} of {where} is not finite "
                                       "(a lost target is a row of NaN)")
        for name, a in (("nominal_deg", nom), *arrays.items()):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "step_deg", s)

    @classmethod
    def from_visit_order(cls, joint, step_deg, nominal_deg, zero, forward, return_visited):
        """Build from the return pass in the order it was taken (−limit first)."""
        return cls(joint, step_deg, nominal_deg, zero, forward, np.asarray(return_visited, float)[:, ::-1])

    @property
    def n_runs(self) -> int:
        return len(self.zero)

    def lost(self) -> list[str]:
        """Where the target was lost (rows of NaN): "run 2 return pass step 7 (θ = -1.2°)"."""
        out = [f"run {r} zero image" for r in np.flatnonzero(np.isnan(self.zero).any(1))]
        for p, a in zip(PASSES, (self.forward, self.return_)):
            out += [_where(r, p, k, self.nominal_deg) for r, k in np.argwhere(np.isnan(a).any(2))]
        return out


# ------------------------------------------------------------------ analysis
def _errors(sw: JointSweep, circle: CircleFit, sense: int):
    """Errors (R,2,M) deg and their gradient (R,2,M,2) deg/mm w.r.t. the circle centre."""
    def polar(p):
        d = p - circle.center
        g = np.stack([d[..., 1], -d[..., 0]], -1) / np.sum(d * d, axis=-1)[..., None]
        return np.degrees(np.arctan2(d[..., 1], d[..., 0])), g
    psi, g = polar(np.stack([sw.forward, sw.return_[:, ::-1]], axis=1))  # visit order
    psi0, g0 = polar(sw.zero)
    psi = np.unwrap(psi, period=360.0, axis=-1)
    psi[:, 1], g[:, 1] = psi[:, 1, ::-1].copy(), g[:, 1, ::-1].copy()  # return: forward order
    err = sense * (psi - psi0[:, None, None]) - sw.nominal_deg
    err -= 360.0 * np.round(err.mean(axis=-1, keepdims=True) / 360.0)  # branch of each pass
    return err, sense * np.degrees(g - g0[:, None, None, :])


def _lsq(X: np.ndarray, e: np.ndarray):
    """β, residuals and the pseudo-inverse P (β = P e), solved column-scaled."""
    norms = np.linalg.norm(X, axis=0)
    norms[norms == 0] = 1.0
    pinv = np.linalg.pinv(X / norms) / norms[:, None]
    beta = pinv @ e
    return beta, e - X @ beta, pinv


def _cond(X: np.ndarray) -> float:
    norms = np.linalg.norm(X, axis=0)
    return float(np.linalg.cond(X / np.where(norms > 0, norms, 1.0)))


def _select(sw, base, theta, e, harmonics, max_harmonic, period):
    """The harmonic numbers to fit and the record of every one tried (see :func:`analyse`)."""
    auto, span, n = harmonics == "auto", float(np.ptp(sw.nominal_deg)), len(e)
    ks = range(1, (max_harmonic if auto else harmonics) + 1)
    cols = lambda kk: [f(2 * np.pi * k * theta / period) for k in kk for f in (np.sin, np.cos)]
    accepted, tests = [], []
    for k in ks:
        per, X1, why = period / k, np.column_stack([base, *cols(accepted + [k])]), None
        if per <= 2 * sw.step_deg * (1 + 1e-9):
            why = f"period {per:.6g}° is not above twice the step {sw.step_deg:g}° (aliased)"
        elif X1.shape[1] >= n:
            why = f"not enough data: {X1.shape[1]} parameters for {n} images"
        elif (cnd := _cond(X1)) > MAX_COND:
            why = (f"not identifiable over a range of {span:.6g}° (period {per:.6g}°): it looks like "
                   f"offset and slope (design condition {cnd:.2g} > {MAX_COND:g})")
        if why:
            tests.append(HarmonicTest(k, per, "not identifiable", why))
            continue
        if not auto:
            accepted.append(k)
            tests.append(HarmonicTest(k, per, "fixed", f"harmonics = {harmonics} asked for"))
            continue
        r0, r1 = _lsq(np.column_stack([base, *cols(accepted)]), e)[1], _lsq(X1, e)[1]
        ssr0, ssr1, dof1 = r0 @ r0, r1 @ r1, n - X1.shape[1]
        if math.sqrt(ssr0 / n) < ROUNDOFF_DEG:
            tests.append(HarmonicTest(k, per, "rejected", "the model already fits to round-off"))
            continue
        p = float(f_sf((ssr0 - ssr1) / 2 / (ssr1 / dof1), 2, dof1)) if ssr1 > 0 else 0.0
        level = ALPHA / len(ks)
        if ok := p < level:
            accepted.append(k)
        tests.append(HarmonicTest(k, per, "accepted" if ok else "rejected",
                                  f"F-test p = {p:.3g} {'<' if ok else '≥'} {level:.3g}", p))
    return accepted, tuple(tests)


def _harmonic(k, period, s, c, cov2, tq) -> Harmonic:
    """Amplitude and phase of s·sin + c·cos, intervals by the delta method (low A ≥ 0)."""
    amp, ph = math.hypot(s, c), math.degrees(math.atan2(c, s))
    ja, jp = (np.array([s, c]) / amp, np.array([-c, s]) / amp ** 2) if amp else (np.zeros(2), None)
    sa = tq * math.sqrt(ja @ cov2 @ ja)
    sp = tq * math.degrees(math.sqrt(jp @ cov2 @ jp)) if amp else 180.0
    return Harmonic(k, period / k, Estimate(amp, max(amp - sa, 0.0), amp + sa, "deg"),
                    Estimate(ph, ph - sp, ph + sp, "deg"))


def analyse(sweep: JointSweep, *, sense: int = -1, harmonics="auto", max_harmonic: int = 6,
            period_deg: float = 360.0, min_points: int = 5, radius_prior=None) -> JointResult:
    """Errors, single-step errors, run means and the model's estimates for one joint.

    One circle is fitted to ALL centres (every run's zero image and both passes lie on the
    same circle about the joint axis); angles, errors, model and intervals follow the module
    docstring (``radius_prior`` (r0, sigma) mm: see :func:`fit_circle`). ``sense`` +1/−1
    (−1: hand camera); ``period_deg`` P of the cyclic error, joint
    deg (360: once per output revolution; 360/N: a motor-side cycle of a ratio-N drive).

    ``harmonics``: an int n fits k = 1..n; "auto" tests k = 1..``max_harmonic`` in turn, each
    by a nested F-test (2, dof) against the model with the harmonics accepted so far, at 5 %
    family-wise (Bonferroni: 0.05/max_harmonic each), keeping every significant one (a drive
    may show k = 2 without k = 1). Either way harmonic k is reported "not identifiable" and
    left out if P/k is not above twice the step (aliased), if it leaves no residual dof, or
    if the column-scaled design's condition number exceeds :data:`MAX_COND` (a range much
    shorter than P/k makes its sin, cos collinear with slope and offset).

    Raises CalibrationError: a bad argument, a lost target (naming run, pass, step and
    angle), a failed circle fit (:func:`fit_circle`), no residual dof."""
    if not isinstance(sweep, JointSweep):
        raise CalibrationError(f"analyse needs a JointSweep, got {type(sweep).__name__}")
    j, sense = sweep.joint, _check_sense(sense)
    if not (type(max_harmonic) is int and max_harmonic >= 0):
        raise CalibrationError(f"{j}: max_harmonic = {max_harmonic!r} must be an int ≥ 0")
    if harmonics != "auto" and not (type(harmonics) is int and harmonics >= 0):
        raise CalibrationError(f"{j}: harmonics = {harmonics!r} must be 'auto' or an int ≥ 0")
    if not (isinstance(period_deg, (int, float)) and 0 < period_deg < math.inf):
        raise CalibrationError(f"{j}: period_deg = {period_deg!r} must be a positive number")
    if lost := sweep.lost():
        more = f" (and {len(lost) - 1} more image(s))" if len(lost) > 1 else ""
        raise CalibrationError(f"{j}: target lost in {lost[0]}{more}; retake the run")
    pts = np.vstack([sweep.zero, sweep.forward.reshape(-1, 2), sweep.return_.reshape(-1, 2)])
    try:
        circle = fit_circle(pts, min_points=min_points, radius_prior=radius_prior)
    except CalibrationError as exc:
        raise CalibrationError(f"{j}: circle through all {len(pts)} target centres: {exc}") from None
    err, grad = _errors(sweep, circle, sense)
    R, M = sweep.n_runs, len(sweep.nominal_deg)
    dirs = np.array([[-1.0] * M, [1.0] * M]) if sweep.pretravel else \
        np.array([[1.0] + [-1.0] * (M - 1), [1.0] * (M - 1) + [-1.0]])

    # every image: run offsets, backlash, slope, harmonics
    e, theta = err.ravel(), np.tile(sweep.nominal_deg, 2 * R)
    base = np.column_stack([np.repeat(np.eye(R), 2 * M, axis=0), np.tile(-dirs.ravel() / 2, R), theta])
    ks, tests = _select(sweep, base, theta, e, harmonics, max_harmonic, float(period_deg))
    X = np.column_stack([base, *[f(2 * np.pi * k * theta / period_deg) for k in ks for f in (np.sin, np.cos)]])
    beta, res, pinv = _lsq(X, e)
    if (dof := len(e) - X.shape[1]) <= 0:
        raise CalibrationError(f"{j}: {len(e)} images cannot fit {X.shape[1]} parameters "
                               "(take more steps or runs)")
    cov = (res @ res / dof) * pinv @ pinv.T
    if np.all(np.isfinite(circle.cov)):
        pg = pinv @ grad.reshape(-1, 2)
        cov = cov + pg @ circle.cov[:2, :2] @ pg.T
    tq = float(t_ppf(1 - ALPHA / 2, dof))
    hw = tq * np.sqrt(np.maximum(np.diag(cov), 0.0))
    est = lambda i, unit: Estimate(float(beta[i]), float(beta[i] - hw[i]), float(beta[i] + hw[i]), unit)
    offs = beta[:R]
    if R > 1:
        h = float(t_ppf(1 - ALPHA / 2, R - 1) * np.std(offs, ddof=1) / math.sqrt(R))
    else:  # the zero image's own noise (σ², as any image's) is in c_1 but not in the residuals
        h = tq * math.sqrt(cov[0, 0] + res @ res / dof)
    offset = Estimate(float(offs.mean()), float(offs.mean() - h), float(offs.mean() + h), "deg")
    found = tuple(_harmonic(k, float(period_deg), beta[R + 2 + 2 * i], beta[R + 3 + 2 * i],
                            cov[R + 2 + 2 * i:R + 4 + 2 * i, R + 2 + 2 * i:R + 4 + 2 * i], tq)
                  for i, k in enumerate(ks))

    steps = np.full_like(err, np.nan)
    steps[:, 0, 1:] = err[:, 0, :-1] - err[:, 0, 1:]
    steps[:, 1, :-1] = err[:, 1, :-1] - err[:, 1, 1:]
    sd = np.std(err, axis=0, ddof=1) if R > 1 else np.full((2, M), np.nan)
    mean, smean, diff = err.mean(axis=0), steps.mean(axis=0), (err[:, 0] - err[:, 1]).mean(axis=0)
    rows = tuple(Row(*map(float, (sweep.nominal_deg[k], mean[0, k], sd[0, k], mean[1, k], sd[1, k],
                                  diff[k], smean[0, k], smean[1, k]))) for k in range(M))
    rep = float(math.sqrt(np.mean(np.var(err - offs[:, None, None], axis=0, ddof=1)))) if R > 1 else None
    for a in (err, steps, dirs):
        a.setflags(write=False)
    return JointResult(j, circle, sense, sweep.step_deg, float(period_deg), sweep.nominal_deg, dirs,
                       rows, err, steps, est(R, "deg"), est(R + 1, "1"), offset, found, tests,
                       R, R * (2 * M + 1), dof, float(math.sqrt(np.mean(res ** 2))), rep)


__all__ = ["CircleFit", "Estimate", "Harmonic", "HarmonicTest", "JointResult", "JointSweep", "Row",
           "analyse", "fit_circle", "plot", "step_angles"]
