"""CiA 402 drive state machine (power drive systems): states, controlword commands,
statusword coding and an explicit transition table. Pure logic, no I/O.

Both sides use it: the simulated station (:mod:`drivers.stations.sim`) steps its
:class:`DriveStateMachine` on every controlword it receives; the controller
(:mod:`drivers.stations.driver`) decodes statuswords and plans the controlword sequence
that brings a drive to *Operation enabled* (:func:`path_to`).

Transition numbers follow CiA 402-2 (figure "State machine"):

====  ==========================  ==========================  =====================
 no.  from                        to                          trigger
====  ==========================  ==========================  =====================
  1   Not ready to switch on      Switch on disabled          internal (self-test)
  2   Switch on disabled          Ready to switch on          Shutdown
  3   Ready to switch on          Switched on                 Switch on
  4   Switched on                 Operation enabled           Enable operation
  5   Operation enabled           Switched on                 Disable operation
  6   Switched on                 Ready to switch on          Shutdown
  7   Ready to switch on          Switch on disabled          Disable voltage / Quick stop
  8   Operation enabled           Ready to switch on          Shutdown
  9   Operation enabled           Switch on disabled          Disable voltage
 10   Switched on                 Switch on disabled          Disable voltage / Quick stop
 11   Operation enabled           Quick stop active           Quick stop
 12   Quick stop active           Switch on disabled          Disable voltage
 13   any but Fault*              Fault reaction active       internal (fault)
 14   Fault reaction active       Fault                       internal (reaction done)
 15   Fault                       Switch on disabled          Fault reset (bit 7 0→1)
 16   Quick stop active           Operation enabled           Enable operation
====  ==========================  ==========================  =====================

Transition 16 exists for quick-stop option codes 5..8; the stations use option code 6
("stop on the quick-stop ramp and stay in Quick stop active"), which is a category 2
stop: the axis stands under control with power on.

An illegal transition raises :class:`IllegalTransition`, never a silent
no-op. Statusword ↔ state decoding uses the masks of CiA 402-2 table 30.
"""
from __future__ import annotations

import enum
from collections import deque

from cell.errors import CellError


class IllegalTransition(CellError, ValueError):
    """A command that the CiA 402 state machine does not allow in the current state."""


class State(enum.Enum):
    """The eight CiA 402 drive states. ``value`` = (statusword mask, statusword value)."""

    NOT_READY_TO_SWITCH_ON = (0x004F, 0x0000)
    SWITCH_ON_DISABLED = (0x004F, 0x0040)
    READY_TO_SWITCH_ON = (0x006F, 0x0021)
    SWITCHED_ON = (0x006F, 0x0023)
    OPERATION_ENABLED = (0x006F, 0x0027)
    QUICK_STOP_ACTIVE = (0x006F, 0x0007)
    FAULT_REACTION_ACTIVE = (0x004F, 0x000F)
    FAULT = (0x004F, 0x0008)

    @property
    def label(self) -> str:
        return self.name.replace("_", " ").capitalize()


class Command(enum.Enum):
    """Controlword commands. ``value`` = (controlword mask, controlword value, word to send)."""

    SHUTDOWN = (0x0087, 0x0006, 0x0006)
    SWITCH_ON = (0x008F, 0x0007, 0x0007)
    DISABLE_VOLTAGE = (0x0082, 0x0000, 0x0000)
    QUICK_STOP = (0x0086, 0x0002, 0x0002)
    DISABLE_OPERATION = (0x008F, 0x0007, 0x0007)  # same bits as SWITCH_ON, told apart by state
    ENABLE_OPERATION = (0x008F, 0x000F, 0x000F)
    FAULT_RESET = (0x0080, 0x0080, 0x0080)  # acts on the rising edge of bit 7

    @property
    def word(self) -> int:
        """The controlword to send for this command (bits 0..3 and 7)."""
        return self.value[2]


class Internal(enum.Enum):
    """Transitions the drive makes by itself (no controlword)."""

    SELF_TEST_DONE = 1
    FAULT = 13
    REACTION_DONE = 14


S, C = State, Command
#: (state, command) → next state. Anything missing is illegal.
TRANSITIONS: dict[tuple[State, Command | Internal], State] = {
    (S.NOT_READY_TO_SWITCH_ON, Internal.SELF_TEST_DONE): S.SWITCH_ON_DISABLED,   # 1
    (S.SWITCH_ON_DISABLED, C.SHUTDOWN): S.READY_TO_SWITCH_ON,                    # 2
    (S.READY_TO_SWITCH_ON, C.SWITCH_ON): S.SWITCHED_ON,                          # 3
    (S.SWITCHED_ON, C.ENABLE_OPERATION): S.OPERATION_ENABLED,                    # 4
    (S.OPERATION_ENABLED, C.DISABLE_OPERATION): S.SWITCHED_ON,                   # 5
    (S.SWITCHED_ON, C.SHUTDOWN): S.READY_TO_SWITCH_ON,                           # 6
    (S.READY_TO_SWITCH_ON, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,             # 7
    (S.READY_TO_SWITCH_ON, C.QUICK_STOP): S.SWITCH_ON_DISABLED,                  # 7
    (S.OPERATION_ENABLED, C.SHUTDOWN): S.READY_TO_SWITCH_ON,                     # 8
    (S.OPERATION_ENABLED, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,              # 9
    (S.SWITCHED_ON, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,                    # 10
    (S.SWITCHED_ON, C.QUICK_STOP): S.SWITCH_ON_DISABLED,                         # 10
    (S.OPERATION_ENABLED, C.QUICK_STOP): S.QUICK_STOP_ACTIVE,                    # 11
    (S.QUICK_STOP_ACTIVE, C.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,              # 12
    (S.FAULT_REACTION_ACTIVE, Internal.REACTION_DONE): S.FAULT,                  # 14
    (S.FAULT, C.FAULT_RESET): S.SWITCH_ON_DISABLED,                              # 15
    (S.QUICK_STOP_ACTIVE, C.ENABLE_OPERATION): S.OPERATION_ENABLED,              # 16
}
for _s in State:  # 13: a fault can strike in every state but the two fault states
    if _s not in (S.FAULT_REACTION_ACTIVE, S.FAULT):
        TRANSITIONS[(_s, Internal.FAULT)] = S.FAULT_REACTION_ACTIVE
del _s

# Statusword bits beyond the state bits (CiA 402-2, 0x6041).
SW_VOLTAGE_ENABLED = 1 << 4
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_SETPOINT_ACK = 1 << 12
SW_FOLLOWING_ERROR = 1 << 13
CW_FAULT_RESET_BIT = 1 << 7


#: (mask, value, state) in the order :func:`decode_statusword` tries them (an enum member's
#: ``value`` is a property: looked up once here, not for every TPDO)
_STATE_BITS = tuple((s.value[0], s.value[1], s) for s in State)


def decode_statusword(statusword: int) -> State:
    """The drive state encoded in a statusword (0x6041).

    :raises IllegalTransition: (a ``ValueError``) when the word is not a 16-bit integer
        or its state bits match no CiA 402 state.
    """
    if isinstance(statusword, bool) or not isinstance(statusword, int) or not 0 <= statusword <= 0xFFFF:
        raise IllegalTransition(f"statusword {statusword!r} is not a 16-bit unsigned integer")
    for mask, value, state in _STATE_BITS:
        if statusword & mask == value:
            return state
    raise IllegalTransition(f"statusword 0x{statusword:04X} encodes no CiA 402 state")


#: state name -> (bits of the word the state leaves free, the state's own word): the state's
#: bits, voltage enabled where the drive is powered, remote; see :func:`encode_statusword`
#: (keyed by name: an enum member hashes in Python, a str at once)
_STATE_WORD = {s.name: (~s.value[0] & 0xFFFF,
                   s.value[1] | SW_REMOTE | (SW_VOLTAGE_ENABLED if s in (
                       S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE) else 0))
               for s in State}


def encode_statusword(state: State, extra_bits: int = 0) -> int:
    """Statusword for ``state`` plus ``extra_bits`` (e.g. :data:`SW_TARGET_REACHED`) where the
    state's own bits leave room; voltage enabled in the powered states; remote always."""
    free, word = _STATE_WORD[state._name_]
    return word | (extra_bits & free)


def decode_controlword(controlword: int, state: State) -> Command | None:
    """The command a controlword means to a drive in ``state``; ``None`` if it means none.

    Bit 7 (fault reset) acts only on its rising edge, which the caller tracks; here a set
    bit 7 in state Fault decodes to :attr:`Command.FAULT_RESET`. ``0x0007`` is *Switch on*
    except in Operation enabled, where it is *Disable operation*.
    :raises IllegalTransition: when the word is not a 16-bit unsigned integer.
    """
    if isinstance(controlword, bool) or not isinstance(controlword, int) or not 0 <= controlword <= 0xFFFF:
        raise IllegalTransition(f"controlword {controlword!r} is not a 16-bit unsigned integer")
    if controlword & CW_FAULT_RESET_BIT:
        return C.FAULT_RESET if state is S.FAULT else None
    order = (C.ENABLE_OPERATION, C.DISABLE_OPERATION if state is S.OPERATION_ENABLED else C.SWITCH_ON,
             C.SHUTDOWN, C.QUICK_STOP, C.DISABLE_VOLTAGE)
    for cmd in order:
        mask, value, _ = cmd.value
        if controlword & mask == value:
            return cmd
    return None


def next_state(state: State, event: Command | Internal) -> State:
    """The state after ``event`` in ``state``.

    :raises IllegalTransition: naming the state and the event when the table has no entry.
    """
    try:
        return TRANSITIONS[(state, event)]
    except KeyError:
        raise IllegalTransition(
            f"CiA 402: {event.name} is not allowed in state {state.label!r}") from None


def path_to(start: State, goal: State) -> list[Command]:
    """Shortest controlword command sequence from ``start`` to ``goal`` (breadth first).

    Only controlword transitions are used; internal ones (fault, self-test) are not
    commandable. ``[]`` when already there.
    :raises IllegalTransition: when ``goal`` cannot be reached by commands alone (e.g.
        from Fault reaction active, which ends by itself).
    """
    prev: dict[State, tuple[State, Command] | None] = {start: None}
    todo = deque([start])
    while todo:
        s = todo.popleft()
        if s is goal:
            out: list[Command] = []
            while prev[s] is not None:
                s, cmd = prev[s]  # type: ignore[misc]
                out.append(cmd)
            return out[::-1]
        for (frm, ev), to in TRANSITIONS.items():
            if frm is s and isinstance(ev, Command) and to not in prev:
                prev[to] = (s, ev)
                todo.append(to)
    raise IllegalTransition(f"CiA 402: no command sequence leads from {start.label!r} to {goal.label!r}")


class DriveStateMachine:
    """One drive's CiA 402 state, stepped by commands and internal events (not thread-safe;
    the owner serialises access).

    :param state: initial state, *Not ready to switch on* after power-up.
    """

    def __init__(self, state: State = S.NOT_READY_TO_SWITCH_ON):
        self.state = state

    def apply(self, event: Command | Internal) -> State:
        """Take ``event``; returns the new state.

        :raises IllegalTransition: (state unchanged) when the transition table forbids it.
        """
        self.state = next_state(self.state, event)
        return self.state

    @property
    def enabled(self) -> bool:
        """True in *Operation enabled* (the only state in which set-points move the axis)."""
        return self.state is S.OPERATION_ENABLED
