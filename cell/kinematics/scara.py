"""4-axis SCARA kinematics (θ1, θ2, z, θ4) with the planar part of seed 000 and the
z/wrist chain of seed 002. Pure numerics, no I/O.

The SCARA is a chain like any other: :func:`dh_rows` is its standard-DH model and
:attr:`Scara.chain` the :class:`~cell.kinematics.chain.Chain` built from it, which the
calibration (:mod:`cell.calibration.dh`) and the chain diagnosis evaluate with
:mod:`cell.kinematics.evaluate`. The methods here are that chain's closed form (α = 0
everywhere), for the control loop's single poses; a test holds the two equal.

Conventions (all documented units, angles in degrees at the interface):

* joints ``q = (θ1_deg, θ2_deg, d3_mm, θ4_deg)``; θ2 is measured from link 1.
* pose ``(x_mm, y_mm, z_mm, phi_deg)`` of the tool centre in the robot base frame::

      x = l1·cos θ1 + l2·cos(θ1+θ2)          (seed 000 eq. 4)
      y = l1·sin θ1 + l2·sin(θ1+θ2)
      z = base_z + d3 + tool_z               (seed 002: tool offset (0, 0, −50))
      phi = θ1 + θ2 + θ4

* elbow ``"right"`` means θ2 > 0 (the seed 000 start pose (60°, 30°) is right-handed),
  ``"left"`` means θ2 < 0. θ2 = 0 or ±180° is a singularity.
* Joints are commanded in whole *command units* (seed 000 eq. 1: θ = m·Δ);
  :meth:`Scara.to_units` / :meth:`Scara.from_units` convert.

Every bad input raises :class:`~cell.errors.KinematicsError` naming the value.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from cell.errors import KinematicsError

if TYPE_CHECKING:
    from cell.kinematics.chain import Chain
    from cell.robots import Geometry

Elbow = Literal["right", "left"]
JOINT_NAMES = ("j1", "j2", "j3", "j4")


@dataclass(frozen=True)
class PlanarArm:
    """The planar part of a SCARA (seed 000): link lengths and the limits of θ1, θ2 (deg),
    as a campaign's model.yaml gives them; what the sim-to-real diagnosis replays. A full
    robot is a :class:`cell.robots.Geometry` (its ``l1_mm``, ``l2_mm`` and ``limits`` serve
    wherever a PlanarArm does)."""

    l1_mm: float
    l2_mm: float
    limits: tuple[tuple[float, float], ...] = ((-170.0, 170.0), (-150.0, 150.0))


def planar_xy(l1_mm, l2_mm, q_deg) -> np.ndarray:
    """Seed 000 eq. 4, vectorised: tool centres (N, 2) mm for joints ``q_deg`` (N, 2)
    (θ1, θ2 in degrees). Link lengths are scalars or (N,) arrays (true lengths per row).
    No checks: callers validate their inputs."""
    q = np.asarray(q_deg, dtype=float)
    a = np.radians(q[:, 0])
    ab = a + np.radians(q[:, 1])
    return np.column_stack([l1_mm * np.cos(a) + l2_mm * np.cos(ab),
                            l1_mm * np.sin(a) + l2_mm * np.sin(ab)])


def dh_rows(geometry: "Geometry") -> list[dict]:
    """The SCARA as standard-DH rows (the ``joints`` of a ``kinematics: dh`` model), α = 0
    everywhere so that φ = θ1 + θ2 + θ4 and z = base_z + d3 + tool_z::

        j1: revolute  θ1,  d = base_z, a = l1
        j2: revolute  θ2,  d = 0,      a = l2
        j3: prismatic d3,  θ = 0,      a = 0
        j4: revolute  θ4,  d = tool_z, a = 0
    """
    g = geometry
    rows = [("revolute", g.base_z_mm, g.l1_mm), ("revolute", 0.0, g.l2_mm),
            ("prismatic", 0.0, 0.0), ("revolute", g.tool_z_mm, 0.0)]
    return [{"name": name, "type": kind, "theta_deg": 0.0, "d_mm": float(d), "a_mm": float(a),
             "alpha_deg": 0.0, "limits": [float(v) for v in lim]}
            for name, (kind, d, a), lim in zip(JOINT_NAMES, rows, g.limits)]


def scara_chain(geometry: "Geometry") -> "Chain":
    """The SCARA of ``geometry`` as a :class:`~cell.kinematics.chain.Chain` (:func:`dh_rows`;
    tool point at the flange, gravity along −z)."""
    from cell.kinematics.chain import dh_chain
    return dh_chain(f"robot {geometry.name!r}", dh_rows(geometry), "standard", [],
                    (0.0, 0.0, 0.0), (0.0, 0.0, -1.0))


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise KinematicsError(f"{name} = {value!r} is not a finite number")
    return v


class Scara:
    """Forward/inverse kinematics, Jacobian, limits and command units for one geometry.

    ``approach_dirs`` is the side (+1 or −1 for θ1, θ2) every measured arrival takes up the
    joints' backlash from: moving up, as the calibration procedures approach every pose
    (:meth:`cell.calibration.procedure.HandRig.approach`). A model fitted on such arrivals
    predicts arrivals made the same way; a calibrated robot carries the side its file
    records. ``backlash_deg`` is the lost motion of θ1, θ2 as seed 004 measured it (0: not
    measured, as for every nominal robot); ``arrival_scatter_mm`` how far measured
    arrivals lay from the model on poses its calibration held out (2-D rms, mm; 0: not
    measured).
    """

    approach_dirs: tuple[int, int] = (1, 1)
    backlash_deg: tuple[float, float] = (0.0, 0.0)
    arrival_scatter_mm: float = 0.0

    def __init__(self, geometry: "Geometry"):
        self.g = geometry
        self._unit = np.array(geometry.unit, dtype=float)
        self._chain: "Chain | None" = None

    @property
    def chain(self) -> "Chain":
        """This robot as a chain (:func:`scara_chain`), built on first use."""
        if self._chain is None:
            self._chain = scara_chain(self.g)
        return self._chain

    @classmethod
    def preset(cls, name: str) -> "Scara":
        """A robot from :data:`cell.robots.PRESETS` (the robot files); unknown names raise
        ``KeyError`` listing the known ones."""
        from cell.robots import PRESETS
        try:
            return cls(PRESETS[name])
        except KeyError:
            raise KeyError(f"unknown robot preset {name!r}; known: {sorted(PRESETS)}") from None

    # ---------------------------------------------------------------- planar part
    def fk_planar(self, t1_deg: float, t2_deg: float) -> np.ndarray:
        """Tool centre (x_mm, y_mm) for joint angles θ1, θ2 in degrees (seed 000 eq. 4)."""
        a = math.radians(_finite("theta1_deg", t1_deg))
        b = math.radians(_finite("theta2_deg", t2_deg))
        l1, l2 = self.g.l1_mm, self.g.l2_mm
        return np.array([l1 * math.cos(a) + l2 * math.cos(a + b),
                         l1 * math.sin(a) + l2 * math.sin(a + b)])

    def fk_planar_batch(self, q_deg) -> np.ndarray:
        """Tool centres (N, 2) mm for joints (N, 2) (θ1, θ2 deg), vectorised; no checks.
        A calibrated robot overrides it with :meth:`fk_planar`, so callers that predict
        many commands at once must use this, not :func:`planar_xy` on the nominal links."""
        return planar_xy(self.g.l1_mm, self.g.l2_mm, q_deg)

    def jacobian(self, t1_deg: float, t2_deg: float) -> np.ndarray:
        """∂(x, y)/∂(θ1, θ2) in **mm per degree** (seed 000 eq. 5, scaled by π/180)."""
        a = math.radians(_finite("theta1_deg", t1_deg))
        b = math.radians(_finite("theta2_deg", t2_deg))
        l1, l2 = self.g.l1_mm, self.g.l2_mm
        s1, c1, s12, c12 = math.sin(a), math.cos(a), math.sin(a + b), math.cos(a + b)
        return np.array([[-l1 * s1 - l2 * s12, -l2 * s12],
                         [l1 * c1 + l2 * c12, l2 * c12]]) * (math.pi / 180.0)

    def ik_planar(self, x_mm: float, y_mm: float, elbow: Elbow = "right",
                  check_limits: bool = True) -> np.ndarray:
        """Joint angles (θ1_deg, θ2_deg) that put the tool centre at (x, y).

        Raises KinematicsError when the point is out of reach, at (or within
        ``singular_margin_deg`` of) the stretched/folded singularity, or when the
        solution breaks a joint limit.
        """
        x, y = _finite("x_mm", x_mm), _finite("y_mm", y_mm)
        if elbow not in ("right", "left"):
            raise KinematicsError(f"elbow = {elbow!r}; choose 'right' or 'left'")
        q = np.array(self._planar_angles(x, y, elbow == "left"))
        q[0] = (q[0] + 180.0) % 360.0 - 180.0
        if check_limits:
            self.check_limits(q, joints=(0, 1))
        return q

    def _planar_angles(self, x: float, y: float, left: bool) -> tuple[float, float]:
        """:meth:`ik_planar`'s (θ1, θ2) in degrees, θ1 not yet wrapped, for a finite (x, y);
        raises its KinematicsError for a point out of reach or at a singularity."""
        l1, l2 = self.g.l1_mm, self.g.l2_mm
        r = math.hypot(x, y)
        rmin, rmax = abs(l1 - l2), l1 + l2
        if r > rmax or r < rmin:
            raise KinematicsError(
                f"target ({x:.4f}, {y:.4f}) mm is out of reach: radius {r:.4f} mm outside "
                f"[{rmin:.4f}, {rmax:.4f}] mm")
        c2 = (r * r - l1 * l1 - l2 * l2) / (2 * l1 * l2)
        t2 = math.acos(max(-1.0, min(1.0, c2)))
        margin = math.radians(self.g.singular_margin_deg)
        if t2 < margin or math.pi - t2 < margin:
            raise KinematicsError(
                f"target ({x:.4f}, {y:.4f}) mm lies at a singularity: θ2 = ±{math.degrees(t2):.4f}° "
                f"is within {self.g.singular_margin_deg}° of the stretched or folded arm")
        if left:
            t2 = -t2
        t1 = math.atan2(y, x) - math.atan2(l2 * math.sin(t2), l1 + l2 * math.cos(t2))
        return math.degrees(t1), math.degrees(t2)

    # ---------------------------------------------------------------- full 4-axis
    def fk(self, q) -> np.ndarray:
        """Pose (x_mm, y_mm, z_mm, phi_deg) for joints (θ1_deg, θ2_deg, d3_mm, θ4_deg)."""
        q = self._as_joints(q)
        x, y = self.fk_planar(q[0], q[1])
        z = self.g.base_z_mm + q[2] + self.g.tool_z_mm
        return np.array([x, y, z, q[0] + q[1] + q[3]])

    def ik(self, pose, elbow: Elbow = "right") -> np.ndarray:
        """Joints for pose (x_mm, y_mm, z_mm, phi_deg); limits are checked on every joint."""
        p = np.asarray(pose, dtype=float)
        if p.shape != (4,):
            raise KinematicsError(f"pose must be (x_mm, y_mm, z_mm, phi_deg), got shape {p.shape}")
        for name, v in zip(("x_mm", "y_mm", "z_mm", "phi_deg"), p):
            _finite(name, v)
        t1, t2 = self.ik_planar(p[0], p[1], elbow=elbow, check_limits=False)
        d3 = p[2] - self.g.base_z_mm - self.g.tool_z_mm
        t4 = (p[3] - t1 - t2 + 180.0) % 360.0 - 180.0
        q = np.array([t1, t2, d3, t4])
        self.check_limits(q)
        return q

    def ik_rows(self, poses: np.ndarray, elbow: Elbow = "right") -> np.ndarray | None:
        """:meth:`ik` of every row of ``poses`` (N, 4), to the last bit, or ``None`` when
        :meth:`ik` would raise for a row (the caller then asks :meth:`ik` row by row, which
        names the row and the reason). The checks :meth:`ik` makes on each row are made
        once on the whole: every pose finite, every joint finite and within its limits. The
        planar part is :meth:`ik_planar`'s angles of each row (a calibrated robot's own
        :meth:`ik_planar`), the rest the same operations element-wise."""
        p = np.asarray(poses, dtype=float)
        if p.ndim != 2 or p.shape[1] != 4 or not np.isfinite(p).all():
            return None
        q = np.empty_like(p)
        xy = p[:, :2].tolist()
        try:
            if type(self).ik_planar is Scara.ik_planar:      # the nominal planar part: its angles
                if elbow not in ("right", "left"):
                    return None
                left = elbow == "left"
                if xy:
                    q[:, :2] = [self._planar_angles(x, y, left) for x, y in xy]
                q[:, 0] = (q[:, 0] + 180.0) % 360.0 - 180.0
            else:
                for k, (x, y) in enumerate(xy):
                    q[k, :2] = self.ik_planar(x, y, elbow=elbow, check_limits=False)
        except KinematicsError:
            return None
        q[:, 2] = p[:, 2] - self.g.base_z_mm - self.g.tool_z_mm
        q[:, 3] = (p[:, 3] - q[:, 0] - q[:, 1] + 180.0) % 360.0 - 180.0
        lo, hi = np.array(self.g.limits, dtype=float).T
        if not (np.isfinite(q).all() and (q >= lo).all() and (q <= hi).all()):
            return None
        return q

    def check_limits(self, q, joints=(0, 1, 2, 3)) -> None:
        """Raise KinematicsError naming the first joint of ``joints`` outside its limits."""
        for i in joints:
            v = _finite(f"{JOINT_NAMES[i]}", q[i])
            lo, hi = self.g.limits[i]
            if not lo <= v <= hi:
                raise KinematicsError(
                    f"{JOINT_NAMES[i]} = {v:.4f} is outside its limits [{lo}, {hi}]")

    # ---------------------------------------------------------------- command units
    def to_units(self, q_deg, joints=(0, 1)) -> np.ndarray:
        """Quantise joint values to whole command units (round half away from zero)."""
        q = np.asarray(q_deg, dtype=float)
        for i, v in zip(joints, q):
            _finite(JOINT_NAMES[i], v)
        u = self._unit[list(joints)]
        return (np.sign(q) * np.floor(np.abs(q) / u + 0.5)).astype(np.int64)

    def from_units(self, units, joints=(0, 1)) -> np.ndarray:
        """Joint values (deg or mm) for whole command units."""
        return np.asarray(units, dtype=float) * self._unit[list(joints)]

    def _as_joints(self, q) -> np.ndarray:
        a = np.asarray(q, dtype=float)
        if a.shape != (4,):
            raise KinematicsError(f"joints must be (θ1_deg, θ2_deg, d3_mm, θ4_deg), got shape {a.shape}")
        for name, v in zip(JOINT_NAMES, a):
            _finite(name, v)
        return a
