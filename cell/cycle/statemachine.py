"""The cell's state machine: explicit states, events and one transition table.

An event that the table does not list for the current state raises
:class:`IllegalTransition`; nothing changes silently. The numeric value of each state is
what the PLC reads in the ``state`` register, so values are stable: append, never renumber.

Life of a part (PLCopen Execute/Busy/Done/Error)::

    STARTING --started--> IDLE --execute--> APPROACH -> CAPTURE -> LOCATE -> COMPENSATE
        -> FINAL_MOVE -> VERIFY -> LOGGING --step_done--> DONE --acknowledge--> IDLE

A robot calibration (seed 004 / seed 001, started by the PLC's ``calibrate`` bit) is one
busy state of its own, with the same ending::

    IDLE --calibrate--> CALIBRATING --step_done--> DONE --acknowledge--> IDLE

From any busy state, ``fault`` leads to STOPPING (the joints are brought to a controlled
stop) and then FAULT; ``abort`` leads to STOPPING and then ABORTED. FAULT is left only by
``reset`` (RESETTING -> IDLE); ABORTED and DONE are held until the PLC acknowledges.
"""
from __future__ import annotations

import enum
import threading


class State(enum.IntEnum):
    STARTING = 1
    IDLE = 2
    APPROACH = 10
    CAPTURE = 11
    LOCATE = 12
    COMPENSATE = 13
    FINAL_MOVE = 14
    VERIFY = 15
    LOGGING = 16
    DONE = 20
    STOPPING = 30
    ABORTED = 31
    FAULT = 40
    RESETTING = 41
    CALIBRATING = 50

    @property
    def busy(self) -> bool:
        """True while a part's cycle or a calibration is running (the PLC's Busy)."""
        return self in CYCLE_STEPS or self is State.STOPPING or self is State.CALIBRATING


class Event(enum.Enum):
    STARTED = "started"
    EXECUTE = "execute"
    STEP_DONE = "step_done"
    ACKNOWLEDGE = "acknowledge"
    FAULT = "fault"
    ABORT = "abort"
    STOPPED_FAULT = "stopped_fault"
    STOPPED_ABORT = "stopped_abort"
    RESET = "reset"
    RESET_DONE = "reset_done"
    CALIBRATE = "calibrate"


CYCLE_STEPS = (State.APPROACH, State.CAPTURE, State.LOCATE, State.COMPENSATE,
               State.FINAL_MOVE, State.VERIFY, State.LOGGING)


def _table() -> dict[tuple[State, Event], State]:
    t: dict[tuple[State, Event], State] = {
        (State.STARTING, Event.STARTED): State.IDLE,
        (State.STARTING, Event.FAULT): State.FAULT,
        (State.IDLE, Event.EXECUTE): State.APPROACH,
        (State.IDLE, Event.FAULT): State.STOPPING,
        (State.DONE, Event.ACKNOWLEDGE): State.IDLE,
        (State.DONE, Event.FAULT): State.STOPPING,
        (State.ABORTED, Event.ACKNOWLEDGE): State.IDLE,
        (State.ABORTED, Event.FAULT): State.STOPPING,
        (State.STOPPING, Event.STOPPED_FAULT): State.FAULT,
        (State.STOPPING, Event.STOPPED_ABORT): State.ABORTED,
        (State.STOPPING, Event.FAULT): State.STOPPING,       # a second fault while stopping
        (State.FAULT, Event.FAULT): State.FAULT,             # further faults keep it latched
        (State.FAULT, Event.RESET): State.RESETTING,
        (State.RESETTING, Event.RESET_DONE): State.IDLE,
        (State.RESETTING, Event.FAULT): State.FAULT,
        (State.IDLE, Event.CALIBRATE): State.CALIBRATING,
        (State.CALIBRATING, Event.STEP_DONE): State.DONE,
        (State.CALIBRATING, Event.FAULT): State.STOPPING,
        (State.CALIBRATING, Event.ABORT): State.STOPPING,
    }
    for here, nxt in zip(CYCLE_STEPS, CYCLE_STEPS[1:] + (State.DONE,)):
        t[(here, Event.STEP_DONE)] = nxt
        t[(here, Event.FAULT)] = State.STOPPING
        t[(here, Event.ABORT)] = State.STOPPING
    return t


TRANSITIONS: dict[tuple[State, Event], State] = _table()


class IllegalTransition(RuntimeError):
    """An event the transition table does not allow in the current state."""


class StateMachine:
    """Holds the current state; :meth:`fire` applies one event (thread-safe)."""

    def __init__(self, state: State = State.STARTING):
        self._state = state
        self._lock = threading.Lock()

    @property
    def state(self) -> State:
        return self._state

    def can(self, event: Event) -> bool:
        return (self._state, event) in TRANSITIONS

    def fire(self, event: Event) -> State:
        """Apply ``event``; return the new state. Raises IllegalTransition if not allowed."""
        with self._lock:
            try:
                self._state = TRANSITIONS[(self._state, event)]
            except KeyError:
                raise IllegalTransition(
                    f"event {event.value!r} is not allowed in state {self._state.name}") from None
            return self._state
