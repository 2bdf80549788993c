"""A serial chain as data: the ``kinematics: dh`` and ``kinematics: urdf`` models of the
measurement format (``cell/measurements.md``, Extension v1.1) turned into one product of
elementary transforms. Pure numerics after the URDF is parsed; no other I/O.

Every chain, whatever its source, is the product (base to tip) of **ops**::

    T_tip(q) = op_1 · op_2 · … · op_m          op = F (a fixed 4×4) or R/T (about/along
                                                   a unit axis of the frame it starts in)

An R/T op's value is ``nominal + Σ (its parameters) + joint terms``. Joint K's op carries
its *model value* ``reading_K + Σ factor · reading_from`` (coupling), plus whatever error
effects add to it (:mod:`cell.diagnosis.chain.fit`). Because every parameter enters one op as a
plain sum, the derivative of a point with respect to any parameter is that op's twist at
the frame it starts in: exact analytic Jacobians (:mod:`cell.kinematics.evaluate`).

* **Standard DH** row K: ``Rz(θ_K + q) · Tz(d_K) · Tx(a_K) · Rx(α_K)`` (prismatic: q in Tz).
* **Modified DH** (Craig) row K: ``Rx(α_{K−1}) · Tx(a_{K−1}) · Rz(θ_K + q) · Tz(d_K)``.
* **URDF** moving joint: ``F(origin) · Tx · Ty · Tz · Rx · Ry · Rz · R/T(axis, q)``; the six
  zero-valued ops are the origin's error parameters; fixed joints fold into F.

Units at every interface: mm and degrees (URDF metres × 1000, radians × 180/π).
Errors raise :class:`~cell.errors.CampaignFormatError` naming the file and the joint.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from cell.errors import CampaignFormatError

D2R = math.pi / 180.0
AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}
JointType = Literal["revolute", "prismatic"]


@dataclass(frozen=True)
class Joint:
    """Joint K of the campaign: CSV column ``column`` (``j1`` …), ``name`` in the model,
    reading unit deg (revolute) or mm (prismatic), limits in the same unit (None: unknown);
    ``motor_ratio`` the motor turns per joint turn when the model states it (None: not
    stated), the period of a motor-side ripple at the joint; ``bus_position`` its 1-based
    position on the drives' bus, the order in which it receives a command frame (None: not
    known; a planar campaign's ``stations``)."""

    column: str
    name: str
    type: JointType
    lower: float | None = None
    upper: float | None = None
    motor_ratio: float | None = None
    bus_position: int | None = None

    @property
    def unit(self) -> str:
        return "deg" if self.type == "revolute" else "mm"


@dataclass(frozen=True)
class Op:
    """One elementary transform. ``kind`` F (fixed ``matrix``), R (rotation about ``axis`` by
    value deg) or T (translation along ``axis`` by value mm); value = ``nominal`` + sum of
    the parameters and joint terms that act on it. ``joint`` is the 0-based joint it
    carries (None: none); ``params`` names the geometric error parameters it carries."""

    kind: Literal["F", "R", "T"]
    axis: np.ndarray | None = None
    nominal: float = 0.0
    matrix: np.ndarray | None = None
    joint: int | None = None
    params: tuple[str, ...] = ()

    def at(self, value: float) -> np.ndarray:
        """The 4×4 transform of an R/T op at ``value`` (deg / mm)."""
        return rot(self.axis, value) if self.kind == "R" else trans(self.axis, value)

    @property
    def nominal_matrix(self) -> np.ndarray:
        """The 4×4 transform at the nominal value (F: its matrix), computed once."""
        m = self.__dict__.get("_nominal_matrix")
        if m is None:
            m = self.matrix if self.kind == "F" else self.at(self.nominal)
            object.__setattr__(self, "_nominal_matrix", m)
        return m


@dataclass
class Chain:
    """A serial chain: ``ops`` base → tip link, its ``joints`` (CSV order), ``coupling``
    (N×N: model value = reading + C @ reading), the nominal tool point ``tool_mm`` in the
    tip frame, the gravity direction in the base frame, and the geometric error
    parameters the kinematic source defines (``geometric``: name → op index)."""

    kind: str
    ops: list[Op]
    joints: list[Joint]
    coupling: np.ndarray
    tool_mm: np.ndarray
    gravity: np.ndarray
    convention: str = ""
    geometric: dict[str, int] = field(default_factory=dict)
    joint_op: list[int] = field(default_factory=list)

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    def model_values(self, readings: np.ndarray) -> np.ndarray:
        """(N, J) model joint values from (N, J) readings (coupling applied)."""
        return readings + readings @ self.coupling.T


# -------------------------------------------------------------- elementary matrices
def rot(axis: np.ndarray, deg) -> np.ndarray:
    """(…, 4, 4) rotation about unit ``axis`` by ``deg`` (scalar or array)."""
    a = np.asarray(deg, dtype=float) * D2R
    c, s = np.cos(a), np.sin(a)
    x, y, z = axis
    C = 1.0 - c
    if a.ndim and _unit_axis(axis) and np.isfinite(a).all():
        return _rot_unit(axis, a.shape, c, s, C)
    R = np.empty(a.shape + (4, 4))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = c + x * x * C, x * y * C - z * s, x * z * C + y * s
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = y * x * C + z * s, c + y * y * C, y * z * C - x * s
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = z * x * C - y * s, z * y * C + x * s, c + z * z * C
    R[..., :3, 3] = 0.0
    R[..., 3, :3] = 0.0
    R[..., 3, 3] = 1.0
    return R


def _unit_axis(axis) -> bool:
    """``axis`` is x, y or z: one component 1, the others +0."""
    u = [float(v) for v in axis]
    return sorted(u) == [0.0, 0.0, 1.0] and all(v == 1.0 or math.copysign(1.0, v) > 0 for v in u)


def _rot_unit(axis, shape, c, s, C) -> np.ndarray:
    """:func:`rot` about x, y or z at finite angles, entry for entry the same values (their
    signs included): the general formula's terms with a zero factor are +0, so an entry is
    c, c + C, s + 0, 0 − s or +0."""
    k = [float(v) for v in axis].index(1.0)
    i, j = (k + 1) % 3, (k + 2) % 3                   # the plane turned, right-handed
    R = np.zeros(shape + (4, 4))
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., k, k] = c + C
    R[..., j, i] = s + 0.0                              # u_j·u_i·C + u_k·s
    R[..., i, j] = 0.0 - s                              # u_i·u_j·C − u_k·s
    R[..., 3, 3] = 1.0
    return R


def trans(axis: np.ndarray, mm) -> np.ndarray:
    """(…, 4, 4) translation along unit ``axis`` by ``mm``."""
    d = np.asarray(mm, dtype=float)
    T = np.broadcast_to(np.eye(4), d.shape + (4, 4)).copy()
    T[..., :3, 3] = d[..., None] * axis
    return T


def rpy_matrix(xyz_mm, rpy_rad) -> np.ndarray:
    """URDF origin: ``Trans(xyz) · Rz(yaw) · Ry(pitch) · Rx(roll)`` (fixed-axis XYZ)."""
    r, p, y = (float(v) / D2R for v in rpy_rad)
    T = rot(AXES["z"], y) @ rot(AXES["y"], p) @ rot(AXES["x"], r)
    T[:3, 3] = xyz_mm
    return T


def matrix_rpy(T: np.ndarray) -> tuple[list[float], list[float]]:
    """Inverse of :func:`rpy_matrix`: (xyz in mm, rpy in rad) of a 4×4 transform."""
    R = T[:3, :3]
    pitch = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    if abs(math.cos(pitch)) < 1e-9:  # gimbal lock: put everything in yaw
        roll, yaw = 0.0, math.atan2(-R[0, 1], R[1, 1])
    else:
        roll, yaw = math.atan2(R[2, 1], R[2, 2]), math.atan2(R[1, 0], R[0, 0])
    return [float(v) for v in T[:3, 3]], [roll, pitch, yaw]


# ------------------------------------------------------------------- builders
def _check_coupling(file: Path | str, joints: list[Joint], coupling: list[dict]) -> np.ndarray:
    index = {j.name: k for k, j in enumerate(joints)}
    C = np.zeros((len(joints), len(joints)))
    for i, c in enumerate(coupling):
        for key in ("joint", "from"):
            if c[key] not in index:
                raise CampaignFormatError(file, f"coupling[{i}].{key} {c[key]!r} is not one of the "
                                                f"joints {list(index)}", column="coupling")
            if joints[index[c[key]]].type != "revolute":
                raise CampaignFormatError(file, f"coupling[{i}]: {c[key]!r} is prismatic; couplings "
                                                "link revolute joints only", column="coupling")
        if c["joint"] == c["from"]:
            raise CampaignFormatError(file, f"coupling[{i}]: a joint cannot couple to itself",
                                      column="coupling")
        C[index[c["joint"]], index[c["from"]]] += float(c["factor"])
    return C


def dh_chain(file: Path | str, rows: list[dict], convention: str, coupling: list[dict],
             tool_mm, gravity) -> Chain:
    """Chain from DH rows (dicts with name, type, a_mm, alpha_deg, d_mm, theta_deg and
    optional limits [lo, hi]). Geometric parameters ``jK_{theta_deg,d_mm,a_mm,alpha_deg}``;
    the joint's own variable (θ revolute, d prismatic) is its joint offset instead."""
    ops: list[Op] = []
    joints: list[Joint] = []
    geometric: dict[str, int] = {}
    z, x = AXES["z"], AXES["x"]
    for k, r in enumerate(rows):
        col = f"j{k + 1}"
        lim = r.get("limits")
        joints.append(Joint(col, r["name"], r["type"], *(lim if lim else (None, None))))
        rev = r["type"] == "revolute"
        th = Op("R", z, r["theta_deg"], joint=k if rev else None, params=(f"{col}_theta_deg",))
        dd = Op("T", z, r["d_mm"], joint=None if rev else k, params=(f"{col}_d_mm",))
        aa = Op("T", x, r["a_mm"], params=(f"{col}_a_mm",))
        al = Op("R", x, r["alpha_deg"], params=(f"{col}_alpha_deg",))
        row_ops = [th, dd, aa, al] if convention == "standard" else [al, aa, th, dd]
        for op in row_ops:
            if op.params[0] not in ((f"{col}_theta_deg",) if rev else (f"{col}_d_mm",)):
                geometric[op.params[0]] = len(ops)
            ops.append(op)
    ops.append(Op("F", matrix=trans(z, 0.0)))
    C = _check_coupling(file, joints, coupling)
    return Chain("dh", ops, joints, C, np.asarray(tool_mm, float), np.asarray(gravity, float),
                 convention, geometric, _joint_ops(ops, len(joints)))


def urdf_chain(file: Path, urdf_path: Path, base: str, tip: str, names: list[str],
               tool_mm, gravity) -> Chain:
    """Chain ``base`` → ``tip`` of a URDF (read by urdf_parser_py, the ROS reference
    parser). ``names`` are the moving joints in CSV order; they must be exactly the moving
    joints on the path. Geometric parameters per moving joint: its origin's
    ``jK_{x,y,z}_mm`` and ``jK_{roll,pitch,yaw}_deg``."""
    where = str(urdf_path)
    try:
        text = urdf_path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CampaignFormatError(file, f"urdf {where}: cannot read: {exc.strerror}", column="urdf") from None
    try:
        robot = parse_urdf(text)
    except Exception as exc:  # lxml's XMLSyntaxError, or the parser's own on a bad element
        raise CampaignFormatError(urdf_path, f"not a valid URDF: {exc}") from None
    links = {lk.name for lk in robot.links}
    for key, link in (("base_link", base), ("tip_link", tip)):
        if link not in links:
            raise CampaignFormatError(file, f"{key} {link!r} is not a link of {urdf_path.name}",
                                      column=key)
    path = _path_down(robot, base, tip)
    if path is None:
        raise CampaignFormatError(file, f"no path from base_link {base!r} to tip_link {tip!r} in "
                                        f"{urdf_path.name}: {_where_tip_hangs(robot, base, tip)}",
                                  column="tip_link")
    moving = [j for j in path if robot.joint_map[j].type not in ("fixed",)]
    for j in moving:
        js = robot.joint_map[j]
        if js.type not in ("revolute", "continuous", "prismatic"):
            raise CampaignFormatError(urdf_path, f"joint {j!r}: type {js.type!r} is not supported "
                                                 "(revolute, continuous, prismatic, fixed)")
        if js.mimic is not None:
            raise CampaignFormatError(urdf_path, f"joint {j!r} is a mimic joint; mimic joints are "
                                                 "refused (give it as a coupling of a dh model)")
    for j in names:
        if j not in robot.joint_map:
            raise CampaignFormatError(file, f"joint {j!r} is not in {urdf_path.name}", column="joints")
        if j not in moving:
            raise CampaignFormatError(file, f"joint {j!r} is not a moving joint between {base!r} and "
                                            f"{tip!r}", column="joints")
    missing = [j for j in moving if j not in names]
    if missing:
        raise CampaignFormatError(file, f"moving joint(s) {missing} between {base!r} and {tip!r} are "
                                        "not in joints; every moving joint on the path needs a column",
                                  column="joints")
    if [j for j in moving if j in names] != list(names):
        raise CampaignFormatError(file, f"joints must follow the chain order base to tip: {moving}",
                                  column="joints")
    for jname in path:
        _check_finite(urdf_path, text, robot.joint_map[jname])
    ops: list[Op] = []
    joints: list[Joint] = []
    geometric: dict[str, int] = {}
    pending = np.eye(4)
    for jname in path:
        js = robot.joint_map[jname]
        o = js.origin
        T = rpy_matrix(np.asarray(o.xyz if o and o.xyz else [0, 0, 0], float) * 1000.0,
                       o.rpy if o and o.rpy else [0, 0, 0])
        pending = pending @ T
        if js.type == "fixed":
            continue
        k = names.index(jname)
        col = f"j{k + 1}"
        prism = js.type == "prismatic"
        unit = 1000.0 if prism else 1.0 / D2R
        lo = hi = None
        if js.limit is not None and js.type != "continuous":
            lo, hi = js.limit.lower * unit, js.limit.upper * unit
        joints.append(Joint(col, jname, "prismatic" if prism else "revolute", lo, hi))
        axis = np.asarray(js.axis if js.axis is not None else [1, 0, 0], float)
        if not np.linalg.norm(axis) > 0:
            raise CampaignFormatError(urdf_path, f"joint {jname!r}: zero axis", line=_line_of(text, jname))
        ops.append(Op("F", matrix=pending))
        pending = np.eye(4)
        for stem, kind, ax in (("x_mm", "T", "x"), ("y_mm", "T", "y"), ("z_mm", "T", "z"),
                               ("roll_deg", "R", "x"), ("pitch_deg", "R", "y"), ("yaw_deg", "R", "z")):
            geometric[f"{col}_{stem}"] = len(ops)
            ops.append(Op(kind, AXES[ax], 0.0, params=(f"{col}_{stem}",)))
        ops.append(Op("T" if prism else "R", axis / np.linalg.norm(axis), 0.0, joint=k))
    ops.append(Op("F", matrix=pending))
    return Chain("urdf", ops, joints, np.zeros((len(joints), len(joints))),
                 np.asarray(tool_mm, float), np.asarray(gravity, float), "", geometric,
                 _joint_ops(ops, len(joints)))


def _path_down(robot, base: str, tip: str) -> list[str] | None:
    """Joint names from ``base`` down to ``tip``, or None when ``tip`` is not below ``base``."""
    path, link = [], tip
    while link != base:
        if link not in robot.parent_map:
            return None
        joint, link = robot.parent_map[link]
        path.append(joint)
    return path[::-1] or None


def _where_tip_hangs(robot, base: str, tip: str) -> str:
    """Why ``tip`` is not below ``base``, in words: its own chain up to its root, and what
    hangs below ``base`` (the links a tip_link could name)."""
    up, link = [tip], tip
    while link in robot.parent_map and len(up) <= len(robot.links):
        link = robot.parent_map[link][1]
        up.append(link)
    below, todo = [], [base]
    while todo:
        for _, child in robot.child_map.get(todo.pop(), []):
            below.append(child)
            todo.append(child)
    hangs = (f"{tip!r} is attached to no joint" if len(up) == 1 else
             f"{tip!r} hangs from {' → '.join(reversed(up))}")
    return (f"{hangs}; below {base!r} are " + (", ".join(repr(b) for b in below[:8])
                                               + (", …" if len(below) > 8 else "")
                                               if below else "no links"))


def _line_of(text: str, joint: str) -> int | None:
    """1-based line of ``<joint name="joint"`` in the URDF text, if found."""
    import re
    m = re.search(r"<joint\b[^>]*\bname\s*=\s*[\"']" + re.escape(joint) + r"[\"']", text)
    return text.count("\n", 0, m.start()) + 1 if m else None


def _check_finite(urdf_path: Path, text: str, js) -> None:
    """Refuse a joint on the path whose origin, axis or limits hold a NaN or an inf."""
    o = js.origin
    fields = {"origin xyz": o.xyz if o else None, "origin rpy": o.rpy if o else None, "axis": js.axis}
    if js.limit is not None and js.type != "continuous":
        fields["limit lower/upper"] = [js.limit.lower, js.limit.upper]
    for what, values in fields.items():
        if values is not None and not np.all(np.isfinite(np.asarray(values, float))):
            raise CampaignFormatError(urdf_path, f"joint {js.name!r}: {what} "
                                                 f"{' '.join(f'{v:g}' for v in values)} is not finite",
                                      line=_line_of(text, js.name))


def _joint_ops(ops: list[Op], n: int) -> list[int]:
    out = [0] * n
    for i, op in enumerate(ops):
        if op.joint is not None:
            out[op.joint] = i
    return out


def parse_urdf(text: str):
    """The URDF ``text`` as urdf_parser_py's Robot (the parser prints unknown-element notes
    to stderr; they are kept off the report). Raises what the parser raises."""
    import contextlib
    import io
    from urdf_parser_py.urdf import URDF  # lazy: only chain campaigns need it
    with contextlib.redirect_stderr(io.StringIO()):
        return URDF.from_xml_string(text.encode("utf-8"))
