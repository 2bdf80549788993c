"""The calibration procedures: drive the robot, grab from the hand camera, measure targets.

This is the one module of :mod:`cell.calibration` that moves the robot. It works on any
set of devices (simulated or real) through :class:`HandRig`: the nominal robot, the joint
stations, the hand camera and that camera's plane calibration (in the *hand frame*:
origin on the tool axis, x along the tool's x axis, mm).

* :func:`plan_joint` / :func:`sweep_joint` — seed 004 for one joint (the numerics are in
  :mod:`cell.calibration.joint`);
* :func:`board_candidates` / :func:`measure_board` — seed 001's poses over a board of
  known points (the numerics are in :mod:`cell.calibration.kinematic`);
  :func:`anchor_candidates` / :func:`measure_anchors` — a few poses where the cell's fixed
  camera measures the tool in the base frame, which ties the board's frame to the cell's.

Every failure is a :class:`~cell.errors.CalibrationError` naming the step, the pose and
the cause; a cancel (``cancel.check()``) ends a procedure between moves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.calibration.joint import JointSweep
from cell.errors import CalibrationError, CellError
from cell.faults import CellFault
from cell.kinematics import JOINT_NAMES, Scara
from cell.motion.mover import MotionSpec, Mover
from cell.vision import VisionError
from cell.vision.calibration import CircleGridBoard, PlaneCalibration, locate

VIEW_MARGIN_MM = 2.0        #: kept between the target's edge and the image edge
APPROACH_DEG = 0.5          #: every measured pose is approached from this far below (θ1, θ2)
_BELOW = APPROACH_DEG * np.array([*Scara.approach_dirs, 0, 0], dtype=float)
CALIBRATION_MOTION = MotionSpec(mode="corrected", segment_s=0.02, time_law="smooth", joint_speed=60.0)


class _Never:
    def check(self) -> None:
        pass


class HandRig:
    """The robot with its hand camera, as the procedures use it.

    :param robot: the nominal robot (limits, command units);
    :param motion: the joint stations (``drivers.stations.JointStations``): ``stream``,
        ``wait_reached``, ``actual_positions``;
    :param camera: the hand camera (any :class:`drivers.camera.base.CameraBase`, opened);
    :param calibration: the hand camera's plane calibration (hand frame, mm);
    :param target_radius_mm: radius of the target disc / the board's dots;
    :param z_mm: d3 (joint units, mm) held during calibration;
    :param cancel: anything with ``check()`` that raises to stop (the controller's token).
    """

    def __init__(self, robot: Scara, motion, camera, calibration: PlaneCalibration, *,
                 target_radius_mm: float, z_mm: float = 0.0, move_timeout_s: float = 10.0,
                 reach_tol_deg: float = 0.001, spec: MotionSpec = CALIBRATION_MOTION, cancel=None):
        self.robot, self.motion, self.camera, self.cal = robot, motion, camera, calibration
        self.target_radius_mm = float(target_radius_mm)
        self.z_mm = float(z_mm)
        self.move_timeout_s, self.reach_tol_deg = move_timeout_s, reach_tol_deg
        self.spec = spec
        self.cancel = cancel or _Never()
        self.mover = Mover(robot, motion)
        self.last = np.asarray(motion.actual_positions(), dtype=float)

    @property
    def view_radius_mm(self) -> float:
        """Radius about the image centre within which a target lies whole in the image."""
        c = self.cal
        half = min(c.width, c.height) / 2.0 * c.mm_per_px(c.width / 2, c.height / 2)
        return half - self.target_radius_mm - VIEW_MARGIN_MM

    def move(self, q) -> None:
        """Move to joints ``q`` (4,) and wait until arrived. Raises CalibrationError naming
        the joints for a move out of limits, that cannot be planned or that times out."""
        self.cancel.check()
        q = np.asarray(q, dtype=float)
        try:
            self.robot.check_limits(q)
            self.mover.move(self.last, q, self.spec, self.move_timeout_s, self.reach_tol_deg)
        except (CellError, TimeoutError) as exc:
            raise CalibrationError(f"move to joints {_q(q)} failed: {exc}") from exc
        self.last = q
        self.cancel.check()

    def approach(self, q) -> None:
        """Move to joints ``q`` with θ1 and θ2 arriving from ``APPROACH_DEG`` below (as ISO
        9283 approaches its poses): backlash then takes one side of its band at every pose."""
        q = np.asarray(q, dtype=float)
        self.move(q - _BELOW)
        self.move(q)

    def target(self, where: str) -> np.ndarray:
        """Grab one frame; the single target's centre (x, y) mm in the hand frame.
        Raises CalibrationError naming ``where`` when the target is lost, cut, doubled or
        the camera fails."""
        try:
            image = self.camera.grab().image
        except Exception as exc:                          # any driver failure
            raise CalibrationError(f"{where}: hand camera gave no frame: {exc}", "measurement") from exc
        r_px = self.target_radius_mm / self.cal.mm_per_px(self.cal.width / 2, self.cal.height / 2)
        try:
            fix = locate(image, self.cal, expected=1, min_radius_px=0.7 * r_px, max_radius_px=1.3 * r_px)[0]
        except VisionError as exc:
            raise CalibrationError(f"{where}: target not measured ({exc.kind}): {exc}",
                                   "measurement") from exc
        return np.array([fix.x_mm, fix.y_mm])


# ---------------------------------------------------------------------- seed 004
@dataclass(frozen=True)
class JointPlan:
    """One joint's sweep: nominal angles of the forward pass (+limit → −limit, deg or mm),
    its step, the range the target stays in view over and why."""

    joint: str
    step_deg: float
    nominal_deg: tuple[float, ...]
    in_view_deg: tuple[float, float]
    reason: str
    runs: int

    def as_dict(self) -> dict:
        return {"joint": self.joint, "step_deg": self.step_deg, "runs": self.runs,
                "range_deg": [self.nominal_deg[-1], self.nominal_deg[0]],
                "positions": len(self.nominal_deg), "in_view_deg": list(self.in_view_deg),
                "range_reason": self.reason}


def plan_joint(robot: Scara, joint: str, view_radius_mm: float, *, runs: int = 3,
               step_deg: float | None = None, range_deg: float | None = None,
               j4_target_radius_mm: float = 15.0) -> JointPlan:
    """The angles to visit for seed 004 on ``joint`` (j1, j2 or j4) with all others at zero.

    The hand camera turns about the joint's axis at distance R (j1: l1 + l2, j2: l2, j4: 0),
    so a target laid under it at zero moves 2R·sin(θ/2) across the image: it stays whole in
    view while that is below ``view_radius_mm`` (the caller takes off how far from the image
    centre the target lies at zero). The range is that, cut to the joint limits
    less one step of pre-travel, and to ``range_deg`` if given. For j4 the target lies
    ``j4_target_radius_mm`` off the axis and stays in view at every angle. The step is
    ``step_deg`` (rounded to whole command units) or the range / 10.
    Raises CalibrationError for j3 (prismatic), bad runs/step, or a range under 2 steps.
    """
    if joint not in JOINT_NAMES:
        raise CalibrationError(f"joint {joint!r}: use one of {', '.join(JOINT_NAMES)}")
    if joint == "j3":
        raise CalibrationError("j3 is prismatic: seed 004 calibrates revolute joints (j1, j2, j4)")
    if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= 50:
        raise CalibrationError(f"runs = {runs!r} must be a whole number in 1..50")
    i = JOINT_NAMES.index(joint)
    unit = robot.g.unit[i]
    lo, hi = robot.g.limits[i]
    g = robot.g
    radius = {"j1": g.l1_mm + g.l2_mm, "j2": g.l2_mm, "j4": 0.0}[joint]
    if radius > 0:
        if view_radius_mm <= 0:
            raise CalibrationError(f"the hand camera's field ({view_radius_mm + VIEW_MARGIN_MM:.1f} mm "
                                   "less the target) is too small to keep the target in view", "refused")
        view = math.degrees(2.0 * math.asin(min(1.0, view_radius_mm / (2.0 * radius))))
        reason = (f"target in view while 2R·sin(θ/2) < {view_radius_mm:.1f} mm, R = {radius:.1f} mm "
                  f"from the {joint} axis")
    else:
        view = 180.0
        reason = f"the target circles the camera axis at {j4_target_radius_mm:.1f} mm: in view at every angle"
    if step_deg is not None and not (math.isfinite(step_deg) and step_deg > 0):
        raise CalibrationError(f"step = {step_deg!r} deg must be > 0")
    top = min(view, hi, -lo, range_deg if range_deg is not None else math.inf)
    step = step_deg if step_deg is not None else top / 10.0
    step = max(unit, round(step / unit) * unit)
    top = min(top, hi - step, -lo - step)              # room for one step of pre-travel
    n = int(math.floor(top / step + 1e-9))
    if n < 2:
        raise CalibrationError(f"{joint}: a step of {step:g}° leaves {2 * n + 1} position(s) in the "
                               f"range ±{top:.4g}° ({reason}); choose a smaller --step-deg")
    nominal = tuple(round(k * step, 9) for k in range(n, -n - 1, -1))
    return JointPlan(joint, step, nominal, (-view, view), reason, runs)


def sweep_joint(rig: HandRig, plan: JointPlan, progress=None) -> JointSweep:
    """Run seed 004's procedure (``plan.runs`` runs) and return the measured centres.

    Per run: the zero image (all joints at zero, approached from one step below); one step
    of pre-travel beyond the positive limit, then the forward pass down to the negative
    limit, an image at every angle; one step beyond the negative limit, then the return
    pass up to the positive limit. The pre-travel makes every image of a pass arrive in the
    pass's direction, so each pass sees one side of the backlash band. ``progress(done,
    total)`` is called after every image. Raises CalibrationError (see :class:`HandRig`).
    """
    i = JOINT_NAMES.index(plan.joint)
    home = np.zeros(4)
    home[2] = rig.z_mm

    def at(angle: float) -> np.ndarray:
        q = home.copy()
        q[i] = angle
        return q

    angles = np.asarray(plan.nominal_deg)
    m, step = len(angles), plan.step_deg
    total, done = plan.runs * (2 * m + 1), 0
    zero = np.full((plan.runs, 2), np.nan)
    fwd = np.full((plan.runs, m, 2), np.nan)
    ret = np.full((plan.runs, m, 2), np.nan)

    def shot(where: str) -> np.ndarray:
        nonlocal done
        xy = rig.target(where)
        done += 1
        if progress is not None:
            progress(done, total)
        return xy

    for r in range(plan.runs):
        rig.move(at(-step))
        rig.move(at(0.0))
        zero[r] = shot(f"run {r + 1} zero image")
        rig.move(at(angles[0] + step))
        for k, a in enumerate(angles):
            rig.move(at(a))
            fwd[r, k] = shot(f"run {r + 1} forward pass step {k} ({plan.joint} = {a:+.4f}°)")
        rig.move(at(angles[-1] - step))
        for k in range(m - 1, -1, -1):
            rig.move(at(angles[k]))
            ret[r, k] = shot(f"run {r + 1} return pass step {k} ({plan.joint} = {angles[k]:+.4f}°)")
    rig.move(home)
    return JointSweep(joint=plan.joint, step_deg=step, nominal_deg=angles, zero=zero,
                      forward=fwd, return_=ret, pretravel=True)


# ---------------------------------------------------------------------- seed 001
@dataclass(frozen=True)
class Candidate:
    """A pose over one known point: its index on the board, the elbow and the joints."""

    point: int
    elbow: str
    q: np.ndarray


TOOL_PHIS_DEG = (0.0, 90.0, 180.0, -90.0)   #: tool orientations tried over each point


def board_candidates(robot: Scara, board: CircleGridBoard, *, z_mm: float = 0.0,
                     tool_phis_deg=TOOL_PHIS_DEG) -> list[Candidate]:
    """Every pose that puts the tool axis over a known point of ``board`` (nominal place,
    base frame), in both elbow configurations and at each tool orientation of
    ``tool_phis_deg`` where reachable, within limits and away from the singularities.
    (Turning the tool is what separates the hand camera's offset from the tool axis,
    ``j4.a``, from the board's place.) Raises CalibrationError when none is reachable."""
    out = []
    for k, (x, y) in enumerate(board.points_mm()):
        for elbow in ("right", "left"):
            for phi in tool_phis_deg:
                q = _pose(robot, x, y, elbow, phi, z_mm)
                if q is not None:
                    out.append(Candidate(k, elbow, q))
    if not out:
        raise CalibrationError(f"board not found: none of its {board.cols * board.rows} points "
                               f"(origin {board.origin_mm} mm) is within the robot's reach and limits")
    return out


def measure_board(rig: HandRig, board: CircleGridBoard, poses: list[Candidate],
                  progress=None) -> np.ndarray:
    """Visit ``poses`` and measure the tool position (x, y) mm (N, 2) in the base frame as
    the board's nominal place defines it: ``m = b − R(φ)·h``, with ``b`` the known point,
    ``h`` where the hand camera sees it and ``φ`` the nominal tool orientation. The camera
    turns with the true tool, so this errs by Δφ·|b − m|, and systematically (the zeros'
    error turned by their own Δφ points along the arm): the fit redoes the reduction with
    its model's φ, from :func:`board_lever`. Every pose is approached the same way
    (:meth:`HandRig.approach`), so backlash acts as a constant offset the joint zeros
    absorb, not as scatter between poses.
    Raises CalibrationError naming the pose and point when the point is not seen."""
    points = board.points_mm()
    out = np.empty((len(poses), 2))
    for n, c in enumerate(poses):
        rig.approach(c.q)
        phi = float(rig.robot.fk(c.q)[3])
        h = rig.target(f"pose {n + 1} of {len(poses)} (board point {c.point}, {c.elbow} elbow, "
                       f"joints {_q(c.q)})")
        a = math.radians(phi)
        out[n] = points[c.point] - np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]) @ h
        if progress is not None:
            progress(n + 1, len(poses))
    return out


def board_lever(robot: Scara, board: CircleGridBoard, q, measured, points) -> np.ndarray:
    """How :func:`measure_board` reduced each pose, for the fit
    (:mod:`cell.calibration.kinematic`, "Lever"): rows (b_x − m_x, b_y − m_y, φ₀) (N, 3), mm
    and deg, with ``b`` the known point, ``m`` the measured tool position and φ₀ the nominal
    tool orientation of joints ``q`` (N, 4) it used. A pose whose ``points`` entry is < 0
    was measured directly (an anchor: the cell camera, base frame): its row is 0.
    Raises CalibrationError for a point the board does not have."""
    q = np.asarray(q, dtype=float)
    m = np.asarray(measured, dtype=float)[:, :2]
    pts = board.points_mm()
    out = np.zeros((len(q), 3))
    for n, k in enumerate(points):
        k = int(k)
        if k < 0:
            continue
        if k >= len(pts):
            raise CalibrationError(f"pose {n + 1}: board point {k} is not on the board "
                                   f"({len(pts)} points)")
        out[n] = [*(pts[k] - m[n]), float(robot.fk(q[n])[3])]
    return out


def anchor_candidates(robot: Scara, camera_cal: PlaneCalibration, n: int, *, z_mm: float = 0.0,
                      tool_phis_deg=TOOL_PHIS_DEG) -> list[Candidate]:
    """Up to ``n`` poses that put the tool's fiducial in the cell camera's view: a 3 × 3 grid
    over the middle of its field (centre first), tool orientations taken in turn, right
    elbow (left where the right one is out of limits). ``point`` is −1 (no board point).
    Raises CalibrationError if n > 0 and none is reachable."""
    c = camera_cal
    u0, v0 = c.centre_px
    centre = np.array(c.pixel_to_base(u0, v0))
    half = 0.25 * min(c.width, c.height) * c.mm_per_px(u0, v0)
    grid = [(0, 0), (-1, -1), (1, 1), (-1, 1), (1, -1), (0, -1), (0, 1), (-1, 0), (1, 0)]
    out: list[Candidate] = []
    for k, (i, j) in enumerate(grid):
        if len(out) >= n:
            break
        x, y = centre + half * np.array([i, j])
        phi = tool_phis_deg[k % len(tool_phis_deg)]
        for elbow in ("right", "left"):
            q = _pose(robot, x, y, elbow, phi, z_mm)
            if q is not None:
                out.append(Candidate(-1, elbow, q))
                break
    if n > 0 and not out:
        raise CalibrationError(f"no pose puts the tool in the cell camera's view (centre "
                               f"({centre[0]:.1f}, {centre[1]:.1f}) mm) within the robot's reach and limits")
    return out


def measure_anchors(rig: HandRig, measuring_camera, poses: list[Candidate], progress=None) -> np.ndarray:
    """Visit ``poses`` (approached as :func:`measure_board` does) and measure the tool's
    fiducial with the cell's fixed camera (``measuring_camera.tool()``): tool positions
    (N, 2) mm in the base frame the cell works in. Raises CalibrationError naming the pose
    when the fiducial is not measured."""
    out = np.empty((len(poses), 2))
    for n, c in enumerate(poses):
        rig.approach(c.q)
        try:
            out[n] = measuring_camera.tool()
        except (CellError, CellFault) as exc:
            raise CalibrationError(f"anchor pose {n + 1} of {len(poses)} (joints {_q(c.q)}): target not "
                                   f"measured: the cell camera did not measure the tool: {exc}",
                                   "measurement") from exc
        if progress is not None:
            progress(n + 1, len(poses))
    return out


def _pose(robot: Scara, x: float, y: float, elbow: str, phi: float, z_mm: float) -> np.ndarray | None:
    """Joints that put the tool axis at (x, y) with orientation ``phi``, if they and the
    approach from below lie within limits and away from the singularities; else None."""
    try:
        t1, t2 = robot.ik_planar(x, y, elbow=elbow)
        q = np.array([t1, t2, z_mm, (phi - t1 - t2 + 180.0) % 360.0 - 180.0])
        robot.check_limits(q)
        robot.check_limits(q - _BELOW)
    except CellError:
        return None
    return q


def _q(q) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in np.asarray(q, dtype=float)) + ")"
