"""ControllerCore.quiet_step: a scan with no news changes nothing but the heartbeat.

Every scenario of ``test_controller_core`` runs again here with a twin beside the core it
steps: the twin takes :meth:`~cell.controller.core.ControllerCore.quiet_step` wherever the
controller shell would (no PLC write, no station fault, no cycle end, drive reset or recipe
refresh in the inputs) and :meth:`step` otherwise. At every scan the twin must have written
what the stepped core wrote (status bits, registers, actions) and be in the same state. The
tests below them pin where the quiet step must decline.
"""
import pytest

from cell.controller.core import EXECUTE, ControllerCore, ControllerSettings, RecipesIn, RefreshRecipes, ScanInputs
from cell.cycle.statemachine import State
from tests.cell import test_controller_core as core_tests
from tests.cell.test_controller_core import *  # noqa: F401,F403 -- every scenario again, with the twin
from tests.cell.test_controller_core import BASE_REGISTERS, S, T0, Cell, ready_cell

#: what must be equal in the stepped core and its twin after every scan
STATE = ("fault_code", "fault_text", "fault_at", "execute_refused", "cycle_count", "recipe_number",
         "recipe_status", "last_outcome", "calibration_version", "plant_backlog", "_pending_select",
         "_armed", "_rearming", "_link_ok", "_heartbeat", "_cycle_running", "_next_refresh", "_now")


def news(inp: ScanInputs, core: ControllerCore) -> bool:
    """What the controller shell counts as news (it then steps the core)."""
    return bool(inp.writes or inp.station_fault is not None or inp.cycle_ended is not None
                or inp.drives_reset is not None or inp.recipes.refreshed
                or inp.recipes.numbers != core._recipes.numbers)


class Twin:
    """A core the scenario steps (``ref``) and its twin, built alike; reads go to ``ref``."""

    quiet = 0                                        #: quiet steps the twins took

    def __init__(self, settings: ControllerSettings = ControllerSettings()):
        self.ref, self.twin = ControllerCore(settings), ControllerCore(settings)
        self.last = None                             #: the last outputs of a full step

    def __getattr__(self, name):
        return getattr(self.ref, name)

    def started(self, *args, **kwargs):
        assert self.twin.started(*args, **kwargs) == (out := self.ref.started(*args, **kwargs))
        self.last = out
        return out

    def shutdown(self):
        assert self.twin.shutdown() == (actions := self.ref.shutdown())
        return actions

    def step(self, inp: ScanInputs):
        out = self.ref.step(inp)
        hb = None if self.last is None or news(inp, self.twin) else self.twin.quiet_step(
            inp.now, inp.last_heartbeat_change, inp.cycle_step, inp.recalibration_due, inp.plant_backlog)
        if hb is None:
            assert self.twin.step(inp) == out
            self.last = out
        else:
            Twin.quiet += 1
            base = {k: v for k, v in self.last.registers.items() if k in BASE_REGISTERS}
            assert out.actions == [] and out.status == self.last.status
            assert out.registers == {**base, "controller_heartbeat": hb}
        assert self.twin.sm.state is self.ref.sm.state
        assert {k: getattr(self.twin, k) for k in STATE} == {k: getattr(self.ref, k) for k in STATE}
        return out


@pytest.fixture(autouse=True)
def twin_cores(monkeypatch):
    """Every core the scenarios build is a :class:`Twin`."""
    monkeypatch.setattr(core_tests, "ControllerCore", Twin)


def quiet(c: Cell, **inputs) -> int | None:
    """One scan of ``c`` as the shell runs it when there is no news: the quiet step only."""
    c.now += c.s.scan_s
    if c.heartbeat:
        c.last_hb = c.now
    hb = c.core.ref.quiet_step(c.now, c.last_hb, **inputs)
    assert c.core.twin.quiet_step(c.now, c.last_hb, **inputs) == hb
    return hb


# ------------------------------------------------------------------------------ the quiet step itself
def test_an_idle_ready_cell_scans_quietly_and_only_its_heartbeat_moves():
    c = ready_cell()
    hb = c.out.registers["controller_heartbeat"]
    assert [quiet(c) for _ in range(5)] == [hb + 1, hb + 2, hb + 3, hb + 4, hb + 5]
    assert c.scan().registers["controller_heartbeat"] == hb + 6 and c.out.status["ready"]


def test_the_quiet_step_declines_the_scan_that_loses_the_link():
    c = ready_cell()
    c.heartbeat = False
    while c.now + c.s.scan_s - c.last_hb <= S.plc_heartbeat_timeout_s:
        assert quiet(c) is not None
    before = c.core.ref._heartbeat
    assert quiet(c) is None and c.core.ref._heartbeat == before        # nothing changed
    c.scan(dt=0.0)
    assert c.state is State.FAULT and not c.out.status["plc_link_ok"]


def test_the_quiet_step_declines_a_changed_backlog_or_recalibration_flag():
    c = ready_cell()
    assert quiet(c, plant_backlog=3) is None
    assert quiet(c, recalibration_due=True) is None
    c.scan(plant_backlog=3, recalibration_due=True)
    assert quiet(c, plant_backlog=3, recalibration_due=True) is not None
    assert quiet(c, plant_backlog=3) is None


def test_the_quiet_step_declines_when_the_recipe_refresh_is_due():
    c = ready_cell(settings=ControllerSettings(scan_s=0.0625, plc_heartbeat_timeout_s=1.0, recipe_refresh_s=0.25))
    while RefreshRecipes() not in c.scan().actions:
        pass
    assert [quiet(c) is None for _ in range(4)] == [False, False, False, True]    # due 0.25 s later
    assert RefreshRecipes() in c.scan(dt=0.0).actions


def test_the_quiet_step_declines_a_cycle_step_the_core_has_not_followed():
    c = ready_cell()
    c.command(EXECUTE)
    assert c.state is State.APPROACH
    assert quiet(c, cycle_step=State.APPROACH) is not None
    assert quiet(c, cycle_step=State.LOCATE) is None
    c.scan(cycle_step=State.LOCATE)
    assert c.state is State.LOCATE and quiet(c, cycle_step=State.LOCATE) is not None


def test_the_quiet_step_declines_while_a_recipe_selection_waits():
    c = ready_cell()
    c.command(EXECUTE)
    c.select(2)                                     # while busy: applied once idle
    assert quiet(c, cycle_step=State.APPROACH) is None


def test_a_scenario_takes_quiet_steps():
    """The twins are not all stepped in full: a whole cycle has quiet scans in every step."""
    before = Twin.quiet
    core_tests.test_heartbeat_loss_mid_cycle_cancels_stops_then_faults_when_the_cycle_ends(State.VERIFY)
    assert Twin.quiet > before


def test_a_core_started_with_no_heartbeat_yet_declines_until_the_link_is_up():
    core = ControllerCore(S)
    core.started(T0, RecipesIn(frozenset({1}), refreshed=True))
    assert core.quiet_step(T0 + 0.0625, None) is not None           # no link before, none now
    assert core.quiet_step(T0 + 0.125, T0 + 0.125) is None          # the link comes up: a step
