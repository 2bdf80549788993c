"""The cell controller's scan loop: read the PLC and the devices, step the core, write the
PLC and carry out what the core asked for.

One task ("cell-scan") runs :meth:`CellController.scan` every ``scan_s`` of the injected
clock (on a clock that runs timed callbacks, ``call_at``: the simulated clock, each scan is
one, run by whichever thread runs the clock's agenda, at the same clock times and in the
same order as the task's, without a thread switch of its own); a part's cycle (:class:`~cell.cycle.runner.CycleRunner`) or a calibration runs as a job of
a second, long-lived task (the "cell-cycle" :class:`~cell.worker.Worker`), so the scan keeps
serving the PLC, the heartbeat watchdog and abort while joints move. (Long-lived on
purpose: OpenCV keeps about 0.9 kB of thread-local state for every thread that calls it,
which a thread per cycle leaked, about 0.9 MB per 1000 cycles; bench/bench_soak.py.) All
decisions are in :class:`~cell.controller.core.ControllerCore` (see its module doc for the
handshake); this shell only moves data in and out:

* in: the PLC's writes and heartbeat time, the register image, the stations' latched
  fault, the running cycle's step or its outcome, the results of last scan's drive reset
  and recipe refresh;
* out: status bits and registers; actions — start a cycle (with an atomic snapshot of
  the recipe) or a calibration (``calibrator``, in the same task slot), cancel it (the
  cycle is *given* the reason), quick-stop every joint, reset the drives, re-read the
  recipes (auditing every change), record what the PLC was told; publish each settled
  cycle and every status change (:mod:`cell.publish`, the one place plant integration
  subscribes to).

Nothing slow runs on the scan task. Re-reading recipes and log updates go to the
``cell-log`` worker, re-enabling drives to the ``cell-drives`` worker
(:class:`~cell.worker.Worker`); their results are picked up at a later scan. Only the quick
stop is sent from the scan itself (a few CAN frames).
"""
from __future__ import annotations

import contextvars
import threading
from collections import deque
from typing import TYPE_CHECKING, Callable

import structlog

from cell.clock import Clock, MonotonicClock

from cell.controller.core import (Audit, CancelCycle, ClearInterrupted, ControllerCore, ControllerSettings,
                                  DrivesResetIn, QuickStop, RecipesIn, RefreshRecipes, ResetDrives,
                                  ScanInputs, SettleCycle, StartCalibration, StartCycle, StationFaultIn)
from cell.cycle.runner import CancelToken, CycleOutcome, CycleRunner
from cell.cycle.statemachine import State, StateMachine
from cell.cyclelog import CycleLog, CycleStatus
from cell.errors import CellError
from cell.faults import Fault, station_fault
from cell.log import get_logger
from cell.publish import Publisher
from cell.recipes import ActiveRecipe, RecipeAction
from cell.recipes.store import RecipeStore
from cell.worker import Job, Worker

if TYPE_CHECKING:
    from cell.motion.mover import JointMotion
    from drivers.plc import PlcPort

log = get_logger("controller")

#: refused PLC writes are audited at most this often (clock s), one row per client and reason
REFUSAL_AUDIT_S = 10.0
#: the joints' actual positions in the published status are sampled this often (clock s)
#: and rounded to JOINTS_DIGITS decimals: at most ten status messages a second while the
#: arm moves, none while it stands
JOINTS_SAMPLE_S = 0.1
JOINTS_DIGITS = 3

__all__ = ["CellController", "ControllerSettings"]


class OutputWriter:
    """Publishes a scan's outputs to the PLC link so that a PLC read between the writes
    never sees a raised flag beside values that are not yet its own (the register map:
    results are valid before ``done`` is set): the ``status_word`` bits that go down first,
    then the registers, then the bits that go up; each of the three is atomic on the link.

    Only what changed since the last write goes to the link: the controller alone writes
    its outputs, and each write is validated against the map and takes the link's lock."""

    def __init__(self, plc):
        self.plc = plc
        self._status: dict[str, bool] = {}
        self._registers: dict[str, int] = {}

    def write(self, status: dict[str, bool], registers: dict[str, int]) -> None:
        old_status, old = self._status, self._registers
        down = {k: v for k, v in status.items() if not v and old_status.get(k) is not False}
        up = {k: v for k, v in status.items() if v and old_status.get(k) is not True}
        changed = {k: v for k, v in registers.items() if old.get(k) != v}
        if down:
            self.plc.set_bits("status_word", **down)
        if changed:
            self.plc.write_many(changed)
        if up:
            self.plc.set_bits("status_word", **up)
        self._status = {**old_status, **down, **up}
        self._registers = {**old, **changed}

    def write_heartbeat(self, value: int) -> None:
        """A scan whose outputs are the last ones but for ``controller_heartbeat``."""
        if self._registers.get("controller_heartbeat") != value:
            self.plc.write_many({"controller_heartbeat": value})
            self._registers["controller_heartbeat"] = value   # a dict of this writer's own


class CellController:
    """Owns the core and the scan task; devices are injected."""

    def __init__(self, plc: PlcPort, motion: JointMotion, runner: CycleRunner, cyclelog: CycleLog, recipes: RecipeStore,
                 settings: ControllerSettings = ControllerSettings(), clock: Clock | None = None,
                 calibrator=None, publisher: Publisher | None = None):
        """:param calibrator: runs calibrations the PLC starts (``run_safely(select, cancel)
            -> CycleOutcome``, ``version``; :class:`cell.calibration.service.CellCalibrator`);
            None: every calibrate edge ends in fault 601.
        :param publisher: where settled cycles and status changes go for the plant
            (:mod:`cell.publish`); default: one of its own (:attr:`publisher`)."""
        self.plc, self.motion, self.runner, self.log, self.recipes = plc, motion, runner, cyclelog, recipes
        self.calibrator = calibrator
        self.publisher = publisher or Publisher()   #: settled cycles and status, for the plant
        self._task_outcome = lambda: self.runner.outcome   # where the running task leaves its end
        self.settings = settings
        self.clock = clock or MonotonicClock()
        self.core = ControllerCore(settings)
        self.recalibration_due = False
        #: the plant outbox's backlog (set by :class:`cell.app.Cell` with a plant section; None
        #: or a None answer: 0, no plant path or not read yet) for the plant_backlog register
        self.plant_backlog: Callable[[], int | None] | None = None
        self.scans = 0
        self.quiet_scans = 0                      #: scans that wrote only the heartbeat (quiet_step)
        self._job: Job | None = None              # the running cycle or calibration
        self._cancel: CancelToken | None = None
        self._recipes_in = RecipesIn()
        self._stop = self.clock.event()
        self._task = None
        self._timer = None                        # the next scan's clock callback (call_at clocks)
        self._next_t = 0.0
        self._tick_lock = threading.Lock()        # a stop from outside the clock waits for a scan
        self._scan_context = contextvars.Context()   # the scan's log context, as a task's own
        self.log_worker = Worker(self.clock, "cell-log")        #: recipes and log updates
        self.drives_worker = Worker(self.clock, "cell-drives")  #: re-enabling drives
        self.cycle_worker = Worker(self.clock, "cell-cycle")    #: cycles and calibrations
        self._refresh: Job | None = None
        self._plc_detached = False        # going down: what the scan writes no longer reaches the PLC
        self._resets: deque[tuple[str, Job]] = deque()      # in the order asked
        self._owner: str | None = None                      # the PLC client that owns the link
        self._next_refusal_audit = 0.0
        self._outputs = OutputWriter(plc)
        self._joints: list[float] | None = None
        self._joints_at = -float("inf")

    # ------------------------------------------------------------------ views (jobs, tests)
    @property
    def sm(self) -> StateMachine:
        return self.core.sm

    @property
    def fault_code(self) -> int:
        return self.core.fault_code

    @property
    def fault_text(self) -> str:
        return self.core.fault_text

    @property
    def cycle_count(self) -> int:
        return self.core.cycle_count

    @property
    def last_outcome(self) -> CycleOutcome | None:
        return self.core.last_outcome

    @property
    def recipe_number(self) -> int:
        return self.core.recipe_number

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Read the recipes, find a cycle a restart interrupted, come up in IDLE — or FAULT 503
        if there was one — with nothing moving, start the scan task.

        :raises LogError: the log cannot record the interrupted cycle.
        """
        self._recipes_in = self._recipes_result(self.log_worker.run_here(self.recipes.refresh))
        interrupted = self.log.recover_interrupted()
        if interrupted is not None:
            log.error("cycle_interrupted_by_restart", part_id=interrupted.part_id, cycle_id=interrupted.cycle_id)
        out = self.core.started(self.clock.now(), self._recipes_in, interrupted,
                                getattr(self.calibrator, "version", 0))
        self._write(out.status, out.registers)
        self._apply(out.actions)
        self.log_worker.start()
        self.drives_worker.start()
        self.cycle_worker.start()
        call_at = getattr(self.clock, "call_at", None)
        if call_at is not None:                   # where the task would start: its first scan
            self._next_t = self.clock.now()
            self._timer = call_at(self._next_t, self._tick)
        else:
            self._task = self.clock.spawn(self._run, "cell-scan")
        log.info("controller_started", recipes=sorted(self.recipes.active))

    def detach_plc(self) -> None:
        """The PLC link is about to stop: nothing the scan writes reaches the PLC any more, so
        no cycle is settled as told (the next start reports a cycle in flight as interrupted)."""
        self._plc_detached = True

    def stop(self) -> None:
        """Stop the scan loop; a running cycle is cancelled and the joints quick-stopped."""
        self.detach_plc()
        self._apply(self.core.shutdown())
        with self._tick_lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
        self._stop.set()
        if self._task is not None:
            self._task.join(timeout=5)
        if self._job is not None:
            self._job.finished.wait(10)
        for w in (self.cycle_worker, self.log_worker, self.drives_worker):
            if not w.stop(timeout_s=10):
                log.error("worker_did_not_stop", worker=w.name)

    def _run(self) -> None:
        """The scan as a task (a clock without ``call_at``)."""
        next_t = self.clock.now()
        while not self._stop.is_set():
            self._scan_safely()
            next_t = self._next(next_t)
            self._stop.wait(next_t - self.clock.now())

    def _tick(self) -> None:
        """Scans as a clock callback, until the next one is due later: then it is scheduled
        where the task's wait would end (``now + (next - now)``, to the last bit). A wait
        of zero or less does not wait, so such a scan follows at once, as in the task."""
        with self._tick_lock:
            while self._timer is not None:       # None: stopped meanwhile
                self._scan_context.run(self._scan_safely)
                self._next_t = self._next(self._next_t)
                now = self.clock.now()
                wait = self._next_t - now
                if wait > 0:
                    self._timer = self.clock.call_at(now + wait, self._tick)
                    return

    def _next(self, next_t: float) -> float:
        """The next scan's time after the one due at ``next_t``."""
        next_t += self.settings.scan_s
        if next_t < self.clock.now():            # overran: keep the period, skip the lost scans
            next_t = self.clock.now()
        return next_t

    def _scan_safely(self) -> None:
        try:
            self.scan()
        except Exception as exc:                 # noqa: BLE001 -- the loop must not die silently
            log.exception("scan_failed", error=repr(exc))

    # ------------------------------------------------------------------ one scan
    def scan(self) -> None:
        """Read inputs, step the core, write outputs, act.

        A scan with no news (no PLC write, no station fault, no cycle end, drive reset or
        recipe refresh to take) that the core finds would change nothing but its heartbeat
        (:meth:`ControllerCore.quiet_step`) writes only that, and publishes the status only
        when the joints are due to be sampled or the link's owner changed: what else the
        status shows is the core's, unchanged."""
        self.scans += 1
        owner_changed = self._tag_owner()
        writes = self.plc.drain_writes()
        if not writes and not self._news():
            now = self.clock.now()
            hb = self.core.quiet_step(now, self.plc.last_heartbeat_change,
                                      self.runner.progress if self._job is not None else None,
                                      self.recalibration_due, self._plant_backlog())
            if hb is not None:
                self.quiet_scans += 1
                self._outputs.write_heartbeat(hb)
                self._audit_refusals()
                if owner_changed or now - self._joints_at >= JOINTS_SAMPLE_S:
                    self.publisher.status(now, self.status_snapshot())
                return
        out = self.core.step(self._read(writes))
        self._write(out.status, out.registers)
        self._apply(out.actions)
        self._audit_refusals()
        self.publisher.status(self.clock.now(), self.status_snapshot())

    def _news(self) -> bool:
        """Something for the core to take besides the PLC's writes: a station fault, or the
        end of the running cycle, of the oldest drive reset or of a recipe refresh."""
        return (self.motion.fault is not None or (self._job is not None and self._job.done)
                or bool(self._resets and self._resets[0][1].done)
                or (self._refresh is not None and self._refresh.done))

    def _plant_backlog(self) -> int:
        return (self.plant_backlog() or 0) if self.plant_backlog is not None else 0

    def status_snapshot(self) -> dict:
        """What a PLC or an operator looks at, as published on ``status`` (:mod:`cell.publish`):
        also the active recipe's name and ``joints``, the stations' last reported actual
        positions j1..j4 (deg; mm for j3; None until every station has reported one),
        sampled every :data:`JOINTS_SAMPLE_S`."""
        active = self.recipes.by_number(self.recipe_number) if self.recipe_number else None
        return {"state": self.sm.state.name.lower(), "fault_code": int(self.fault_code),
                "fault_text": self.fault_text, "cycle_count": int(self.cycle_count),
                "recipe_number": int(self.recipe_number),
                "recipe_name": active.recipe.name if active is not None else "",
                "recalibration_due": bool(self.recalibration_due),
                "plc_owner": self._owner, "joints": self._sample_joints()}

    def _sample_joints(self) -> list[float] | None:
        """The stations' actual positions, re-read every :data:`JOINTS_SAMPLE_S` (memory reads
        of their last TPDOs: no bus traffic)."""
        now = self.clock.now()
        if now - self._joints_at >= JOINTS_SAMPLE_S:
            self._joints_at = now
            try:
                q = self.motion.actual_positions()
            except CellError:                      # a station has not reported a position yet
                self._joints = None
            else:
                self._joints = [round(float(v), JOINTS_DIGITS) for v in q]
        return self._joints

    def _tag_owner(self) -> bool:
        """Every log line of the scan thread names the PLC client that owns the link; True
        if the owner changed."""
        owner = self.plc.owner
        if owner == self._owner:
            return False
        self._owner = owner
        structlog.contextvars.bind_contextvars(plc_owner=owner)
        log.info("plc_owner_changed", owner=owner)
        return True

    def _audit_refusals(self) -> None:
        """Writes the link refused (not the owner, or a role without the right) go to the
        audit trail every :data:`REFUSAL_AUDIT_S`, summed per client and reason."""
        now = self.clock.now()
        if now < self._next_refusal_audit:
            return
        self._next_refusal_audit = now + REFUSAL_AUDIT_S
        for r in self.plc.take_refusals():
            who = f"plc {r.client}" + (f" ({r.role})" if r.role else "")
            self._apply([Audit(who, "plc_write_refused", r.reason, f"{r.count} refused with exception 01")])

    def _read(self, writes: list) -> ScanInputs:
        """This scan's inputs, with the PLC's ``writes`` already drained."""
        ended = None
        if self._job is not None and self._job.done:
            ended = self._task_outcome()
            self._job = None
        reset = None
        if self._resets and self._resets[0][1].done:
            purpose, job = self._resets.popleft()
            reset = DrivesResetIn(purpose, job.error is None, "" if job.error is None else str(job.error))
        if self._refresh is not None and self._refresh.done:
            self._recipes_in = self._recipes_result(self._refresh)
            self._refresh = None
        recipes, self._recipes_in = self._recipes_in, RecipesIn(self._recipes_in.numbers)
        return ScanInputs(
            now=self.clock.now(), writes=tuple(writes),
            last_heartbeat_change=self.plc.last_heartbeat_change,
            command_word=self.plc.read("command_word"), part_id=self.plc.read("part_id"),
            calibration_select=self.plc.read("calibration_select"),
            station_fault=self._station_fault(),
            cycle_step=self.runner.progress if self._job is not None else None,
            cycle_ended=ended, drives_reset=reset, recipes=recipes,
            recalibration_due=self.recalibration_due,
            plant_backlog=self._plant_backlog())

    def _station_fault(self) -> StationFaultIn | None:
        rec = self.motion.fault
        if rec is None:
            return None
        requested = getattr(rec.code, "name", "") == "QUICK_STOP"     # we asked for it
        return StationFaultIn(station_fault(rec.code), str(rec), requested)

    def _write(self, status: dict, registers: dict) -> None:
        self._outputs.write(status, registers)

    # ------------------------------------------------------------------ actions
    def _apply(self, actions: list) -> None:
        for a in actions:
            if isinstance(a, CancelCycle):
                if self._cancel is not None:
                    self._cancel.cancel(a.code, a.text)
            elif isinstance(a, QuickStop):
                self._quick_stop(a.reason)
            elif isinstance(a, StartCycle):
                self._start_cycle(a)
            elif isinstance(a, StartCalibration):
                self._start_calibration(a)
            elif isinstance(a, ResetDrives):
                self._resets.append((a.purpose, self.drives_worker.submit(self.motion.reset)))
            elif isinstance(a, RefreshRecipes):
                if self._refresh is None:
                    self._refresh = self.log_worker.submit(self.recipes.refresh)
            elif isinstance(a, SettleCycle):
                if self._plc_detached:
                    log.warning("cycle_not_settled", reason="the PLC link is going down", cycle_id=a.cycle_id)
                else:
                    self.log_worker.submit(self._settle, a)
            elif isinstance(a, Audit):
                self.log_worker.submit(self._logged, f"audit {a.action}", lambda a=a: self.log.audit(
                    a.who or "plc", a.action, a.target, "", a.result))
            elif isinstance(a, ClearInterrupted):
                self.log_worker.submit(self._logged, "clear_interrupted", self.log.clear_interrupted)

    def _start_cycle(self, a: StartCycle) -> None:
        active: ActiveRecipe | None = self.recipes.by_number(a.recipe_number)
        self._cancel = CancelToken(self.clock)
        cancel = self._cancel
        self.runner.progress = State.APPROACH     # not the last cycle's step while this one starts
        if active is None:                       # the core saw it active: cannot happen
            cancel.cancel(0, f"recipe {a.recipe_number} vanished")
        self._task_outcome = lambda: self.runner.outcome
        self._job = self.cycle_worker.submit(self.runner.run_safely, active, a.part_id, cancel)
        log.info("cycle_task_started", part_id=a.part_id, recipe=getattr(getattr(active, "recipe", None), "name", None))

    def _start_calibration(self, a: StartCalibration) -> None:
        self._cancel = CancelToken(self.clock)
        cancel, box = self._cancel, {}

        def run():
            if self.calibrator is None:
                box["out"] = CycleOutcome(CycleStatus.ABORTED, Fault.CALIBRATION_REFUSED,
                                          "this cell has no calibration service (no hand camera)")
            else:
                box["out"] = self.calibrator.run_safely(a.select, cancel)

        self._task_outcome = lambda: box.get("out") or CycleOutcome(
            CycleStatus.ABORTED, Fault.INTERNAL, "calibration task ended without an outcome")
        self._job = self.cycle_worker.submit(run)
        log.info("calibration_task_started", select=a.select)

    def _quick_stop(self, why: str) -> None:
        try:
            self.motion.quick_stop_all(why)
        except Exception as exc:                   # noqa: BLE001 -- stations may be gone already
            log.error("quick_stop_failed", error=repr(exc))

    # ------------------------------------------------------------------ log worker jobs
    def _settle(self, a: SettleCycle) -> None:
        def settle():
            if self.log.settle_cycle(a.started_at, a.cycle_id, a.status, a.fault_code, a.text):
                log.warning("cycle_row_corrected", cycle_id=a.cycle_id, told=a.status, fault=a.fault_code)
            rec = self.log.cycle(a.cycle_id) if a.cycle_id is not None else None
            if rec is not None:                    # settled: as the log and the PLC have it
                self.publisher.cycle(self.clock.now(), rec)
        self._logged("settle_cycle", settle)

    @staticmethod
    def _logged(what: str, fn) -> None:
        try:
            fn()
        except Exception as exc:                   # noqa: BLE001 -- e.g. disk full; the next start reports it
            log.error("log_update_failed", update=what, error=repr(exc))

    # ------------------------------------------------------------------ recipes
    def _recipes_result(self, job: Job) -> RecipesIn:
        if job.error is not None:                  # e.g. folder gone, audit failed: keep the last good set
            log.error("recipe_refresh_failed", error=str(job.error))
        entries = job.result or []
        numbers = frozenset(a.recipe.number for a in self.recipes.active.values())
        return RecipesIn(numbers, refreshed=True, changed=bool(entries),
                         rejected=any(e.action == RecipeAction.REJECT and not e.example for e in entries))
