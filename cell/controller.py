"""The cell controller's scan loop: read the PLC, step the state machine, write the PLC.

One thread ("cell-scan") runs :meth:`CellController.scan` every ``scan_s``; a part's cycle
runs in a second thread ("cell-cycle", :class:`~cell.cycle.CycleRunner`) so the scan loop
keeps serving the PLC, the heartbeat watchdog and abort while joints move.

Handshake (PLCopen Execute/Busy/Done/Error over the register map):

* ``execute`` starts a cycle only on a rising edge seen while the PLC heartbeat is alive
  and after ``execute`` was seen low with the link alive: written low by the PLC, or low in
  the register image once the link has been alive for ``arm_grace_s`` (an execute held high
  across a heartbeat gap, a reconnect or a controller restart starts nothing). The edge latches the
  active recipe and ``part_id``. An edge while not ready sets ``execute_refused``.
* ``done``/``aborted`` are held until ``acknowledge``; ``error`` until ``reset``.
* PLC heartbeat lost for longer than ``plc_heartbeat_timeout_s`` — also mid-cycle —, a
  joint-station fault, or a failed cycle step: every joint gets a CiA 402 quick stop
  (category 2; the emergency stop stays hard-wired), the fault code goes to the PLC and
  nothing moves again until ``reset``. An interrupted cycle is logged as aborted.
* Recipe files are re-read only between cycles (atomic swap in the recipe store); an
  invalid edit is rejected (recipe_status 2), the last good version stays active, and every
  change is written to the audit table.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from cell.clock import Clock, MonotonicClock
from cell.cycle import CycleOutcome, CycleRunner
from cell.cyclelog import CycleLog
from cell.faults import Fault, station_fault
from cell.log import get_logger
from cell.recipes import ActiveRecipe, AuditEntry, RecipeStore
from cell.statemachine import Event, State, StateMachine

log = get_logger("controller")

EXECUTE, RESET, ABORT, ACK = 1, 2, 4, 8        # command_word bits (drivers/plc/register_map.py)
RECIPE_OK, RECIPE_UNKNOWN, RECIPE_REJECTED, RECIPE_BUSY = 0, 1, 2, 3


@dataclass(frozen=True)
class ControllerSettings:
    scan_s: float = 0.01
    plc_heartbeat_timeout_s: float = 1.0
    recipe_refresh_s: float = 1.0
    arm_grace_s: float = 0.3


class CellController:
    """Owns the state machine and the PLC handshake. Devices are injected (STYLE habit 2)."""

    def __init__(self, plc, motion, runner: CycleRunner, cyclelog: CycleLog, recipes: RecipeStore,
                 settings: ControllerSettings = ControllerSettings(), clock: Clock | None = None):
        self.plc, self.motion, self.runner, self.log, self.recipes = plc, motion, runner, cyclelog, recipes
        self.settings = settings
        self.clock = clock or MonotonicClock()
        self.sm: StateMachine = runner.sm
        self.fault_code = 0
        self.fault_text = ""
        self.recalibration_due = False
        self.execute_refused = False
        self.cycle_count = 0
        self.last_outcome: CycleOutcome | None = None
        self._recipe_number = 0
        self._recipe_status = RECIPE_OK
        self._pending_select: int | None = None
        self._armed = False
        self._link_ok = False
        self._link_since = 0.0
        self._heartbeat = 0
        self._worker: threading.Thread | None = None
        self._outcome: CycleOutcome | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_refresh = 0.0
        self.scans = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Read the recipes, come up in IDLE (nothing moves), start the scan thread."""
        self._refresh_recipes()
        self.sm.fire(Event.STARTED)
        self._write_outputs()
        self._thread = threading.Thread(target=self._run, name="cell-scan", daemon=True)
        self._thread.start()
        log.info("controller_started", recipes=sorted(self.recipes.active))

    def stop(self) -> None:
        """Stop the scan loop; a running cycle is cancelled and the joints quick-stopped."""
        if self.sm.state.busy:
            self._fault(Fault.INTERNAL, "controller shutting down")
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=5)
        if self._worker:
            self._worker.join(timeout=10)

    def _run(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.scan()
            except Exception as exc:             # noqa: BLE001 -- the loop must not die silently
                log.exception("scan_failed", error=repr(exc))
                self._fault(Fault.INTERNAL, f"scan failed: {exc!r}")
            self._stop.wait(max(0.0, self.settings.scan_s - (time.monotonic() - t0)))

    # ------------------------------------------------------------------ one scan
    def scan(self) -> None:
        """Read inputs, update the state machine, write outputs (STYLE habit 5)."""
        now = self.clock.now()
        self.scans += 1
        writes = self.plc.drain_writes()
        last_hb = self.plc.last_heartbeat_change
        link_ok = last_hb is not None and now - last_hb <= self.settings.plc_heartbeat_timeout_s
        if self._link_ok and not link_ok:
            log.warning("plc_heartbeat_lost", timeout_s=self.settings.plc_heartbeat_timeout_s)
            self._fault(Fault.PLC_HEARTBEAT_LOST, "PLC heartbeat lost for more than "
                        f"{self.settings.plc_heartbeat_timeout_s} s")
        if not link_ok:
            self._armed = False
        elif not self._link_ok:
            self._link_since = now
        self._link_ok = link_ok

        station = getattr(self.motion, "fault", None)
        ours = station is not None and getattr(station.code, "name", "") == "QUICK_STOP"  # we asked for it
        if station is not None and not ours and \
                self.sm.state not in (State.FAULT, State.STOPPING, State.RESETTING):
            self._fault(station_fault(station.code), f"joint stations: {station}")

        self._finish_cycle_if_ended()
        for w in writes:                           # in the order the PLC wrote them
            if w.name == "recipe_select":
                self._pending_select = w.value
            if self._pending_select is not None and not self.sm.state.busy:
                self._select_recipe(self._pending_select)
                self._pending_select = None
            if w.name == "command_word" and link_ok:
                self._on_command(w.value & ~w.previous, w.value)
        if self._pending_select is not None:
            self._recipe_status = RECIPE_BUSY
        # execute low in the image, with the link alive for a grace time: long enough for a PLC
        # that rewrites its outputs after a reconnect to have done so (a fresh register image
        # after a controller restart reads 0 while the PLC may still hold execute high)
        if link_ok and now - self._link_since >= self.settings.arm_grace_s \
                and not self.plc.read("command_word") & EXECUTE:
            self._armed = True
        if not self.sm.state.busy and now >= self._next_refresh:
            self._next_refresh = now + self.settings.recipe_refresh_s
            self._refresh_recipes()
        self._write_outputs()

    # ------------------------------------------------------------------ commands
    def _on_command(self, rising: int, value: int) -> None:
        state = self.sm.state
        if rising & ABORT and state.busy and state is not State.STOPPING:
            self.runner.request_cancel(0, "abort by PLC")
            self.sm.fire(Event.ABORT)
            self.motion.quick_stop_all("abort by PLC")
            log.info("cycle_abort_requested")
        if rising & RESET and state is State.FAULT:
            self._reset()
        if rising & ACK and state in (State.DONE, State.ABORTED):
            if state is State.ABORTED:
                self._rearm_drives()
            self.sm.fire(Event.ACKNOWLEDGE)
            self.execute_refused = False
        if rising & EXECUTE:
            if self._armed and self.sm.state is State.IDLE:
                self._start_cycle()
            else:
                self.execute_refused = True
                why = "not armed (execute must be written low while the PLC link is alive)" \
                    if not self._armed else f"state {self.sm.state.name}"
                log.warning("execute_refused", reason=why)
        if not value & EXECUTE:                    # the PLC wrote execute low: armed
            self._armed = True

    def _start_cycle(self) -> None:
        active: ActiveRecipe | None = self.recipes.by_number(self._recipe_number)
        if active is None:                         # nothing moved: refuse, no fault to reset
            self.execute_refused = True
            log.warning("execute_refused", reason=f"recipe {self._recipe_number} is not active")
            return
        part_id = self.plc.read("part_id")
        self.plc.write("part_id_echo", part_id)
        self.execute_refused = False
        self._outcome = None
        self.runner.clear_cancel()
        self.sm.fire(Event.EXECUTE)
        self._worker = threading.Thread(target=self._work, args=(active, part_id), name="cell-cycle",
                                        daemon=True)
        self._worker.start()
        log.info("cycle_started", part_id=part_id, recipe=active.recipe.name)

    def _work(self, active: ActiveRecipe, part_id: int) -> None:
        self._outcome = self.runner.run(active, part_id)

    def _finish_cycle_if_ended(self) -> None:
        if self._worker is None or self._worker.is_alive():
            return
        self._worker = None
        out, self._outcome = self._outcome, None
        self.last_outcome = out
        if out is None:
            self._fault(Fault.INTERNAL, "cycle worker ended without an outcome")
            return
        self._publish_results(out)
        state = self.sm.state
        if out.status == "done" and state is State.DONE:
            self.cycle_count += 1
            self.plc.write("cycle_count", self.cycle_count & 0xFFFFFFFF)
            return
        if state is State.STOPPING:
            self._stopped()
            return
        self._fault(out.fault_code or Fault.INTERNAL, out.fault_text or "cycle failed")

    def _publish_results(self, out: CycleOutcome) -> None:
        rec = out.record
        if rec is None:
            return
        final = rec.verify_error_mm if rec.verify_error_mm is not None else rec.final_error_mm

        def um(v):
            return 0 if v is None else min(int(round(v * 1000)), 0xFFFFFFFF)
        self.plc.write_many({"initial_error_um": um(rec.initial_error_mm), "final_error_um": um(final),
                             "moves": rec.moves or 0,
                             "cycle_time_ms": min(int((rec.cycle_time_s + out.log_write_s) * 1000),
                                                  0xFFFFFFFF)})

    # ------------------------------------------------------------------ faults
    def _fault(self, code: int, text: str) -> None:
        """Latch a fault (the first one wins until reset) and stop every joint under control."""
        state = self.sm.state
        if state is State.FAULT:
            log.warning("further_fault_while_latched", code=int(code), detail=text)
            return
        if self.fault_code == 0:
            self.fault_code, self.fault_text = int(code), text
        log.error("fault", code=int(code), detail=text, state=state.name)
        if state.busy and state is not State.STOPPING:
            self.runner.request_cancel(code, text)
        if state is State.STARTING or state is State.RESETTING:
            self.sm.fire(Event.FAULT)
            return
        if state is not State.STOPPING:
            self.sm.fire(Event.FAULT)
        self._quick_stop(text)
        if self._worker is None:                   # no cycle to wind down: stopped now
            self.sm.fire(Event.STOPPED_FAULT)

    def _quick_stop(self, why: str) -> None:
        try:
            self.motion.quick_stop_all(why)
        except Exception as exc:                   # noqa: BLE001 -- stations may be gone already
            log.error("quick_stop_failed", error=repr(exc))

    def _stopped(self) -> None:
        """The cycle worker has ended after STOPPING: settle in FAULT or ABORTED."""
        if self.fault_code:
            self.sm.fire(Event.STOPPED_FAULT)
        else:
            self.sm.fire(Event.STOPPED_ABORT)

    def _rearm_drives(self) -> None:
        try:
            self.motion.reset()
        except Exception as exc:                   # noqa: BLE001
            self._fault(Fault.STATION, f"drives could not be re-enabled after abort: {exc}")

    def _reset(self) -> None:
        if not self._link_ok:
            log.warning("reset_refused", reason="PLC link not alive")
            return
        self.sm.fire(Event.RESET)
        try:
            self.motion.reset()
        except Exception as exc:                   # noqa: BLE001 -- the cause persists: stay in FAULT
            log.error("reset_failed", error=str(exc))
            self.sm.fire(Event.FAULT)
            return
        self.fault_code, self.fault_text = 0, ""
        self.execute_refused = False
        self.sm.fire(Event.RESET_DONE)
        log.info("reset_done")

    # ------------------------------------------------------------------ recipes
    def _select_recipe(self, number: int) -> None:
        if number == 0:
            return
        if self.recipes.by_number(number) is None:
            self._recipe_status = RECIPE_UNKNOWN
            log.warning("recipe_select_unknown", number=number)
            return
        self._recipe_number = number
        self._recipe_status = RECIPE_OK

    def _refresh_recipes(self) -> None:
        try:
            entries = self.recipes.refresh()
        except Exception as exc:                   # noqa: BLE001 -- e.g. directory gone: keep the last good set
            log.error("recipe_refresh_failed", error=str(exc))
            return
        for e in entries:
            self._audit(e)
        if any(e.action == "reject" for e in entries):
            self._recipe_status = RECIPE_REJECTED
        elif entries and self._recipe_status == RECIPE_REJECTED:
            self._recipe_status = RECIPE_OK
        if self.recipes.by_number(self._recipe_number) is None and self._recipe_number:
            self._recipe_status = RECIPE_UNKNOWN

    def _audit(self, e: AuditEntry) -> None:
        try:
            self.log.audit(e.who, f"recipe_{e.action}", e.target, e.hash, e.result)
            if e.action == "activate":
                a = self.recipes.active.get(e.recipe)
                if a is not None:
                    self.log.remember_recipe(a.recipe.name, a.hash, a.text)
        except Exception as exc:                   # noqa: BLE001
            log.error("audit_write_failed", error=repr(exc))

    # ------------------------------------------------------------------ outputs
    def _write_outputs(self) -> None:
        state = self.sm.state
        self._heartbeat = (self._heartbeat + 1) & 0xFFFF
        bits = dict(
            ready=state is State.IDLE and self._link_ok and self._armed and self.fault_code == 0,
            busy=state.busy, done=state is State.DONE,
            error=state in (State.FAULT, State.RESETTING) or self.fault_code != 0,
            auto=True, homed=state is not State.STARTING,
            recalibration_due=self.recalibration_due, aborted=state is State.ABORTED,
            plc_link_ok=self._link_ok, execute_refused=self.execute_refused)
        self.plc.set_bits("status_word", **bits)
        self.plc.write_many({"controller_heartbeat": self._heartbeat, "state_code": int(state),
                             "fault_code": self.fault_code, "recipe_ack": self._recipe_number,
                             "recipe_status": self._recipe_status})
