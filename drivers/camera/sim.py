"""The simulated camera: renders the scene on the work plane through a camera model.

The scene is a callable returning what lies on the plane now: :class:`Fiducial` tuples
``(x_mm, y_mm, radius_mm, kind)`` at their TRUE positions in the robot base frame (the plant
supplies them), and calibration boards (:class:`~cell.vision.calibration.CircleGridBoard`,
:class:`~cell.vision.calibration.ChessBoard`).

Image formation, in order (all linear until the last step):
1. Radiance at pixel resolution: the bare plane is ``background``; board paper ``paper``,
   board marks ``ink``; fiducials ``background + contrast``. Edges are anti-aliased by
   supersampling (``supersample``^2 samples per pixel) with a linear ramp one sample wide
   on the signed distance to the edge, i.e. close to exact area coverage. Every sample is
   mapped to the plane through the full camera model (distortion, tilt), and only a region
   of interest around each item is rendered.
2. Optics: Gaussian PSF of ``blur_sigma_px`` (applied inside the rendered regions only:
   elsewhere the radiance is flat).
3. Lighting: ``gain * (1 + gx * du + gy * dv) * L + offset``, du, dv running -1..1 from
   the image centre to the right / bottom edge.
4. Sensor: Gaussian noise of ``noise_sigma`` grey levels (seeded), rounded and clipped to
   0..255 (so over-exposure saturates, as on a real sensor).

``render_radiance`` / ``render_float`` give the noise-free image (benchmarks use it for the
Cramer-Rao bound). Frame metadata carries the truth (sim only): the fiducials and their
projected centres in pixels.
"""
from __future__ import annotations

import functools
import math
import threading
from dataclasses import asdict, dataclass
from typing import Callable, Iterable, NamedTuple

import cv2
import numpy as np

from cell.clock import Clock
from cell.errors import ConfigError
from cell.vision.calibration import ChessBoard, CircleGridBoard
from cell.vision.camera_model import CameraModel, VisionError
from drivers.camera.base import CameraBase, CameraError
from drivers.camera.sim_noise import NoiseAhead


class Fiducial(NamedTuple):
    """A circular mark on the work plane: centre (base frame, mm), radius (mm), kind
    (e.g. ``"tool"`` or ``"part"``)."""

    x_mm: float
    y_mm: float
    radius_mm: float
    kind: str = "tool"


@dataclass(frozen=True)
class Optics:
    """Everything between the scene and the 8-bit image. Grey levels are 0..255 units."""

    blur_sigma_px: float = 0.9
    noise_sigma: float = 2.0
    background: float = 50.0
    contrast: float = 160.0
    paper: float = 220.0
    ink: float = 30.0
    gain: float = 1.0
    offset: float = 0.0
    gradient: tuple[float, float] = (0.0, 0.0)
    supersample: int = 4

    def __post_init__(self) -> None:
        for name in ("blur_sigma_px", "noise_sigma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 50):
                raise ConfigError(f"optics.{name} = {v!r} must be in [0, 50]")
        for name in ("background", "contrast", "paper", "ink", "gain", "offset"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and abs(v) <= 1e4):
                raise ConfigError(f"optics.{name} = {v!r} must be a finite number")
        g = self.gradient
        if not (isinstance(g, (tuple, list)) and len(g) == 2
                and all(isinstance(x, (int, float)) and abs(x) < 1 for x in g)):
            raise ConfigError(f"optics.gradient = {g!r} must be (gx, gy) with |g| < 1")
        s = self.supersample
        if isinstance(s, bool) or not isinstance(s, int) or not 1 <= s <= 16:
            raise ConfigError(f"optics.supersample = {s!r} must be an integer in [1, 16]")

    @classmethod
    def from_dict(cls, d: dict) -> "Optics":
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            raise ConfigError(f"optics: unknown keys {sorted(unknown)}")
        if "gradient" in d:
            d = {**d, "gradient": tuple(d["gradient"])}
        return cls(**d)


SceneItem = Fiducial | CircleGridBoard | ChessBoard


def check_scene(items: Iterable) -> list:
    """Validate scene items; tuples become :class:`Fiducial`. Raises :class:`CameraError`
    naming the index and value of the first bad item."""
    try:
        items = list(items)
    except TypeError:
        raise CameraError(f"scene must be a list of fiducials and boards, got "
                          f"{type(items).__name__}") from None
    out = []
    for i, it in enumerate(items):
        if isinstance(it, (CircleGridBoard, ChessBoard)):
            out.append(it)
            continue
        try:
            f = Fiducial(*it)
            vals = [float(f.x_mm), float(f.y_mm), float(f.radius_mm)]
        except (TypeError, ValueError):
            raise CameraError(f"scene item {i} = {it!r} is not (x_mm, y_mm, radius_mm, kind) "
                              f"or a board") from None
        if not all(math.isfinite(x) for x in vals) or vals[2] <= 0 or not isinstance(f.kind, str):
            raise CameraError(f"scene item {i} = {it!r}: needs finite x, y, radius > 0 and a str kind")
        out.append(Fiducial(*vals, f.kind))
    return out


def _roi(model: CameraModel, outline_mm: np.ndarray, margin: float):
    """Inclusive pixel box (u0, v0, u1, v1) around the projected outline, or None."""
    w, h = model.size
    try:
        q = model.project(outline_mm)
    except VisionError:
        return None                      # behind the camera: not visible
    u0, v0 = np.floor(q.min(axis=0) - margin).astype(int)
    u1, v1 = np.ceil(q.max(axis=0) + margin).astype(int)
    u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w - 1), min(v1, h - 1)
    return (u0, v0, u1, v1) if u0 <= u1 and v0 <= v1 else None


def _pixel_grid(model: CameraModel, u0: int, v0: int, u1: int, v1: int) -> np.ndarray:
    """Plane points (mm) of the pixels u0..u1 x v0..v1, shape (v1-v0+1, u1-u0+1, 2):
    ``model.unproject`` of those pixels (a view into :func:`_frame_grid` where the model
    has one)."""
    full = _frame_grid(model)
    if full is not None:
        return full[v0 + 1:v1 + 2, u0 + 1:u1 + 2]
    return _unproject_box(model, u0, v0, u1, v1)


@functools.lru_cache(maxsize=2)         # the cell's two cameras
def _frame_grid(model: CameraModel) -> np.ndarray | None:
    """``model.unproject`` of every pixel of the frame and a one-pixel border around it,
    shape (h+2, w+2, 2) (pixel (u, v) at [v+1, u+1]), made once per model; None where the
    map is not provably point by point. It is for a model without lens distortion whose
    camera axes are the base axes up to sign and order (a nadir camera at yaw 0, as the
    simulated cell's): its unprojection is then elementwise arithmetic plus a rotation
    whose products are exact (by 0 or ±1), so a pixel's plane point is the same floats
    whether it is unprojected alone, in a box or in the whole frame. Otherwise (whose
    undistortion iterates over the batch, or whose rotation rounds in a batch-size-dependent
    matrix kernel) the boxes are unprojected each time as before."""
    rot = np.abs(model.pose.rotation_camera_to_base())
    if not (model.distortion.is_zero and np.isin(rot, (0.0, 1.0)).all()
            and (rot.sum(axis=0) == 1.0).all() and (rot.sum(axis=1) == 1.0).all()):
        return None
    w, h = model.size
    try:
        grid = _unproject_box(model, -1, -1, w, h)
    except VisionError:
        return None                          # every pixel looks away: the boxes raise as before
    grid.flags.writeable = False
    return grid


def _unproject_box(model: CameraModel, u0: int, v0: int, u1: int, v1: int) -> np.ndarray:
    us, vs = np.arange(u0, u1 + 1), np.arange(v0, v1 + 1)
    uu, vv = np.meshgrid(us, vs)
    return model.unproject(np.column_stack([uu.ravel(), vv.ravel()])).reshape(len(vs), len(us), 2)


def _samples(model: CameraModel, box, ss: int) -> np.ndarray:
    """Plane points (mm) of ss x ss samples per pixel of the box, shape (nv*ss, nu*ss, 2):
    :func:`_sample_planes` with the coordinate last."""
    return np.moveaxis(_sample_planes(model, box, ss), 0, -1)


def _sample_planes(model: CameraModel, box, ss: int) -> np.ndarray:
    """Plane points (mm) of ss x ss samples per pixel of the box, shape (2, nv*ss, nu*ss):
    x, then y, each a contiguous plane.

    The full model is evaluated once per pixel (plus a one-pixel border) and interpolated
    bilinearly to the samples: the map is so smooth that this is exact to ~1e-5 px here.
    Sample j of every pixel lies between the same two neighbours relative to its pixel, so
    each of the ss places is one weighted sum of two shifted slices, per axis and coordinate.
    """
    u0, v0, u1, v1 = box
    grid = _pixel_grid(model, u0 - 1, v0 - 1, u1 + 1, v1 + 1)
    offs = (np.arange(ss) + 0.5) / ss - 0.5

    def index(lo, hi):                       # sample positions as (floor index, fraction)
        s = (np.arange(lo, hi + 1)[:, None] + offs).ravel() - (lo - 1)
        i = np.floor(s).astype(int)
        return i, (s - i)

    def pairs(i, n):
        """Per sample place j: the slices (or, if not consecutive, indices) of the lower
        and the upper neighbours of every pixel's sample j."""
        out = []
        for j in range(ss):
            ij = i[j::ss]
            out.append((slice(ij[0], ij[0] + n), slice(ij[0] + 1, ij[0] + 1 + n)) if ij[-1] - ij[0] == n - 1
                       else (ij, ij + 1))
        return out

    iu, fu = index(u0, u1)
    iv, fv = index(v0, v1)
    nu, nv = u1 - u0 + 1, v1 - v0 + 1
    cols_at, rows_at = pairs(iu, nu), pairs(iv, nv)
    out = np.empty((2, nv * ss, nu * ss))
    g = np.empty((nv + 2, nu * ss))
    for c in (0, 1):                             # each coordinate a contiguous plane
        plane = np.ascontiguousarray(grid[..., c])
        for j, (lo, hi) in enumerate(cols_at):
            w = fu[j::ss][None, :]
            g[:, j::ss] = plane[:, lo] * (1 - w) + plane[:, hi] * w
        for j, (lo, hi) in enumerate(rows_at):
            w = fv[j::ss][:, None]
            out[c, j::ss] = g[lo] * (1 - w) + g[hi] * w
    return out


def _pool(cov: np.ndarray, ss: int) -> np.ndarray:
    """Mean of each ss x ss block: ``cov.reshape(n/ss, ss, m/ss, ss).mean(axis=(1, 3))``.

    For 2 x 2 blocks in more than one block column it adds as numpy's mean does there (each
    block row's pair, then the two pairs, then / 4: its reduction runs over the last axis
    innermost and the block rows in memory order), the same floats ten times faster."""
    n, m = cov.shape
    if ss == 2 and m > 2:
        return ((cov[0::2, 0::2] + cov[0::2, 1::2]) + (cov[1::2, 0::2] + cov[1::2, 1::2])) / 4.0
    return cov.reshape(n // ss, ss, m // ss, ss).mean(axis=(1, 3))


def _ramp(d_px: np.ndarray, ss: int) -> np.ndarray:
    """Coverage from signed distance inside (>0) an edge, linear over one sample."""
    return np.clip(0.5 + d_px * ss, 0.0, 1.0)


def _disc_coverage(model: CameraModel, x: float, y: float, r: float, ss: int, margin: float):
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    box = _roi(model, np.column_stack([x + r * np.cos(t), y + r * np.sin(t)]), margin)
    if box is None:
        return None, None
    px, py = _sample_planes(model, box, ss)
    dx, dy = px - x, py - y
    # px per mm along the radial direction (local Jacobian at the centre)
    jac = model.jacobian((x, y))
    axes = _axis_entries(jac)
    band = _edge_band(dx, dy, r, axes, ss)
    if band is None:
        rho = np.hypot(dx, dy)
        return box, _pool(_ramp((r - rho) * _radial_scale(dx, dy, rho, jac, axes), ss), ss)
    inside, at = band
    bx, by = dx.ravel()[at], dy.ravel()[at]
    rho = np.hypot(bx, by)
    cov = inside.astype(float)
    cov.ravel()[at] = _ramp((r - rho) * _radial_scale(bx, by, rho, jac, axes), ss)
    return box, _pool(cov, ss)


def _axis_entries(jac: np.ndarray) -> tuple[tuple[int, float], tuple[int, float]] | None:
    """Per row of a 2 x 2 Jacobian, (column, entry) of its one nonzero entry, where each row
    has one and a zero and the two are in different columns (a camera whose axes are the
    plane's up to sign and order, as a nadir one); None for any other Jacobian."""
    j = jac.tolist()
    picks = [[(k, row[k]) for k in (0, 1) if row[k] != 0.0] for row in j]
    if len(picks[0]) != 1 or len(picks[1]) != 1 or picks[0][0][0] == picks[1][0][0]:
        return None
    return picks[0][0], picks[1][0]


def _edge_band(dx: np.ndarray, dy: np.ndarray, r: float, axes, ss: int):
    """The samples at (dx, dy) from a disc's centre whose coverage is not saturated: where
    ``_ramp((r - rho) * scale, ss)`` is exactly 1 (well inside) or 0 (well outside) it needs
    no square root; the rest, and the centre (where the unit vector is not one), are the
    band. Returns (inside: bool array of dx's shape, the band's flat indices), or None to
    take every sample (``axes`` None, see :func:`_axis_entries`, or a degenerate one).

    With ``axes`` the radial scale |J n| of a unit vector n lies within the entries'
    magnitudes, so a sample more than half a sample's width in px (``0.5 / (ss * smin)`` mm)
    inside or outside the edge saturates; the band is 1 % and 1e-9 r wider than that, which
    no rounding of rho, the scale or their product can cross."""
    if axes is None:
        return None
    smin = min(abs(axes[0][1]), abs(axes[1][1]))
    if not 0.0 < smin < math.inf:
        return None
    w = 1.01 * 0.5 / (ss * smin) + 1e-9 * r
    d2 = dx * dx
    d2 += dy * dy
    lo, hi = r - w, r + w
    inside = d2 < lo * lo if lo > 0 else np.zeros(d2.shape, bool)
    outside = d2 > hi * hi
    outside &= d2 < math.inf                           # an infinite one is computed as ever
    band = ~(inside | outside)                         # a NaN too
    band |= d2 < 1e-22                                 # rho under 1e-12: n is not a unit vector
    return inside, np.flatnonzero(band)


def _radial_scale(dx: np.ndarray, dy: np.ndarray, rho: np.ndarray, jac: np.ndarray,
                  axes) -> np.ndarray:
    """|J n| for the unit vectors n = (dx, dy) / max(rho, 1e-12): ``np.linalg.norm(n @ jac.T,
    axis=-1)`` as the squares' sum's root, for the 2 x 2 Jacobian ``jac``.

    Where ``axes`` (:func:`_axis_entries` of ``jac``) has one entry in each row, each component of ``n @ jac.T``
    is one product, however the matrix product sums it (an exact zero added, fused or not),
    so it is taken as that product, plane by plane: the same floats without the matrix
    product's pass over every sample; otherwise the matrix product itself."""
    den = np.maximum(rho, 1e-12)
    if axes is not None:
        (k0, a), (k1, b) = axes
        n = (np.divide(dx, den), np.divide(dy, den))
        m0 = np.multiply(n[k0], a)
        m1 = np.multiply(n[k1], b)
        m0 *= m0
        m1 *= m1
        m0 += m1
        return np.sqrt(m0, out=m0)
    n = np.empty(dx.shape + (2,))                       # np.stack([dx, dy], axis=-1) / the same
    np.divide(dx, den, out=n[..., 0])
    np.divide(dy, den, out=n[..., 1])
    m = n @ jac.T
    m *= m
    return np.sqrt(m[..., 0] + m[..., 1])


def _board_coverage(model: CameraModel, board, ss: int, margin: float):
    """(box, paper coverage, ink coverage) for a board, or Nones if out of view."""
    lo_c, lo_r, hi_c, hi_r = board.paper_units()
    t = np.linspace(0, 1, 17)
    edge = np.concatenate([np.column_stack([lo_c + (hi_c - lo_c) * t, np.full_like(t, y)])
                           for y in (lo_r, hi_r)]
                          + [np.column_stack([np.full_like(t, x), lo_r + (hi_r - lo_r) * t])
                             for x in (lo_c, hi_c)])
    rot = board._rot()
    outline = edge * board.unit_mm @ rot.T + np.asarray(board.origin_mm)
    box = _roi(model, outline, margin)
    if box is None:
        return None, None, None
    b = board.to_board_units(_samples(model, box, ss).reshape(-1, 2))
    centre = np.asarray(board.origin_mm) + rot @ [(lo_c + hi_c) / 2 * board.unit_mm,
                                                  (lo_r + hi_r) / 2 * board.unit_mm]
    k = model.px_per_mm(centre) * board.unit_mm * ss      # samples per board unit

    def rect(lo_x, lo_y, hi_x, hi_y):
        dx = np.minimum(b[:, 0] - lo_x, hi_x - b[:, 0])
        dy = np.minimum(b[:, 1] - lo_y, hi_y - b[:, 1])
        return np.clip(0.5 + dx * k, 0, 1) * np.clip(0.5 + dy * k, 0, 1)

    paper = rect(lo_c, lo_r, hi_c, hi_r)
    ink = np.zeros_like(paper)
    if isinstance(board, ChessBoard):
        def wave(c):                       # +-1 square wave, ramped across each line
            sign = np.where(np.floor(c) % 2 == 0, 1.0, -1.0)
            return sign * np.clip(np.abs(c - np.round(c)) * 2 * k, 0, 1)
        ink = (1 + wave(b[:, 0] + 1) * wave(b[:, 1] + 1)) / 2 * rect(*board.squares_units())
    shape = (box[3] - box[1] + 1) * ss, (box[2] - box[0] + 1) * ss
    return box, _pool(paper.reshape(shape), ss), _pool(ink.reshape(shape), ss)


def _merge_boxes(boxes: list) -> list:
    """Merge overlapping inclusive boxes until none overlap (so nothing is blurred twice)."""
    boxes = list(boxes)
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]:
                    boxes[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return boxes


def render_radiance(model: CameraModel, items: Iterable, optics: Optics,
                    out: np.ndarray | None = None) -> np.ndarray:
    """Noise-free scene radiance (H, W) float64 after the PSF, before lighting and noise;
    into ``out`` (a float64 (H, W) array, overwritten and returned) if given, else a new array."""
    items = check_scene(items)
    w, h = model.size
    if out is None:
        img = np.full((h, w), float(optics.background))
    else:
        img = out
        img.fill(float(optics.background))
    _paint(img, model, items, optics)
    return img


def _paint(img: np.ndarray, model: CameraModel, items: list, optics: Optics) -> list:
    """Paint checked scene ``items`` onto ``img``, flat ``optics.background`` (radiance,
    blurred); returns the boxes (u0, v0, u1, v1), inclusive and not overlapping, outside
    which ``img`` is still flat."""
    ss, margin = optics.supersample, 4.0 * optics.blur_sigma_px + 3.0
    boxes = []

    def paint(box, cov, level):
        if box is not None:
            img[box[1]:box[3] + 1, box[0]:box[2] + 1] += cov * level
            boxes.append(box)

    for it in items:                                    # boards first, fiducials on top
        if isinstance(it, (CircleGridBoard, ChessBoard)):
            # boards are large: 2x2 samples keep the corners exact to ~0.01 px at 1/4 the cost
            box, paper, ink = _board_coverage(model, it, min(ss, 2), margin)
            paint(box, paper, optics.paper - optics.background)
            paint(box, ink, optics.ink - optics.paper)
            if box is not None and isinstance(it, CircleGridBoard):
                for x, y in it.points_mm():
                    paint(*_disc_coverage(model, x, y, it.radius_mm, ss, margin),
                          optics.ink - optics.paper)
    for it in items:
        if isinstance(it, Fiducial):
            paint(*_disc_coverage(model, it.x_mm, it.y_mm, it.radius_mm, ss, margin), optics.contrast)
    boxes = _merge_boxes(boxes)
    if optics.blur_sigma_px > 0:
        # outside the boxes the radiance is flat, and blurring flat changes nothing; each box
        # has `margin` (4 sigma + 3 px) of flat ground around what it holds
        for u0, v0, u1, v1 in boxes:
            sl = np.s_[v0:v1 + 1, u0:u1 + 1]
            img[sl] = cv2.GaussianBlur(img[sl], (0, 0), optics.blur_sigma_px,
                                       borderType=cv2.BORDER_REPLICATE)
    return boxes


def render_float(model: CameraModel, items: Iterable, optics: Optics,
                 out: np.ndarray | None = None) -> np.ndarray:
    """Noise-free expected grey levels (H, W) float64: radiance with lighting, unclipped
    (into ``out`` as :func:`render_radiance`)."""
    img = render_radiance(model, items, optics, out)
    gx, gy = optics.gradient
    if optics.gain != 1.0 or gx or gy:
        h, w = img.shape
        du = np.linspace(-1.0, 1.0, w)[None, :]
        dv = np.linspace(-1.0, 1.0, h)[:, None]
        img *= optics.gain * (1.0 + gx * du + gy * dv)
    if optics.offset:                                   # adding 0.0 changes no grey level
        img += optics.offset
    return img


def render(model: CameraModel, items: Iterable, optics: Optics,
           rng: np.random.Generator | None = None, *,
           out: np.ndarray | None = None, noise: np.ndarray | None = None) -> np.ndarray:
    """The 8-bit image the sensor delivers: :func:`render_float` + noise, rounded, clipped.

    :param rng: draws the noise, ``noise_sigma * N(0, 1)`` in float32 (default: seeded 0).
    :param out: a float64 (H, W) array to work in, for a camera that renders frame after
        frame (fresh frame-sized arrays cost page faults every frame); the same image.
    :param noise: the noise already drawn, float32 (H, W), as ``rng`` would draw it
        (:class:`~drivers.camera.sim_noise.NoiseAhead`); ``rng`` is then not used.
    """
    img = render_float(model, items, optics, out)
    if optics.noise_sigma > 0:
        if noise is None:
            rng = rng if rng is not None else np.random.default_rng(0)
            noise = rng.standard_normal(img.shape, dtype=np.float32)
            noise *= optics.noise_sigma                 # in float32, as the draw
        img += noise
    np.rint(img, out=img)
    np.clip(img, 0, 255, out=img)
    return img.astype(np.uint8)


def _plain_lighting(optics: Optics) -> bool:
    """Lighting leaves the radiance as it is (gain 1, no gradient, no offset)."""
    return optics.gain == 1.0 and not any(optics.gradient) and not optics.offset


class SimCamera(CameraBase):
    """Simulated camera: each ``grab`` renders ``scene()`` through ``model``.

    ``model`` and ``optics`` may be given as dicts (config). ``seed`` seeds the noise, so
    a run is repeatable frame by frame; the next frame's noise is drawn while the cell works
    on this one (:class:`~drivers.camera.sim_noise.NoiseAhead`, the same frames). ``frame_time_s`` is the exposure and read-out of one
    frame in clock seconds: ``grab`` waits that long on the clock, then renders the scene
    as it is at the end of the exposure. The frame metadata holds the truth (sim only):
    ``fiducials`` (the scene's fiducials) and ``fiducials_px`` (their projected centres).
    Raises :class:`~cell.errors.ConfigError` for bad parameters at construction and
    :class:`CameraError` when the scene returns a bad item (frame counter unchanged).
    """

    backend = "sim"

    def __init__(self, model: CameraModel | dict | None = None,
                 scene: Callable[[], Iterable] | None = None, *,
                 optics: Optics | dict | None = None, seed: int = 0, clock: Clock | None = None,
                 frame_time_s: float = 0.0):
        super().__init__(clock)
        if not (isinstance(frame_time_s, (int, float)) and math.isfinite(frame_time_s)
                and 0 <= frame_time_s <= 10):
            raise ConfigError(f"sim camera: frame_time_s = {frame_time_s!r} must be in [0, 10] s")
        self.frame_time_s = float(frame_time_s)
        if model is None:
            model = CameraModel.nadir(1280, 1024, 0.1)
        self.model = model if isinstance(model, CameraModel) else CameraModel.from_dict(model)
        self.optics = (optics if isinstance(optics, Optics)
                       else Optics.from_dict(optics or {}))
        if scene is not None and not callable(scene):
            raise ConfigError(f"sim camera: scene must be a callable, got {type(scene).__name__}")
        self.scene = scene if scene is not None else (lambda: [])
        self._seed = seed
        self._noise = NoiseAhead(np.random.default_rng(seed))
        self._work: np.ndarray | None = None     # render's float64 work image
        self._flat: np.ndarray | None = None     # radiance, flat background between frames
        self._optics_dict = (self.optics, asdict(self.optics))   # for the frame metadata
        self._render_lock = threading.Lock()
        self._released = None                    # a clock event while hung (fault injection)

    def hang(self) -> None:
        """Fault-injection hook: from now on a grab blocks (as a camera whose driver or
        trigger hangs) until :meth:`release`."""
        self._released = self._clock.event()

    def release(self) -> None:
        """End :meth:`hang`: blocked grabs go on and deliver their frames."""
        released, self._released = self._released, None
        if released is not None:
            released.set()

    def describe(self) -> str:
        w, h = self.model.size
        return f"sim camera ({w}x{h})"

    def _open(self) -> None:
        self._noise.close()
        self._noise = NoiseAhead(np.random.default_rng(self._seed))

    def _close(self) -> None:
        self._noise.close()

    def _grab(self):
        if self._released is not None:
            self._released.wait()
        if self.frame_time_s:
            self._clock.sleep(self.frame_time_s)
        items = check_scene(self.scene())
        w, h = self.model.size
        with self._render_lock:                  # one frame at a time in the work arrays
            if self._work is None or self._work.shape != (h, w):
                self._work = np.empty((h, w))
            sigma = self.optics.noise_sigma
            noise = self._noise.take((h, w), sigma) if sigma > 0 else None
            if noise is not None and _plain_lighting(self.optics):
                img = self._render_on_flat(items, noise)
            else:
                img = render(self.model, items, self.optics, out=self._work, noise=noise)
        fids = [f for f in items if isinstance(f, Fiducial)]
        px = self.model.project([(f.x_mm, f.y_mm) for f in fids]).tolist() if fids else []
        return img, {"source": "sim", "fiducials": [f._asdict() for f in fids],
                     "fiducials_px": px, "optics": self._optics_meta()}

    def _optics_meta(self) -> dict:
        if self._optics_dict[0] is not self.optics:
            self._optics_dict = (self.optics, asdict(self.optics))
        return dict(self._optics_dict[1])

    def _render_on_flat(self, items: list, noise: np.ndarray) -> np.ndarray:
        """:func:`render` for optics whose lighting changes nothing: the scene is painted on
        a radiance image kept flat between frames (only its painted boxes are made flat
        again), and the noise is added, rounded and clipped into the 8-bit frame in one pass
        (:func:`_grey_frame`): the same frame without the passes to fill the image, round it
        and clip it."""
        w, h = self.model.size
        bg = float(self.optics.background)
        flat = self._flat
        if flat is None or flat.shape != (h, w) or flat[0, 0] != bg:
            flat = np.full((h, w), bg)
        self._flat = None                        # until it is flat again
        boxes = _paint(flat, self.model, items, self.optics)
        frame = _grey_frame(flat, bg, noise, boxes, self._work)
        for u0, v0, u1, v1 in boxes:
            flat[v0:v1 + 1, u0:u1 + 1] = bg
        self._flat = flat
        return frame


#: radiance bound (grey levels) below which cv2's saturating conversion to 8 bits is
#: np.rint then np.clip to 0..255: it rounds half to even into an int32, then saturates
_CV_EXACT = 2.0 ** 30


def _grey_frame(flat: np.ndarray, bg: float, noise: np.ndarray, boxes: list,
                work: np.ndarray) -> np.ndarray:
    """The 8-bit frame of radiance ``flat`` (float64, ``bg`` outside the inclusive ``boxes``)
    plus ``noise`` (float32, the frame's shape): each pixel's sum in float64, rounded half to
    even, clipped to 0..255, as :func:`render` makes it. One cv2 pass (the sum in float64,
    rounded, saturated) where every radiance lies within ``_CV_EXACT`` (noise of at most 50
    grey levels sigma cannot take a sum beyond int32), else numpy's three passes in ``work``
    (a float64 array of the frame's shape); a NaN takes numpy's path too."""
    if abs(bg) < _CV_EXACT and all(
            np.abs(flat[v0:v1 + 1, u0:u1 + 1]).max() < _CV_EXACT for u0, v0, u1, v1 in boxes):
        return cv2.add(flat, noise, dtype=cv2.CV_8U)
    img = np.add(flat, noise, out=work)
    np.rint(img, out=img)
    frame = np.empty(flat.shape, np.uint8)
    np.clip(img, 0, 255, out=frame, casting="unsafe")     # whole grey levels: exact
    return frame
