"""One part's cycle, as the recipe says: approach, capture, locate, compensate, final move,
verify, log. Runs in the cycle task (see docs/architecture.md).

:class:`CycleRunner` publishes the step it is in (:attr:`CycleRunner.progress`) and times
each step on the injected clock; the scan loop follows it with the state machine. It never
decides the cell's fault handling: it returns a :class:`CycleOutcome` (status, fault code)
and the scan loop stops the joints and latches the fault. The cycle's row is written to
the cycle log by the runner itself, *before* the scan loop raises Done, so a cycle the PLC
was told is done is on disk. The scan loop stops a cycle by *giving* it the reason in its
:class:`CancelToken`; the cycle checks it between steps and after every move, and a motion
cut short by the quick stop that follows ends the cycle with that reason. A cancelled
cycle is recorded as ``aborted`` and never resumed.

Every move streams seed 002's interpolation segments (:mod:`cell.motion.mover`) in the recipe's
synchronisation mode; the cycle's record keeps the mode, the segments and each station's
delay of its moves.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from cell.clock import Clock, MonotonicClock
from cell.compensation.base import CompensationResult, Step
from cell.compensation.lattice import margin_units, nearest_lattice, run_lattice, via_point
from cell.compensation.paper import run_paper
from cell.cycle.statemachine import State
from cell.cyclelog import CycleLog, CycleRecord, CycleStatus, utc_now
from cell.errors import KinematicsError, TrajectoryError
from cell.faults import CellFault, Fault, station_fault
from cell.kinematics import Scara
from cell.log import get_logger
from cell.motion.mover import MotionSpec, MoveReport, Mover
from cell.recipes import ActiveRecipe
from cell.vision.measure import MeasuringCamera

log = get_logger("cycle")

VERIFY_NOTE = "verify correction"   #: trace note of a move made after a verification above tolerance


class CycleCancelled(Exception):
    """The scan loop cancelled the cycle (abort or a fault it detected)."""


class CancelToken:
    """How the scan loop stops a cycle: the reason (fault code, 0 for an abort, and text),
    then the flag. Set once; later cancels keep the first reason."""

    def __init__(self, clock: Clock | None = None):
        self._event = (clock or MonotonicClock()).event()
        self._wake: list = []
        self.code = 0
        self.text = ""

    def cancel(self, code: int, text: str) -> None:
        if not self._event.is_set():
            self.code, self.text = int(code), text
            self._event.set()
            for event in list(self._wake):
                event.set()

    def wake_on_cancel(self, event) -> None:
        """Set ``event`` (a clock event someone waits on) when the cycle is cancelled."""
        self._wake.append(event)
        if self._event.is_set():
            event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        """:raises CycleCancelled: once cancelled."""
        if self._event.is_set():
            raise CycleCancelled()


def calibration_of(robot: Scara) -> str:
    """Id of the robot calibration ``robot`` carries ('' for the nominal model)."""
    return getattr(robot, "calibration", "")


@dataclass(frozen=True)
class CycleSettings:
    move_timeout_s: float = 10.0      #: a move that takes longer is a MOTION_TIMEOUT fault
    reach_tol_deg: float = 0.001      #: joints count as arrived within this (≪ one command unit)
    tool_phi_deg: float = 0.0         #: tool orientation held during the cycle
    elbow: str = "right"


@dataclass
class CycleOutcome:
    status: CycleStatus
    fault_code: int = 0
    fault_text: str = ""
    record: CycleRecord | None = None
    log_write_s: float = 0.0          #: time to write the row (the LOGGING step)
    #: a calibration's end (no record): residual_um, residual_udeg, version (None: none written)
    calibration: dict | None = None


@dataclass
class OffsetMemory:
    """Seed 000's step (5), learned in millimetres: per recipe, how far the measured arrivals
    of the last ``n`` completed cycles lay from the robot model's prediction (base frame;
    each cycle contributes the mean over its arrivals). The next cycle's first command is
    the whole-unit command the model, shifted by their mean, predicts nearest the target
    (:meth:`start`). An empty memory starts from the model's own prediction, so a
    calibrated robot starts from its calibration; only cycles run with the robot's
    calibration count (:meth:`from_log`).

    Seed 000 learns whole command units instead. A mean of commands chosen for different
    targets, rounded, moves the first arrival by a whole unit when the model is already
    right; a residual in mm keeps what the arrivals measured."""

    n: int = 10
    history: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def offset_mm(self, recipe: str) -> np.ndarray:
        """Mean residual (x, y) mm of ``recipe``'s remembered cycles; zero when none."""
        h = self.history.get(recipe)
        return np.mean(h, axis=0) if h else np.zeros(2)

    def scatter_mm(self, recipe: str, prior_mm: float = 0.0) -> float:
        """How far one cycle's residual typically lies from the last one's (2-D rms of
        successive differences over √2, mm) over ``recipe``'s remembered cycles: the
        arrivals' scatter (repeatability, measurement noise), without the slow drift
        (warm-up) a spread about the mean would count. A correction predicted to gain less
        than this is as likely to lose. ``prior_mm`` with fewer than 3 cycles remembered
        (the robot's :attr:`~cell.kinematics.Scara.arrival_scatter_mm`: what its
        calibration measured, 0 for a nominal robot)."""
        h = self.history.get(recipe)
        if not h or len(h) < 3:
            return prior_mm
        d = np.diff(np.asarray(h), axis=0)
        return float(np.sqrt(np.sum(d ** 2) / (2 * len(d))))

    def learn(self, recipe: str, residual_mm) -> None:
        """Remember one cycle's residual (see :meth:`residual`); None is ignored."""
        if residual_mm is None:
            return
        h = self.history.setdefault(recipe, [])
        h.append(np.asarray(residual_mm, dtype=float))
        del h[:-self.n]

    def start(self, robot: Scara, recipe: str, target, elbow: str = "right") -> np.ndarray:
        """First command (whole units) for ``target``: the lattice point the model plus the
        learned residual (none: the model alone) predicts nearest it, searched
        (:func:`~cell.compensation.lattice.nearest_lattice`) around the model's inverse
        kinematics rounded joint by joint. That rounding alone is not the nearest point: the
        lattice's cells are skewed (at bracket-a's place a θ1 unit moves the tool 0.17 mm,
        a θ2 unit 0.09 mm, in directions 16° apart). :raises KinematicsError:
        unreachable target."""
        q = robot.to_units(robot.ik_planar(*target, elbow=elbow))
        predicted = robot.fk_planar(*robot.from_units(q)) + self.offset_mm(recipe)
        return nearest_lattice(robot, q, predicted, np.asarray(target, dtype=float))[0]

    @staticmethod
    def residual(robot: Scara, steps) -> np.ndarray | None:
        """Mean of measured − predicted (x, y) mm over the measured arrivals of a trace
        (:class:`~cell.compensation.base.Step` dicts); None if it has none. Backlash
        pre-moves of traces written before arrivals took up backlash through via points
        measured a point on the other side of the band, and moves after the verification
        measure at the place height: neither counts."""
        res = [np.subtract(s["point_mm"], robot.fk_planar(*s["joints_deg"])) for s in steps
               if s.get("moved") and s.get("note") != "backlash pre-move"
               and not s.get("note", "").startswith(VERIFY_NOTE)]
        return np.mean(res, axis=0) if res else None

    @classmethod
    def from_log(cls, cyclelog: CycleLog, robot: Scara, n: int = 10) -> "OffsetMemory":
        """Rebuild the memory from the last completed cycles in the log (each row holds its
        trace), so a restart does not forget what was learned. Only cycles that ran with
        ``robot``'s calibration count: residuals against another model (the nominal one, or
        an older calibration) refer to it, so a new calibration starts learning afresh."""
        memory = cls(n=n)
        calibration = calibration_of(robot)
        for rec in cyclelog.cycles(limit=50 * n, status=CycleStatus.DONE):   # oldest first
            if rec.trace and rec.calibration == calibration:
                memory.learn(rec.recipe, cls.residual(robot, rec.trace))
        return memory


def compensate(robot: Scara, arm, memory: OffsetMemory, recipe, target, *, elbow: str = "right",
               from_units=None) -> CompensationResult:
    """One part's compensation as the cell runs it (the COMPENSATE step), on any
    :class:`~cell.compensation.base.Arm`: the first command from ``memory`` (the model plus
    the learned residual), then ``recipe.compensation``'s method. The lattice takes up
    backlash from ``robot.approach_dirs`` at every arrival (``from_units``: where θ1, θ2 are
    before the first one, command units; None: unknown) and moves only for a gain above
    the recipe's ``min_gain_mm`` and the memory's scatter (before three parts, the scatter
    the robot's calibration measured). Does not learn: the caller
    teaches ``memory`` once the part is verified."""
    c = recipe.compensation
    start = memory.start(robot, recipe.name, target, elbow)
    if c.method == "paper":
        return run_paper(robot, arm, target, k=c.k, start_units=start,
                         repeatability_mm=c.repeatability_mm)
    gain = max(c.min_gain_mm, memory.scatter_mm(recipe.name, robot.arrival_scatter_mm))
    return run_lattice(robot, arm, target, start_units=start, max_moves=c.max_moves,
                       min_gain_mm=gain, backlash_margin_units=margin_units(robot, c.backlash_margin_units),
                       approach_dirs=robot.approach_dirs, from_units=from_units)


class CellArm:
    """The compensation's "robot + measurer" on the cell: move θ1, θ2 to a command by
    streaming the recipe's seed 002 segments, wait until arrived, measure the tool."""

    def __init__(self, robot: Scara, mover: Mover, camera: MeasuringCamera, z_mm: float,
                 spec: MotionSpec, cancel: CancelToken, settings: CycleSettings, start_joints):
        self.robot, self.mover, self.camera = robot, mover, camera
        self.z_mm, self.spec, self.cancel, self.settings = z_mm, spec, cancel, settings
        self.last_joints = np.asarray(start_joints, dtype=float)   #: last commanded joints
        self.reports: list[MoveReport] = []

    def joints(self, t1: float, t2: float, z_mm: float) -> np.ndarray:
        g = self.robot.g
        q = np.array([t1, t2, z_mm - g.base_z_mm - g.tool_z_mm,
                      (self.settings.tool_phi_deg - t1 - t2 + 180.0) % 360.0 - 180.0])
        self.robot.check_limits(q)
        return q

    def move(self, q: np.ndarray) -> None:
        self.cancel.check()
        q = np.asarray(q, dtype=float)
        try:
            report = self.mover.move(self.last_joints, q, self.spec, self.settings.move_timeout_s,
                                     self.settings.reach_tol_deg)
        except TimeoutError as exc:
            raise CellFault(Fault.MOTION_TIMEOUT, str(exc)) from exc
        except TrajectoryError as exc:
            raise CellFault(Fault.UNREACHABLE, str(exc)) from exc
        self.last_joints = q
        self.reports.append(report)
        self.cancel.check()

    def arrive(self, command_units, z_mm: float, via_units=None) -> None:
        """Move θ1, θ2 to ``command_units`` at height ``z_mm``, through ``via_units`` first
        if given (see :class:`~cell.compensation.base.Arm`)."""
        for units in ([] if via_units is None else [via_units]) + [command_units]:
            q = self.robot.from_units(units)
            self.move(self.joints(q[0], q[1], z_mm))

    def move_and_measure(self, command_units, via_units=None) -> np.ndarray:
        self.arrive(command_units, self.z_mm, via_units)
        return self.camera.tool(self.cancel, self.predicted(command_units))

    def predicted(self, command_units) -> np.ndarray:
        """Where the robot model puts the tool at ``command_units``: where the camera looks."""
        return self.robot.fk_planar(*self.robot.from_units(command_units))

    def units_now(self) -> np.ndarray:
        """θ1, θ2 of the last command, in (fractional) command units."""
        return self.last_joints[:2] / self.robot.from_units([1, 1])

    def motion_summary(self) -> dict:
        """Mode, moves, segments and the mean per-joint delay of this cycle's moves."""
        if not self.reports:
            return {"mode": self.spec.mode, "moves": 0}
        delays = np.mean([r.delays_s for r in self.reports], axis=0)
        return {"mode": self.spec.mode, "moves": len(self.reports),
                "segments": int(sum(r.segments for r in self.reports)),
                "segment_ms": round(self.spec.segment_s * 1e3, 6), "time_law": self.spec.time_law,
                "paths": sorted({r.path for r in self.reports}),
                "delays_ms": [round(float(d) * 1e3, 6) for d in delays]}


class CycleRunner:
    """Runs cycles; one instance per controller, one cycle at a time.

    :param motion: the joint stations (``stream``, ``burst_delays``, ``wait_reached``,
        ``actual_positions``).
    :param clock: the injected clock (step and cycle times are in its seconds).
    """

    def __init__(self, robot: Scara, motion, camera: MeasuringCamera, cyclelog: CycleLog,
                 settings: CycleSettings = CycleSettings(), memory: OffsetMemory | None = None,
                 clock: Clock | None = None):
        self.robot, self.motion, self.camera, self.log = robot, motion, camera, cyclelog
        self.settings = settings
        self.memory = memory or OffsetMemory()
        self.clock = clock or MonotonicClock()
        self.mover = Mover(robot, motion, settings.elbow)
        self.progress: State = State.IDLE         #: the step the running cycle is in
        self.outcome: CycleOutcome | None = None  #: how the last cycle ended
        #: the thread that ran the last cycle: the controller runs every cycle on its one
        #: long-lived ``cell-cycle`` worker (a thread per cycle leaks OpenCV's thread state)
        self.last_thread: threading.Thread | None = None

    def run_safely(self, active: ActiveRecipe | None, part_id: int, cancel: CancelToken) -> CycleOutcome:
        """:meth:`run`, keeping the outcome in :attr:`outcome` (the cycle task's target)."""
        self.outcome = None
        if active is None:
            self.outcome = CycleOutcome(CycleStatus.ABORTED, cancel.code, cancel.text or "no recipe")
        else:
            self.outcome = self.run(active, part_id, cancel)
        return self.outcome

    def run(self, active: ActiveRecipe, part_id: int, cancel: CancelToken) -> CycleOutcome:
        """Run one cycle; returns how it ended (never raises)."""
        self.last_thread = threading.current_thread()
        self.progress = State.APPROACH
        r = active.recipe
        rec = CycleRecord(part_id=part_id, recipe=r.name, recipe_hash=active.hash, started_at=utc_now(),
                          finished_at="", status=CycleStatus.ABORTED, cycle_time_s=0.0,
                          method=r.compensation.method, calibration=calibration_of(self.robot))
        t_start = self.clock.now()
        spec = MotionSpec(r.motion.sync, r.motion.segment_ms / 1000.0, r.motion.time_law,
                          r.approach.joint_speed_deg_s)
        arm = None
        outcome = CycleOutcome(CycleStatus.ABORTED)
        try:
            self._begin(rec)
            arm = CellArm(self.robot, self.mover, self.camera, r.approach.z_mm, spec, cancel,
                          self.settings, self.motion.actual_positions())
            self._step(rec, State.APPROACH, cancel, lambda: self._approach(arm, r))
            image = self._step(rec, State.CAPTURE, cancel, lambda: self.camera.grab(cancel))
            part = self._step(rec, State.LOCATE, cancel, lambda: self._locate(image, r))
            rec.target_mm = (float(part[0]), float(part[1]))
            result = self._step(rec, State.COMPENSATE, cancel, lambda: self._compensate(arm, r, part))
            rec.initial_error_mm, rec.moves = result.initial_error_mm, result.moves
            rec.final_error_mm = result.final_error_mm
            rec.trace = [s.as_dict() for s in result.steps]
            last = result.final.command_units
            self._step(rec, State.FINAL_MOVE, cancel, lambda: arm.arrive(last, r.place.z_mm))
            self._step(rec, State.VERIFY, cancel, lambda: self._verify(rec, r, part, arm, last, cancel))
            self.progress = State.LOGGING
            self.memory.learn(r.name, OffsetMemory.residual(self.robot, rec.trace))
            outcome = CycleOutcome(CycleStatus.DONE)
        except CycleCancelled:
            outcome = CycleOutcome(CycleStatus.ABORTED, cancel.code, cancel.text)
        except CellFault as exc:
            ended = CycleStatus.FAULT if self.progress is State.VERIFY else CycleStatus.ABORTED
            outcome = CycleOutcome(ended, exc.code, exc.detail)
        except KinematicsError as exc:
            outcome = CycleOutcome(CycleStatus.ABORTED, Fault.UNREACHABLE, str(exc))
        except Exception as exc:                 # noqa: BLE001 -- every failure must reach the PLC
            code = getattr(getattr(exc, "record", None), "code", None)
            if code is not None:                 # a joint-station fault (StationFaultError)
                outcome = CycleOutcome(CycleStatus.ABORTED, station_fault(code), str(exc))
            else:
                log.exception("cycle_internal_error", part_id=part_id)
                outcome = CycleOutcome(CycleStatus.ABORTED, Fault.INTERNAL, repr(exc))
        if cancel.cancelled and outcome.status != CycleStatus.DONE:
            # the scan loop's reason is the cause; what the motion raised (a quick stop) follows
            outcome = CycleOutcome(CycleStatus.ABORTED, cancel.code, cancel.text)
        rec.status, rec.fault_code, rec.fault_text = outcome.status, outcome.fault_code, outcome.fault_text
        rec.motion = arm.motion_summary() if arm is not None else {"mode": spec.mode, "moves": 0}
        rec.finished_at = utc_now()
        rec.cycle_time_s = self.clock.now() - t_start
        outcome.record = self._write(rec, outcome)
        return outcome

    # ------------------------------------------------------------------ steps
    def _begin(self, rec: CycleRecord) -> None:
        """Record the cycle as in flight before anything moves, so a controller that dies
        during it reports it at the next start (:meth:`CycleLog.recover_interrupted`)."""
        try:
            self.log.begin_cycle(rec.part_id, rec.recipe, rec.recipe_hash, rec.started_at)
        except Exception as exc:                 # noqa: BLE001 -- nothing moves unless it is recorded
            raise CellFault(Fault.LOG_WRITE_FAILED, f"cycle log cannot record the cycle's start: {exc}") from exc

    def _step(self, rec: CycleRecord, state: State, cancel: CancelToken, work):
        cancel.check()
        self.progress = state
        t0 = self.clock.now()
        out = work()
        rec.step_times[state.name.lower()] = round(self.clock.now() - t0, 6)
        return out

    def _approach(self, arm: CellArm, r) -> None:
        x, y = np.add(r.part.nominal_xy_mm, r.approach.offset_mm)
        t1, t2 = self.robot.ik_planar(x, y, elbow=self.settings.elbow)
        arm.move(arm.joints(t1, t2, r.approach.z_mm))

    def _locate(self, image: np.ndarray, r) -> np.ndarray:
        part = self.camera.find(image, r.part.fiducial_radius_mm, "part fiducial",
                                near_mm=r.part.nominal_xy_mm, within_mm=r.part.search_radius_mm + 1.0)
        off = float(np.hypot(*(part - np.asarray(r.part.nominal_xy_mm))))
        if off > r.part.search_radius_mm:
            raise CellFault(Fault.PART_OUT_OF_WINDOW, f"part found at ({part[0]:.3f}, {part[1]:.3f}) mm, "
                            f"{off:.3f} mm from nominal > search radius {r.part.search_radius_mm} mm")
        return part

    def _verify(self, rec: CycleRecord, r, part: np.ndarray, arm: CellArm, command,
                cancel: CancelToken) -> None:
        """Measure the placed tool against the part. Above tolerance, finish the part rather
        than fault it: while ``compensation.extra_moves`` allows and a whole-unit command is
        predicted within tolerance, lift to the approach height, move there (taking up
        backlash from the robot's side), place and measure again; each such move counts in
        the cycle's moves and trace. Faults (VERIFY_OUT_OF_TOLERANCE) when no command is
        predicted within tolerance or the extra moves are spent, saying which."""
        tol, allowed = r.verify.tolerance_mm, r.compensation.extra_moves
        command = np.asarray(command, dtype=np.int64)
        point, extra = self.camera.tool(cancel, arm.predicted(command)), 0
        while True:
            rec.verify_error_mm = float(np.hypot(*(point - part)))
            if rec.verify_error_mm <= tol:
                return
            best, predicted = nearest_lattice(self.robot, command, point, part)
            what = f"verified error {rec.verify_error_mm:.4f} mm > tolerance {tol} mm"
            if predicted > tol or tuple(best) == tuple(command):
                raise CellFault(Fault.VERIFY_OUT_OF_TOLERANCE, f"{what}; no whole-unit command is "
                                f"predicted within it (nearest {predicted:.4f} mm)")
            if extra >= allowed:
                raise CellFault(Fault.VERIFY_OUT_OF_TOLERANCE, f"{what}; compensation.extra_moves = "
                                f"{allowed} spent (the next move was predicted to {predicted:.4f} mm)")
            via = via_point(self.robot.approach_dirs,
                            margin_units(self.robot, r.compensation.backlash_margin_units),
                            command, best, self.robot)
            arm.arrive(command, r.approach.z_mm)
            arm.arrive(best, r.approach.z_mm, via)
            arm.arrive(best, r.place.z_mm)
            command, extra = best, extra + 1
            point = self.camera.tool(cancel, arm.predicted(command))
            rec.moves += 1
            rec.trace.append(Step.at(best, self.robot.from_units([1, 1]), point, part,
                                     note=f"{VERIFY_NOTE}, predicted {predicted:.4f} mm",
                                     via=via).as_dict())

    def _compensate(self, arm: CellArm, r, part: np.ndarray) -> CompensationResult:
        return compensate(self.robot, arm, self.memory, r, part, elbow=self.settings.elbow,
                          from_units=arm.units_now())

    def _write(self, rec: CycleRecord, outcome: CycleOutcome) -> CycleRecord:
        """Write the cycle's row (the LOGGING step). Its own duration cannot be inside the row
        it writes: it is returned in ``outcome.log_write_s`` and included in the cycle time
        the PLC reads."""
        t0 = self.clock.now()
        try:
            rec.id = self.log.add_cycle(rec)
        except Exception as exc:                 # noqa: BLE001
            log.error("cycle_log_write_failed", error=repr(exc), part_id=rec.part_id)
            if outcome.status == CycleStatus.DONE:
                outcome.status, outcome.fault_code = CycleStatus.FAULT, Fault.LOG_WRITE_FAILED
                outcome.fault_text = f"cycle log write failed: {exc}"
        outcome.log_write_s = self.clock.now() - t0
        log.info("cycle_end", part_id=rec.part_id, recipe=rec.recipe, status=outcome.status,
                 fault=outcome.fault_code, final_error_mm=rec.final_error_mm, moves=rec.moves)
        return rec
