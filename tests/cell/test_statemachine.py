"""State machine: the happy path, faults and aborts from every busy state, illegal events."""
import pytest

from cell.cycle.statemachine import CYCLE_STEPS, TRANSITIONS, Event, IllegalTransition, State, StateMachine


def test_full_cycle_then_acknowledge():
    sm = StateMachine()
    assert sm.fire(Event.STARTED) is State.IDLE
    assert sm.fire(Event.EXECUTE) is State.APPROACH
    seen = [sm.state]
    while sm.state is not State.DONE:
        seen.append(sm.fire(Event.STEP_DONE))
    assert seen[:-1] == list(CYCLE_STEPS)
    assert sm.fire(Event.ACKNOWLEDGE) is State.IDLE


@pytest.mark.parametrize("step", CYCLE_STEPS)
def test_fault_from_every_step_stops_then_latches(step):
    sm = StateMachine(step)
    assert sm.state.busy
    assert sm.fire(Event.FAULT) is State.STOPPING
    assert sm.fire(Event.STOPPED_FAULT) is State.FAULT
    for ev in (Event.EXECUTE, Event.ACKNOWLEDGE, Event.STEP_DONE):
        with pytest.raises(IllegalTransition):
            sm.fire(ev)
    assert sm.state is State.FAULT            # refused events change nothing
    assert sm.fire(Event.RESET) is State.RESETTING
    assert sm.fire(Event.RESET_DONE) is State.IDLE


@pytest.mark.parametrize("step", CYCLE_STEPS)
def test_abort_from_every_step(step):
    sm = StateMachine(step)
    sm.fire(Event.ABORT)
    assert sm.fire(Event.STOPPED_ABORT) is State.ABORTED
    assert sm.fire(Event.ACKNOWLEDGE) is State.IDLE


def test_execute_while_busy_is_illegal_and_named():
    sm = StateMachine(State.COMPENSATE)
    with pytest.raises(IllegalTransition, match="'execute' is not allowed in state COMPENSATE"):
        sm.fire(Event.EXECUTE)
    assert sm.state is State.COMPENSATE


def test_fault_while_idle_also_stops():
    sm = StateMachine(State.IDLE)
    assert sm.fire(Event.FAULT) is State.STOPPING


def test_table_is_closed():
    # every target state is a State, and FAULT can only be left by reset
    assert all(isinstance(v, State) for v in TRANSITIONS.values())
    assert {e for (s, e) in TRANSITIONS if s is State.FAULT} == {Event.FAULT, Event.RESET}
    assert len({s.value for s in State}) == len(State)
