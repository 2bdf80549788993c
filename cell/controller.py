"""The cell controller's scan loop: read the PLC and the devices, step the core, write the
PLC and carry out what the core asked for.

One task ("cell-scan") runs :meth:`CellController.scan` every ``scan_s`` of the injected
clock; a part's cycle runs in a second task ("cell-cycle", :class:`~cell.cycle.CycleRunner`)
so the scan keeps serving the PLC, the heartbeat watchdog and abort while joints move. All
decisions are in :class:`~cell.controller_core.ControllerCore` (see its module doc for the
handshake); this shell only moves data in and out:

* in: the PLC's writes and heartbeat time, the register image, the stations' latched
  fault, the running cycle's step or its outcome, the results of last scan's drive reset
  and recipe refresh;
* out: status bits and registers; actions — start a cycle (with an atomic snapshot of
  the recipe), cancel it (the cycle is *given* the reason), quick-stop every joint, reset
  the drives, re-read the recipes (auditing every change).
"""
from __future__ import annotations

from cell.clock import Clock, MonotonicClock
from cell.controller_core import (CancelCycle, ControllerCore, ControllerSettings, DrivesResetIn,
                                  QuickStop, RecipesIn, RefreshRecipes, ResetDrives, ScanInputs,
                                  StartCycle, StationFaultIn)
from cell.cycle import CancelToken, CycleOutcome, CycleRunner
from cell.cyclelog import CycleLog
from cell.faults import station_fault
from cell.log import get_logger
from cell.recipes import ActiveRecipe, AuditEntry, RecipeStore
from cell.statemachine import State, StateMachine

log = get_logger("controller")

__all__ = ["CellController", "ControllerSettings"]


class CellController:
    """Owns the core and the scan task; devices are injected."""

    def __init__(self, plc, motion, runner: CycleRunner, cyclelog: CycleLog, recipes: RecipeStore,
                 settings: ControllerSettings = ControllerSettings(), clock: Clock | None = None):
        self.plc, self.motion, self.runner, self.log, self.recipes = plc, motion, runner, cyclelog, recipes
        self.settings = settings
        self.clock = clock or MonotonicClock()
        self.core = ControllerCore(settings)
        self.recalibration_due = False
        self.scans = 0
        self._worker = None
        self._cancel: CancelToken | None = None
        self._drives_reset: DrivesResetIn | None = None
        self._recipes_in = RecipesIn()
        self._stop = self.clock.event()
        self._task = None

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
        """Read the recipes, come up in IDLE (nothing moves), start the scan task."""
        self._refresh_recipes()
        out = self.core.started(self.clock.now(), self._recipes_in)
        self._write(out.status, out.registers)
        self._task = self.clock.spawn(self._run, "cell-scan")
        log.info("controller_started", recipes=sorted(self.recipes.active))

    def stop(self) -> None:
        """Stop the scan loop; a running cycle is cancelled and the joints quick-stopped."""
        self._apply(self.core.shutdown())
        self._stop.set()
        if self._task is not None:
            self._task.join(timeout=5)
        if self._worker is not None:
            self._worker.join(timeout=10)

    def _run(self) -> None:
        next_t = self.clock.now()
        while not self._stop.is_set():
            try:
                self.scan()
            except Exception as exc:             # noqa: BLE001 -- the loop must not die silently
                log.exception("scan_failed", error=repr(exc))
            next_t += self.settings.scan_s
            if next_t < self.clock.now():        # overran: keep the period, skip the lost scans
                next_t = self.clock.now()
            self._stop.wait(next_t - self.clock.now())

    # ------------------------------------------------------------------ one scan
    def scan(self) -> None:
        """Read inputs, step the core, write outputs, act."""
        self.scans += 1
        out = self.core.step(self._read())
        self._write(out.status, out.registers)
        self._apply(out.actions)

    def _read(self) -> ScanInputs:
        ended = None
        if self._worker is not None and self._worker.finished:
            ended = self.runner.outcome
            self._worker = None
        reset, self._drives_reset = self._drives_reset, None
        recipes, self._recipes_in = self._recipes_in, RecipesIn(self._recipes_in.numbers)
        return ScanInputs(
            now=self.clock.now(), writes=tuple(self.plc.drain_writes()),
            last_heartbeat_change=self.plc.last_heartbeat_change,
            command_word=self.plc.read("command_word"), part_id=self.plc.read("part_id"),
            station_fault=self._station_fault(),
            cycle_step=self.runner.progress if self._worker is not None else None,
            cycle_ended=ended, drives_reset=reset, recipes=recipes,
            recalibration_due=self.recalibration_due)

    def _station_fault(self) -> StationFaultIn | None:
        rec = getattr(self.motion, "fault", None)
        if rec is None:
            return None
        requested = getattr(rec.code, "name", "") == "QUICK_STOP"     # we asked for it
        return StationFaultIn(station_fault(rec.code), str(rec), requested)

    def _write(self, status: dict, registers: dict) -> None:
        self.plc.set_bits("status_word", **status)
        self.plc.write_many(registers)

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
            elif isinstance(a, ResetDrives):
                self._reset_drives(a.purpose)
            elif isinstance(a, RefreshRecipes):
                self._refresh_recipes()

    def _start_cycle(self, a: StartCycle) -> None:
        active: ActiveRecipe | None = self.recipes.by_number(a.recipe_number)
        self._cancel = CancelToken(self.clock)
        cancel = self._cancel
        self.runner.progress = State.APPROACH     # not the last cycle's step while this one starts
        if active is None:                       # the core saw it active: cannot happen
            cancel.cancel(0, f"recipe {a.recipe_number} vanished")
        self._worker = self.clock.spawn(self.runner.run_safely, "cell-cycle", active, a.part_id, cancel)
        log.info("cycle_task_started", part_id=a.part_id, recipe=getattr(getattr(active, "recipe", None), "name", None))

    def _quick_stop(self, why: str) -> None:
        try:
            self.motion.quick_stop_all(why)
        except Exception as exc:                   # noqa: BLE001 -- stations may be gone already
            log.error("quick_stop_failed", error=repr(exc))

    def _reset_drives(self, purpose: str) -> None:
        try:
            self.motion.reset()
        except Exception as exc:                   # noqa: BLE001 -- the cause persists
            self._drives_reset = DrivesResetIn(purpose, False, str(exc))
        else:
            self._drives_reset = DrivesResetIn(purpose, True)

    # ------------------------------------------------------------------ recipes
    def _refresh_recipes(self) -> None:
        try:
            entries = self.recipes.refresh()
        except Exception as exc:                   # noqa: BLE001 -- e.g. directory gone: keep the last good set
            log.error("recipe_refresh_failed", error=str(exc))
            entries = []
        for e in entries:
            self._audit(e)
        numbers = frozenset(a.recipe.number for a in self.recipes.active.values())
        self._recipes_in = RecipesIn(numbers, refreshed=True, changed=bool(entries),
                                     rejected=any(e.action == "reject" for e in entries))

    def _audit(self, e: AuditEntry) -> None:
        try:
            self.log.audit(e.who, f"recipe_{e.action}", e.target, e.hash, e.result)
            if e.action == "activate":
                a = self.recipes.active.get(e.recipe)
                if a is not None:
                    self.log.remember_recipe(a.recipe.name, a.hash, a.text)
        except Exception as exc:                   # noqa: BLE001
            log.error("audit_write_failed", error=repr(exc))
