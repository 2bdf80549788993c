"""One part's cycle, as the recipe says: approach, capture, locate, compensate, final move,
verify, log. Runs in the cycle worker thread (see the README's architecture page).

:class:`CycleRunner` fires ``STEP_DONE`` on the shared state machine after each step and
times it. It never decides the cell's fault handling: it returns a :class:`CycleOutcome`
(status, fault code) and the scan loop stops the joints and latches the fault. The cycle's
row is written to the cycle log by the runner itself, *before* the scan loop raises Done,
so a cycle the PLC was told is done is on disk. A cancelled cycle (abort, or a fault the
scan loop saw such as PLC heartbeat loss) is recorded as ``aborted`` and never resumed.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from cell.compensation.base import CompensationResult
from cell.compensation.lattice import run_lattice
from cell.compensation.paper import run_paper
from cell.cyclelog import CycleLog, CycleRecord, utc_now
from cell.errors import KinematicsError
from cell.faults import CellFault, Fault, station_fault
from cell.kinematics import Scara
from cell.log import get_logger
from cell.measure import MeasuringCamera
from cell.recipes import ActiveRecipe
from cell.statemachine import Event, IllegalTransition, State, StateMachine

log = get_logger("cycle")


class Motion(Protocol):
    """What the cycle needs of the joint stations (``drivers.stations.JointStations``)."""

    def move_to(self, targets_deg, speed: float) -> float: ...
    def wait_reached(self, timeout_s: float, tol: float = 0.02) -> None: ...
    def quick_stop_all(self, reason: str = "requested") -> None: ...


class CycleCancelled(Exception):
    """The scan loop cancelled the cycle (abort or a fault it detected)."""


@dataclass(frozen=True)
class CycleSettings:
    move_timeout_s: float = 10.0      #: a move that takes longer is a MOTION_TIMEOUT fault
    reach_tol_deg: float = 0.001      #: joints count as arrived within this (≪ one command unit)
    tool_phi_deg: float = 0.0         #: tool orientation held during the cycle
    elbow: str = "right"


@dataclass
class CycleOutcome:
    status: str                       #: "done", "fault" or "aborted"
    fault_code: int = 0
    fault_text: str = ""
    record: CycleRecord | None = None
    log_write_s: float = 0.0          #: time to write the row (the LOGGING step)


@dataclass
class OffsetMemory:
    """Seed 000's step (5): per recipe, the joint offsets (last command − nominal IK command,
    in command units) of the last ``n`` completed cycles; their rounded mean is where the
    next cycle starts."""

    n: int = 10
    history: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def offset(self, recipe: str) -> np.ndarray:
        h = self.history.get(recipe)
        return np.rint(np.mean(h, axis=0)).astype(np.int64) if h else np.zeros(2, np.int64)

    def learn(self, recipe: str, offset_units) -> None:
        h = self.history.setdefault(recipe, [])
        h.append(np.asarray(offset_units, dtype=np.int64))
        del h[:-self.n]

    @classmethod
    def from_log(cls, cyclelog: CycleLog, robot: Scara, elbow: str = "right", n: int = 10) -> "OffsetMemory":
        """Rebuild the memory from the last completed cycles in the log (each row holds the
        target and the trace's last command), so a restart does not forget what was learned."""
        memory = cls(n=n)
        for rec in cyclelog.cycles(limit=50 * n, status="done"):
            if rec.target_mm is None or not rec.trace:
                continue
            try:
                nominal = robot.to_units(robot.ik_planar(*rec.target_mm, elbow=elbow))
            except KinematicsError:
                continue
            memory.learn(rec.recipe, robot.to_units(rec.trace[-1]["joints_deg"]) - nominal)
        return memory


class CellArm:
    """The compensation's "robot + measurer" on the real (or simulated) cell: move θ1, θ2 to a
    command through the joint stations, wait until arrived, measure the tool with the camera."""

    def __init__(self, robot: Scara, motion: Motion, camera: MeasuringCamera, z_mm: float,
                 speed_deg_s: float, cancel: threading.Event, settings: CycleSettings):
        self.robot, self.motion, self.camera = robot, motion, camera
        self.z_mm, self.speed, self.cancel, self.settings = z_mm, speed_deg_s, cancel, settings
        self.last_joints = np.full(4, np.nan)       #: last commanded joints (for directions)

    def joints(self, t1: float, t2: float, z_mm: float) -> np.ndarray:
        g = self.robot.g
        q = np.array([t1, t2, z_mm - g.base_z_mm - g.tool_z_mm,
                      (self.settings.tool_phi_deg - t1 - t2 + 180.0) % 360.0 - 180.0])
        self.robot.check_limits(q)
        return q

    def move(self, q: np.ndarray) -> None:
        if self.cancel.is_set():
            raise CycleCancelled()
        self.last_joints = np.asarray(q, dtype=float)
        self.motion.move_to(q, self.speed)
        try:
            self.motion.wait_reached(self.settings.move_timeout_s, tol=self.settings.reach_tol_deg)
        except TimeoutError as exc:
            raise CellFault(Fault.MOTION_TIMEOUT, str(exc)) from exc
        if self.cancel.is_set():
            raise CycleCancelled()

    def move_and_measure(self, command_units) -> np.ndarray:
        q = self.robot.from_units(command_units)
        self.move(self.joints(q[0], q[1], self.z_mm))
        return self.camera.tool()


class CycleRunner:
    """Runs cycles; one instance per controller, one cycle at a time."""

    def __init__(self, robot: Scara, motion: Motion, camera: MeasuringCamera, cyclelog: CycleLog,
                 sm: StateMachine, settings: CycleSettings = CycleSettings(),
                 memory: OffsetMemory | None = None):
        self.robot, self.motion, self.camera, self.log, self.sm = robot, motion, camera, cyclelog, sm
        self.settings = settings
        self.memory = memory or OffsetMemory()
        self.cancel = threading.Event()
        self.cancel_code = 0
        self.cancel_text = ""

    def clear_cancel(self) -> None:
        """Called by the scan loop before it starts a cycle (not by the cycle itself, which
        would erase a cancel that arrived before it ran)."""
        self.cancel_code, self.cancel_text = 0, ""
        self.cancel.clear()

    def request_cancel(self, code: int, text: str) -> None:
        """Called by the scan loop (any thread): stop at the next check; recorded as aborted."""
        if not self.cancel.is_set():
            self.cancel_code, self.cancel_text = int(code), text
            self.cancel.set()

    def run(self, active: ActiveRecipe, part_id: int) -> CycleOutcome:
        """Run one cycle from state APPROACH; returns how it ended (never raises)."""
        r = active.recipe
        rec = CycleRecord(part_id=part_id, recipe=r.name, recipe_hash=active.hash, started_at=utc_now(),
                          finished_at="", status="aborted", cycle_time_s=0.0,
                          method=r.compensation.method)
        t_start = time.monotonic()
        arm = CellArm(self.robot, self.motion, self.camera, r.approach.z_mm,
                      r.approach.joint_speed_deg_s, self.cancel, self.settings)
        outcome = CycleOutcome("aborted")
        try:
            self._step(rec, State.APPROACH, lambda: self._approach(arm, r))
            image = self._step(rec, State.CAPTURE, self.camera.grab)
            part = self._step(rec, State.LOCATE, lambda: self._locate(image, r))
            rec.target_mm = (float(part[0]), float(part[1]))
            nominal = self.robot.to_units(self.robot.ik_planar(*part, elbow=self.settings.elbow))
            result = self._step(rec, State.COMPENSATE, lambda: self._compensate(arm, r, part, nominal))
            rec.initial_error_mm, rec.moves = result.initial_error_mm, result.moves
            rec.final_error_mm = result.final_error_mm
            rec.trace = [s.as_dict() for s in result.steps]
            last = self.robot.from_units(result.final.command_units)
            self._step(rec, State.FINAL_MOVE, lambda: arm.move(arm.joints(last[0], last[1], r.place.z_mm)))
            self._step(rec, State.VERIFY, lambda: self._verify(rec, r, part))
            self.memory.learn(r.name, np.subtract(result.final.command_units, nominal))
            outcome = CycleOutcome("done")
        except CycleCancelled:
            outcome = CycleOutcome("aborted", self.cancel_code, self.cancel_text)
        except IllegalTransition:                 # the scan loop moved the state machine away
            outcome = CycleOutcome("aborted", self.cancel_code, self.cancel_text or "cycle interrupted")
        except CellFault as exc:
            outcome = CycleOutcome("fault" if self.sm.state is State.VERIFY else "aborted",
                                   exc.code, exc.detail)
        except KinematicsError as exc:
            outcome = CycleOutcome("aborted", Fault.UNREACHABLE, str(exc))
        except Exception as exc:                 # noqa: BLE001 -- every failure must reach the PLC
            code = getattr(getattr(exc, "record", None), "code", None)
            if code is not None:                 # a joint-station fault (StationFaultError)
                outcome = CycleOutcome("aborted", station_fault(code), str(exc))
            else:
                log.exception("cycle_internal_error", part_id=part_id)
                outcome = CycleOutcome("aborted", Fault.INTERNAL, repr(exc))
        if self.cancel.is_set() and outcome.status != "done":
            # the scan loop's reason is the cause; what the motion raised (a quick stop) follows
            outcome = CycleOutcome("aborted", self.cancel_code, self.cancel_text)
        rec.status, rec.fault_code, rec.fault_text = outcome.status, outcome.fault_code, outcome.fault_text
        rec.finished_at = utc_now()
        rec.cycle_time_s = time.monotonic() - t_start
        outcome.record = self._write(rec, outcome)
        if outcome.status == "done":
            try:
                self.sm.fire(Event.STEP_DONE)    # LOGGING -> DONE, after the row is on disk
            except IllegalTransition:
                pass
        return outcome

    # ------------------------------------------------------------------ steps
    def _step(self, rec: CycleRecord, state: State, work):
        if self.sm.state is not state:
            raise IllegalTransition(f"cycle expected state {state.name}, is {self.sm.state.name}")
        if self.cancel.is_set():
            raise CycleCancelled()
        t0 = time.monotonic()
        out = work()
        rec.step_times[state.name.lower()] = round(time.monotonic() - t0, 6)
        self.sm.fire(Event.STEP_DONE)
        return out

    def _approach(self, arm: CellArm, r) -> None:
        x, y = np.add(r.part.nominal_xy_mm, r.approach.offset_mm)
        t1, t2 = self.robot.ik_planar(x, y, elbow=self.settings.elbow)
        arm.move(arm.joints(t1, t2, r.approach.z_mm))

    def _locate(self, image: np.ndarray, r) -> np.ndarray:
        part = self.camera.find(image, r.part.fiducial_radius_mm, "part fiducial")
        off = float(np.hypot(*(part - np.asarray(r.part.nominal_xy_mm))))
        if off > r.part.search_radius_mm:
            raise CellFault(Fault.PART_OUT_OF_WINDOW, f"part found at ({part[0]:.3f}, {part[1]:.3f}) mm, "
                            f"{off:.3f} mm from nominal > search radius {r.part.search_radius_mm} mm")
        return part

    def _verify(self, rec: CycleRecord, r, part: np.ndarray) -> None:
        rec.verify_error_mm = float(np.hypot(*(self.camera.tool() - part)))
        if rec.verify_error_mm > r.verify.tolerance_mm:
            raise CellFault(Fault.VERIFY_OUT_OF_TOLERANCE, f"verified error {rec.verify_error_mm:.4f} mm "
                            f"> tolerance {r.verify.tolerance_mm} mm")

    def _compensate(self, arm: CellArm, r, part: np.ndarray, nominal: np.ndarray) -> CompensationResult:
        c = r.compensation
        start = nominal + self.memory.offset(r.name)
        if c.method == "paper":
            return run_paper(self.robot, arm, part, k=c.k, start_units=start,
                             repeatability_mm=c.repeatability_mm)
        return run_lattice(self.robot, arm, part, start_units=start, max_moves=c.max_moves,
                           min_gain_mm=c.min_gain_mm, backlash_margin_units=c.backlash_margin_units,
                           approach_dirs=np.sign(self.robot.from_units(start) - arm.last_joints[:2]))

    def _write(self, rec: CycleRecord, outcome: CycleOutcome) -> CycleRecord:
        """Write the cycle's row (the LOGGING step). Its own duration cannot be inside the row
        it writes: it is returned in ``outcome.log_write_s`` and included in the cycle time
        the PLC reads."""
        t0 = time.monotonic()
        try:
            rec.id = self.log.add_cycle(rec)
        except Exception as exc:                 # noqa: BLE001
            log.error("cycle_log_write_failed", error=repr(exc), part_id=rec.part_id)
            if outcome.status == "done":
                outcome.status, outcome.fault_code = "fault", Fault.LOG_WRITE_FAILED
                outcome.fault_text = f"cycle log write failed: {exc}"
        outcome.log_write_s = time.monotonic() - t0
        log.info("cycle_end", part_id=rec.part_id, recipe=rec.recipe, status=outcome.status,
                 fault=outcome.fault_code, final_error_mm=rec.final_error_mm, moves=rec.moves)
        return rec
