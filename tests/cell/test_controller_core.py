"""ControllerCore: every transition and fault path of the controller's pure step.

No threads, no I/O: a made-up clock (plain numbers for ``now``) and made-up PLC writes.
:class:`Cell` plays the controller shell and a PLC: it steps the core every ``scan_s``, keeps
the PLC heartbeat alive unless told not to, keeps the register image of ``command_word`` and
``part_id`` in step with the writes, and feeds the results of last scan's requests back the
way :class:`cell.controller.CellController` does (as ScanInputs of the next step).

Times are dyadic fractions (scan 1/16 s) so that every ``now`` is exact and the tests can
name the exact scan at which something must happen.
"""
from dataclasses import replace

import pytest

from cell.controller.core import (ABORT, ACK, EXECUTE, RESET, Audit, CancelCycle, ClearInterrupted,
                                  ControllerCore, ControllerSettings, DrivesResetIn, PlcWriteIn,
                                  QuickStop, RecipesIn, RefreshRecipes, ResetDrives, ScanInputs,
                                  SettleCycle, StartCalibration, StartCycle, StationFaultIn)
from cell.cycle.runner import CycleOutcome
from cell.cycle.statemachine import CYCLE_STEPS, State
from cell.cyclelog import CycleRecord
from cell.faults import Fault
from drivers.plc.register_map import PLC_MAP

S = ControllerSettings(scan_s=0.0625, plc_heartbeat_timeout_s=1.0, recipe_refresh_s=64.0)
T0 = 100.0
HB_TEXT = "PLC heartbeat lost for more than 1.0 s"
ABORT_TEXT = "abort by PLC"
STATUS_BITS = {b.name for b in PLC_MAP["status_word"].bits}
BASE_REGISTERS = {"controller_heartbeat", "state_code", "fault_code", "recipe_ack", "recipe_status",
                  "calibration_version", "plant_backlog"}


def cw(value: int, previous: int) -> PlcWriteIn:
    return PlcWriteIn("command_word", value, previous)


class Cell:
    """One core driven scan by scan on a made-up clock (see the module doc)."""

    def __init__(self, settings: ControllerSettings = S, numbers=(1, 2), t0: float = T0,
                 heartbeat: bool = True, command_word: int = 0, rejected: bool = False):
        self.s = settings
        self.core = ControllerCore(settings)
        self.now = t0
        self.heartbeat = heartbeat            #: the PLC changes plc_heartbeat every scan
        self.last_hb: float | None = None
        self.command_word = command_word      #: register image
        self.part_id = 0                      #: register image
        self.calibration_select = 0           #: register image
        self.numbers = frozenset(numbers)
        self.out = self.core.started(t0, RecipesIn(self.numbers, refreshed=True, rejected=rejected))
        self.audits: list[Audit] = []         #: audit rows asked for, kept apart from the actions

    @property
    def state(self) -> State:
        return self.core.sm.state

    @property
    def actions(self) -> list:
        return self.out.actions

    def scan(self, *writes, dt: float | None = None, **inputs):
        """Advance the clock by one scan (or ``dt``) and step the core once."""
        self.now += self.s.scan_s if dt is None else dt
        if self.heartbeat:
            self.last_hb = self.now
        for w in writes:                               # the image holds what the PLC wrote
            if w.name == "command_word":
                self.command_word = w.value
            elif w.name == "part_id":
                self.part_id = w.value
            elif w.name == "calibration_select":
                self.calibration_select = w.value
        inputs.setdefault("recipes", RecipesIn(self.numbers))
        self.out = self.core.step(ScanInputs(
            now=self.now, writes=tuple(writes), last_heartbeat_change=self.last_hb,
            command_word=self.command_word, part_id=self.part_id,
            calibration_select=self.calibration_select, **inputs))
        check_map(self.out)
        self.audits += [a for a in self.out.actions if isinstance(a, Audit)]
        self.out.actions = [a for a in self.out.actions if not isinstance(a, Audit)]
        return self.out

    def scans(self, n: int, **inputs) -> list:
        return [self.scan(**inputs) for _ in range(n)]

    def command(self, value: int, **inputs):
        """The PLC writes ``command_word`` = value (previous = the image)."""
        return self.scan(cw(value, self.command_word), **inputs)

    def select(self, number: int, **inputs):
        return self.scan(PlcWriteIn("recipe_select", number, 0), **inputs)

    def lose_link(self, **inputs):
        """The PLC heartbeat stops; scan once past the time-out."""
        self.heartbeat = False
        return self.scan(dt=self.s.plc_heartbeat_timeout_s + self.s.scan_s, **inputs)

    def refresh(self, numbers=None, **flags):
        if numbers is not None:
            self.numbers = frozenset(numbers)
        return self.scan(recipes=RecipesIn(self.numbers, refreshed=True, **flags))


def check_map(out) -> None:
    """Every output is a status_word bit or a register of the map, in its range."""
    assert set(out.status) == STATUS_BITS
    assert all(isinstance(v, bool) for v in out.status.values())
    assert BASE_REGISTERS <= set(out.registers)
    for name, value in out.registers.items():
        assert PLC_MAP[name].access.value == "RO", name
        PLC_MAP.check(name, value)


def ready_cell(**kw) -> Cell:
    """Link up, execute written low (armed), recipe 1 selected: ready."""
    c = Cell(**kw)
    c.scan()
    c.command(0)
    c.select(1)
    assert c.out.status["ready"] and c.core.recipe_number == 1 and c.out.actions == []
    return c


def start(c: Cell, part_id: int = 4711):
    c.scan(PlcWriteIn("part_id", part_id, c.part_id))
    out = c.command(EXECUTE)
    assert out.actions == [StartCycle(1, part_id)]
    assert c.state is State.APPROACH
    return out


def at_step(step: State, **kw) -> Cell:
    c = ready_cell(**kw)
    start(c)
    c.scan(cycle_step=step)
    assert c.state is step
    return c


def record(**kw) -> CycleRecord:
    base = dict(part_id=4711, recipe="bracket-a", recipe_hash="h", started_at="s", finished_at="f",
                status="done", cycle_time_s=2.5, initial_error_mm=0.0424, final_error_mm=0.0126,
                verify_error_mm=0.0186, moves=3)
    base.update(kw)
    return CycleRecord(**base)


SETTLED_DONE = SettleCycle("s", None, "done", 0, "")


def done(**kw) -> CycleOutcome:
    return CycleOutcome("done", record=record(**kw), log_write_s=0.25)


def done_cell(**kw) -> Cell:
    c = at_step(State.VERIFY, **kw)
    c.scan(cycle_ended=done())
    assert c.state is State.DONE
    return c


def aborted_cell() -> Cell:
    c = at_step(State.LOCATE)
    c.command(EXECUTE | ABORT)
    c.scan(cycle_ended=CycleOutcome("aborted", 0, ABORT_TEXT))
    assert c.state is State.ABORTED
    return c


def fault_cell(code: int = 204) -> Cell:
    c = ready_cell()
    c.scan(station_fault=StationFaultIn(code, "limit"))
    assert c.state is State.FAULT and c.core.fault_code == code
    return c


# ------------------------------------------------------------------------------ start-up
def test_started_goes_idle_with_nothing_moving_and_map_outputs():
    core = ControllerCore(S)
    assert core.sm.state is State.STARTING
    out = core.started(T0, RecipesIn(frozenset({1, 2}), refreshed=True))
    assert core.sm.state is State.IDLE
    assert out.actions == []
    assert out.status == dict(ready=False, busy=False, done=False, error=False, auto=True, homed=True,
                              recalibration_due=False, aborted=False, plc_link_ok=False,
                              execute_refused=False)
    assert out.registers == dict(controller_heartbeat=1, state_code=2, fault_code=0, recipe_ack=0,
                                 recipe_status=0, calibration_version=0, plant_backlog=0)
    check_map(out)


def test_startup_with_a_rejected_recipe_file_reports_status_2():
    c = Cell(rejected=True)
    assert c.out.registers["recipe_status"] == 2
    assert c.scan().registers["recipe_status"] == 2


def test_controller_heartbeat_increments_every_step_and_wraps():
    c = Cell()
    assert c.out.registers["controller_heartbeat"] == 1
    beats = [c.scan().registers["controller_heartbeat"] for _ in range(5)]
    assert beats == [2, 3, 4, 5, 6]
    assert c.core.shutdown() == []                   # not a step: no heartbeat
    assert c.scan().registers["controller_heartbeat"] == 7
    beats = [c.scan().registers["controller_heartbeat"] for _ in range(0x10000 - 6)]   # 7 → 1
    assert beats[-3:] == [0xFFFF, 0, 1]               # 16 bits: wraps to 0 after 65 535
    assert beats == [(8 + k) & 0xFFFF for k in range(len(beats))]


def test_the_plant_backlog_is_passed_through_within_the_registers_range():
    c = Cell()
    assert c.scan(plant_backlog=7).registers["plant_backlog"] == 7
    assert c.scan(plant_backlog=2 ** 40).registers["plant_backlog"] == 2 ** 32 - 1
    assert c.scan().registers["plant_backlog"] == 0


def test_recalibration_due_is_passed_through():
    c = Cell()
    assert c.scan(recalibration_due=True).status["recalibration_due"] is True
    assert c.scan().status["recalibration_due"] is False


def test_first_recipe_refresh_only_after_recipe_refresh_s_then_periodic():
    c = Cell(settings=replace(S, recipe_refresh_s=2.0))
    hits = [k for k in range(1, 100) if c.scan().actions]
    assert hits == [32, 64, 96]                       # now = T0 + 2.0, + 4.0, + 6.0


def test_no_recipe_refresh_during_a_cycle_then_at_once_when_it_ends():
    c = ready_cell(settings=replace(S, recipe_refresh_s=1.0))
    start(c)
    outs = c.scans(40, cycle_step=State.CAPTURE)      # 2.5 s: due long ago
    assert all(o.actions == [] for o in outs)
    out = c.scan(cycle_ended=done())
    assert c.state is State.DONE
    assert out.actions == [SETTLED_DONE, RefreshRecipes()]
    assert c.scan().actions == []


# ------------------------------------------------------------------------------ PLC link
def test_link_ok_only_after_a_heartbeat_change():
    c = Cell(heartbeat=False)
    for out in c.scans(40):                           # 2.5 s without any heartbeat change
        assert out.status["plc_link_ok"] is False and out.status["ready"] is False
    assert c.state is State.IDLE and c.core.fault_code == 0
    c.last_hb = T0 - 5.0                              # a change long ago: still no link, no fault
    assert c.scan().status["plc_link_ok"] is False and c.state is State.IDLE
    c.heartbeat = True
    out = c.scan()
    assert out.status["plc_link_ok"] is True and c.core.link_ok
    assert out.actions == [] and c.core.fault_code == 0


def test_commands_are_ignored_while_the_link_is_down():
    c = Cell(heartbeat=False)
    c.scan(PlcWriteIn("recipe_select", 1, 0))
    out = c.command(0)
    out = c.command(EXECUTE)
    assert out.actions == [] and out.status["execute_refused"] is False
    assert c.state is State.IDLE


@pytest.mark.parametrize("phase, first_k", [
    (0.0, 17), (1 / 64, 16), (1 / 32, 16), (3 / 64, 16), (1 / 16 - 1 / 1024, 16)])
def test_heartbeat_loss_faults_at_the_first_scan_after_the_timeout(phase, first_k):
    c = ready_cell()
    c.scans(3)
    hb = c.last_hb
    c.heartbeat = False
    times = [hb + phase + k * S.scan_s for k in range(1, 30)]
    faulted = []
    for t in times:
        out = c.scan(dt=t - c.now)
        faulted.append(out.registers["fault_code"] == Fault.PLC_HEARTBEAT_LOST)
    k = faulted.index(True)
    assert k + 1 == first_k
    assert all(faulted[k:])
    assert times[k] - hb > S.plc_heartbeat_timeout_s                   # not earlier
    assert times[k] - hb <= S.plc_heartbeat_timeout_s + S.scan_s        # at most one scan late
    assert times[k - 1] - hb <= S.plc_heartbeat_timeout_s


def test_heartbeat_loss_boundary_is_strictly_after_the_timeout():
    c = ready_cell()
    hb = c.last_hb
    c.heartbeat = False
    out = c.scan(dt=hb + S.plc_heartbeat_timeout_s - c.now)           # exactly the time-out
    assert out.status["plc_link_ok"] is True and c.core.fault_code == 0 and out.actions == []
    out = c.scan(dt=1e-9)
    assert c.core.fault_code == Fault.PLC_HEARTBEAT_LOST
    assert out.status["plc_link_ok"] is False


def test_heartbeat_loss_while_idle_faults_at_once_with_quick_stop():
    c = ready_cell()
    out = c.lose_link()
    assert out.actions == [QuickStop(HB_TEXT)]
    assert c.state is State.FAULT
    assert (c.core.fault_code, c.core.fault_text) == (101, HB_TEXT)
    assert c.core.fault_at == c.now
    assert out.status["error"] and not out.status["ready"] and not out.status["plc_link_ok"]
    assert out.registers["fault_code"] == 101 and out.registers["state_code"] == 40
    assert c.scan().actions == []                     # still lost: latched, nothing more


@pytest.mark.parametrize("step", CYCLE_STEPS)
def test_heartbeat_loss_mid_cycle_cancels_stops_then_faults_when_the_cycle_ends(step):
    c = at_step(step)
    out = c.lose_link()
    assert out.actions == [CancelCycle(101, HB_TEXT), QuickStop(HB_TEXT)]
    assert c.state is State.STOPPING
    assert out.status["busy"] and out.status["error"] and not out.status["done"]
    assert out.registers["fault_code"] == 101 and out.registers["state_code"] == 30
    assert c.scan(cycle_step=State.LOGGING).actions == [] and c.state is State.STOPPING
    out = c.scan(cycle_ended=CycleOutcome("aborted", 101, HB_TEXT))
    assert c.state is State.FAULT and c.core.fault_code == 101
    assert out.actions == [] and not out.status["busy"] and out.status["error"]


@pytest.mark.parametrize("make", [done_cell, aborted_cell])
def test_heartbeat_loss_while_done_or_aborted_faults(make):
    c = make()
    out = c.lose_link()
    assert out.actions == [QuickStop(HB_TEXT)]
    assert c.state is State.FAULT and c.core.fault_code == 101
    assert not out.status["done"] and not out.status["aborted"]


def test_link_comes_back_after_a_heartbeat_fault_but_the_fault_stays():
    c = ready_cell()
    c.lose_link()
    c.heartbeat = True
    out = c.scan()
    assert out.status["plc_link_ok"] is True
    assert c.state is State.FAULT and c.core.fault_code == 101 and out.status["error"]
    assert not out.status["ready"]


# ------------------------------------------------------------------------------ arming
def test_execute_low_in_the_image_never_arms_by_itself():
    """Field probe: after a restart the PLC resumed its heartbeat first and rewrote its held
    execute 0.5 s later; a grace time had armed the controller, and the robot moved."""
    c = Cell()
    c.select(1)                                       # link up at this scan
    for out in c.scans(int(0.5 / S.scan_s)):          # 0.5 s of heartbeat, execute low in the image
        assert out.status["ready"] is False
    out = c.command(EXECUTE)                          # the PLC rewrites its held execute
    assert out.actions == [] and out.status["execute_refused"] is True
    assert c.state is State.IDLE
    c.command(0)                                      # written low: armed ...
    assert c.out.status["ready"] is True
    assert c.command(EXECUTE).actions == [StartCycle(1, 0)]   # ... and a fresh edge starts


def test_execute_written_low_arms_at_once():
    c = Cell()
    c.scan()
    assert c.scan().status["ready"] is False
    assert c.command(0).status["ready"] is True


def test_execute_low_then_high_in_one_scan_starts_in_plc_order():
    c = Cell()
    c.select(1)
    out = c.scan(cw(0, 0), cw(EXECUTE, 0))
    assert out.actions == [StartCycle(1, 0)] and c.state is State.APPROACH


def test_execute_held_high_at_startup_starts_nothing():
    c = Cell(command_word=EXECUTE)
    c.select(1)
    for out in c.scans(20):                           # well past the grace time
        assert out.status["ready"] is False
    out = c.scan(cw(EXECUTE, EXECUTE))                # the PLC rewrites its outputs: no edge
    assert out.actions == [] and out.status["execute_refused"] is False
    out = c.scan(cw(EXECUTE, 0))                      # an edge, but execute never seen low
    assert out.actions == [] and out.status["execute_refused"] is True
    assert c.state is State.IDLE
    out = c.command(0)
    assert out.status["ready"] is True
    assert c.command(EXECUTE).actions == [StartCycle(1, 0)]
    assert c.out.status["execute_refused"] is False


def test_execute_held_high_across_a_link_gap_starts_nothing():
    c = ready_cell()
    c.command(EXECUTE)                                # a cycle ... that faults
    c.scan(cycle_ended=CycleOutcome("aborted", 403, "timeout"))
    c.command(EXECUTE | RESET)
    c.scan(drives_reset=DrivesResetIn("reset", True))
    assert c.state is State.IDLE and c.out.status["ready"] is True   # armed from before
    c.lose_link()
    assert c.command(0).actions == []                 # written during the gap: ignored
    assert c.command(EXECUTE).actions == []
    c.heartbeat = True
    c.scan()
    assert c.command(EXECUTE | RESET).actions == [ResetDrives("reset")]
    out = c.scan(cw(EXECUTE, EXECUTE | RESET), drives_reset=DrivesResetIn("reset", True))
    assert c.state is State.IDLE and c.core.fault_code == 0
    for out in c.scans(20):                           # execute high in the image: never armed
        assert out.status["ready"] is False and out.actions == []
    out = c.scan(cw(EXECUTE, 0))
    assert out.actions == [] and out.status["execute_refused"] is True
    c.command(0)
    assert c.out.status["ready"] is True
    assert c.command(EXECUTE).actions == [StartCycle(1, 0)]


def test_execute_counts_on_the_rising_edge_only():
    c = ready_cell()
    out = c.scan(cw(EXECUTE, EXECUTE))
    assert out.actions == [] and not out.status["execute_refused"] and c.state is State.IDLE
    out = c.scan(cw(EXECUTE | ACK, EXECUTE))
    assert out.actions == [] and c.state is State.IDLE
    assert c.scan(cw(EXECUTE, 0)).actions == [StartCycle(1, 0)]


def test_ready_bit_conditions():
    c = Cell(heartbeat=False)
    assert c.scan().status["ready"] is False          # no link
    c.heartbeat = True
    assert c.scan().status["ready"] is False          # link, not armed
    assert c.command(0).status["ready"] is True       # armed, idle, no fault (no recipe needed)
    c.select(1)
    out = c.command(EXECUTE)
    assert out.status["ready"] is False and out.status["busy"] is True
    c.scan(cycle_ended=done())
    assert c.out.status["ready"] is False and c.out.status["done"] is True
    assert c.command(EXECUTE | ACK).status["ready"] is True
    c.scan(station_fault=StationFaultIn(204, "limit"))
    assert c.out.status["ready"] is False
    c.command(RESET)
    assert c.out.status["ready"] is False             # resetting
    assert c.scan(drives_reset=DrivesResetIn("reset", True)).status["ready"] is True
    c.lose_link()
    assert c.out.status["ready"] is False


# ------------------------------------------------------------------------------ execute
@pytest.mark.parametrize("make, state", [
    (lambda: at_step(State.APPROACH), State.APPROACH),
    (lambda: at_step(State.VERIFY), State.VERIFY),
    (done_cell, State.DONE), (aborted_cell, State.ABORTED), (fault_cell, State.FAULT)])
def test_execute_while_not_idle_is_refused(make, state):
    c = make()
    c.command(0)
    out = c.command(EXECUTE)
    assert out.actions == []
    assert out.status["execute_refused"] is True
    assert c.state is state


def test_execute_refused_is_cleared_by_acknowledge_reset_and_an_accepted_execute():
    c = done_cell()
    c.command(0)
    assert c.command(EXECUTE).status["execute_refused"] is True
    assert c.command(EXECUTE | ACK).status["execute_refused"] is False
    c = fault_cell()
    c.command(0)
    assert c.command(EXECUTE).status["execute_refused"] is True
    c.command(EXECUTE | RESET)
    assert c.out.status["execute_refused"] is True    # still resetting
    assert c.scan(drives_reset=DrivesResetIn("reset", True)).status["execute_refused"] is False
    c = ready_cell()
    c.refresh(numbers=(2,), changed=True)             # recipe 1 gone: refused
    c.command(EXECUTE)
    assert c.out.status["execute_refused"] is True
    c.command(0)
    c.select(2)
    assert c.command(EXECUTE).actions == [StartCycle(2, 0)]
    assert c.out.status["execute_refused"] is False


def test_execute_with_no_recipe_selected_is_refused_without_fault():
    c = Cell()
    c.scan()
    c.command(0)
    out = c.command(EXECUTE)
    assert out.actions == [] and out.status["execute_refused"] is True
    assert c.state is State.IDLE and c.core.fault_code == 0 and not out.status["error"]


def test_execute_with_an_inactive_recipe_is_refused_without_fault():
    c = ready_cell()
    out = c.refresh(numbers=(2,), changed=True)       # recipe 1's file was removed
    assert out.registers["recipe_status"] == 1 and out.registers["recipe_ack"] == 1
    out = c.command(EXECUTE)
    assert out.actions == [] and out.status["execute_refused"] is True
    assert c.state is State.IDLE and c.core.fault_code == 0
    assert out.status["ready"] is True and not out.status["error"]


def test_part_id_is_latched_at_the_edge_and_echoed():
    c = ready_cell()
    out = start(c, part_id=0xFFFFFFFF)
    assert out.registers["part_id_echo"] == 0xFFFFFFFF
    assert out.status["busy"] and not out.status["done"] and out.registers["state_code"] == 10
    out = c.scan(PlcWriteIn("part_id", 12, c.part_id))     # the next part's id, while busy
    assert "part_id_echo" not in out.registers and out.actions == []
    out = c.scan(cycle_ended=done(part_id=0xFFFFFFFF))
    assert "part_id_echo" not in out.registers        # the echo was written at the edge
    c.command(EXECUTE | ACK)
    c.command(0)
    out = c.command(EXECUTE)
    assert out.actions == [StartCycle(1, 12)] and out.registers["part_id_echo"] == 12


def test_part_id_written_after_the_edge_in_the_same_scan_is_not_latched():
    c = ready_cell()
    c.scan(PlcWriteIn("part_id", 7, 0))
    out = c.scan(cw(EXECUTE, 0), PlcWriteIn("part_id", 8, 7))   # next part's id, right after
    assert out.actions == [StartCycle(1, 7)]


# ------------------------------------------------------------------------------ cycle
def test_cycle_progress_moves_the_state_machine_step_by_step_and_several_at_once():
    c = ready_cell()
    start(c)
    seen = []
    for step in (State.CAPTURE, State.LOCATE):
        out = c.scan(cycle_step=step)
        seen.append((c.state, out.registers["state_code"]))
    assert seen == [(State.CAPTURE, 11), (State.LOCATE, 12)]
    assert c.scan(cycle_step=State.VERIFY).registers["state_code"] == 15        # 3 steps at once
    assert c.scan(cycle_step=State.CAPTURE).registers["state_code"] == 15       # never back
    assert c.scan(cycle_step=State.LOGGING).registers["state_code"] == 16
    assert c.out.actions == [] and c.out.status["busy"]


def test_cycle_progress_without_a_running_cycle_is_ignored():
    c = ready_cell()
    assert c.scan(cycle_step=State.CAPTURE).registers["state_code"] == 2
    assert c.state is State.IDLE


def test_done_cycle_publishes_results_then_acknowledge_returns_to_idle():
    c = at_step(State.CAPTURE)
    out = c.scan(cycle_ended=done())
    assert c.state is State.DONE and c.core.cycle_count == 1
    assert out.actions == [SETTLED_DONE]
    assert out.status["done"] and not out.status["busy"] and not out.status["error"]
    assert {k: v for k, v in out.registers.items() if k not in BASE_REGISTERS} == dict(
        initial_error_um=42, final_error_um=19, moves=3, cycle_time_ms=2750, cycle_count=1)
    assert out.registers["state_code"] == 20 and out.registers["fault_code"] == 0
    assert c.core.last_outcome.record.part_id == 4711
    assert "cycle_count" not in c.scan().registers    # written once, at the end
    out = c.command(EXECUTE | ACK)
    assert out.actions == [] and c.state is State.IDLE
    assert not out.status["done"] and out.status["ready"]
    c.command(0)
    start(c, part_id=5)
    out = c.scan(cycle_ended=done(verify_error_mm=None, cycle_time_s=1.2344, initial_error_mm=None,
                                  moves=None))
    assert {k: v for k, v in out.registers.items() if k not in BASE_REGISTERS} == dict(
        initial_error_um=0, final_error_um=13, moves=0, cycle_time_ms=1484, cycle_count=2)


def test_done_outcome_without_a_record_still_finishes():
    c = at_step(State.LOGGING)
    out = c.scan(cycle_ended=CycleOutcome("done"))
    assert c.state is State.DONE
    assert set(out.registers) == BASE_REGISTERS | {"cycle_count"}


@pytest.mark.parametrize("step, status, code", [
    (State.CAPTURE, "aborted", Fault.CAMERA_FAILED), (State.LOCATE, "aborted", Fault.NO_TARGET),
    (State.FINAL_MOVE, "aborted", Fault.MOTION_TIMEOUT),
    (State.VERIFY, "fault", Fault.VERIFY_OUT_OF_TOLERANCE), (State.APPROACH, "aborted", 204),
    (State.LOGGING, "fault", Fault.LOG_WRITE_FAILED)])
def test_failed_cycle_faults_with_its_code(step, status, code):
    c = at_step(step)
    out = c.scan(cycle_ended=CycleOutcome(status, int(code), "it broke", record(status=status)))
    assert out.actions == [CancelCycle(int(code), "it broke"), QuickStop("it broke"),
                           SettleCycle("s", None, status, int(code), "")]   # the row says it already
    assert c.state is State.FAULT
    assert (c.core.fault_code, c.core.fault_text) == (int(code), "it broke")
    assert out.status["error"] and not out.status["busy"] and not out.status["done"]
    assert out.registers["fault_code"] == int(code) and out.registers["final_error_um"] == 19
    assert c.core.cycle_count == 0 and "cycle_count" not in out.registers


def test_failed_cycle_without_a_code_is_an_internal_fault():
    c = at_step(State.COMPENSATE)
    out = c.scan(cycle_ended=CycleOutcome("aborted"))
    assert out.actions == [CancelCycle(501, "cycle failed"), QuickStop("cycle failed")]
    assert c.state is State.FAULT and c.core.fault_code == Fault.INTERNAL == 501
    c = at_step(State.APPROACH)
    c.scan(cycle_ended=CycleOutcome("aborted", 0, "recipe 1 vanished"))
    assert (c.core.fault_code, c.core.fault_text) == (501, "recipe 1 vanished")


# ------------------------------------------------------------------------------ abort
@pytest.mark.parametrize("step", CYCLE_STEPS)
def test_abort_cancels_stops_and_ends_aborted(step):
    c = at_step(step)
    out = c.command(EXECUTE | ABORT)
    assert out.actions == [CancelCycle(0, ABORT_TEXT), QuickStop(ABORT_TEXT)]
    assert c.state is State.STOPPING
    assert out.status["busy"] and not out.status["error"] and not out.status["aborted"]
    assert c.command(EXECUTE).actions == []
    assert c.command(EXECUTE | ABORT).actions == []   # a second abort edge while stopping
    out = c.scan(cycle_ended=CycleOutcome("aborted", 0, ABORT_TEXT))
    assert c.state is State.ABORTED and c.core.fault_code == 0
    assert out.actions == []
    assert out.status["aborted"] and not out.status["busy"] and not out.status["error"]
    assert out.registers["state_code"] == 31


def test_abort_while_not_busy_does_nothing():
    c = ready_cell()
    assert c.command(ABORT).actions == [] and c.state is State.IDLE
    c = done_cell()
    assert c.command(EXECUTE | ABORT).actions == [] and c.state is State.DONE


def test_acknowledge_of_aborted_rearms_the_drives():
    c = aborted_cell()
    out = c.command(EXECUTE | ACK)
    assert out.actions == [ResetDrives("rearm")]
    assert c.state is State.IDLE and not out.status["aborted"]
    out = c.scan(drives_reset=DrivesResetIn("rearm", True))
    assert out.actions == [] and c.state is State.IDLE and c.core.fault_code == 0
    c.command(0)
    assert c.out.status["ready"] is True


def test_failed_rearm_faults_station():
    c = aborted_cell()
    c.command(EXECUTE | ACK)
    out = c.scan(drives_reset=DrivesResetIn("rearm", False, "j2 still faulted"))
    text = "drives could not be re-enabled after abort: j2 still faulted"
    assert out.actions == [QuickStop(text)]
    assert c.state is State.FAULT
    assert (c.core.fault_code, c.core.fault_text) == (Fault.STATION, text)
    assert out.registers["fault_code"] == 200


def test_a_fault_while_stopping_after_abort_ends_in_fault_not_aborted():
    c = at_step(State.FINAL_MOVE)
    c.command(EXECUTE | ABORT)
    out = c.lose_link()
    assert out.actions == [QuickStop(HB_TEXT)]        # cycle already being cancelled
    assert c.state is State.STOPPING and c.core.fault_code == 101
    c.scan(cycle_ended=CycleOutcome("aborted", 0, ABORT_TEXT))
    assert c.state is State.FAULT and c.core.fault_code == 101


def test_done_outcome_after_an_abort_ends_aborted():
    c = at_step(State.LOGGING)
    c.command(EXECUTE | ABORT)
    out = c.scan(cycle_ended=done())
    assert c.state is State.ABORTED and c.core.cycle_count == 0
    assert "cycle_count" not in out.registers


# ------------------------------------------------------------------------------ station faults
@pytest.mark.parametrize("make", [ready_cell, done_cell, aborted_cell])
def test_station_fault_when_no_cycle_runs_faults_at_once(make):
    c = make()
    out = c.scan(station_fault=StationFaultIn(204, "EMCY_LIMIT (4) on j2"))
    text = "joint stations: EMCY_LIMIT (4) on j2"
    assert out.actions == [QuickStop(text)]
    assert c.state is State.FAULT and (c.core.fault_code, c.core.fault_text) == (204, text)


@pytest.mark.parametrize("step", CYCLE_STEPS)
def test_station_fault_mid_cycle_cancels_and_stops(step):
    c = at_step(step)
    out = c.scan(station_fault=StationFaultIn(201, "HEARTBEAT_LOST"))
    text = "joint stations: HEARTBEAT_LOST"
    assert out.actions == [CancelCycle(201, text), QuickStop(text)]
    assert c.state is State.STOPPING and c.core.fault_code == 201
    assert c.scan(station_fault=StationFaultIn(201, "HEARTBEAT_LOST")).actions == []
    c.scan(station_fault=StationFaultIn(201, "HEARTBEAT_LOST"),
           cycle_ended=CycleOutcome("aborted", 201, text))
    assert c.state is State.FAULT and c.core.fault_code == 201


@pytest.mark.parametrize("make", [ready_cell, lambda: at_step(State.COMPENSATE), aborted_cell])
def test_the_controllers_own_quick_stop_is_not_a_fault(make):
    c = make()
    state = c.state
    out = c.scan(station_fault=StationFaultIn(214, "QUICK_STOP", requested=True))
    assert out.actions == [] and c.state is state and c.core.fault_code == 0


def test_station_faults_are_ignored_while_fault_stopping_or_resetting():
    c = fault_cell(204)
    assert c.scan(station_fault=StationFaultIn(205, "following")).actions == []
    assert c.core.fault_code == 204 and c.state is State.FAULT
    c.command(RESET)
    assert c.state is State.RESETTING
    out = c.scan(station_fault=StationFaultIn(205, "following"))
    assert out.actions == [] and c.state is State.RESETTING and c.core.fault_code == 204
    c = at_step(State.APPROACH)
    c.command(EXECUTE | ABORT)
    out = c.scan(station_fault=StationFaultIn(205, "following"))
    assert out.actions == [] and c.state is State.STOPPING and c.core.fault_code == 0
    c.scan(cycle_ended=CycleOutcome("aborted", 0, ABORT_TEXT))
    assert c.state is State.ABORTED


def test_a_station_fault_before_start_up_latches_without_moving_anything():
    core = ControllerCore(S)
    out = core.step(ScanInputs(now=T0, station_fault=StationFaultIn(203, "BUS_OFF")))
    assert core.sm.state is State.FAULT and core.fault_code == 203
    assert not any(isinstance(a, (QuickStop, CancelCycle, StartCycle)) for a in out.actions)


# ------------------------------------------------------------------------------ reset
def test_reset_in_fault_with_the_link_alive_resets_the_drives_then_idle():
    c = fault_cell(204)
    c.command(0)
    out = c.command(RESET)
    assert out.actions == [ResetDrives("reset")]
    assert c.state is State.RESETTING
    assert out.status["error"] and out.registers["state_code"] == 41 and out.registers["fault_code"] == 204
    out = c.scan(drives_reset=DrivesResetIn("reset", True))
    assert out.actions == [] and c.state is State.IDLE
    assert (c.core.fault_code, c.core.fault_text, c.core.fault_at) == (0, "", None)
    assert not out.status["error"] and out.registers["fault_code"] == 0 and out.status["ready"]


def test_failed_reset_returns_to_fault_keeping_the_code_then_reset_again():
    c = fault_cell(204)
    text = c.core.fault_text
    c.command(RESET)
    out = c.scan(drives_reset=DrivesResetIn("reset", False, "EMCY_LIMIT still latched"))
    assert out.actions == [] and c.state is State.FAULT
    assert (c.core.fault_code, c.core.fault_text) == (204, text) and out.status["error"]
    c.command(0)
    assert c.command(RESET).actions == [ResetDrives("reset")]
    c.scan(drives_reset=DrivesResetIn("reset", True))
    assert c.state is State.IDLE and c.core.fault_code == 0


def test_resets_and_recipe_changes_are_audited_with_the_plc_client():
    c = fault_cell(204)
    c.audits.clear()
    c.command(0)
    c.scan(PlcWriteIn("command_word", RESET, 0, "10.0.0.5:5001"))
    assert c.audits == [Audit("10.0.0.5:5001", "reset", "fault 204", "accepted")]
    c.scan(drives_reset=DrivesResetIn("reset", True))
    c.audits.clear()
    c.scan(PlcWriteIn("recipe_select", 2, 1, "10.0.0.5:5001"))
    c.scan(PlcWriteIn("recipe_select", 2, 2, "10.0.0.5:5001"))          # the same again: no row
    assert c.audits == [Audit("10.0.0.5:5001", "recipe_select", "2", "active (was 1)")]


def test_reset_is_refused_while_the_link_is_down():
    c = ready_cell()
    c.lose_link()
    out = c.command(RESET)
    assert out.actions == [] and c.state is State.FAULT and c.core.fault_code == 101
    c.heartbeat = True
    c.command(0)
    assert c.command(RESET).actions == [ResetDrives("reset")]


@pytest.mark.parametrize("make", [ready_cell, lambda: at_step(State.LOCATE), done_cell, aborted_cell])
def test_reset_outside_fault_does_nothing(make):
    c = make()
    state = c.state
    out = c.command(c.command_word | RESET)
    assert out.actions == [] and c.state is state


def test_heartbeat_loss_while_resetting_goes_back_to_fault_and_a_late_reset_result_is_ignored():
    c = fault_cell(204)
    c.command(RESET)
    out = c.lose_link()
    assert out.actions == [] and c.state is State.FAULT and c.core.fault_code == 204
    c.scan(drives_reset=DrivesResetIn("reset", True))
    assert c.state is State.FAULT and c.core.fault_code == 204


def test_first_fault_wins():
    c = fault_cell(204)
    out = c.lose_link()
    assert out.actions == [] and c.core.fault_code == 204
    c = at_step(State.COMPENSATE)
    c.lose_link()
    c.scan(station_fault=StationFaultIn(204, "limit"))
    c.scan(cycle_ended=CycleOutcome("aborted", 403, "timeout"))
    assert c.state is State.FAULT and (c.core.fault_code, c.core.fault_text) == (101, HB_TEXT)


# ------------------------------------------------------------------------------ recipes
def test_select_known_and_unknown_recipes():
    c = Cell()
    out = c.select(2)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (2, 0)
    out = c.select(7)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (2, 1)
    out = c.select(1)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 0)
    out = c.select(0)                                 # 0 = no request
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 0)


def test_select_while_busy_is_held_then_applied_when_idle():
    c = ready_cell()
    start(c)
    out = c.select(2)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 3)
    assert c.scan(cycle_step=State.VERIFY).registers["recipe_status"] == 3
    out = c.scan(cycle_ended=done())                  # not busy any more: applied at once
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (2, 0)
    out = c.command(EXECUTE | ACK)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (2, 0)
    assert c.core.recipe_number == 2
    c.command(0)
    assert c.command(EXECUTE).actions == [StartCycle(2, 4711)]


def test_select_while_busy_of_an_unknown_recipe_is_unknown_when_applied():
    c = ready_cell()
    start(c)
    c.select(9)
    c.scan(cycle_ended=done())
    out = c.command(EXECUTE | ACK)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 1)


def test_select_zero_while_busy_does_not_leave_status_busy():
    c = ready_cell()
    start(c)
    c.select(0)
    c.scan(cycle_ended=done())
    out = c.command(EXECUTE | ACK)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 0)


def test_rejected_refresh_then_a_good_change():
    c = ready_cell()
    out = c.refresh(rejected=True, changed=True)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 2)
    assert c.scan().registers["recipe_status"] == 2   # held
    assert c.refresh().registers["recipe_status"] == 2  # a refresh that found nothing new
    assert c.command(EXECUTE).actions == [StartCycle(1, 0)]   # the last good version runs
    c.scan(cycle_ended=done())
    c.command(EXECUTE | ACK)
    out = c.refresh(changed=True)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 0)


def test_active_recipe_disappearing_is_unknown():
    c = ready_cell()
    out = c.refresh(numbers=(2,), changed=True)
    assert (out.registers["recipe_ack"], out.registers["recipe_status"]) == (1, 1)
    out = c.scan(recipes=RecipesIn(frozenset({2})))
    assert out.registers["recipe_status"] == 1
    c = ready_cell()
    c.numbers = frozenset({2})                        # the active set changed without a refresh flag
    assert c.scan().registers["recipe_status"] == 1


# ------------------------------------------------------------------------------ shutdown
def test_shutdown_while_busy_cancels_stops_and_latches_internal():
    c = at_step(State.FINAL_MOVE)
    text = "controller shutting down"
    assert c.core.shutdown() == [CancelCycle(501, text), QuickStop(text)]
    assert c.state is State.STOPPING and c.core.fault_code == Fault.INTERNAL
    c.scan(cycle_ended=CycleOutcome("aborted", 501, text))
    assert c.state is State.FAULT and c.core.fault_code == 501


def test_shutdown_while_stopping_after_abort_latches_internal():
    c = at_step(State.APPROACH)
    c.command(EXECUTE | ABORT)
    assert c.core.shutdown() == [QuickStop("controller shutting down")]
    assert c.state is State.STOPPING and c.core.fault_code == 501


@pytest.mark.parametrize("make", [ready_cell, done_cell, aborted_cell, fault_cell])
def test_shutdown_when_no_cycle_runs_does_nothing(make):
    c = make()
    state, code = c.state, c.core.fault_code
    assert c.core.shutdown() == []
    assert c.state is state and c.core.fault_code == code


# ------------------------------------------------------------------------------ what the PLC was told
def test_heartbeat_lost_while_the_row_is_written_settles_the_row_as_the_fault_told():
    """Field probe: a fault 101 during LOGGING left a row saying done; the PLC got 101."""
    c = at_step(State.LOGGING)
    c.lose_link()
    assert c.state is State.STOPPING
    out = c.scan(cycle_ended=done())                  # the runner had already written "done"
    assert c.state is State.FAULT and not out.status["done"] and out.status["error"]
    assert out.actions == [SettleCycle("s", None, "aborted", 101, HB_TEXT)]


def test_abort_while_the_row_is_written_settles_the_row_as_aborted():
    c = at_step(State.LOGGING)
    c.command(EXECUTE | ABORT)
    out = c.scan(cycle_ended=done())
    assert c.state is State.ABORTED and out.status["aborted"] and not out.status["done"]
    assert out.actions == [SettleCycle("s", None, "aborted", 0, ABORT_TEXT)]


def test_abort_mid_cycle_settles_with_what_the_row_says():
    c = at_step(State.LOCATE)
    c.command(EXECUTE | ABORT)
    out = c.scan(cycle_ended=CycleOutcome("aborted", 0, ABORT_TEXT, record(status="aborted")))
    assert out.actions == [SettleCycle("s", None, "aborted", 0, ABORT_TEXT)]


# ------------------------------------------------------------------------------ restart
class _Interrupted:
    part_id, started_at = 4242, "2026-11-23T10:00:00.000+00:00"


def test_a_cycle_interrupted_by_a_restart_comes_up_as_fault_503_with_its_part_id():
    core = ControllerCore(S)
    out = core.started(T0, RecipesIn(frozenset({1}), refreshed=True), _Interrupted())
    assert core.sm.state is State.FAULT and out.registers["fault_code"] == Fault.INTERRUPTED == 503
    assert out.registers["part_id_echo"] == 4242 and out.status["error"] and not out.status["ready"]
    assert "part 4242" in core.fault_text and "restart" in core.fault_text


def test_reset_of_the_interrupted_fault_clears_it_in_the_log_and_nothing_moves_before():
    c = Cell()
    c.core = ControllerCore(S)
    c.core.started(c.now, RecipesIn(c.numbers, refreshed=True), _Interrupted())
    c.select(1)
    c.command(0)
    out = c.command(EXECUTE)                          # execute while the fault is latched
    assert out.actions == [] and out.status["execute_refused"] and c.state is State.FAULT
    assert c.command(RESET).actions == [ResetDrives("reset")]
    out = c.scan(drives_reset=DrivesResetIn("reset", True))
    assert out.actions == [ClearInterrupted()] and c.state is State.IDLE and c.core.fault_code == 0
    c.command(0)
    assert c.command(EXECUTE).actions == [StartCycle(1, 0)]


def test_not_ready_and_execute_refused_while_drives_re_enable_after_abort():
    c = aborted_cell()
    c.command(ACK)                                    # execute low, acknowledge: rearm asked
    assert c.out.actions == [ResetDrives("rearm")] and c.out.status["ready"] is False
    out = c.command(EXECUTE)
    assert out.actions == [] and out.status["execute_refused"]
    out = c.scan(drives_reset=DrivesResetIn("rearm", True))
    assert out.status["ready"] is True and out.actions == []   # execute held high starts nothing
    assert c.scans(5)[-1].actions == [] and c.state is State.IDLE
    c.command(0)
    assert c.command(EXECUTE).actions == [StartCycle(1, 4711)]    # a fresh edge does


# ---------------------------------------------------------------------- calibration (issue 10)
CALIBRATE = 16


def calibrating(select: int = 2) -> Cell:
    c = ready_cell()
    c.scan(PlcWriteIn("calibration_select", select, 0))
    out = c.command(CALIBRATE)
    assert out.actions == [StartCalibration(select)]
    assert c.state is State.CALIBRATING and out.status["busy"] and not out.status["ready"]
    assert out.registers["state_code"] == 50
    return c


def test_calibrate_edge_starts_the_selected_calibration_then_done_publishes_residuals():
    c = calibrating(2)
    out = c.scan(cycle_ended=CycleOutcome("done", calibration={"residual_um": 0, "residual_udeg": 1234.6}))
    assert c.state is State.DONE and out.status["done"] and not out.status["busy"]
    assert out.registers["calibration_residual_udeg"] == 1235 and out.registers["calibration_residual_um"] == 0
    assert c.core.cycle_count == 0                       # a calibration is not a part's cycle
    c.command(ACK)
    assert c.state is State.IDLE


def test_kinematic_calibration_done_raises_the_calibration_version():
    c = calibrating(0)
    out = c.scan(cycle_ended=CycleOutcome("done", calibration={"residual_um": 95.9, "residual_udeg": 0,
                                                               "version": 3}))
    assert out.registers["calibration_version"] == 3 and out.registers["calibration_residual_um"] == 96
    assert c.scan().registers["calibration_version"] == 3     # held


def test_select_is_latched_at_the_edge_as_written_before_it():
    c = ready_cell()
    out = c.scan(PlcWriteIn("calibration_select", 1, 0), cw(CALIBRATE, 0),
                 PlcWriteIn("calibration_select", 4, 1))
    assert out.actions == [StartCalibration(1)]


def test_failed_calibration_latches_its_fault_and_stops_the_joints():
    c = calibrating(0)
    out = c.scan(cycle_ended=CycleOutcome("fault", Fault.CALIBRATION_FIT, "held-out check failed"))
    assert c.state is State.FAULT and out.status["error"]
    assert out.registers["fault_code"] == 603
    assert any(isinstance(a, QuickStop) for a in out.actions)


def test_abort_and_heartbeat_loss_stop_a_calibration():
    c = calibrating(1)
    out = c.command(CALIBRATE | ABORT)
    assert c.state is State.STOPPING and CancelCycle(0, ABORT_TEXT) in out.actions
    c.scan(cycle_ended=CycleOutcome("aborted", 0, ABORT_TEXT))
    assert c.state is State.ABORTED
    c = calibrating(1)
    out = c.lose_link()
    assert any(isinstance(a, CancelCycle) and a.code == Fault.PLC_HEARTBEAT_LOST for a in out.actions)
    c.scan(cycle_ended=CycleOutcome("aborted", Fault.PLC_HEARTBEAT_LOST, HB_TEXT))
    assert c.state is State.FAULT and c.core.fault_code == Fault.PLC_HEARTBEAT_LOST


def test_calibrate_is_refused_unless_ready_and_never_with_execute():
    c = Cell()                                # link up but not armed: calibrate held from before
    c.scan()
    out = c.command(CALIBRATE)
    assert out.actions == [] and out.status["execute_refused"] and c.state is State.IDLE
    c = ready_cell()
    out = c.command(EXECUTE | CALIBRATE)
    assert out.actions == [] and out.status["execute_refused"] and c.state is State.IDLE
    c = at_step(State.CAPTURE)                # busy with a part
    out = c.command(EXECUTE | CALIBRATE)
    assert not any(isinstance(a, StartCalibration) for a in out.actions) and out.status["execute_refused"]


def test_arming_needs_calibrate_written_low_too():
    c = Cell(command_word=CALIBRATE)
    c.scan()
    c.command(CALIBRATE)                       # rewritten high after a restart: not armed
    assert not c.out.status["ready"]
    c.command(0)
    assert c.out.status["ready"]
