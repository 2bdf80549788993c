"""Find circular fiducials in an 8-bit grey image, at sub-pixel accuracy (pure numerics, no I/O).

Pipeline
--------
1. *Coarse*: the local background (a grey opening ~2.5x wider than the largest target, on
   a decimated image) is subtracted, the rest is thresholded at
   ``max(5 sigma_noise, min_contrast / 4, 3)`` grey levels and split into connected
   components. Components of fiducial size are candidates; each is checked for being cut by
   the image edge, saturation, contrast and roundness.
2. *Refine*, one of
   ``"model"`` (default): least-squares fit of the blurred-disc image model
   ``I = B + gx (u - u0) + gy (v - v0) + A * erfc((rho - r) / (sqrt 2 s)) / 2`` with
   ``rho = |(u, v) - (uc, vc)|`` over a square region of interest. Under Gaussian noise this
   is the maximum-likelihood estimate and reaches the Cramer-Rao bound (see
   ``bench/bench_vision.py``); the fit covariance gives the centre uncertainty.
   ``"centroid"``: grey-level centroid with a plane fitted to the ROI border subtracted.
   ``"moments"``: centroid of the binary blob (the baseline; stalls near 0.08 px).

Pixel convention: OpenCV's, the centre of the top-left pixel is (0, 0).
Every failure raises :class:`~cell.vision.camera_model.VisionError` naming what went wrong
and the pixel region ``(u0..u1, v0..v1)``; nothing is guessed.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import cv2
import numpy as np
from scipy.special import erfc

from cell.numerics.lsq import least_squares
from cell.vision.camera_model import VisionError

METHODS = ("model", "centroid", "moments")
_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)


@dataclass(frozen=True)
class FiducialFix:
    """One measured fiducial.

    ``u_px, v_px``: centre (pixels). ``radius_px``: fitted radius (edge at half contrast).
    ``contrast``: |disc - background| in grey levels; ``background``: grey level around it.
    ``edge_sigma_px``: fitted edge blur (optics PSF and pixel size together).
    ``circularity``: roundness of the coarse blob, 1 - (radial spread of its boundary
    beyond digitisation) / radius: 1.0 for a disc, ~0.92 for a square (see ``_circularity``).
    ``residual_rms``: rms of the fit residual, grey levels (about the image noise if the
    model fits). ``sigma_u_px, sigma_v_px``: estimated 1-sigma centre uncertainty.
    ``saturated``: clipped pixels in the region. ``region``: (u0, v0, u1, v1), inclusive.
    """

    u_px: float
    v_px: float
    radius_px: float
    contrast: float
    background: float
    edge_sigma_px: float
    circularity: float
    residual_rms: float
    sigma_u_px: float
    sigma_v_px: float
    saturated: int
    region: tuple[int, int, int, int]
    method: str
    polarity: str

    @property
    def uv(self) -> tuple[float, float]:
        return self.u_px, self.v_px

    def as_dict(self) -> dict:
        d = asdict(self)
        d["region"] = list(self.region)
        return d


def _where(region) -> str:
    u0, v0, u1, v1 = region
    return f"pixel region u {u0}..{u1}, v {v0}..{v1}"


def check_image(image, what: str = "image") -> np.ndarray:
    """Return ``image`` if it is a non-empty 2-D uint8 array, else raise :class:`VisionError`."""
    if not isinstance(image, np.ndarray):
        raise VisionError(f"{what} must be a numpy array, got {type(image).__name__}", "bad_image")
    if image.dtype != np.uint8:
        raise VisionError(f"{what} must be 8-bit grey (uint8), got dtype {image.dtype}", "bad_image")
    if image.ndim != 2:
        raise VisionError(f"{what} must be 2-D (grey), got shape {image.shape}", "bad_image")
    if image.shape[0] < 8 or image.shape[1] < 8:
        raise VisionError(f"{what} is empty or too small: shape {image.shape} (need >= 8x8)", "bad_image")
    return image


def _check_polarity(polarity: str) -> None:
    if polarity not in ("bright", "dark"):
        raise VisionError(f"polarity = {polarity!r} must be 'bright' or 'dark'")


def estimate_noise(work: np.ndarray) -> float:
    """Robust image-noise sigma (grey levels) from horizontal pixel differences (MAD) of
    every other row. For 8-bit images the median is read off the differences' histogram:
    the same value np.median gives (the mean of the two middle values for an even count)."""
    if work.dtype != np.uint8:
        d = np.abs(np.diff(work[::2].astype(np.int16), axis=1))
        return max(0.5, 1.4826 * float(np.median(d)) / _SQRT2)
    rows = work[::2]
    d = cv2.absdiff(rows[:, 1:], rows[:, :-1])
    counts = np.cumsum(cv2.calcHist([d], [0], None, [256], [0, 256]).ravel().astype(np.int64))
    n = d.size
    lo, hi = np.searchsorted(counts, [(n - 1) // 2, n // 2], side="right")
    return max(0.5, 1.4826 * (float(lo + hi) / 2.0) / _SQRT2)


def _local_background(work: np.ndarray, max_radius_px: float) -> np.ndarray:
    """Background under bright blobs: grey opening with a square wider than the largest
    target, on a decimated image. An opening keeps linear lighting ramps exactly and
    removes every bright feature narrower than the square; the image is extended by point
    reflection first, so ramps are kept up to the image edge too."""
    h, w = work.shape
    max_radius_px = min(max_radius_px, min(h, w) / 5.0)    # a window wider than the image
    f = max(1, int(max_radius_px // 4))                    # would follow no gradient at all
    small = cv2.resize(work, (max(1, w // f), max(1, h // f)),
                       interpolation=cv2.INTER_AREA).astype(np.float32)
    k = int(math.ceil(2.5 * max_radius_px / f)) | 1
    pad = min(k, *small.shape) - 1
    mirrored = cv2.copyMakeBorder(small, pad, pad, pad, pad, cv2.BORDER_REFLECT_101)
    edge = cv2.copyMakeBorder(small, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    ext = 2.0 * edge - mirrored                            # odd extension: continues ramps
    bg = cv2.morphologyEx(ext, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    bg = bg[pad:pad + small.shape[0], pad:pad + small.shape[1]]
    return cv2.resize(bg, (w, h), interpolation=cv2.INTER_LINEAR)


def _disc_model(p: np.ndarray, uu: np.ndarray, vv: np.ndarray, du0: np.ndarray, dv0: np.ndarray,
                columns: int = 8):
    """Model values and Jacobian (m, 8) for parameters (uc, vc, r, A, B, s, gx, gy) at pixels
    (uu, vv), ``du0, dv0`` = uu - u0, vv - v0; only the first ``columns`` columns are filled.

    ``(B + A E(rho)) * (1 + gx (u - u0) + gy (v - v0))``: the lighting gradient multiplies
    disc and ground alike, as uneven illumination does. A < 0 for a dark disc. With
    gx = gy = 0 the lighting factor is exactly 1 and is left out.
    """
    uc, vc, r, a, b, s, gx, gy = p
    sgn = 1.0 if s >= 0 else -1.0
    s = abs(s) + 1e-9
    du, dv = uu - uc, vv - vc
    rho = np.sqrt(du * du + dv * dv) + 1e-12
    z = (rho - r) / s
    e = 0.5 * erfc(z / _SQRT2)
    base = b + a * e
    aphi = a * np.exp(-0.5 * z * z) / (s * _SQRT2PI)            # A * (-dE/drho) (* light)
    jac = np.empty((uu.size, 8))
    flat = gx == 0 and gy == 0
    if flat:
        jac[:, 3] = e
        jac[:, 4] = 1.0
    else:
        light = 1.0 + gx * du0 + gy * dv0
        aphi *= light
        jac[:, 3] = e * light
        jac[:, 4] = light
    jac[:, 0] = aphi * du / rho
    jac[:, 1] = aphi * dv / rho
    jac[:, 2] = aphi
    jac[:, 5] = aphi * z * sgn
    if columns > 6:
        jac[:, 6] = base * du0
        jac[:, 7] = base * dv0
    return (base if flat else base * light), jac


def _median(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a 1-D float array, without its wrapper: the mean of the
    two middle values (the middle one for an odd count), NaN if any value is NaN."""
    n = x.size
    part = np.partition(x, [(n - 1) // 2, n // 2, n - 1])
    if np.isnan(part[-1]):
        return float("nan")
    return float((part[(n - 1) // 2] + part[n // 2]) / 2.0) if n % 2 == 0 else float(part[n // 2])


def _fit_plane(vals: np.ndarray, du: np.ndarray, dv: np.ndarray):
    """Least-squares plane B + gx du + gy dv (du, dv: offsets from the plane's origin);
    returns (B, gx, gy) and the largest |slope| / standard error of the slopes (how sure
    we are there is a gradient)."""
    a = np.column_stack([np.ones_like(du), du, dv])
    coef, *_ = np.linalg.lstsq(a, vals, rcond=None)
    dof = max(1, len(vals) - 3)
    res_var = float(np.sum((vals - a @ coef) ** 2)) / dof
    se = np.sqrt(np.maximum(np.diag(np.linalg.pinv(a.T @ a)) * res_var, 1e-30))
    return coef, float(np.max(np.abs(coef[1:]) / se[1:]))


def refine_fiducial(image: np.ndarray, u: float, v: float, radius_px: float, *,
                    polarity: str = "bright", method: str = "model",
                    min_contrast: float = 30.0, max_saturated_fraction: float = 0.02,
                    circularity: float = float("nan")) -> FiducialFix:
    """Measure one fiducial whose centre is roughly at (u, v), radius roughly ``radius_px``.

    The region of interest is a square of half-size ``radius_px + margin`` around (u, v).
    Raises :class:`VisionError` if the region leaves the image, more than
    ``max_saturated_fraction`` of the disc area is clipped (255 for bright, 0 for dark
    fiducials), the contrast is below ``min_contrast`` grey levels, or the fit fails.
    """
    check_image(image)
    _check_polarity(polarity)
    if method not in METHODS:
        raise VisionError(f"method = {method!r} must be one of {METHODS}")
    if not (math.isfinite(u) and math.isfinite(v) and math.isfinite(radius_px) and radius_px > 0):
        raise VisionError(f"refine_fiducial: bad start (u={u}, v={v}, radius_px={radius_px})")
    h, w = image.shape
    margin = int(math.ceil(max(5.0, 0.25 * radius_px + 4.0)))
    half = int(math.ceil(radius_px)) + margin
    ui, vi = int(round(u)), int(round(v))
    region = (ui - half, vi - half, ui + half, vi + half)
    if region[0] < 0 or region[1] < 0 or region[2] > w - 1 or region[3] > h - 1:
        raise VisionError(f"target at {_where(region)} is cut by or too close to the image edge "
                          f"(image {w}x{h}, needs {margin} px of margin around the disc)", "cut")
    raw = image[region[1]:region[3] + 1, region[0]:region[2] + 1]
    sat_level = 255 if polarity == "bright" else 0
    saturated = int(np.count_nonzero(raw == sat_level))
    disc_area = math.pi * radius_px ** 2
    if saturated > max(2.0, max_saturated_fraction * disc_area):
        raise VisionError(f"target at {_where(region)} is saturated: {saturated} pixels at "
                          f"{sat_level} (> {max_saturated_fraction:.0%} of the disc area "
                          f"{disc_area:.0f} px); lower exposure or gain", "saturated")
    work = raw.astype(np.float64)
    sign = 1.0 if polarity == "bright" else -1.0
    uu = np.arange(region[0], region[2] + 1, dtype=np.float64)[None, :]   # the pixel grid as a
    vv = np.arange(region[1], region[3] + 1, dtype=np.float64)[:, None]   # row and a column
    du, dv = uu - u, vv - v
    rho0 = _radii(du, dv, (radius_px + 0.6 * margin, 0.5 * radius_px, radius_px + 3.0))

    # Background: a plane fitted to the ROI border, outside the disc and its blur.
    ring = rho0 > radius_px + 0.6 * margin
    if np.count_nonzero(ring) < 12:
        ring = _radii(du, dv, (radius_px + 2,)) > radius_px + 2
    (b, gx, gy), slope_t = _fit_plane(work[ring], np.broadcast_to(du, work.shape)[ring],
                                      np.broadcast_to(dv, work.shape)[ring])
    signal = sign * (work - (b + gx * du + gy * dv))
    inner = rho0 < 0.5 * radius_px
    contrast0 = _median(signal[inner]) if np.any(inner) else float(signal.max())
    if not contrast0 >= min_contrast:
        raise VisionError(f"target at {_where(region)} has too low contrast: {contrast0:.1f} "
                          f"grey levels < min_contrast {min_contrast:g}", "low_contrast")

    # Grey-level centroid over the disc plus its blurred edge.
    win = rho0 <= radius_px + 3.0
    wsig = np.where(win, signal, 0.0)
    mass = float(wsig.sum())
    uc, vc = float((wsig * uu).sum() / mass), float((wsig * vv).sum() / mass)
    r_est = math.sqrt(max(mass, 1.0) / (math.pi * contrast0))
    fix = dict(u_px=uc, v_px=vc, radius_px=r_est, contrast=contrast0, background=float(b),
               edge_sigma_px=float("nan"), residual_rms=float("nan"),
               sigma_u_px=float("nan"), sigma_v_px=float("nan"))
    if method == "model":
        # Fit the lighting gradient only where the border shows one (slope > 3 standard
        # errors): its two parameters correlate with the centre and cost ~15 % precision.
        bb = b if abs(b) > 1.0 else 1.0
        gradient = slope_t > 3.0
        p0 = np.array([uc, vc, r_est, sign * contrast0, b, 1.0,
                       gx / bb if gradient else 0.0, gy / bb if gradient else 0.0])
        fix.update(_fit_disc(work, uu, vv, p0, u, v, region, sign, free=8 if gradient else 6))
    return FiducialFix(**fix, circularity=circularity, saturated=saturated, region=region,
                       method=method, polarity=polarity)


#: the edge ring the disc model is fitted over: ± (RING_PX + RING_FRACTION·r) px about the edge
RING_PX, RING_FRACTION = 5.0, 0.1


def edge_ring(uu, vv, uc: float, vc: float, r: float) -> np.ndarray:
    """Pixels within ``RING_PX + RING_FRACTION·r`` of the circle of radius ``r`` about
    (uc, vc): the edge, where the image depends on the centre, with enough of both plateaus
    on either side to fix contrast and ground. Pixels deeper inside or further out carry
    no information on the centre, only cost. ``uu``, ``vv``: the pixels' coordinates, or a
    row and a column that broadcast to them."""
    band = RING_PX + RING_FRACTION * r
    return np.abs(_radii(uu - uc, vv - vc, (r - band, r + band)) - r) <= band


#: _radii takes np.hypot's value within this much (px, times 1 + the threshold) of a threshold
RADII_GUARD = 1e-9


def _radii(du: np.ndarray, dv: np.ndarray, thresholds) -> np.ndarray:
    """``np.hypot(du, dv)`` (arrays that broadcast) as far as comparing it with
    ``thresholds`` can tell, at a third of its cost: ``sqrt(du² + dv²)``, within a few ulp of
    hypot, and hypot's own value wherever that comes within ``RADII_GUARD·(1 + |t|)`` of a
    threshold t. A distance further from every threshold lies on the same side of each, by
    a margin far above both roundings, so every <, <=, >, >= with a threshold (or with
    ``|d - r|`` against a band whose ends are thresholds) comes out as with hypot."""
    d = np.sqrt(du * du + dv * dv)
    near = np.zeros(d.shape, dtype=bool)
    for t in thresholds:
        near |= np.abs(d - t) < RADII_GUARD * (1.0 + abs(t))
    if near.any():
        d[near] = np.hypot(np.broadcast_to(du, d.shape)[near], np.broadcast_to(dv, d.shape)[near])
    return d



def _fit_disc(work, uu, vv, p0, u0, v0, region, sign: float, free: int = 8) -> dict:
    # the first `free` parameters are fitted, the rest held at p0; over the edge ring only
    keep = edge_ring(uu, vv, p0[0], p0[1], p0[2])
    z, uf, vf = work[keep], np.broadcast_to(uu, work.shape)[keep], np.broadcast_to(vv, work.shape)[keep]
    du0, dv0 = uf - u0, vf - v0
    fixed = p0[free:]
    last: dict = {}

    def model(q):                        # least_squares asks for f and J at the same q
        key = q.tobytes()
        if last.get("key") != key:
            last["key"], last["fj"] = key, _disc_model(np.concatenate([q, fixed]), uf, vf, du0, dv0, free)
        return last["fj"]

    def fun(q):
        return model(q)[0] - z

    def jac(q):
        return model(q)[1][:, :free]

    sol = least_squares(fun, p0[:free], jac=jac, xtol=1e-10, ftol=1e-10, max_nfev=100 * (free + 1))
    p = sol.x
    uc, vc, r, a, b, s = np.concatenate([p, fixed])[:6]
    moved = math.hypot(uc - p0[0], vc - p0[1])
    if not sol.success or not np.all(np.isfinite(p)) or r <= 0 or sign * a <= 0 \
            or moved > 0.5 * p0[2] \
            or abs(s) > 0.5 * r:
        raise VisionError(f"disc-model fit failed at {_where(region)} (status {sol.status}, "
                          f"centre moved {moved:.2f} px, r={r:.2f}, contrast={a:.1f}, blur={abs(s):.2f})")
    dof = max(1, z.size - p.size)
    res_var = float(sol.fun @ sol.fun) / dof
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * res_var
    except np.linalg.LinAlgError:
        raise VisionError(f"disc-model fit at {_where(region)} is degenerate (singular normal matrix)") from None
    return dict(u_px=float(uc), v_px=float(vc), radius_px=float(r), contrast=float(abs(a)),
                background=float(b), edge_sigma_px=float(abs(s)), residual_rms=math.sqrt(res_var),
                sigma_u_px=math.sqrt(max(cov[0, 0], 0.0)), sigma_v_px=math.sqrt(max(cov[1, 1], 0.0)))


#: how far a blob's area radius may lie outside the radius range and still be fitted (the
#: threshold takes in part of the blurred edge, so the area radius runs ~1 px large)
SIZE_SLACK_PX = 3.0


def find_fiducials(image: np.ndarray, *, expected: int | None = None, polarity: str = "bright",
                   min_radius_px: float = 3.0, max_radius_px: float = 60.0,
                   min_contrast: float = 30.0, min_circularity: float = 0.95,
                   max_saturated_fraction: float = 0.02, method: str = "model",
                   roi: tuple[int, int, int, int] | None = None) -> list[FiducialFix]:
    """Find every circular fiducial in ``image`` (or in ``roi`` = (u0, v0, u1, v1), inclusive).

    ``polarity``: "bright" discs on a darker ground, or "dark" on lighter. Radii are in
    pixels, contrasts in grey levels. Results are sorted by v, then u.

    Raises :class:`VisionError` when the image is not a non-empty 2-D uint8 array; when no
    target is found; when a target-sized blob is cut by the image edge, saturated, or of
    too low contrast (an unmeasurable target is never skipped silently); and when
    ``expected`` is given and a different number of targets is found.
    """
    check_image(image)
    _check_polarity(polarity)
    if method not in METHODS:
        raise VisionError(f"method = {method!r} must be one of {METHODS}")
    if expected is not None and (isinstance(expected, bool) or not isinstance(expected, int)
                                 or expected < 1):
        raise VisionError(f"expected = {expected!r} must be a positive integer or None")
    if not 0 < min_radius_px <= max_radius_px:
        raise VisionError(f"radius range [{min_radius_px}, {max_radius_px}] px is empty or negative")
    h, w = image.shape
    full_image, off_u, off_v = image, 0, 0
    if roi is not None:
        u0, v0, u1, v1 = (int(x) for x in roi)
        if not (0 <= u0 < u1 < w and 0 <= v0 < v1 < h):
            raise VisionError(f"roi {_where(roi)} is not inside the {w}x{h} image")
        image, off_u, off_v = image[v0:v1 + 1, u0:u1 + 1], u0, v0
        check_image(image, f"roi {_where(roi)}")
    work = image if polarity == "bright" else cv2.bitwise_not(image)
    noise = estimate_noise(work)
    bg = _local_background(work, max_radius_px)
    thr = max(5.0 * noise, 0.25 * min_contrast, 3.0)
    mask = ((work.astype(np.float32) - bg) > thr).astype(np.uint8)
    n, labels, (lu, lv), stats, cents = _components(mask)
    a_min, a_max = 0.5 * math.pi * min_radius_px ** 2, math.pi * (max_radius_px + 2.0) ** 2
    hh, ww = image.shape
    found, problems, ignored = [], [], []
    kinds: list[str] = []
    for i in range(1, n):
        x, y, bw, bh, area = (int(t) for t in stats[i])
        region = (x + off_u, y + off_v, x + bw - 1 + off_u, y + bh - 1 + off_v)
        too_big = area > a_max or max(bw, bh) > 2.0 * max_radius_px + 4.0
        if area < a_min or too_big:
            if too_big:
                ignored.append(f"blob of {area} px at {_where(region)} (larger than max_radius_px)")
            continue
        if x == 0 or y == 0 or x + bw == ww or y + bh == hh:
            edge = "image" if roi is None else "roi"
            problems.append(f"target at {_where(region)} is cut by the {edge} edge")
            kinds.append("cut")
            continue
        blob = (labels[y - lv:y - lv + bh, x - lu:x - lu + bw] == i).astype(np.uint8)
        holes = _hole_area(blob)
        if holes > 0.05 * area:
            ignored.append(f"ring-shaped blob at {_where(region)} ({holes} px hole)")
            continue
        circ = _circularity(blob, cents[i][0] - x, cents[i][1] - y)
        if circ < min_circularity:
            ignored.append(f"blob at {_where(region)} with circularity {circ:.2f} < {min_circularity}")
            continue
        u, v = float(cents[i][0]) + off_u, float(cents[i][1]) + off_v
        r0 = math.sqrt(area / math.pi)
        if r0 + SIZE_SLACK_PX < min_radius_px or r0 - SIZE_SLACK_PX > max_radius_px:
            ignored.append(f"disc of radius about {r0:.1f} px at {_where(region)} (outside "
                           f"{min_radius_px:g}..{max_radius_px:g} px)")
            continue                     # plainly another size: not worth a fit
        if method == "moments":
            found.append(FiducialFix(u, v, r0, float("nan"), float("nan"), float("nan"), circ,
                                     float("nan"), float("nan"), float("nan"), 0, region,
                                     "moments", polarity))
            continue
        try:
            # the refinement works on the full image so its ROI may extend past `roi`
            fix = refine_fiducial(full_image, u, v, r0, polarity=polarity,
                                  method=method, min_contrast=min_contrast,
                                  max_saturated_fraction=max_saturated_fraction, circularity=circ)
        except VisionError as exc:
            problems.append(str(exc))
            kinds.append(exc.kind)
            continue
        if not min_radius_px <= fix.radius_px <= max_radius_px:
            ignored.append(f"disc of radius {fix.radius_px:.1f} px at {_where(region)} (outside "
                           f"{min_radius_px:g}..{max_radius_px:g} px)")
            continue
        found.append(fix)
    if problems:
        raise VisionError("; ".join(problems), kinds[0])
    if not found:
        extra = f" ({'; '.join(ignored[:3])})" if ignored else ""
        full = (off_u, off_v, off_u + ww - 1, off_v + hh - 1)
        raise VisionError(f"no target found in {_where(full)}: nothing of radius "
                          f"{min_radius_px:g}..{max_radius_px:g} px standing out by > {thr:.0f} "
                          f"grey levels{extra}", "no_target")
    found.sort(key=lambda f: (f.v_px, f.u_px))
    if expected is not None and len(found) != expected:
        where = ", ".join(f"({f.u_px:.1f}, {f.v_px:.1f}) in {_where(f.region)}" for f in found)
        raise VisionError(f"expected {expected} target(s), found {len(found)}: {where}", "multiple")
    return found


def _components(mask: np.ndarray):
    """``cv2.connectedComponentsWithStats(mask, connectivity=8)`` run on the bounding box of
    the mask's pixels only: (n, labels of that box, (u, v) of its corner, stats, centroids),
    stats and centroids of the components (rows 1..n-1) in the mask's coordinates.

    The same components, numbered alike and with the same centroids to the bit: the box
    starts on even coordinates, so OpenCV's 2x2-block labelling meets the pixels as it did
    in the whole mask, and a centroid is moved by re-forming OpenCV's own quotient (pixel
    sum / area) from the exact integer sum. Row 0 (the background) is left as it is."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0:
        return 1, None, (0, 0), np.zeros((1, 5), np.int32), np.zeros((1, 2))
    u0, v0 = x & ~1, y & ~1
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask[v0:y + h, u0:x + w], connectivity=8)
    stats[1:, 0] += u0
    stats[1:, 1] += v0
    area = stats[1:, 4:5].astype(np.float64)
    cents[1:] = (np.rint(cents[1:] * area) + area * np.array([u0, v0], np.float64)) / area
    return n, labels, (u0, v0), stats, cents


def _hole_area(blob: np.ndarray) -> int:
    """Pixels enclosed by the blob but not part of it (a ring's hole; a disc has none)."""
    filled = cv2.copyMakeBorder(blob, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    cv2.floodFill(filled, None, (0, 0), 2)
    return int(np.count_nonzero(filled == 0))


def _circularity(blob: np.ndarray, cu: float, cv: float) -> float:
    """1 - (radial spread of the blob's boundary beyond 0.5 px of digitisation) / mean radius.

    A digitised disc reads 1.0, a square ~0.93, an ellipse of axis ratio 0.8 ~0.97.
    """
    contours, _ = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64)
    d = np.hypot(pts[:, 0] - cu, pts[:, 1] - cv)
    mean = np.add.reduce(d) / d.size                       # d.mean() and d.std() as numpy
    dev = d - mean                                         # forms them, the sum taken once
    std = math.sqrt(np.add.reduce(dev * dev) / d.size)
    return float(1.0 - max(std - 0.5, 0.0) / max(float(mean), 1e-9))


def find_fiducial(image: np.ndarray, **kwargs) -> FiducialFix:
    """Exactly one fiducial: :func:`find_fiducials` with ``expected=1``. Same raises."""
    return find_fiducials(image, expected=1, **kwargs)[0]
