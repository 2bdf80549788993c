"""Robot calibration as the cell runs it: from the command line or from the PLC.

:class:`CellCalibrator` joins the pieces for one cell: its devices (hand camera, stations,
fixture), the nominal robot, the calibration file. Both the ``cellctl calibrate`` commands
and the controller's CALIBRATING state call it:

* :meth:`CellCalibrator.joint` — seed 004 on one joint: plan, sweep, analyse, and record
  the joint's terms in the calibration file (:mod:`cell.calibration.joint_terms`): the
  backlash always applies; a gear-ratio or cyclic term only when the kinematic fit, redone
  on the file's own poses with it, predicts the held-out poses better;
* :meth:`CellCalibrator.kinematics` — seed 001: candidate poses over the board, D-optimal
  choice of the fit poses, held-out poses drawn from the rest, a few anchor poses where the
  cell's fixed camera sees the tool (they tie the board's frame, rotation included, to
  the cell's: without them θ1's zero absorbs the board's rotation), measure all, identify
  (with seed 004's terms of the file weighed as above, so the zeros do not absorb them),
  check on the held-out poses (:func:`cell.calibration.kinematic.holdout_check`); only a
  passing result is written (versioned, see :mod:`cell.calibration.calfile`) and applied
  (``on_applied``), or a failing one the caller accepts (``accept_worse``, the command's
  ``--accept-worse``: never from the PLC), with the warning in the file;
* :meth:`CellCalibrator.run_safely` — the PLC's entry: never raises, returns a
  :class:`~cell.cycle.runner.CycleOutcome` whose ``calibration`` holds the residuals.

A cancel (abort, heartbeat, station fault) ends a procedure at its next move.
"""
from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from typing import TYPE_CHECKING

from pathlib import Path

import numpy as np

from cell.calibration import calfile
from cell.config import CellConfig
from cell.cycle.runner import CycleCancelled, CycleOutcome
from cell.cyclelog import CycleStatus
from cell.errors import CalibrationError, CellError
from cell.faults import Fault
from cell.jsonsafe import json_safe
from cell.kinematics import JOINT_NAMES, Scara
from cell.log import get_logger
from cell.vision.calibration import DEFAULT_BOARD, CircleGridBoard

if TYPE_CHECKING:       # the numerics (scipy) load when a calibration runs, not with the cell
    from cell.calibration.joint import JointResult
    from cell.calibration.kinematic import HoldoutCheck, Identification
    from cell.calibration.procedure import HandRig, JointPlan

log = get_logger("calibration")


def board_of(config: CellConfig) -> CircleGridBoard:
    """The board of known points (``calibration.board``, default the simulated cell's)."""
    try:
        board = config.calibration.circle_board()
    except ValueError as exc:
        raise CalibrationError(str(exc)) from None
    if board is None:
        return DEFAULT_BOARD
    return board


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def load_active(config: CellConfig, nominal: Scara) -> tuple[Scara, dict | None]:
    """The robot the cell runs with: calibrated by ``calibration.file`` if it exists (checked:
    :func:`calfile.load` raises CalibrationError for a corrupt or foreign file), else the
    nominal one. A file written with ``--accept-worse`` is used, and its warning logged."""
    path = Path(config.calibration.file)
    if not path.exists():
        return nominal, None
    doc = calfile.load(path, nominal, config.name)
    if doc.get("accept_worse"):
        log.warning("robot_calibration_accepted_worse", path=str(path), warning=doc.get("warning"))
    return calfile.calibrated_robot(nominal, doc), doc


#: the PLC's fault code for each kind of :class:`~cell.errors.CalibrationError`
CALIBRATION_FAULTS = {"refused": Fault.CALIBRATION_REFUSED, "measurement": Fault.CALIBRATION_MEASUREMENT,
                      "fit": Fault.CALIBRATION_FIT}

CALIBRATED_RADIUS_SIGMA_MM = 0.2   #: links of a kinematic calibration (held-out rms ~0.015 mm)


def radius_prior(robot: Scara, joint: str, zero_centres, sigma_mm: float):
    """(r0, sigma) mm: how far the target lies from ``joint``'s axis, from the robot's links
    and where the zero images saw it. At the all-zero pose the hand frame is the base frame
    moved to the tool axis (l1 + l2, 0), so the j1 axis lies at (−l1 − l2, 0) in it and the
    j2 axis at (−l2, 0); r0 = |zero centre − axis|. The links are the calibrated ones if
    ``robot`` carries a kinematic calibration (sigma :data:`CALIBRATED_RADIUS_SIGMA_MM`),
    else the nominal ones (``sigma_mm``: how well they and the camera's place on the tool
    axis are known). None for j4: its target circles the camera axis whole, the points fix
    the radius themselves."""
    g = getattr(robot, "calibrated_geometry", None)
    if g is not None:
        sigma_mm = CALIBRATED_RADIUS_SIGMA_MM
    else:
        g = robot.g
    axis = {"j1": (-(g.l1_mm + g.l2_mm), 0.0), "j2": (-g.l2_mm, 0.0)}.get(joint)
    zc = np.asarray(zero_centres, dtype=float)
    if axis is None or not np.all(np.isfinite(zc)):
        return None
    return float(np.hypot(*(zc.mean(axis=0) - np.array(axis)))), float(sigma_mm)


@dataclass
class KinematicOutcome:
    """What :meth:`CellCalibrator.kinematics` did: the fit, the held-out check, the poses
    (fit, held-out) and their measurements, and the document written (None if not)."""

    identification: Identification
    holdout: HoldoutCheck
    q_fit: np.ndarray
    m_fit: np.ndarray
    q_hold: np.ndarray
    m_hold: np.ndarray
    points_fit: list[int]
    points_hold: list[int]
    document: dict | None = None
    #: seed 004's terms per joint, with what the fit applies (None: no joint calibrated)
    joints: dict | None = None
    #: seed 001's own gear-ratio estimates, which apply and why (None: not fitted)
    gear_ratio: dict | None = None

    def parameters(self, nominal: Scara) -> dict:
        from cell.calibration.dh import scara_chain
        ident, chain = self.identification, scara_chain(nominal.g)
        return {n: {"value": float(v), "se": float(se), "low": float(lo), "high": float(hi),
                    "unit": chain.unit(n)}
                for n, v, se, (lo, hi) in zip(ident.kept, [ident.value(k) for k in ident.kept],
                                               ident.std_err, ident.ci95)}

    def report(self) -> dict:
        ident = self.identification
        return {"identifiability": ident.report.as_dict(), "holdout": self.holdout.as_dict(),
                "fit": {"poses": len(self.q_fit), "rms_xy_mm": ident.rms_xy_mm,
                        "sigma_xy_mm": ident.sigma_xy_mm, "dof": ident.dof,
                        "iterations": ident.iterations,
                        "condition_number": ident.condition_number},
                "measurement": "x, y of the tool axis over one known board point per pose "
                               "(hand camera; board frame), and at the anchor poses (point -1) "
                               "the tool's fiducial seen by the cell camera (base frame); φ is "
                               "not measured",
                "anchors": int(sum(1 for k in self.points_fit if k < 0))}


class CellCalibrator:
    """Calibrations of one cell. ``devices``: the cell's devices (``motion``, ``clock``,
    ``hand_camera``, ``hand_calibration()``, ``place_fixture()``); ``nominal``: the nominal
    robot; ``on_applied(robot, doc)``: called after a kinematic calibration is written, to
    put it to use; ``version``: the version of the calibration in use (0: nominal)."""

    def __init__(self, config: CellConfig, devices, nominal: Scara, *, version: int = 0,
                 on_applied=None, path: str | None = None, measuring_camera=None,
                 robot: Scara | None = None):
        self.config, self.devices, self.nominal = config, devices, nominal
        #: the model the cell runs with (calibrated or nominal): seed 004's radius prior
        self.robot = robot or nominal
        #: the cell's fixed camera (``tool()``, ``calibration``) for anchor poses; made on first use
        self.measuring_camera = measuring_camera
        self.version = version
        self.on_applied = on_applied
        self.path = path or config.calibration.file
        #: the calibration document last written (None: nothing written yet)
        self.written: dict | None = None

    # ------------------------------------------------------------------ pieces
    def rig(self, cancel=None) -> HandRig:
        from cell.calibration.procedure import HandRig
        cam = self.devices.hand_camera
        if cam is None:
            raise CalibrationError("no hand camera: set calibration.hand_camera in the cell config",
                                   "refused")
        c = self.config
        return HandRig(self.nominal, self.devices.motion, cam, self.devices.hand_calibration(),
                       target_radius_mm=c.calibration.target_radius_mm, z_mm=c.calibration.z_mm,
                       move_timeout_s=c.cycle.move_timeout_s, reach_tol_deg=c.cycle.reach_tol_deg,
                       cancel=cancel)

    def joint(self, joint: str, *, runs: int | None = None, step_deg: float | None = None,
              range_deg: float | None = None, period_deg: float = 360.0, cancel=None,
              progress=None, write: bool = True) -> tuple[JointPlan, JointResult]:
        """Seed 004 on ``joint`` (j1, j2, j4): the plan (range kept in view) and the result.
        With ``write``, the joint's terms are recorded in the calibration file and applied as
        the module doc says (:attr:`written` is the document). Raises CalibrationError (bad
        joint, target lost, too few points, ...)."""
        from cell.calibration.joint import analyse
        from cell.calibration.procedure import plan_joint, sweep_joint
        self.devices.place_fixture("joint", joint)
        rig = self.rig(cancel)
        # where the target lies at the all-zero pose: the range must keep it whole from there
        # (a person lays it only roughly under the camera, and the joints' zeros are off)
        home = np.array([0.0, 0.0, self.config.calibration.z_mm, 0.0])
        rig.move(home - np.array([1.0, 1.0, 0.0, 1.0]) * 0.5)
        rig.move(home)
        h0 = rig.target("locating the target at the all-zero pose")
        plan = plan_joint(self.nominal, joint, rig.view_radius_mm - float(np.hypot(*h0)),
                          runs=self.config.calibration.runs if runs is None else runs,
                          step_deg=step_deg, range_deg=range_deg)
        log.info("joint_calibration_started", joint=joint, step_deg=plan.step_deg,
                 positions=len(plan.nominal_deg), runs=plan.runs)
        sweep = sweep_joint(rig, plan, progress)
        result = analyse(sweep, sense=-1, period_deg=period_deg,
                         radius_prior=radius_prior(self.robot, joint, sweep.zero,
                                                   self.config.calibration.radius_sigma_mm))
        log.info("joint_calibration_done", joint=joint, backlash_deg=result.backlash_deg.value,
                 residual_rms_deg=result.residual_rms_deg)
        if write:
            self._record_joint(joint, result)
        return plan, result

    def _active(self) -> dict | None:
        """The calibration document in use (None: no file yet). Raises CalibrationError for a
        file that cannot be read or trusted: what it holds is not built on."""
        if not Path(self.path).exists():
            return None
        return calfile.load(self.path, self.nominal, self.config.name)

    def _record_joint(self, joint: str, result: "JointResult") -> None:
        from cell.calibration import joint_terms as jt
        doc = self._active() or {}
        section = {**(doc.get("joints") or {}), joint: jt.entry(result)}
        data = jt.FitData.of(doc, self.nominal)
        if data is None:
            section = jt.annotate(section, None, "no kinematic calibration to weigh it against yet "
                                                 "(calibrate kinematics does)")
            new = calfile.new_document(self.nominal, self.config.name, doc.get("parameters", {}),
                                       doc.get("report", {}), doc.get("data", {}), _now(),
                                       doc.get("warning"), joints=section)
            self._store(new)
            return
        w = jt.weigh(self.nominal, data, section, min_gain=self.config.calibration.min_gain)
        fit, hold = doc["data"]["fit"], doc["data"]["holdout"]
        out = KinematicOutcome(w.identification, w.holdout, data.q_fit, data.m_fit, data.q_hold,
                               data.m_hold, [f.get("point", 0) for f in fit],
                               [h.get("point", 0) for h in hold], joints=jt.annotate(section, w),
                               gear_ratio=w.gear_ratio)
        self._write(out, doc.get("warning"))

    def kinematics(self, *, poses: int | None = None, holdout: int | None = None, cancel=None,
                   progress=None, write: bool = True, seed: int = 0,
                   accept_worse: bool = False) -> KinematicOutcome:
        """Seed 001 over the board. Writes and applies the calibration only if ``write`` and
        the held-out check passes, or ``accept_worse`` (the check's failures are then the
        file's ``warning``; see the module doc). Raises CalibrationError (board not
        found, a point not seen, singular design, ...); a failed held-out check is returned
        (``holdout.passed`` False, ``document`` None), not raised."""
        from cell.calibration.dh import scara_chain
        from cell.calibration.kinematic import select_poses
        from cell.calibration.procedure import (anchor_candidates, board_candidates, board_lever,
                                                measure_anchors, measure_board)
        c = self.config.calibration
        n_fit = c.poses if poses is None else poses
        n_hold = c.holdout if holdout is None else holdout
        board = board_of(self.config)
        self.devices.place_fixture("board")
        cands = board_candidates(self.nominal, board, z_mm=c.z_mm)
        if n_fit + n_hold > len(cands):
            raise CalibrationError(f"the board offers {len(cands)} reachable poses, fewer than the "
                                   f"{n_fit} fit + {n_hold} held-out poses asked for")
        chain = scara_chain(self.nominal.g)
        cq = np.array([x.q for x in cands])
        fit = list(select_poses(chain, cq, n_fit, position_only=True))
        rest = np.setdiff1d(np.arange(len(cands)), fit)
        hold = list(np.random.default_rng(seed).choice(rest, n_hold, replace=False))
        rig = self.rig(cancel)

        def step(done, _):
            if progress is not None:
                progress(done, total)

        cam = self._measuring_camera() if c.anchors else None
        anchors = anchor_candidates(self.nominal, cam.calibration, c.anchors, z_mm=c.z_mm) if cam else []
        total = n_fit + n_hold + len(anchors)
        m_fit = measure_board(rig, board, [cands[i] for i in fit], step)
        m_hold = measure_board(rig, board, [cands[i] for i in hold],
                               (lambda d, _: step(n_fit + d, 0)))
        m_anchor = measure_anchors(rig, cam, anchors, (lambda d, _: step(n_fit + n_hold + d, 0))) \
            if anchors else np.zeros((0, 2))
        rig.move(np.array([0.0, 90.0, c.z_mm, -90.0]))   # out of the way, elbow bent
        q_fit = np.vstack([cq[fit], *[a.q[None] for a in anchors]])
        m_all = np.vstack([m_fit, m_anchor])
        in_base = np.r_[np.zeros(len(fit), bool), np.ones(len(anchors), bool)]
        points_fit = [cands[i].point for i in fit] + [-1] * len(anchors)
        points_hold = [cands[i].point for i in hold]
        # seed 004's terms of the file, and seed 001's own gear ratios: weighed on the
        # held-out poses, and applied to the commanded angles of the fit (never twice)
        from cell.calibration import joint_terms as jt
        joints = (self._active() or {}).get("joints")
        data = jt.FitData(q_fit, m_all, in_base, cq[hold], m_hold,
                          board_lever(self.nominal, board, q_fit, m_all, points_fit),
                          board_lever(self.nominal, board, cq[hold], m_hold, points_hold))
        w = jt.weigh(self.nominal, data, joints, min_gain=c.min_gain)
        ident, check = w.identification, w.holdout
        out = KinematicOutcome(ident, check, q_fit, m_all, cq[hold], m_hold, points_fit, points_hold,
                               joints=jt.annotate(joints, w) if joints else None, gear_ratio=w.gear_ratio)
        log.info("kinematic_calibration_measured", passed=check.passed, reason=check.reason)
        if write and (check.passed or accept_worse):
            self._write(out, None if check.passed else
                        f"written with --accept-worse although its check failed: {check.reason}")
        return out

    def _measuring_camera(self):
        if self.measuring_camera is None:
            from cell.vision.measure import MeasuringCamera
            v = self.config.vision
            self.measuring_camera = MeasuringCamera(self.devices.camera, self.devices.calibration(),
                                                    v.tool_radius_mm, v.radius_tolerance,
                                                    v.grab_timeout_s, clock=self.devices.clock,
                                                    window_mm=v.window_mm)
        return self.measuring_camera

    def _write(self, out: KinematicOutcome, warning: str | None = None) -> None:
        data = {"board": board_of(self.config).as_dict(),
                "fit": [{"q": q.tolist(), "measured_mm": m.tolist(), "point": k}
                        for q, m, k in zip(out.q_fit, out.m_fit, out.points_fit)],
                "holdout": [{"q": q.tolist(), "measured_mm": m.tolist(), "point": k}
                            for q, m, k in zip(out.q_hold, out.m_hold, out.points_hold)]}
        doc = calfile.new_document(self.nominal, self.config.name, out.parameters(self.nominal),
                                   json_safe(out.report()), data, _now(), warning,
                                   joints=json_safe(out.joints) if out.joints else None,
                                   gear_ratio=json_safe(out.gear_ratio) if out.gear_ratio else None)
        out.document = self._store(doc)

    def _store(self, doc: dict) -> dict:
        """Write ``doc`` as the active calibration and put it to use; returns it as written."""
        doc = calfile.write(self.path, doc)
        self.written = doc
        self.version = int(doc["version"])
        log.info("robot_calibration_written", path=str(self.path), version=self.version,
                 id=calfile.calibration_id(doc), warning=doc.get("warning"))
        self.robot = calfile.calibrated_robot(self.nominal, doc)
        if self.on_applied is not None:
            self.on_applied(self.robot, doc)
        return doc

    # ------------------------------------------------------------------ the PLC's entry
    def run_safely(self, select: int, cancel) -> CycleOutcome:
        """Run what ``calibration_select`` names (0 kinematics, N joint jN); never raises."""
        try:
            if select == 0:
                out = self.kinematics(cancel=cancel)
                if not out.holdout.passed:
                    return CycleOutcome(CycleStatus.FAULT, Fault.CALIBRATION_FIT,
                                        f"held-out check failed, nothing written: {out.holdout.reason}",
                                        calibration={"residual_um": 1000 * out.holdout.rms_xy_after_mm,
                                                     "residual_udeg": 0})
                return CycleOutcome(CycleStatus.DONE, calibration={
                    "residual_um": 1000 * out.holdout.rms_xy_after_mm, "residual_udeg": 0,
                    "version": self.version})
            if not 1 <= select <= 4 or JOINT_NAMES[select - 1] == "j3":
                return CycleOutcome(CycleStatus.ABORTED, Fault.CALIBRATION_REFUSED,
                                    f"calibration_select {select}: no such calibration (0 kinematics, "
                                    "1, 2, 4 joint; j3 is prismatic)")
            _, result = self.joint(JOINT_NAMES[select - 1], cancel=cancel)
            return CycleOutcome(CycleStatus.DONE, calibration={"residual_um": 0,
                                                     "residual_udeg": 1e6 * result.residual_rms_deg,
                                                     "version": self.version})
        except CycleCancelled:
            return CycleOutcome(CycleStatus.ABORTED, cancel.code, cancel.text)
        except CalibrationError as exc:
            if cancel.cancelled:
                return CycleOutcome(CycleStatus.ABORTED, cancel.code, cancel.text)
            return CycleOutcome(CycleStatus.FAULT, CALIBRATION_FAULTS[exc.fault], str(exc))
        except CellError as exc:
            return CycleOutcome(CycleStatus.FAULT, Fault.CALIBRATION_FIT, str(exc))
        except Exception as exc:                       # noqa: BLE001 -- the PLC must hear of it
            log.exception("calibration_failed", error=repr(exc))
            return CycleOutcome(CycleStatus.FAULT, Fault.INTERNAL, f"calibration failed: {exc!r}")
