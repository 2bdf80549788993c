"""The controller's decisions as one step over typed inputs and outputs, with no I/O.

:meth:`ControllerCore.step` takes what one scan read (:class:`ScanInputs`: the time, the
PLC's writes and heartbeat, station faults, the running cycle's progress or its end, the
results of last scan's requests) and returns what to write and do (:class:`ScanOutputs`:
register values and :data:`Action` requests). :class:`cell.controller.CellController`
does the reading, the writing and the actions; unit tests drive the core directly with
made-up inputs and a made-up clock.

Handshake (PLCopen Execute/Busy/Done/Error over the register map):

* ``execute`` starts a cycle only on a rising edge the PLC writes while its heartbeat is
  alive, and only after the PLC has *written* ``execute`` low while its heartbeat was alive
  (armed). Arming is observed, never inferred: after a controller start, a heartbeat gap
  or a reconnect, an ``execute`` the PLC held high — or rewrites high — starts nothing
  until the PLC has written it low and raised it again. The edge latches the active recipe
  and ``part_id``. An edge while not ready sets ``execute_refused``.
* A cycle a controller restart interrupted (:meth:`ControllerCore.started` is told of it)
  comes up as fault 503 with its part id in ``part_id_echo``; ``reset`` clears it.
* ``done``/``aborted`` are held until ``acknowledge``; ``error`` until ``reset``.
* PLC heartbeat unchanged for longer than ``plc_heartbeat_timeout_s`` (also mid-cycle), a
  joint-station fault, or a failed cycle step: the cycle is cancelled, every joint gets a
  quick stop, the fault code goes to the PLC and nothing moves again until ``reset``.
  The heartbeat fault is raised at the first scan after the time-out: no earlier than the
  time-out, no later than one scan after it.
* ``calibrate`` starts the robot calibration ``calibration_select`` names (latched at the
  edge, as ``part_id`` is for a cycle), under the same rules as ``execute`` (armed, ready;
  CALIBRATING is busy; done, error or aborted at its end; abort and the watchdogs stop it).
  Its residuals and the calibration version in use go to the calibration registers.
* Recipe files are re-read only between cycles; an invalid edit is rejected
  (recipe_status 2), the last good version stays active.
* When a cycle ends, :class:`SettleCycle` says what the PLC was told (done, aborted, or the
  fault code), after the outputs that tell it were written; the cycle's row is corrected
  to match if it says otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Union

from cell.cycle.runner import CycleOutcome
from cell.cycle.statemachine import CYCLE_STEPS, Event, State, StateMachine
from cell.cyclelog import CycleStatus
from cell.faults import Fault
from cell.log import get_logger
from drivers.plc.register_map import PLC_MAP, RecipeStatus

log = get_logger("controller")

# command_word's bits, as the register map defines them
EXECUTE, RESET, ABORT, ACK, CALIBRATE = (PLC_MAP.mask("command_word", b) for b in (
    "execute", "reset", "abort", "acknowledge", "calibrate"))


@dataclass(frozen=True)
class ControllerSettings:
    scan_s: float = 0.01
    plc_heartbeat_timeout_s: float = 1.0
    recipe_refresh_s: float = 1.0


# ---------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class PlcWriteIn:
    """One register the PLC wrote, in the order it wrote them (``drivers.plc.PlcWrite``)."""

    name: str
    value: int
    previous: int
    peer: str = ""          #: the client that wrote it (host:port)


@dataclass(frozen=True)
class StationFaultIn:
    """The joint stations' latched fault: its PLC code (200 + station code), text, and
    whether it is the quick stop the controller itself asked for."""

    code: int
    text: str
    requested: bool = False


@dataclass(frozen=True)
class DrivesResetIn:
    """How last scan's :class:`ResetDrives` ended."""

    purpose: Literal["reset", "rearm"]
    ok: bool
    text: str = ""


@dataclass(frozen=True)
class RecipesIn:
    """The recipe store as the core needs it: active numbers, and what the last
    :class:`RefreshRecipes` found (``None`` if none ran since the last step)."""

    numbers: frozenset[int] = frozenset()
    refreshed: bool = False
    rejected: bool = False
    changed: bool = False


@dataclass(frozen=True)
class ScanInputs:
    now: float                                  #: clock time of this scan, s
    writes: tuple = ()                          #: PlcWriteIn (or PlcWrite) in PLC order
    last_heartbeat_change: float | None = None  #: clock time plc_heartbeat last changed
    command_word: int = 0                       #: command_word in the register image
    part_id: int = 0                            #: part_id in the register image
    calibration_select: int = 0                 #: calibration_select in the register image
    station_fault: StationFaultIn | None = None
    cycle_step: State | None = None             #: the running cycle's current step
    cycle_ended: CycleOutcome | None = None     #: the cycle worker has ended with this
    drives_reset: DrivesResetIn | None = None
    recipes: RecipesIn = RecipesIn()
    recalibration_due: bool = False
    plant_backlog: int = 0                      #: records the plant historian has not confirmed


# ---------------------------------------------------------------------------- outputs
@dataclass(frozen=True)
class StartCycle:
    recipe_number: int
    part_id: int


@dataclass(frozen=True)
class StartCalibration:
    select: int                                 #: calibration_select: 0 kinematics, N joint jN


@dataclass(frozen=True)
class CancelCycle:
    code: int
    text: str


@dataclass(frozen=True)
class QuickStop:
    reason: str


@dataclass(frozen=True)
class ResetDrives:
    purpose: Literal["reset", "rearm"]


@dataclass(frozen=True)
class RefreshRecipes:
    pass


@dataclass(frozen=True)
class SettleCycle:
    """The PLC has been told this about the cycle that started at ``started_at`` (its row
    ``cycle_id``): status ``done``/``aborted``/``fault`` and the fault code (0 for none)."""

    started_at: str
    cycle_id: int | None
    status: str
    fault_code: int
    text: str


@dataclass(frozen=True)
class ClearInterrupted:
    """The PLC has reset the fault that reported a cycle interrupted by a restart."""


@dataclass(frozen=True)
class Audit:
    """A row for the hash-chained audit trail: ``who`` (the PLC client, ``host:port``),
    what it did, to what, and how it ended."""

    who: str
    action: str
    target: str
    result: str


Action = Union[StartCycle, StartCalibration, CancelCycle, QuickStop, ResetDrives, RefreshRecipes,
               SettleCycle, ClearInterrupted, Audit]


@dataclass
class ScanOutputs:
    status: dict[str, bool]                      #: status_word bits
    registers: dict[str, int]                    #: other registers to write
    actions: list = field(default_factory=list)  #: Action requests, in order


# ---------------------------------------------------------------------------- the core
class ControllerCore:
    """State of the handshake, watchdogs, fault latch and recipe selection."""

    def __init__(self, settings: ControllerSettings = ControllerSettings()):
        self.settings = settings
        self.sm = StateMachine()
        self.fault_code = 0
        self.fault_text = ""
        self.fault_at: float | None = None      #: clock time the latched fault was raised
        self.execute_refused = False
        self.cycle_count = 0
        self.recipe_number = 0
        self.recipe_status = RecipeStatus.OK
        self.last_outcome: CycleOutcome | None = None
        self.calibration_version = 0             #: version of the robot calibration in use
        self.plant_backlog = 0                   #: records the plant has not confirmed (register)
        self._pending_select: int | None = None
        self._selected_by = ""                      #: PLC client of the pending selection
        self._writer = ""                           #: PLC client of the command being handled
        self._armed = False
        self._rearming = False                   # drives being re-enabled after an abort
        self._link_ok = False
        self._heartbeat = 0
        self._cycle_running = False
        self._recalibration_due = False          # as last written
        self._next_refresh = 0.0
        self._recipes = RecipesIn()
        self._now = 0.0
        self._actions: list = []
        self._results: dict[str, int] = {}

    # ------------------------------------------------------------------ lifecycle
    def started(self, now: float, recipes: RecipesIn, interrupted=None,
                calibration_version: int = 0) -> ScanOutputs:
        """The controller came up (recipes read once): STARTING → IDLE, nothing moves.

        :param interrupted: the cycle a restart interrupted (``part_id``, ``started_at``;
            :class:`cell.cyclelog.Interrupted`), if any: STARTING → FAULT 503 instead.
        :param calibration_version: version of the robot calibration loaded (0: nominal).
        """
        self._actions = []
        self.calibration_version = int(calibration_version) & 0xFFFF
        self._now = now
        self._take_recipes(recipes)
        self._next_refresh = now + self.settings.recipe_refresh_s
        if interrupted is not None:
            self._results["part_id_echo"] = int(interrupted.part_id) & 0xFFFFFFFF
            self._fault(Fault.INTERRUPTED, f"the cycle of part {interrupted.part_id} (started "
                        f"{interrupted.started_at}) was interrupted by a controller restart")
        else:
            self.sm.fire(Event.STARTED)
        return self._outputs(False)

    def shutdown(self) -> list:
        """The controller is going down: a running cycle is cancelled, joints stopped."""
        self._actions = []
        if self.sm.state.busy:
            self._fault(Fault.INTERNAL, "controller shutting down")
        return self._actions

    @property
    def link_ok(self) -> bool:
        return self._link_ok

    @property
    def cycle_running(self) -> bool:
        return self._cycle_running

    # ------------------------------------------------------------------ one step
    def step(self, inp: ScanInputs) -> ScanOutputs:
        """Read → update: decide this scan's register values and actions."""
        self._actions = []
        self._results = {}
        now = self._now = inp.now
        s = self.settings
        if inp.cycle_step is not None and self._cycle_running:
            self._follow(inp.cycle_step)
        if inp.drives_reset is not None:
            self._drives_reset_done(inp.drives_reset)
        if inp.recipes.refreshed or inp.recipes.numbers != self._recipes.numbers:
            self._take_recipes(inp.recipes)

        last_hb = inp.last_heartbeat_change
        link_ok = last_hb is not None and now - last_hb <= s.plc_heartbeat_timeout_s
        if self._link_ok and not link_ok:
            log.warning("plc_heartbeat_lost", timeout_s=s.plc_heartbeat_timeout_s)
            self._fault(Fault.PLC_HEARTBEAT_LOST, f"PLC heartbeat lost for more than "
                        f"{s.plc_heartbeat_timeout_s} s")
        if not link_ok:
            self._armed = False
        self._link_ok = link_ok

        st = inp.station_fault
        if st is not None and not st.requested and \
                self.sm.state not in (State.FAULT, State.STOPPING, State.RESETTING):
            self._fault(st.code, f"joint stations: {st.text}")

        if inp.cycle_ended is not None:
            self._cycle_ended(inp.cycle_ended)
        # part_id as it stood at each write: an execute edge latches the value written before
        # it, not one the PLC wrote after it in the same scan
        part_id = next((w.previous for w in inp.writes if w.name == "part_id"), inp.part_id)
        select = next((w.previous for w in inp.writes if w.name == "calibration_select"),
                      inp.calibration_select)
        for w in inp.writes:                        # in the order the PLC wrote them
            if w.name == "part_id":
                part_id = w.value
            if w.name == "calibration_select":
                select = w.value
            if w.name == "recipe_select" and w.value:   # 0 = no selection
                self._pending_select = w.value
                self._selected_by = getattr(w, "peer", "")
            if self._pending_select is not None and not self.sm.state.busy:
                self._select_recipe(self._pending_select)
                self._pending_select = None
            if w.name == "command_word" and link_ok:
                self._writer = getattr(w, "peer", "")
                self._on_command(w.value & ~w.previous, w.value, part_id, select)
        if self._pending_select is not None and not self.sm.state.busy:
            self._select_recipe(self._pending_select)   # asked while busy: applied once idle
            self._pending_select = None
        if self._pending_select is not None:
            self.recipe_status = RecipeStatus.BUSY
        if not self.sm.state.busy and not self._cycle_running and now >= self._next_refresh:
            self._next_refresh = now + s.recipe_refresh_s
            self._actions.append(RefreshRecipes())
        self.plant_backlog = min(max(int(inp.plant_backlog), 0), 0xFFFFFFFF)
        return self._outputs(inp.recalibration_due)

    def quiet_step(self, now: float, last_heartbeat_change: float | None, cycle_step: State | None = None,
                   recalibration_due: bool = False, plant_backlog: int = 0) -> int | None:
        """:meth:`step` for a scan with no news, where it would change nothing but the
        controller's heartbeat: then that is advanced and returned, and the scan's outputs are
        the last ones with this heartbeat (no actions). Otherwise None and nothing changed:
        call :meth:`step`.

        No news is the caller's part: no PLC write, no station fault, no cycle end, drive
        reset or recipe refresh to take, the same recipe numbers. The rest is checked here
        with :meth:`step`'s own rules: the link's health (``now`` against
        ``last_heartbeat_change``, s), the running cycle's step, a pending recipe selection,
        the recipe refresh's time, ``recalibration_due`` and ``plant_backlog`` as last
        written. Cheap: a few comparisons, no allocation.
        """
        s = self.settings
        link_ok = last_heartbeat_change is not None and now - last_heartbeat_change <= s.plc_heartbeat_timeout_s
        state = self.sm.state
        if link_ok is not self._link_ok \
                or self._pending_select is not None \
                or bool(recalibration_due) is not bool(self._recalibration_due) \
                or min(max(int(plant_backlog), 0), 0xFFFFFFFF) != self.plant_backlog \
                or (cycle_step is not None and self._cycle_running and state in CYCLE_STEPS and state < cycle_step) \
                or (not state.busy and not self._cycle_running and now >= self._next_refresh):
            return None
        self._now = now
        self._heartbeat = (self._heartbeat + 1) & 0xFFFF
        return self._heartbeat

    # ------------------------------------------------------------------ cycle
    def _follow(self, step: State) -> None:
        """Move the state machine along with the cycle's own progress."""
        while self.sm.state in CYCLE_STEPS and self.sm.state < step:
            self.sm.fire(Event.STEP_DONE)

    def _start_cycle(self, part_id: int) -> None:
        if self.recipe_number not in self._recipes.numbers:  # nothing moved: refuse, no fault
            self.execute_refused = True
            log.warning("execute_refused", reason=f"recipe {self.recipe_number} is not active")
            return
        self.execute_refused = False
        self.sm.fire(Event.EXECUTE)
        self._cycle_running = True
        self._results["part_id_echo"] = part_id
        self._actions.append(StartCycle(self.recipe_number, part_id))
        log.info("cycle_started", part_id=part_id, recipe_number=self.recipe_number)

    def _start_calibration(self, select: int) -> None:
        self.execute_refused = False
        self.sm.fire(Event.CALIBRATE)
        self._cycle_running = True
        self._actions.append(StartCalibration(select))
        log.info("calibration_started", select=select)

    def _cycle_ended(self, out: CycleOutcome) -> None:
        self._cycle_running = False
        self.last_outcome = out
        self._publish(out)
        if out.calibration is not None:
            self._publish_calibration(out.calibration)
        if out.status == CycleStatus.DONE and self.sm.state is State.CALIBRATING:
            self.sm.fire(Event.STEP_DONE)            # CALIBRATING → DONE: written and applied
        elif out.status == CycleStatus.DONE and self.sm.state in CYCLE_STEPS:
            self._follow(State.LOGGING)
            self.sm.fire(Event.STEP_DONE)            # LOGGING → DONE: the row is on disk
            self.cycle_count += 1
            self._results["cycle_count"] = self.cycle_count & 0xFFFFFFFF
        elif self.sm.state is State.STOPPING:
            self._stopped()
        else:
            self._fault(out.fault_code or Fault.INTERNAL, out.fault_text or "cycle failed")
        self._settle(out)

    def _settle(self, out: CycleOutcome) -> None:
        """What this scan tells the PLC about the cycle that ended, for its row."""
        rec = out.record
        if rec is None:
            return
        state = self.sm.state
        if state is State.DONE:
            told = (CycleStatus.DONE, 0, "")
        elif state is State.ABORTED:
            told = (CycleStatus.ABORTED, 0, "abort by PLC")
        else:
            done = out.status == CycleStatus.DONE
            told = (CycleStatus.ABORTED if done else out.status, self.fault_code,
                    self.fault_text if done or self.fault_code != out.fault_code else "")
        self._actions.append(SettleCycle(rec.started_at, rec.id, *told))

    def _publish(self, out: CycleOutcome) -> None:
        rec = out.record
        if rec is None:
            return
        final = rec.verify_error_mm if rec.verify_error_mm is not None else rec.final_error_mm

        def um(v):
            return 0 if v is None else min(int(round(v * 1000)), 0xFFFFFFFF)
        self._results.update(initial_error_um=um(rec.initial_error_mm), final_error_um=um(final),
                             moves=rec.moves or 0,
                             cycle_time_ms=min(int((rec.cycle_time_s + out.log_write_s) * 1000), 0xFFFFFFFF))

    def _publish_calibration(self, result: dict) -> None:
        def clamp(v):
            return min(max(int(round(v)), 0), 0xFFFFFFFF)
        if result.get("version") is not None:
            self.calibration_version = int(result["version"]) & 0xFFFF
        self._results.update(calibration_residual_um=clamp(result.get("residual_um", 0)),
                             calibration_residual_udeg=clamp(result.get("residual_udeg", 0)))

    # ------------------------------------------------------------------ commands
    def _on_command(self, rising: int, value: int, part_id: int, select: int = 0) -> None:
        state = self.sm.state
        if rising & ABORT and state.busy and state is not State.STOPPING:
            self._actions.append(CancelCycle(0, "abort by PLC"))
            self.sm.fire(Event.ABORT)
            self._actions.append(QuickStop("abort by PLC"))
            log.info("cycle_abort_requested")
        if rising & RESET and state is State.FAULT:
            self._reset()
        if rising & ACK and state in (State.DONE, State.ABORTED):
            if state is State.ABORTED:
                self._rearming = True
                self._actions.append(ResetDrives("rearm"))
            self.sm.fire(Event.ACKNOWLEDGE)
            self.execute_refused = False
        if rising & (EXECUTE | CALIBRATE):
            if rising & EXECUTE and rising & CALIBRATE:
                self.execute_refused = True
                log.warning("execute_refused", reason="execute and calibrate raised together")
            elif self._armed and self.sm.state is State.IDLE and not self._rearming:
                if rising & EXECUTE:
                    self._start_cycle(part_id)
                else:
                    self._start_calibration(select)
            else:
                self.execute_refused = True
                why = "not armed (execute must be written low while the PLC link is alive)" \
                    if not self._armed else "drives still re-enabling after abort" \
                    if self._rearming else f"state {self.sm.state.name}"
                log.warning("execute_refused", reason=why)
        if not value & (EXECUTE | CALIBRATE):      # the PLC wrote both starts low: armed
            self._armed = True

    # ------------------------------------------------------------------ faults
    def _fault(self, code: int, text: str) -> None:
        """Latch a fault (the first one wins until reset) and stop every joint under control."""
        state = self.sm.state
        if state is State.FAULT:
            log.warning("further_fault_while_latched", code=int(code), detail=text)
            return
        if self.fault_code == 0:
            self.fault_code, self.fault_text, self.fault_at = int(code), text, self._now
        log.error("fault", code=int(code), detail=text, state=state.name)
        if state.busy and state is not State.STOPPING:
            self._actions.append(CancelCycle(int(code), text))
        if state is State.STARTING or state is State.RESETTING:
            self.sm.fire(Event.FAULT)
            return
        if state is not State.STOPPING:
            self.sm.fire(Event.FAULT)
        self._actions.append(QuickStop(text))
        if not self._cycle_running:                # no cycle to wind down: stopped now
            self.sm.fire(Event.STOPPED_FAULT)

    def _stopped(self) -> None:
        """The cycle has ended after STOPPING: settle in FAULT or ABORTED."""
        self.sm.fire(Event.STOPPED_FAULT if self.fault_code else Event.STOPPED_ABORT)

    def _reset(self) -> None:
        target = f"fault {self.fault_code}"
        if not self._link_ok:
            log.warning("reset_refused", reason="PLC link not alive", plc=self._writer)
            self._actions.append(Audit(self._writer, "reset", target, "refused: PLC link not alive"))
            return
        log.info("reset_requested", plc=self._writer, fault_code=self.fault_code)
        self._actions.append(Audit(self._writer, "reset", target, "accepted"))
        self.sm.fire(Event.RESET)
        self._actions.append(ResetDrives("reset"))

    def _drives_reset_done(self, r: DrivesResetIn) -> None:
        if r.purpose == "rearm":
            self._rearming = False
            if not r.ok:
                self._fault(Fault.STATION, f"drives could not be re-enabled after abort: {r.text}")
            return
        if self.sm.state is not State.RESETTING:
            return
        if not r.ok:                               # the cause persists: stay in FAULT
            log.error("reset_failed", error=r.text)
            self.sm.fire(Event.FAULT)
            return
        if self.fault_code == Fault.INTERRUPTED:
            self._actions.append(ClearInterrupted())
        self.fault_code, self.fault_text, self.fault_at = 0, "", None
        self.execute_refused = False
        self.sm.fire(Event.RESET_DONE)
        log.info("reset_done")

    # ------------------------------------------------------------------ recipes
    def _select_recipe(self, number: int) -> None:
        if number == 0:
            return
        if number not in self._recipes.numbers:
            self.recipe_status = RecipeStatus.UNKNOWN
            log.warning("recipe_select_unknown", number=number, plc=self._selected_by)
            return
        if number != self.recipe_number:
            log.info("recipe_selected", number=number, previous=self.recipe_number, plc=self._selected_by)
            self._actions.append(Audit(self._selected_by, "recipe_select", str(number),
                                       f"active (was {self.recipe_number})"))
        self.recipe_number = number
        self.recipe_status = RecipeStatus.OK

    def _take_recipes(self, r: RecipesIn) -> None:
        self._recipes = r
        if r.refreshed:
            if r.rejected:
                self.recipe_status = RecipeStatus.REJECTED
            elif r.changed and self.recipe_status == RecipeStatus.REJECTED:
                self.recipe_status = RecipeStatus.OK
        if self.recipe_number and self.recipe_number not in r.numbers:
            self.recipe_status = RecipeStatus.UNKNOWN

    # ------------------------------------------------------------------ outputs
    def _outputs(self, recalibration_due: bool) -> ScanOutputs:
        state = self.sm.state
        self._recalibration_due = recalibration_due
        self._heartbeat = (self._heartbeat + 1) & 0xFFFF
        status = dict(
            ready=state is State.IDLE and self._link_ok and self._armed and self.fault_code == 0
            and not self._rearming,
            busy=state.busy, done=state is State.DONE,
            error=state in (State.FAULT, State.RESETTING) or self.fault_code != 0,
            auto=True, homed=state is not State.STARTING,
            recalibration_due=recalibration_due, aborted=state is State.ABORTED,
            plc_link_ok=self._link_ok, execute_refused=self.execute_refused)
        registers = {**self._results, "controller_heartbeat": self._heartbeat, "state_code": int(state),
                     "fault_code": self.fault_code, "recipe_ack": self.recipe_number,
                     "recipe_status": self.recipe_status, "calibration_version": self.calibration_version,
                     "plant_backlog": self.plant_backlog}
        return ScanOutputs(status, registers, self._actions)
