"""Pure projection maths for a camera looking down on the work plane (no I/O).

Frames and units
----------------
* Base frame: the robot base frame, millimetres, z up. The work plane is z = 0.
* Pixels: OpenCV convention, (u, v) = (column, row); the centre of the top-left pixel is
  (0, 0), u grows to the right, v grows downwards.
* Camera frame: OpenCV convention, x along +u, y along +v, z along the optical axis (away
  from the camera, towards the plane).

The model is the usual pinhole with Brown-Conrady lens distortion, exactly OpenCV's
``projectPoints`` with ``distCoeffs = (k1, k2, p1, p2)`` (tested against it): a base-frame
point P goes to camera coordinates Xc = R (P - C), to normalised ``x = Xc/Zc, y = Yc/Zc``,
is distorted (:func:`distort`) and scaled by the intrinsics ``u = fx xd + cx``.

The pose is given the way a camera is mounted over a cell rather than as a rotation
vector: the height of the projection centre above the plane, the point where the optical
axis meets the plane, the direction of the image +u axis in the plane (``yaw_deg``) and two
small tilts of the whole camera about the base x and y axes.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from cell.errors import ConfigError, MeasurementError


class VisionError(MeasurementError):
    """An image could not be measured or mapped; the message names what and where (pixels).

    ``kind`` classifies the failure for callers that must react differently (the cell maps
    it to a PLC fault code): "no_target", "multiple", "cut", "saturated", "low_contrast",
    "bad_image" or "other".
    """

    KINDS = ("no_target", "multiple", "cut", "saturated", "low_contrast", "bad_image", "other")

    def __init__(self, message: str, kind: str = "other"):
        super().__init__(message)
        self.kind = kind if kind in self.KINDS else "other"


def _finite(name: str, value: float, lo: float = -math.inf, hi: float = math.inf,
            *, lo_open: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo):
        rng = f"({lo}, {hi}]" if lo_open else f"[{lo}, {hi}]"
        raise ConfigError(f"{name} = {value!r} is outside {rng}")
    return v


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; ``width`` x ``height`` is the image size in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 8 <= v <= 65536:
                raise ConfigError(f"intrinsics.{name} = {v!r} must be an integer in [8, 65536]")
        for name in ("fx", "fy"):
            object.__setattr__(self, name, _finite(f"intrinsics.{name}", getattr(self, name),
                                                   0.0, 1e6, lo_open=True))
        object.__setattr__(self, "cx", _finite("intrinsics.cx", self.cx, -self.width, 2 * self.width))
        object.__setattr__(self, "cy", _finite("intrinsics.cy", self.cy, -self.height, 2 * self.height))

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K (OpenCV layout)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Distortion:
    """Brown-Conrady lens distortion on normalised coordinates (OpenCV's k1, k2, p1, p2)."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("k1", "k2", "p1", "p2"):
            object.__setattr__(self, name, _finite(f"distortion.{name}", getattr(self, name), -10, 10))

    @property
    def is_zero(self) -> bool:
        return self.k1 == self.k2 == self.p1 == self.p2 == 0.0

    def coeffs(self) -> np.ndarray:
        """OpenCV ``distCoeffs`` vector (k1, k2, p1, p2)."""
        return np.array([self.k1, self.k2, self.p1, self.p2])


@dataclass(frozen=True)
class Pose:
    """Where the camera sits over the work plane.

    ``height_mm``: height of the projection centre above the plane (z of the camera).
    ``axis_point_mm``: (x, y) where the optical axis meets the plane, base frame.
    ``yaw_deg``: angle from base +x to the image +u axis, counter-clockwise seen from above.
    ``tilt_x_deg``, ``tilt_y_deg``: rotation of the whole camera about the base x, then y
    axis (0, 0 = optical axis straight down); at most 45 degrees each.
    """

    height_mm: float
    axis_point_mm: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "height_mm", _finite("pose.height_mm", self.height_mm,
                                                      0.0, 1e5, lo_open=True))
        try:
            ax, ay = self.axis_point_mm
        except (TypeError, ValueError):
            raise ConfigError(f"pose.axis_point_mm = {self.axis_point_mm!r} must be (x, y)") from None
        object.__setattr__(self, "axis_point_mm", (_finite("pose.axis_point_mm[0]", ax, -1e5, 1e5),
                                                   _finite("pose.axis_point_mm[1]", ay, -1e5, 1e5)))
        object.__setattr__(self, "yaw_deg", _finite("pose.yaw_deg", self.yaw_deg, -360, 360))
        for name in ("tilt_x_deg", "tilt_y_deg"):
            object.__setattr__(self, name, _finite(f"pose.{name}", getattr(self, name), -45, 45))

    def rotation_camera_to_base(self) -> np.ndarray:
        """R whose columns are the camera x, y, z axes expressed in the base frame."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        nadir = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
        tx, ty = math.radians(self.tilt_x_deg), math.radians(self.tilt_y_deg)
        rx = np.array([[1, 0, 0], [0, math.cos(tx), -math.sin(tx)], [0, math.sin(tx), math.cos(tx)]])
        ry = np.array([[math.cos(ty), 0, math.sin(ty)], [0, 1, 0], [-math.sin(ty), 0, math.cos(ty)]])
        return ry @ rx @ nadir

    def centre_mm(self) -> np.ndarray:
        """The projection centre C in the base frame (mm)."""
        z_axis = self.rotation_camera_to_base()[:, 2]
        t = -self.height_mm / z_axis[2]          # z_axis points down, so t > 0
        return np.array([*self.axis_point_mm, 0.0]) - t * z_axis


def distort(x: np.ndarray, y: np.ndarray, d: Distortion) -> tuple[np.ndarray, np.ndarray]:
    """Apply lens distortion to normalised coordinates (arrays of equal shape)."""
    if d.is_zero:
        return x, y
    r2 = x * x + y * y
    radial = 1.0 + r2 * (d.k1 + d.k2 * r2)
    xd = x * radial + 2.0 * d.p1 * x * y + d.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + d.p1 * (r2 + 2.0 * y * y) + 2.0 * d.p2 * x * y
    return xd, yd


def undistort(xd: np.ndarray, yd: np.ndarray, d: Distortion, *,
              max_iter: int = 100, tol: float = 1e-13) -> tuple[np.ndarray, np.ndarray]:
    """Invert :func:`distort` by fixed-point iteration (as OpenCV does, but to convergence).

    Raises :class:`VisionError` if the iteration does not converge, which happens only for
    points far outside the region where the distortion polynomial is invertible.
    """
    if d.is_zero:
        return xd, yd
    x, y = np.array(xd, dtype=float), np.array(yd, dtype=float)
    for _ in range(max_iter):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (d.k1 + d.k2 * r2)
        dx = 2.0 * d.p1 * x * y + d.p2 * (r2 + 2.0 * x * x)
        dy = d.p1 * (r2 + 2.0 * y * y) + 2.0 * d.p2 * x * y
        xn, yn = (xd - dx) / radial, (yd - dy) / radial
        step = max(float(np.max(np.abs(xn - x), initial=0.0)), float(np.max(np.abs(yn - y), initial=0.0)))
        x, y = xn, yn
        if step < tol:
            return x, y
    bad = np.argmax(np.abs(xd) + np.abs(yd))
    raise VisionError(f"lens undistortion did not converge for normalised point "
                      f"({float(np.ravel(xd)[bad]):.4g}, {float(np.ravel(yd)[bad]):.4g}); "
                      f"it lies outside the region where {d} is invertible")


def _as_points(points, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim == 1 and p.shape == (2,):
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 2:
        raise VisionError(f"{what} must have shape (N, 2), got {np.shape(points)}")
    if not np.all(np.isfinite(p)):
        raise VisionError(f"{what} contains non-finite values at rows {np.nonzero(~np.isfinite(p).all(1))[0][:5].tolist()}")
    return p


@dataclass(frozen=True)
class CameraModel:
    """A calibrated (or nominal) camera over the work plane: intrinsics, pose, distortion."""

    intrinsics: Intrinsics
    pose: Pose
    distortion: Distortion = field(default_factory=Distortion)

    @classmethod
    def nadir(cls, width: int, height: int, mm_per_px: float, *, centre_mm=(0.0, 0.0),
              yaw_deg: float = 0.0, height_mm: float = 500.0,
              distortion: Distortion | None = None) -> "CameraModel":
        """A camera looking straight down with square pixels of ``mm_per_px`` at the plane,
        principal point at the image centre and its optical axis meeting the plane at
        ``centre_mm``."""
        f = height_mm / _finite("mm_per_px", mm_per_px, 0.0, 1e4, lo_open=True)
        return cls(Intrinsics(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height),
                   Pose(height_mm, tuple(centre_mm), yaw_deg), distortion or Distortion())

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.intrinsics.width, self.intrinsics.height

    def extrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with Xc = R @ P + t: OpenCV's world-to-camera rotation and translation (mm)."""
        r = self.pose.rotation_camera_to_base().T
        return r, -r @ self.pose.centre_mm()

    def homography(self) -> np.ndarray:
        """3x3 H mapping plane points (x_mm, y_mm, 1) to undistorted pixels (homogeneous)."""
        r, t = self.extrinsics()
        return self.intrinsics.matrix() @ np.column_stack([r[:, 0], r[:, 1], t])

    def project(self, points_mm) -> np.ndarray:
        """Base-frame plane points (N, 2) mm -> pixels (N, 2), lens distortion included.

        Raises :class:`VisionError` for malformed input or points behind the camera.
        """
        p = _as_points(points_mm, "points_mm")
        r, t = self.extrinsics()
        xc = p @ r[:, :2].T + t
        if np.any(xc[:, 2] <= 0):
            raise VisionError(f"points_mm rows {np.nonzero(xc[:, 2] <= 0)[0][:5].tolist()} "
                              f"lie behind the camera")
        xd, yd = distort(xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2], self.distortion)
        k = self.intrinsics
        return np.column_stack([k.fx * xd + k.cx, k.fy * yd + k.cy])

    def unproject(self, pixels) -> np.ndarray:
        """Pixels (N, 2) -> base-frame points (N, 2) mm on the work plane.

        Raises :class:`VisionError` for malformed input, undistortion that does not converge,
        or a viewing ray that does not meet the plane in front of the camera.
        """
        q = _as_points(pixels, "pixels")
        k = self.intrinsics
        x, y = undistort((q[:, 0] - k.cx) / k.fx, (q[:, 1] - k.cy) / k.fy, self.distortion)
        rays = np.column_stack([x, y, np.ones_like(x)]) @ self.pose.rotation_camera_to_base().T
        c = self.pose.centre_mm()
        if np.any(rays[:, 2] >= 0):
            raise VisionError(f"pixels rows {np.nonzero(rays[:, 2] >= 0)[0][:5].tolist()} "
                              f"look above the horizon and never meet the work plane")
        s = -c[2] / rays[:, 2]
        return c[:2] + s[:, None] * rays[:, :2]

    def jacobian(self, point_mm) -> np.ndarray:
        """2x2 d(u, v)/d(x_mm, y_mm) at a plane point (central differences, 1e-3 mm)."""
        p = np.asarray(point_mm, dtype=float).reshape(2)
        h = 1e-3
        pts = np.array([p + [h, 0], p - [h, 0], p + [0, h], p - [0, h]])
        q = self.project(pts)
        return np.column_stack([(q[0] - q[1]) / (2 * h), (q[2] - q[3]) / (2 * h)])

    def px_per_mm(self, point_mm) -> float:
        """Mean linear scale (px per mm) at a plane point: sqrt(|det J|)."""
        return math.sqrt(abs(float(np.linalg.det(self.jacobian(point_mm)))))

    def as_dict(self) -> dict:
        """Plain dict (JSON/YAML-able); inverse of :meth:`from_dict`."""
        pose = asdict(self.pose)
        pose["axis_point_mm"] = list(self.pose.axis_point_mm)
        return {"intrinsics": asdict(self.intrinsics), "pose": pose,
                "distortion": asdict(self.distortion)}

    @classmethod
    def from_dict(cls, d: dict) -> "CameraModel":
        """Build from :meth:`as_dict` output. Raises :class:`ConfigError` naming the bad field."""
        if not isinstance(d, dict):
            raise ConfigError(f"camera model must be a mapping, got {type(d).__name__}")
        unknown = set(d) - {"intrinsics", "pose", "distortion"}
        if unknown:
            raise ConfigError(f"camera model: unknown keys {sorted(unknown)}")
        parts = {}
        for key, typ, required in (("intrinsics", Intrinsics, True), ("pose", Pose, True),
                                   ("distortion", Distortion, False)):
            sub = d.get(key)
            if sub is None and not required:
                continue
            if not isinstance(sub, dict):
                raise ConfigError(f"camera model: '{key}' must be a mapping, got {sub!r}")
            try:
                if key == "pose" and "axis_point_mm" in sub:
                    sub = {**sub, "axis_point_mm": tuple(sub["axis_point_mm"])}
                parts[key] = typ(**sub)
            except TypeError as exc:
                raise ConfigError(f"camera model: '{key}': {exc}") from None
        return cls(**parts)
