"""Camera-to-work-plane calibration from images of a board lying on the plane (no I/O).

The result is a :class:`PlaneCalibration`: the map from pixels to the robot base frame on
the work plane (mm), made of lens undistortion (k1, k2, p1, p2 about the image centre) and
a plane homography. That is the complete model for points on one plane: it needs no
focal length or camera pose, so a single view of a board (or several placements of it on
the same plane) is enough. The board's placement in the base frame (``origin_mm``,
``angle_deg``) is what ties the pixels to the robot; the cell measures it by touching the
board's reference marks with the tool, or by placing the board on dowel pins.

Steps: OpenCV finds the board (``findCirclesGrid`` with a symmetric grid, or
``findChessboardCornersSB``); circle centres are then refined with the disc-model fit of
:mod:`cell.vision.fiducial`; the grid order OpenCV returned is matched to the board (see
:func:`detect_board`); ``findHomography`` gives the start and a Levenberg-Marquardt fit of
homography + distortion minimises the reprojection error in pixels.

Symmetric boards look the same turned by 180 degrees (and square ones by 90), so the
caller says roughly which way the image +u axis points in the base frame
(``u_axis_deg``, counter-clockwise from base +x, seen from above; it must be right to
within +-45 degrees). A camera looking down sees the base frame mirrored (v grows where y
shrinks); a view that is not is rejected.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Sequence, Union

import cv2
import numpy as np

from cell.errors import ConfigError
from cell.vision.camera_model import Distortion, VisionError, distort, undistort
from cell.vision.fiducial import FiducialFix, check_image, find_fiducials, refine_fiducial

FORMAT = "cell-vision-calibration/1"


@dataclass(frozen=True)
class _Board:
    cols: int
    rows: int
    origin_mm: tuple[float, float] = (0.0, 0.0)
    angle_deg: float = 0.0

    def _check(self, unit: float, unit_name: str) -> None:
        for name in ("cols", "rows"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 3 <= v <= 100:
                raise VisionError(f"{type(self).__name__}.{name} = {v!r} must be an integer in [3, 100]")
        if not (math.isfinite(unit) and unit > 0):
            raise VisionError(f"{type(self).__name__}.{unit_name} = {unit!r} must be > 0")
        ox, oy = self.origin_mm
        if not (math.isfinite(ox) and math.isfinite(oy) and math.isfinite(self.angle_deg)):
            raise VisionError(f"{type(self).__name__}: origin_mm {self.origin_mm} / angle_deg "
                              f"{self.angle_deg} must be finite")

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(cols, rows): OpenCV's patternSize (points per row, points per column)."""
        return self.cols, self.rows

    def _rot(self) -> np.ndarray:
        c, s = math.cos(math.radians(self.angle_deg)), math.sin(math.radians(self.angle_deg))
        return np.array([[c, -s], [s, c]])

    def points_mm(self) -> np.ndarray:
        """Base-frame positions (rows*cols, 2) mm, row-major: index = row * cols + col.
        Point (col, row) lies at origin + R(angle) @ (col, row) * unit_mm."""
        r, c = np.mgrid[0:self.rows, 0:self.cols]
        local = np.column_stack([c.ravel(), r.ravel()]) * self.unit_mm
        return local @ self._rot().T + np.asarray(self.origin_mm, dtype=float)

    def to_board_units(self, points_mm: np.ndarray) -> np.ndarray:
        """Base-frame mm (N, 2) -> board coordinates in units of the pitch (col, row)."""
        return ((np.asarray(points_mm) - np.asarray(self.origin_mm)) @ self._rot()) / self.unit_mm

    def as_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["origin_mm"] = list(self.origin_mm)
        return {"kind": self.kind, **d}


@dataclass(frozen=True)
class CircleGridBoard(_Board):
    """Symmetric grid of dark circles on light paper: ``cols`` x ``rows`` circles of radius
    ``radius_mm`` every ``pitch_mm``; the paper reaches one pitch beyond the outer circles."""

    pitch_mm: float = 10.0
    radius_mm: float = 2.5
    kind = "circles"

    def __post_init__(self) -> None:
        self._check(self.pitch_mm, "pitch_mm")
        if not 0 < self.radius_mm < 0.4 * self.pitch_mm:
            raise VisionError(f"CircleGridBoard.radius_mm = {self.radius_mm} must be in "
                              f"(0, 0.4 * pitch_mm = {0.4 * self.pitch_mm})")

    @property
    def unit_mm(self) -> float:
        return self.pitch_mm

    def paper_units(self) -> tuple[float, float, float, float]:
        """Paper rectangle (col_lo, row_lo, col_hi, row_hi) in board units."""
        return -1.0, -1.0, float(self.cols), float(self.rows)


#: the cell's board of known points when ``calibration.board`` names none: seed 001's
#: board, 7 x 9 discs of seed 004's 3 mm radius at 100 mm pitch (so the hand camera sees
#: one at a time), its first disc at (200, -400) mm in the robot base frame
DEFAULT_BOARD = CircleGridBoard(cols=7, rows=9, pitch_mm=100.0, radius_mm=3.0,
                                origin_mm=(200.0, -400.0), angle_deg=0.0)


@dataclass(frozen=True)
class ChessBoard(_Board):
    """Chessboard with ``cols`` x ``rows`` inner corners, squares of ``square_mm``; the corner
    square at (-1, -1) is black; the paper has a one-square white border."""

    square_mm: float = 10.0
    kind = "chessboard"

    def __post_init__(self) -> None:
        self._check(self.square_mm, "square_mm")

    @property
    def unit_mm(self) -> float:
        return self.square_mm

    def paper_units(self) -> tuple[float, float, float, float]:
        return -2.0, -2.0, self.cols + 1.0, self.rows + 1.0

    def squares_units(self) -> tuple[float, float, float, float]:
        """The chequered area (col_lo, row_lo, col_hi, row_hi) in board units."""
        return -1.0, -1.0, float(self.cols), float(self.rows)


Board = Union[CircleGridBoard, ChessBoard]


def board_from_dict(d: dict) -> Board:
    """Inverse of ``board.as_dict()``, validated as a board file is
    (:func:`cell.vision.board.board_from_mapping`). Raises :class:`ConfigError` naming the
    bad field (an unknown key with the key meant)."""
    from cell.vision.board import board_from_mapping
    return board_from_mapping(d)


def _h_apply(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = p @ h[:, :2].T + h[:, 2]
    return q[:, :2] / q[:, 2:3]


def _h_jacobian(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    x, y = p
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    a = h[:2, 0] * x + h[:2, 1] * y + h[:2, 2]
    return (h[:2, :2] * w - np.outer(a, h[2, :2])) / w ** 2


def _orient(grid: np.ndarray, board: Board, u_axis_deg: float, where: str) -> np.ndarray:
    """Reorder the (rows, cols, 2) grid OpenCV returned so it matches ``board.points_mm()``."""
    cands = [grid, grid[::-1], grid[:, ::-1], grid[::-1, ::-1]]
    if board.cols == board.rows:
        cands += [g.transpose(1, 0, 2) for g in cands]
    truth = board.points_mm()
    centre = truth.mean(axis=0)
    scored = []
    for g in cands:
        h, _ = cv2.findHomography(truth, g.reshape(-1, 2), 0)
        if h is None:
            continue
        jac = _h_jacobian(h, centre)
        if np.linalg.det(jac) >= 0:         # not mirrored: cannot be a camera looking down
            continue
        u_dir = np.linalg.solve(jac, [1.0, 0.0])
        angle = math.degrees(math.atan2(u_dir[1], u_dir[0]))
        scored.append((abs((angle - u_axis_deg + 180.0) % 360.0 - 180.0), g, angle))
    if not scored:
        raise VisionError(f"{where}: the board appears un-mirrored, i.e. not seen from above "
                          f"(camera looking up or through a mirror?)")
    scored.sort(key=lambda t: t[0])
    if scored[0][0] > 45.0:
        raise VisionError(f"{where}: matched to this board, the image +u axis would point at "
                          f"{scored[0][2]:.0f} deg in the base frame, {scored[0][0]:.0f} deg from "
                          f"u_axis_deg = {u_axis_deg}; cols and rows swapped, or a wrong hint?")
    if len(scored) > 1 and scored[1][0] - scored[0][0] < 20.0:
        raise VisionError(f"{where}: board orientation is ambiguous for u_axis_deg = {u_axis_deg}; "
                          f"give the direction of the image +u axis to within 45 degrees")
    return scored[0][1].reshape(-1, 2)


def detect_board(image: np.ndarray, board: Board, *, u_axis_deg: float = 0.0,
                 where: str = "image") -> np.ndarray:
    """Board points in pixels (N, 2), in the order of ``board.points_mm()``.

    Raises :class:`VisionError` if the image is not 8-bit grey, the board (of exactly this
    size) is not found, a circle cannot be refined, or the orientation is ambiguous.
    """
    return _detect(image, board, u_axis_deg, where)[0]


def _detect(image: np.ndarray, board: Board, u_axis_deg: float, where: str
            ) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`detect_board`, and the detector's own 1-σ centre uncertainty (u, v) px of
    each circle (N, 2; any order), None for a chessboard (its corner finder gives none)."""
    check_image(image, where)
    h, w = image.shape
    size = f"{board.cols}x{board.rows}"
    if isinstance(board, CircleGridBoard):
        params = cv2.SimpleBlobDetector_Params()
        params.minArea, params.maxArea = 8.0, float(w * h) / (board.cols * board.rows)
        params.filterByConvexity = False
        params.minDistBetweenBlobs = 2.0
        detector = cv2.SimpleBlobDetector_create(params)
        ok, pts = cv2.findCirclesGrid(image, board.pattern_size, flags=cv2.CALIB_CB_SYMMETRIC_GRID,
                                      blobDetector=detector)
        n_blobs = len(detector.detect(image))
    else:
        ok, pts = cv2.findChessboardCornersSB(image, board.pattern_size,
                                              flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        n_blobs = None
    if not ok or pts is None or len(pts) != board.cols * board.rows:
        raise VisionError(f"{where} ({w}x{h}): {board.kind} board with {size} points not found; "
                          f"check the board size (cols x rows), lighting and focus")
    grid = pts.reshape(board.rows, board.cols, 2).astype(np.float64)
    if isinstance(board, CircleGridBoard):
        if n_blobs is not None and n_blobs >= board.cols * board.rows + min(board.cols, board.rows):
            raise VisionError(f"{where}: {n_blobs} circles seen but the board is {size}; a "
                              f"larger board (or other circles) is in view; check cols x rows")
        pitch_px = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)))
        r_px = board.radius_mm / board.pitch_mm * pitch_px
        sigma = np.empty((board.rows * board.cols, 2))
        for n, idx in enumerate(np.ndindex(grid.shape[:2])):
            fix = refine_fiducial(image, *grid[idx], r_px, polarity="dark", min_contrast=15.0)
            grid[idx] = fix.uv
            sigma[n] = fix.sigma_u_px, fix.sigma_v_px
        return _orient(grid, board, u_axis_deg, f"{where} ({board.kind} {size})"), sigma
    return _orient(grid, board, u_axis_deg, f"{where} ({board.kind} {size})"), None


@dataclass(frozen=True)
class PlaneCalibration:
    """Calibrated map between pixels and the work plane in the base frame (mm).

    ``pixel -> normalised (u - cx) / f -> undistort -> homography -> (x_mm, y_mm)``, with
    ``(cx, cy)`` the image centre and ``f`` a nominal focal length (it only scales the
    distortion coefficients). ``homography`` maps base mm (homogeneous) to undistorted
    normalised coordinates. Residuals: ``rms_px``/``max_px`` of board points reprojected
    into the image, ``rms_mm``/``max_mm`` of detected points mapped onto the plane.
    """

    width: int
    height: int
    focal_px: float
    homography: np.ndarray
    distortion: Distortion = field(default_factory=Distortion)
    rms_px: float = float("nan")
    max_px: float = float("nan")
    rms_mm: float = float("nan")
    max_mm: float = float("nan")
    n_points: int = 0
    boards: tuple = ()
    #: :func:`consistency_check` of the fit ({} when not made, e.g. a loaded file without one)
    check: dict = field(default_factory=dict, compare=False)

    @property
    def centre_px(self) -> tuple[float, float]:
        return (self.width - 1) / 2.0, (self.height - 1) / 2.0

    def base_to_pixels(self, points_mm) -> np.ndarray:
        """Base-frame plane points (N, 2) mm -> pixels (N, 2). Raises VisionError on bad input."""
        p = _points(points_mm, "points_mm")
        x = _h_apply(self.homography, p)
        if self.distortion.is_zero:                  # distort() hands x back as it is
            return x * self.focal_px + self.centre_px
        xd, yd = distort(x[:, 0], x[:, 1], self.distortion)
        cx, cy = self.centre_px
        return np.column_stack([self.focal_px * xd + cx, self.focal_px * yd + cy])

    def pixels_to_base(self, pixels) -> np.ndarray:
        """Pixels (N, 2) -> base-frame plane points (N, 2) mm. Raises VisionError on bad input."""
        q = _points(pixels, "pixels")
        if self.distortion.is_zero:                  # undistort() hands the point back
            return _h_apply(self._plane_from_normalised, (q - self.centre_px) / self.focal_px)
        cx, cy = self.centre_px
        x, y = undistort((q[:, 0] - cx) / self.focal_px, (q[:, 1] - cy) / self.focal_px, self.distortion)
        return _h_apply(self._plane_from_normalised, np.column_stack([x, y]))

    @functools.cached_property
    def _plane_from_normalised(self) -> np.ndarray:
        """The homography's inverse (undistorted normalised -> base mm), formed on first
        use and kept: the calibration is frozen."""
        return np.linalg.inv(self.homography)

    def pixel_to_base(self, u: float, v: float) -> tuple[float, float]:
        """One pixel (u, v) -> (x_mm, y_mm) on the work plane."""
        x, y = self.pixels_to_base([[u, v]])[0]
        return float(x), float(y)

    def base_to_pixel(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """One plane point (x_mm, y_mm) -> pixel (u, v)."""
        u, v = self.base_to_pixels([[x_mm, y_mm]])[0]
        return float(u), float(v)

    def jacobian_px_to_mm(self, u: float, v: float) -> np.ndarray:
        """2x2 d(x_mm, y_mm)/d(u, v) at a pixel: turns pixel uncertainties into mm."""
        h = 1e-3
        p = self.pixels_to_base([[u + h, v], [u - h, v], [u, v + h], [u, v - h]])
        return np.column_stack([(p[0] - p[1]) / (2 * h), (p[2] - p[3]) / (2 * h)])

    def mm_per_px(self, u: float, v: float) -> float:
        """Mean linear scale at a pixel (mm per px)."""
        return math.sqrt(abs(float(np.linalg.det(self.jacobian_px_to_mm(u, v)))))

    def as_dict(self) -> dict:
        """Plain dict (JSON/YAML-able) the cell can store and load with :meth:`from_dict`."""
        return {"format": FORMAT, "width": self.width, "height": self.height,
                "focal_px": self.focal_px, "homography": self.homography.tolist(),
                "distortion": {k: getattr(self.distortion, k) for k in ("k1", "k2", "p1", "p2")},
                "residuals": {"rms_px": self.rms_px, "max_px": self.max_px, "rms_mm": self.rms_mm,
                              "max_mm": self.max_mm, "n_points": self.n_points},
                "boards": list(self.boards), **({"check": self.check} if self.check else {})}

    @classmethod
    def from_dict(cls, d: dict) -> "PlaneCalibration":
        """Load :meth:`as_dict` output. Raises :class:`ConfigError` naming the bad field."""
        if not isinstance(d, dict):
            raise ConfigError(f"calibration must be a mapping, got {type(d).__name__}")
        if d.get("format") != FORMAT:
            raise ConfigError(f"calibration: format = {d.get('format')!r}, expected {FORMAT!r}")
        for key in ("width", "height", "focal_px", "homography"):
            if key not in d:
                raise ConfigError(f"calibration: missing field '{key}'")
        for key in ("width", "height"):
            if isinstance(d[key], bool) or not isinstance(d[key], int) or not 8 <= d[key] <= 65536:
                raise ConfigError(f"calibration: {key} = {d[key]!r} must be an integer in [8, 65536]")
        try:
            f = float(d["focal_px"])
            hom = np.array(d["homography"], dtype=float)
        except (TypeError, ValueError):
            raise ConfigError("calibration: focal_px / homography must be numbers") from None
        if not (math.isfinite(f) and f > 0):
            raise ConfigError(f"calibration: focal_px = {d['focal_px']!r} must be > 0")
        if hom.shape != (3, 3) or not np.all(np.isfinite(hom)) or abs(np.linalg.det(hom)) < 1e-300:
            raise ConfigError(f"calibration: homography must be an invertible 3x3 matrix, got "
                              f"shape {hom.shape}")
        dist = d.get("distortion") or {}
        if not isinstance(dist, dict):
            raise ConfigError(f"calibration: distortion must be a mapping, got {dist!r}")
        try:
            distortion = Distortion(**dist)
        except TypeError as exc:
            raise ConfigError(f"calibration: distortion: {exc}") from None
        res = d.get("residuals") or {}
        return cls(d["width"], d["height"], f, hom, distortion,
                   **{k: float(res.get(k, float("nan"))) for k in ("rms_px", "max_px", "rms_mm", "max_mm")},
                   n_points=int(res.get("n_points", 0)), boards=tuple(d.get("boards") or ()),
                   check=d.get("check") if isinstance(d.get("check"), dict) else {})


def _points(p, what: str) -> np.ndarray:
    a = np.asarray(p, dtype=float)
    if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)):
        raise VisionError(f"{what} must be a finite (N, 2) array, got shape {np.shape(p)}")
    return a


def calibrate(views: Sequence[tuple[np.ndarray, Board]], *, distortion: bool = True,
              u_axis_deg: float = 0.0, focal_px: float | None = None) -> PlaneCalibration:
    """Calibrate the pixel <-> work-plane map from one or more (image, board) views.

    Every board must lie on the work plane at its stated ``origin_mm``/``angle_deg``; all
    images must have the same size. ``distortion=False`` fits a plain homography.
    ``focal_px`` (default: the larger image side) only normalises the distortion terms.
    Raises :class:`VisionError` naming the view if a board is not found or the images
    differ in size, or if too few points (< 8, or < 20 with distortion) are found.

    The result carries its ``check`` (:func:`consistency_check`): whether its residual is far
    above the measurement noise; the caller decides what to do with a failed one
    (``cellctl calibrate-camera`` refuses to write it).
    """
    if not views:
        raise VisionError("calibrate: no views given")
    px, mm, sig, size = [], [], [], None
    for i, view in enumerate(views):
        try:
            image, board = view
        except (TypeError, ValueError):
            raise VisionError(f"view {i}: expected (image, board), got {type(view).__name__}") from None
        check_image(image, f"view {i}")
        if size is not None and image.shape != size:
            raise VisionError(f"view {i}: image shape {image.shape} differs from view 0 {size}")
        size = image.shape
        p, s = _detect(image, board, u_axis_deg, f"view {i}")
        px.append(p)
        mm.append(board.points_mm())
        sig.append(s)
    need = 20 if distortion else 8
    n_all = sum(len(p) for p in px)
    if n_all < need:
        raise VisionError(f"calibrate: {n_all} board points, need >= {need}")
    h, w = size
    f = float(focal_px) if focal_px else float(max(w, h))
    cal = _fit(np.concatenate(px), np.concatenate(mm), w, h, f, distortion)
    return dataclasses.replace(cal, boards=tuple(b.as_dict() for _, b in views),
                               check=consistency_check(cal, px, mm, sig, distortion))


def _fit(px: np.ndarray, mm: np.ndarray, w: int, h: int, f: float, distortion: bool) -> PlaneCalibration:
    """Homography (+ distortion) from pixels ``px`` of plane points ``mm``, with residuals."""
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    norm = (px - [cx, cy]) / f
    # Condition the mm side (Hartley) so the fit is well scaled.
    m0, sc = mm.mean(axis=0), mm.std() or 1.0
    t_mm = np.array([[1 / sc, 0, -m0[0] / sc], [0, 1 / sc, -m0[1] / sc], [0, 0, 1.0]])
    mmc = (mm - m0) / sc
    h0, _ = cv2.findHomography(mmc, norm, 0)
    if h0 is None:
        raise VisionError("calibrate: board points are degenerate (collinear?); no homography")
    h0 = h0 / h0[2, 2]
    dist = Distortion()
    if distortion:
        def resid(p):
            hh = np.append(p[:8], 1.0).reshape(3, 3)
            x = _h_apply(hh, mmc)
            xd, yd = distort(x[:, 0], x[:, 1], Distortion(*p[8:]))
            return (np.column_stack([xd, yd]) - norm).ravel() * f

        from scipy.optimize import least_squares   # 0.1 s to import; the cell never fits distortion
        sol = least_squares(resid, np.concatenate([h0.ravel()[:8], np.zeros(4)]), method="lm",
                            x_scale="jac", xtol=1e-12, ftol=1e-12)
        if not sol.success or not np.all(np.isfinite(sol.x)):
            raise VisionError(f"calibrate: distortion fit did not converge ({sol.message})")
        h0 = np.append(sol.x[:8], 1.0).reshape(3, 3)
        dist = Distortion(*sol.x[8:])
    hom = h0 @ t_mm
    cal = PlaneCalibration(w, h, f, hom / np.linalg.norm(hom), dist)
    err_px = np.linalg.norm(cal.base_to_pixels(mm) - px, axis=1)
    err_mm = np.linalg.norm(cal.pixels_to_base(px) - mm, axis=1)
    return PlaneCalibration(w, h, f, cal.homography, dist,
                            rms_px=float(np.sqrt(np.mean(err_px ** 2))), max_px=float(err_px.max()),
                            rms_mm=float(np.sqrt(np.mean(err_mm ** 2))), max_mm=float(err_mm.max()),
                            n_points=len(px))


def consistency_check(cal: PlaneCalibration, px: list[np.ndarray], mm: list[np.ndarray],
                      sigma: list[np.ndarray | None], distortion: bool) -> dict:
    """Is the residual of ``cal`` (fitted on all views: pixels ``px``, plane points ``mm``
    per view) far above the measurement noise (:mod:`cell.calibration.check`)? Two noise
    estimates, each made apart from the joint fit:

    * **each view alone** (two or more views): every view fitted with its own homography
      (and distortion): the detector's noise and what the lens model leaves, but nothing of
      a disagreement between views (a board bumped between views, a swapped or re-scaled
      image): the joint fit must not leave much more;
    * **the detector** (circle boards): the disc fit's own 1-σ centre uncertainty
      (:func:`~cell.vision.fiducial.refine_fiducial`), pooled over the circles, taken with
      2 dof per circle (fewer than the pixels it comes from: the test is conservative).

    Returns the check as a dict: ``passed``, ``reason``, ``failures``, ``noise`` (see
    :meth:`cell.calibration.check.Verdict.as_dict`) and ``views``: rms and max px of each
    view in the joint fit, the worst first."""
    from cell.calibration import check as C
    k = 12 if distortion else 8
    n = sum(len(p) for p in px)
    rss = float(np.sum((cal.base_to_pixels(np.concatenate(mm)) - np.concatenate(px)) ** 2))
    dof = 2 * n - k
    resid = math.sqrt(rss / dof) if dof > 0 else math.nan
    per_view, noise = [], []
    for i, p in enumerate(px):
        e = np.linalg.norm(cal.base_to_pixels(mm[i]) - p, axis=1)
        per_view.append({"view": i, "rms_px": round(float(np.sqrt(np.mean(e ** 2))), 6),
                         "max_px": round(float(e.max()), 6)})
    if len(px) > 1:
        ss, d = 0.0, 0
        for p, m in zip(px, mm):
            kv = 12 if distortion and len(p) >= 20 else 8
            if 2 * len(p) <= kv:
                continue
            alone = _fit(p, m, cal.width, cal.height, cal.focal_px, kv == 12)
            ss += float(np.sum((alone.base_to_pixels(m) - p) ** 2))
            d += 2 * len(p) - kv
        if d > 0:
            noise.append(C.noise_check(resid, dof, math.sqrt(ss / d) if ss > 0 else None, d,
                                       "each view fitted alone", "px"))
    s = [x for x in sigma if x is not None]
    if s:
        s = np.concatenate(s)
        noise.append(C.noise_check(resid, dof, float(np.sqrt(np.mean(s ** 2))), s.size,
                                   "the detector's own centre uncertainty", "px"))
    out = C.Verdict((), tuple(noise)).as_dict()
    out["views"] = sorted(per_view, key=lambda v: -v["rms_px"])
    return out


@dataclass(frozen=True)
class PlaneFix:
    """A fiducial measured on the work plane: centre (base frame, mm), its 1-sigma
    uncertainty per axis (mm, from the fit's pixel uncertainty) and the pixel measurement."""

    x_mm: float
    y_mm: float
    sigma_x_mm: float
    sigma_y_mm: float
    fix: FiducialFix


def locate(image: np.ndarray, cal: PlaneCalibration, **find_kwargs) -> list[PlaneFix]:
    """Find fiducials (:func:`~cell.vision.fiducial.find_fiducials`, same keywords, e.g.
    ``expected=1``, ``roi=...``) and map them to the work plane in mm.

    Raises :class:`VisionError` from the search, or if the image size differs from the
    size the calibration was made for.
    """
    check_image(image)
    if image.shape != (cal.height, cal.width):
        raise VisionError(f"image is {image.shape[1]}x{image.shape[0]} but the calibration is "
                          f"for {cal.width}x{cal.height}")
    out = []
    for f in find_fiducials(image, **find_kwargs):
        x, y = cal.pixel_to_base(f.u_px, f.v_px)
        jac = cal.jacobian_px_to_mm(f.u_px, f.v_px)
        cov = jac @ np.diag([f.sigma_u_px ** 2, f.sigma_v_px ** 2]) @ jac.T
        out.append(PlaneFix(x, y, math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1]), f))
    return out
