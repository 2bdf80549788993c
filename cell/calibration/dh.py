"""The cell's SCARA as a standard-DH chain and its differential (first-order) error model,
seed 001, for the hand-camera calibration. Pure, vectorised numerics; no I/O.

The chain is evaluated by the one robot model, :mod:`cell.kinematics`: a :class:`DHChain`
is a :class:`~cell.kinematics.chain.Chain` with the board placement ``B`` as its first
three ops, and every error parameter adds to one op, so :func:`error_jacobian`'s columns
are op twists (:mod:`cell.kinematics.evaluate`). What this module adds is the naming of
the seed 001 parameters and the planar (x, y, φ) measurement.

Chain and conventions (angles in degrees and lengths in mm at every interface)::

    T_board_tool(q, p) = B(p) · A_1 · A_2 · ... · A_n
    A_i = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)                      (standard DH)
    revolute i:  θ_i = θ_i,nom + q[joint_i] + Δθ_i,  d_i = d_i,nom + Δd_i
    prismatic i: d_i = d_i,nom + q[joint_i] + Δd_i,  θ_i = θ_i,nom + Δθ_i
    a_i = a_i,nom + Δa_i,  α_i = α_i,nom + Δα_i
    B(p) = Trans(x0 + Δx, y0 + Δy, 0) · Rz(rz0 + Δrz)

**Base nuisance.** ``B`` is the pose of the robot base frame *in the board frame*: the base
origin sits at (base.x, base.y) mm in board coordinates and the base x axis is turned by
base.rz (deg, counter-clockwise about the common vertical z) from the board x axis; so
``p_board = Rz(rz)·p_base + (x, y, 0)``. Equivalently, the board frame is the base frame
moved by the inverse of ``B``. ``(x0, y0, rz0)`` = :attr:`DHChain.base_nominal` is where
the board nominally lies (default: board frame = base frame); the errors Δx, Δy, Δrz are
the unknown placement. The board lies on the work plane, so no base tilt or height is
modelled (the planar measurement could not see them; see :func:`planar_pose`).

**Parameter vector** ``p`` (n_params,) holds *errors* (deviations from nominal), named
``"j<k>.theta", "j<k>.d", "j<k>.a", "j<k>.alpha"`` for link k = 1..n (deg, mm, mm, deg),
then ``"base.x", "base.y", "base.rz"`` (mm, mm, deg): 19 for the 4-link SCARA.

**Measurement.** Per pose the hand camera gives the tool's planar pose (x mm, y mm, φ deg)
in the board frame; stacked pose-major (x0, y0, φ0, x1, ...) in every (N·3,) vector and in
the rows of :func:`error_jacobian`.

Bad input raises :class:`~cell.errors.CalibrationError` naming the value (and the pose).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Mapping

import numpy as np

from cell.errors import CalibrationError
from cell.kinematics import AXES, Chain, Joint, Op, forward

JointType = Literal["revolute", "prismatic"]
DH_FIELDS = ("theta", "d", "a", "alpha")
ANGLE_FIELDS = ("theta", "alpha")
BASE_NAMES = ("base.x", "base.y", "base.rz")
D2R = math.pi / 180.0


def wrap_deg(a):
    """Angles (deg) wrapped into [−180, 180)."""
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class DHLink:
    """One standard-DH link ``A = Rz(θ)·Tz(d)·Tx(a)·Rx(α)`` with its nominal values.

    ``joint`` is the 0-based column of the joint vector q that drives this link: added to
    θ (deg) for a ``"revolute"`` link, to d (mm) for a ``"prismatic"`` one.
    Raises CalibrationError for a non-finite value, an unknown joint type or joint < 0.
    """

    theta_deg: float
    d_mm: float
    a_mm: float
    alpha_deg: float
    joint_type: JointType
    joint: int

    def __post_init__(self):
        for name in ("theta_deg", "d_mm", "a_mm", "alpha_deg"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise CalibrationError(f"DH link {name} = {v!r} is not a finite number")
        if self.joint_type not in ("revolute", "prismatic"):
            raise CalibrationError(f"DH joint type {self.joint_type!r}; choose 'revolute' or 'prismatic'")
        if self.joint < 0:
            raise CalibrationError(f"DH joint index {self.joint} must be >= 0")


@dataclass(frozen=True)
class DHChain:
    """A serial DH chain on a base placed on the calibration board, with the helpers of
    the planar (x, y, φ) measurement. ``source`` names where the model comes from."""

    links: tuple[DHLink, ...]
    base_nominal: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "custom"
    source: str = ""
    param_names: tuple[str, ...] = field(init=False, repr=False, compare=False)
    ops_chain: Chain = field(init=False, repr=False, compare=False)
    param_op: tuple[int, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not self.links:
            raise CalibrationError("a DH chain needs at least one link")
        if len(self.base_nominal) != 3 or not all(math.isfinite(v) for v in self.base_nominal):
            raise CalibrationError(f"base_nominal must be 3 finite numbers (x mm, y mm, rz deg), "
                                   f"got {self.base_nominal!r}")
        names = tuple(f"j{k + 1}.{f}" for k in range(len(self.links)) for f in DH_FIELDS)
        object.__setattr__(self, "param_names", names + BASE_NAMES)
        ops_chain, param_op = _as_ops(self)
        object.__setattr__(self, "ops_chain", ops_chain)
        object.__setattr__(self, "param_op", param_op)

    # ------------------------------------------------------------------ bookkeeping
    @property
    def n_params(self) -> int:
        """Length of the error vector p: 4 per link + 3 base (19 for the SCARA)."""
        return len(self.param_names)

    @property
    def n_joints(self) -> int:
        """Number of columns q must have (highest joint index + 1)."""
        return max(lk.joint for lk in self.links) + 1

    @property
    def reach_mm(self) -> float:
        """Σ|a_i| over the links (mm), the arm's planar reach; 1 mm if all a's are 0."""
        return float(sum(abs(lk.a_mm) for lk in self.links)) or 1.0

    def index(self, name: str) -> int:
        """Position of parameter ``name`` in p; unknown names raise CalibrationError."""
        try:
            return self.param_names.index(name)
        except ValueError:
            raise CalibrationError(f"unknown DH parameter {name!r}; known: {list(self.param_names)}") from None

    def unit(self, name: str) -> str:
        """Unit of parameter ``name``: ``"deg"`` (θ, α, rz) or ``"mm"`` (d, a, x, y)."""
        self.index(name)
        return "deg" if name.split(".")[1] in ANGLE_FIELDS + ("rz",) else "mm"

    def errors(self, values: Mapping[str, float] | None = None) -> np.ndarray:
        """An error vector p (n_params,): zeros, with ``values`` ({name: error}) filled in."""
        p = np.zeros(self.n_params)
        for k, v in (values or {}).items():
            p[self.index(k)] = float(v)
        return self.check_errors(p)

    def check_errors(self, p) -> np.ndarray:
        """``p`` as a float (n_params,) array; wrong shape or non-finite raise CalibrationError."""
        a = np.asarray(p, dtype=float)
        if a.shape != (self.n_params,):
            raise CalibrationError(f"DH error vector must have shape ({self.n_params},), got {a.shape}")
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise CalibrationError(f"DH error {self.param_names[bad[0]]} = {a[bad[0]]!r} is not finite")
        return a

    def check_joints(self, q, what: str = "joints") -> np.ndarray:
        """``q`` as a float (N, n_joints) array (θ deg, d mm); a wrong shape or a non-finite
        value raise CalibrationError naming the pose index."""
        a = np.asarray(q, dtype=float)
        if a.ndim != 2 or a.shape[1] != self.n_joints or a.shape[0] == 0:
            raise CalibrationError(f"{what} must have shape (N >= 1, {self.n_joints}), got {a.shape}")
        _check_finite_rows(a, what)
        return a

    # ------------------------------------------------------------------ measurement
    def predict(self, q, p=None) -> np.ndarray:
        """Planar poses (N, 3) (x mm, y mm, φ deg) in the board frame for joints q, errors p."""
        return planar_pose(fk(self, q, p))

    def residuals(self, q, measured, p=None) -> np.ndarray:
        """measured − predicted (N, 3) with the φ difference wrapped into [−180, 180)."""
        m = check_measured(measured, len(np.asarray(q)))
        r = m - self.predict(q, p)
        r[:, 2] = wrap_deg(r[:, 2])
        return r


def _as_ops(chain: DHChain) -> tuple[Chain, tuple[int, ...]]:
    """The :class:`~cell.kinematics.chain.Chain` of ``chain``: ``Tx(x0) · Ty(y0) · Rz(rz0)``
    (the board placement ``B``) then ``Rz(θ) · Tz(d) · Tx(a) · Rx(α)`` per link; and, in
    ``param_names`` order, the op each error parameter adds to."""
    x, y, z = AXES["x"], AXES["y"], AXES["z"]
    x0, y0, rz0 = chain.base_nominal
    ops = [Op("T", x, x0), Op("T", y, y0), Op("R", z, rz0)]
    link_ops: list[int] = []
    for lk in chain.links:
        rev = lk.joint_type == "revolute"
        link_ops += range(len(ops), len(ops) + 4)
        ops += [Op("R", z, lk.theta_deg, joint=lk.joint if rev else None),
                Op("T", z, lk.d_mm, joint=None if rev else lk.joint),
                Op("T", x, lk.a_mm), Op("R", x, lk.alpha_deg)]
    types = {lk.joint: lk.joint_type for lk in chain.links}
    n = chain.n_joints
    joints = [Joint(f"j{k + 1}", f"j{k + 1}", types.get(k, "revolute")) for k in range(n)]
    joint_op = [next((i for i, op in enumerate(ops) if op.joint == k), 0) for k in range(n)]
    kc = Chain("dh", ops, joints, np.zeros((n, n)), np.zeros(3), np.array([0.0, 0.0, -1.0]),
               "standard", {}, joint_op)
    return kc, tuple(link_ops) + (0, 1, 2)


def _check_finite_rows(a: np.ndarray, what: str) -> None:
    bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
    if bad.size:
        raise CalibrationError(f"{what} of pose {bad[0]} is not finite: {a[bad[0]].tolist()} "
                               f"({bad.size} such poses)")


def check_measured(measured, n: int | None = None, what: str = "measured") -> np.ndarray:
    """``measured`` as a float (N, 3) array (x mm, y mm, φ deg); a wrong shape, a count other
    than ``n`` or a non-finite value raise CalibrationError naming the pose index."""
    m = np.asarray(measured, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or (n is not None and m.shape[0] != n):
        want = f"({n}, 3)" if n is not None else "(N, 3)"
        raise CalibrationError(f"{what} must have shape {want} (x mm, y mm, φ deg), got {m.shape}")
    _check_finite_rows(m, what)
    return m.copy()


def scara_chain(geometry, *, base_nominal=(0.0, 0.0, 0.0)) -> DHChain:
    """The cell's 4-axis SCARA (:class:`cell.robots.Geometry`) as a DH chain: the rows of
    :func:`cell.kinematics.dh_rows` (α = 0 everywhere, so φ = θ1 + θ2 + θ4 and
    z = base_z + d3 + tool_z). ``base_nominal`` (x mm, y mm, rz deg) is the nominal pose of
    the base in the board frame.
    """
    from cell.kinematics import dh_rows
    links = tuple(DHLink(r["theta_deg"], r["d_mm"], r["a_mm"], r["alpha_deg"], r["type"], k)
                  for k, r in enumerate(dh_rows(geometry)))
    return DHChain(links, tuple(float(v) for v in base_nominal), name=geometry.name,
                   source=f"cell.robots.Geometry {geometry.name!r}: {geometry.source}".rstrip(": "))


# ---------------------------------------------------------------------- kinematics
def _forward(chain: DHChain, q, p, keep: bool = False):
    """:func:`cell.kinematics.forward` of ``chain`` at errors ``p`` (checked)."""
    q = chain.check_joints(q)
    p = np.zeros(chain.n_params) if p is None else chain.check_errors(p)
    geo = {op: float(v) for op, v in zip(chain.param_op, p) if v}
    return forward(chain.ops_chain, q, geo, keep=keep)


def fk(chain: DHChain, q, p=None) -> np.ndarray:
    """Tool transforms in the board frame, (N, 4, 4), for joints q (N, n_joints) (θ deg,
    d mm) and errors p (n_params,) (None: nominal), base nuisance ``B(p)`` included.
    Raises CalibrationError for bad shapes or non-finite values."""
    return _forward(chain, q, p)[0]


def planar_pose(T) -> np.ndarray:
    """The planar measurement (N, 3) = (x mm, y mm, φ deg) of transforms T (N, 4, 4):
    the translation's x, y and φ = atan2(R[1,0], R[0,0]), the heading of the tool's x axis
    projected on the plane, in [−180, 180].

    The measurement is blind to z, roll and pitch: a camera looking down at a board on
    the work plane sees neither the height nor a small tilt of the tool directly; they
    only show up through their in-plane lever arms (see :func:`error_jacobian`)."""
    T = np.asarray(T, dtype=float)
    return np.column_stack([T[:, 0, 3], T[:, 1, 3], np.degrees(np.arctan2(T[:, 1, 0], T[:, 0, 0]))])


def _rotation_rows(u, o, tool_p, r1) -> np.ndarray:
    """(N, 3) effect on (x mm, y mm, φ deg) of a 1° rotation about unit axis u through
    point o: dp = u × (p − o)·π/180; dφ is the exact first-order change of
    atan2(r1_y, r1_x) for r1 → r1 + δ·u × r1 (= u_z when the tool x axis is level)."""
    dp = np.cross(u, tool_p - o) * D2R
    w = np.cross(u, r1)
    dphi = (r1[:, 0] * w[:, 1] - r1[:, 1] * w[:, 0]) / (r1[:, 0] ** 2 + r1[:, 1] ** 2)
    return np.column_stack([dp[:, 0], dp[:, 1], dphi])


def _translation_rows(u) -> np.ndarray:
    """(N, 3) effect on (x, y, φ) of a 1 mm translation along u: (u_x, u_y, 0)."""
    return np.column_stack([u[:, 0], u[:, 1], np.zeros(len(u))])


def error_jacobian(chain: DHChain, q, p=None) -> np.ndarray:
    """Identification Jacobian (N·3, n_params) of the planar measurement w.r.t. the errors,
    built from each link's differential transform (seed 001: ΔT = Σ T_i·δ_i, second-order
    terms dropped), evaluated at errors p (None: nominal).

    Rows are pose-major (x_k mm, y_k mm, φ_k deg); columns follow ``chain.param_names`` in
    mm per deg (θ, α, rz) or mm per mm (d, a, x, y), φ rows in deg per unit. For link i
    with frames i−1 (before) and i (after), tool position p_t:

    * Δθ_i: rotation about z_{i−1} through o_{i−1}: dp = u × (p_t − o), dφ = u_z
    * Δd_i: translation along z_{i−1};  Δa_i: translation along x_i
    * Δα_i: rotation about x_i through o_i
    * base.x, base.y: translations along the board's x, y; base.rz: rotation about the
      board's z through the base origin (hence identical to j1.theta's column).

    The model is exact to first order at any p (it is the derivative of
    :func:`fk` → :func:`planar_pose`), so it can be relinearised (Gauss–Newton).
    """
    T, starts = _forward(chain, q, p, keep=True)
    tool_p, r1 = T[:, :3, 3], T[:, :3, 0]
    cols = []
    for o in chain.param_op:
        op, F = chain.ops_chain.ops[o], starts[o]
        u = F[:, :3, :3] @ op.axis
        cols.append(_rotation_rows(u, F[:, :3, 3], tool_p, r1) if op.kind == "R"
                    else _translation_rows(u))
    return np.stack(cols, axis=-1).reshape(len(T) * 3, len(cols))
