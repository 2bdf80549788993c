"""The PLC register map: ONE named table, from which everything else is generated.

The pymodbus datastore (:mod:`drivers.plc.server`), the Markdown register reference in
docs/plc.md (:meth:`RegisterMap.to_markdown`) and ``cellctl registers --format md|csv`` are all
built from :data:`PLC_MAP`; nothing else lists addresses.

Address base: ``Register.address`` is the **protocol address**, i.e. the
0-based register number carried in the Modbus PDU. The Modicon "4xxxx" reference printed
alongside is ``40001 + address`` (1-based), so ``plc_heartbeat`` at protocol address 1 is
"40002" in a PLC tool that counts the Modicon way. Everything is a holding register,
readable with FC3 (one FC3 of ``PLC_MAP.size`` registers reads the whole map).

32-bit values (``u32``) occupy two consecutive registers, **high word first** (big-endian
words, as pymodbus ``DataType.UINT32`` and most PLCs' "ABCD" order). The PLC must write both
words in one FC16/FC23 request; a write touching only one word is refused (exception 02).

Bits: bit ``n`` (0 = least significant) of the register at address ``r`` is also coil /
discrete input number ``16 * r + n`` (FC1/FC2 read any bit, FC5/FC15 write bits of RW
bit-field registers).

Reserved addresses between blocks (room for later versions) read as 0 and refuse writes;
addresses at or beyond ``PLC_MAP.size`` do not exist (exception 02).

This module is pure data and arithmetic: no pymodbus import, so ``cellctl registers`` is cheap.
"""
from __future__ import annotations

import csv
import enum
import functools
import io
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

from cell.errors import CellError

#: Value of the ``map_version`` register; bump it whenever an address or meaning changes.
MAP_VERSION = 3     #: 2 added the calibration block (60..69) and command_word.calibrate; 3 plant_backlog
#: Modicon reference of protocol address 0 (holding registers, 1-based "4xxxx").
MODICON_BASE = 40001


class PlcMapError(CellError, ValueError):
    """A register name, address or value that does not fit the register map."""


class PlcWriteRejected(PlcMapError):
    """A PLC write the map refuses; ``modbus_code`` is the exception code to answer with."""

    modbus_code = 0


class IllegalDataAddress(PlcWriteRejected):
    """Unknown/reserved address, read-only register or half of a 32-bit pair (Modbus 02)."""

    modbus_code = 2


class IllegalDataValue(PlcWriteRejected):
    """A value outside the register's documented range (Modbus 03)."""

    modbus_code = 3


class RegType(str, enum.Enum):
    U16 = "u16"
    U32 = "u32"
    BITFIELD = "bitfield"


class Access(str, enum.Enum):
    RO = "RO"   # PLC reads, only the controller writes
    RW = "RW"   # PLC writes (and reads back)


@dataclass(frozen=True)
class Bit:
    index: int
    name: str
    meaning: str


@dataclass(frozen=True)
class Register:
    """One named entry. ``address`` is the 0-based protocol address of its first word.

    ``lo``/``hi`` bound the raw integer (for a bit field ``hi`` is the mask of defined bits,
    and any undefined bit set is out of range). Engineering value = raw * ``scale`` ``unit``.
    ``words`` and ``max_value`` follow from the fields and are worked out once (every PLC
    request asks for them).
    """

    address: int
    name: str
    type: RegType
    access: Access
    unit: str = ""
    scale: float = 1.0
    lo: int = 0
    hi: int | None = None
    meaning: str = ""
    bits: tuple[Bit, ...] = ()

    @functools.cached_property
    def words(self) -> int:
        return 2 if self.type is RegType.U32 else 1

    @property
    def modicon(self) -> int:
        """1-based Modicon "4xxxx" reference of the first word."""
        return MODICON_BASE + self.address

    @functools.cached_property
    def max_value(self) -> int:
        if self.type is RegType.BITFIELD:
            return sum(1 << b.index for b in self.bits)
        return self.hi if self.hi is not None else (1 << (16 * self.words)) - 1

    def range_text(self) -> str:
        if self.type is RegType.BITFIELD:
            return f"mask 0x{self.max_value:04X}"
        return f"{self.lo}..{self.max_value}"

    def in_range(self, value: int) -> bool:
        if self.type is RegType.BITFIELD:
            return value >= 0 and value & ~self.max_value == 0
        return self.lo <= value <= self.max_value


class RecipeStatus(enum.IntEnum):
    """The values of ``recipe_status`` (its register's meaning says the same to the PLC)."""

    OK = 0          # recipe_ack = recipe_select
    UNKNOWN = 1     # no recipe of that number
    REJECTED = 2    # the last edit failed validation; the previous version stays active
    BUSY = 3        # a change asked while a cycle runs: refused


def _b(index: int, name: str, meaning: str) -> Bit:
    return Bit(index, name, meaning)


_STATUS_BITS = (
    _b(0, "ready", "Controller accepts execute (or calibrate): auto, homed, no error, not busy, "
                   "and execute and calibrate written low by the PLC since the controller started "
                   "or the link came back. Raise execute or calibrate only while ready."),
    _b(1, "busy", "Cycle or calibration running (PLCopen Busy). Set within one controller scan of the accepted "
                  "execute rising edge; done/error/aborted are cleared at the same time."),
    _b(2, "done", "Cycle finished OK (PLCopen Done). Results and part_id_echo are valid before "
                  "this bit is set. Held until acknowledge."),
    _b(3, "error", "A fault is latched (PLCopen Error); fault_code says why. The joints are "
                   "stopped; held until a reset edge once the cause is gone."),
    _b(4, "auto", "Controller in automatic mode: PLC commands are obeyed."),
    _b(5, "homed", "All joints referenced."),
    _b(6, "recalibration_due", "Accuracy drift says: recalibrate soon (cycles still run). The "
                               "procedure: the kinematic calibration (board in place, "
                               "calibration_select 0, calibrate; or cellctl calibrate kinematics)."),
    _b(7, "aborted", "Last cycle stopped by command abort (PLCopen CommandAborted). Held like done."),
    _b(8, "plc_link_ok", "Controller sees plc_heartbeat changing (its watchdog is satisfied)."),
    _b(9, "execute_refused", "The last execute rising edge was refused (not ready: busy, done or "
                             "error not acknowledged, no recipe, or execute not written low since the "
                             "controller started or the link came back). Cleared by the next accepted "
                             "execute, acknowledge or reset."),
)

_COMMAND_BITS = (
    _b(0, "execute", "Rising edge starts a cycle with recipe_ack's recipe; part_id is latched at "
                     "the edge. Keep it high until done, error or aborted is seen, then drop it."),
    _b(1, "reset", "Rising edge clears error and fault_code if the fault is gone."),
    _b(2, "abort", "Rising edge stops the running cycle; busy drops and aborted is set."),
    _b(3, "acknowledge", "Rising edge clears done/aborted after the PLC has read the results."),
    _b(4, "calibrate", "Rising edge starts the robot calibration calibration_select names (the "
                       "fixture must be in place). Accepted like execute: only while ready; busy, "
                       "then done or error, as for a cycle. Keep it high until done, error or "
                       "aborted is seen, then drop it. Abort and the heartbeat watchdog stop it."),
)

_U16, _U32, _BITS = RegType.U16, RegType.U32, RegType.BITFIELD
_RO, _RW = Access.RO, Access.RW

#: The one register table. Blocks start at 0, 10, 20, 40 and 60; the gaps are reserved.
REGISTERS: tuple[Register, ...] = (
    # -- link block 0..9
    Register(0, "map_version", _U16, _RO, meaning=f"Layout version of this map (currently {MAP_VERSION}). "
             "The PLC program checks it at start-up and refuses to run on a mismatch."),
    Register(1, "plc_heartbeat", _U16, _RW, "count", meaning="The PLC increments it every scan (wraps "
             "65535 -> 0). If it stops changing for the configured timeout, the controller clears "
             "plc_link_ok and ignores commands."),
    Register(2, "controller_heartbeat", _U16, _RO, "count", meaning="The controller increments it every "
             "loop cycle (wraps). A value that stops changing means: controller lost."),
    Register(4, "plant_backlog", _U32, _RO, "count", meaning="Cycle records in the cell's log the plant "
             "historian has not confirmed yet (cell/plant.md); 0 without a plant path. It grows while "
             "the broker, the historian or the network is away: the log keeps every record until it is "
             "confirmed, so cycles go on. High word first."),
    # -- handshake block 10..19
    Register(10, "status_word", _BITS, _RO, meaning="Controller status bits (see bit table).",
             bits=_STATUS_BITS),
    Register(11, "command_word", _BITS, _RW, meaning="PLC command bits, acted on at rising edges "
             "(see bit table). Undefined bits must stay 0.", bits=_COMMAND_BITS),
    Register(12, "state_code", _U16, _RO, meaning="Numeric code of the controller state "
             "(cell/cycle/statemachine.py State): 1 starting, 2 idle, 10-16 cycle steps (approach, capture, "
             "locate, compensate, final move, verify, logging), 20 done, 30 stopping, 31 aborted, "
             "40 fault, 41 resetting, 50 calibrating."),
    Register(13, "fault_code", _U16, _RO, meaning="0 = no fault, else the code of the active (or last "
             "unacknowledged) fault (cell/faults.py: 1xx PLC link, 2xx joint stations = 200 + station "
             "code, 3xx camera/vision, 4xx motion/accuracy, 5xx internal, 6xx calibration). Valid while "
             "status_word.error is set."),
    # -- recipe and part block 20..39
    Register(20, "recipe_select", _U16, _RW, hi=999, meaning="Recipe number the PLC asks for. Applied "
             "when the controller is not busy; answered in recipe_ack and recipe_status."),
    Register(21, "recipe_ack", _U16, _RO, hi=999, meaning="Number of the active recipe."),
    Register(22, "recipe_status", _U16, _RO, hi=max(RecipeStatus), meaning="0 ok (recipe_ack = recipe_select), "
             "1 unknown recipe, 2 last edit rejected (file failed validation; previous version "
             "stays active), 3 change refused while busy."),
    Register(24, "part_id", _U32, _RW, meaning="Identifier of the next part; latched at the execute "
             "rising edge. High word first."),
    Register(26, "part_id_echo", _U32, _RO, meaning="part_id latched for the cycle whose results are "
             "shown. High word first."),
    # -- results block 40..59 (last cycle, valid when done or error is set)
    Register(40, "initial_error_um", _U32, _RO, "um", meaning="Position error measured before "
             "correction, last cycle."),
    Register(42, "final_error_um", _U32, _RO, "um", meaning="Position error after the last "
             "correction move, last cycle."),
    Register(44, "moves", _U32, _RO, "count", meaning="Correction moves made in the last cycle."),
    Register(46, "cycle_time_ms", _U32, _RO, "ms", meaning="Duration from execute edge to done/error."),
    Register(48, "cycle_count", _U32, _RO, "count", meaning="Cycles completed since controller start."),
    # -- calibration block 60..69 (seed 004 / seed 001 from the hand camera)
    Register(60, "calibration_select", _U16, _RW, hi=4, meaning="What the calibrate bit starts: 0 "
             "kinematic calibration over the board (seed 001; the board must be in place), 1, 2 or 4 "
             "single-joint calibration of j1, j2 or j4 (seed 004; the target under the hand camera "
             "at the all-zero pose). 3 (j3, prismatic) is refused with fault 601."),
    Register(61, "calibration_version", _U16, _RO, meaning="Version of the robot calibration the "
             "cycles run with (0 = the nominal model). A kinematic calibration that passes its "
             "held-out check is written, applied at once and raises it."),
    Register(62, "calibration_residual_um", _U32, _RO, "um", meaning="Last kinematic calibration: RMS "
             "position error on the held-out poses with the calibrated model. 0 after a joint "
             "calibration."),
    Register(64, "calibration_residual_udeg", _U32, _RO, "udeg", meaning="Last joint calibration: RMS "
             "residual of its error model (backlash, gear ratio, cyclic), micro-degrees. 0 after a "
             "kinematic calibration."),
)

HANDSHAKE = """\
Cycle handshake (PLCopen Execute/Busy/Done/Error, as Epson remote I/O and UR's Modbus map):

1. PLC writes recipe_select; waits until recipe_ack = recipe_select and recipe_status is 0
   (or 2: an edit of some recipe file was rejected, the last good versions still run).
2. PLC writes part_id (both words, one FC16), waits for status_word.ready, then in a later
   write sets command_word.execute.
3. Controller latches recipe and part_id at the execute rising edge and sets status_word.busy
   (only if ready; otherwise it sets execute_refused and starts nothing).
4. Controller writes the results and part_id_echo, then sets done (or error + fault_code,
   or aborted after an abort edge) and clears busy.
5. PLC reads the results, drops execute and pulses acknowledge; the controller clears
   done/aborted. An error is a latched fault: the joints are stopped and nothing moves
   until the PLC pulses reset and the cause is gone; then error and fault_code clear.
6. Execute counts only as a rising edge the PLC writes while plc_heartbeat is alive, after
   the PLC has WRITTEN execute low (and calibrate low; with its heartbeat alive) since the
   controller started or the link came back. A value merely sitting low in the registers does not arm; an execute
   held high across a heartbeat gap, a reconnect or a controller restart - or rewritten high
   after it - starts nothing. After any of these, write command_word with execute = 0, wait
   for ready, then raise execute. A PLC that writes its outputs every scan does so anyway.
7. Restart: a cycle that a controller restart (crash, power loss, service restart) cut off is
   reported once, at the next start: error with fault_code 503 and its part id in
   part_id_echo; its row in the cycle log says aborted, 503. Pulse reset to clear it (the
   part's state is unknown: check it before the next cycle). Nothing moves until then.
8. Calibration: with the fixture in place and the work area clear, the PLC writes
   calibration_select (0 kinematics over the board, 1/2/4 joint j1/j2/j4), waits for ready
   and raises calibrate. Busy, state_code 50 (calibrating), then done, error + fault_code
   (601 refused, 602 a target not measured, 603 the fit or its held-out check failed -
   nothing is written) or aborted, exactly as for a cycle; acknowledge or reset as for a
   cycle. At done: calibration_residual_um (kinematics: held-out RMS after) or
   calibration_residual_udeg (joint: model residual RMS); a kinematic calibration also
   raises calibration_version, and the next cycle already runs with it. Abort, the
   heartbeat watchdog and station faults stop a calibration like a cycle. A kinematic
   calibration takes minutes (about 40 poses): keep the heartbeat going.
9. Time-outs: every device wait has one and turns into a fault - a camera grab
   (vision.grab_timeout_s, 301), a move (cycle.move_timeout_s, 403), a drive's SDO answer
   (stations.sdo_timeout_s, re-sent up to stations.sdo_attempts times; at start-up the
   controller then refuses to start, naming the drive; in a reset the fault stays). An abort
   ends the wait at once: aborted is set at the scan after the abort edge, even while a grab
   hangs.

Writes the map refuses are answered with Modbus exception 02 (unknown or reserved address,
read-only register, half of a 32-bit pair) or 03 (value out of range) and change nothing,
even in a multi-register write where only one value is bad."""


class ImageView(Mapping[str, int]):
    """The named values of a register image, each decoded (high word first for u32) only
    when it is read: a PLC scan reads the whole map, a handshake step looks at two or three
    registers of it. Built by :meth:`RegisterMap.view`."""

    __slots__ = ("_words", "_at")

    def __init__(self, words: Sequence[int], at: Mapping[str, tuple[int, int]]):
        self._words, self._at = words, at

    def __getitem__(self, name: str) -> int:
        a, n = self._at[name]
        return (self._words[a] << 16) | self._words[a + 1] if n == 2 else self._words[a]

    def __iter__(self) -> Iterator[str]:
        return iter(self._at)

    def __len__(self) -> int:
        return len(self._at)


class RegisterMap:
    """An ordered, validated set of :class:`Register` covering addresses ``0 .. size-1``.

    Raises :class:`PlcMapError` at construction on overlapping addresses, duplicate names,
    entries beyond ``size`` or ill-formed bit fields.
    """

    def __init__(self, registers: Sequence[Register], size: int, version: int):
        self.version = version
        self.size = size
        self._by_name: dict[str, Register] = {}
        self._by_addr: dict[int, tuple[Register, int]] = {}
        for reg in sorted(registers, key=lambda r: r.address):
            if reg.name in self._by_name:
                raise PlcMapError(f"register map: name {reg.name!r} used twice")
            if not (0 <= reg.address and reg.address + reg.words <= size):
                raise PlcMapError(f"register map: {reg.name} at {reg.address} ({reg.words} words) "
                                  f"is outside 0..{size - 1}")
            if (reg.type is RegType.BITFIELD) != bool(reg.bits):
                raise PlcMapError(f"register map: {reg.name}: bits are given iff type is bitfield")
            if len({b.index for b in reg.bits}) != len(reg.bits) or any(
                    not 0 <= b.index < 16 for b in reg.bits):
                raise PlcMapError(f"register map: {reg.name}: bit indices must be unique, 0..15")
            for i in range(reg.words):
                if reg.address + i in self._by_addr:
                    other = self._by_addr[reg.address + i][0].name
                    raise PlcMapError(f"register map: {reg.name} overlaps {other} at address "
                                      f"{reg.address + i}")
                self._by_addr[reg.address + i] = (reg, i)
            self._by_name[reg.name] = reg
        # name -> (address, words): what an image view decodes a register from
        self._at = {r.name: (r.address, r.words) for r in self._by_name.values()}
        self._plans: dict[tuple[int, int], tuple[tuple[Register, int], ...]] = {}   # see _write_plan

    # -- look-ups
    def __iter__(self) -> Iterator[Register]:
        return iter(self._by_name.values())

    def __len__(self) -> int:
        return len(self._by_name)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __getitem__(self, name: str) -> Register:
        try:
            return self._by_name[name]
        except KeyError:
            raise PlcMapError(f"register map: no register named {name!r}") from None

    @property
    def names(self) -> list[str]:
        return list(self._by_name)

    def at(self, address: int) -> tuple[Register, int] | None:
        """(register, word index 0/1) holding protocol ``address``, or None if reserved/absent."""
        return self._by_addr.get(address)

    def reserved(self) -> list[tuple[int, int]]:
        """Inclusive (first, last) protocol-address ranges inside ``size`` with no register."""
        out: list[tuple[int, int]] = []
        for a in range(self.size):
            if a not in self._by_addr:
                if out and out[-1][1] == a - 1:
                    out[-1] = (out[-1][0], a)
                else:
                    out.append((a, a))
        return out

    # -- values
    def check(self, name: str, value: int) -> int:
        """Return ``value`` as int if it fits register ``name``; raise :class:`PlcMapError`."""
        reg = self[name]
        if isinstance(value, bool) or not isinstance(value, int):
            raise PlcMapError(f"register {name}: value {value!r} is not an integer")
        if not reg.in_range(value):
            raise PlcMapError(f"register {name}: value {value} outside {reg.range_text()}")
        return value

    def to_words(self, name: str, value: int) -> list[int]:
        """Register words for ``value`` (high word first for u32); validates like :meth:`check`."""
        value = self.check(name, value)
        return [(value >> 16) & 0xFFFF, value & 0xFFFF] if self[name].words == 2 else [value]

    def from_words(self, name: str, words: Sequence[int]) -> int:
        """Integer value of register ``name`` from its words (high word first)."""
        reg = self[name]
        if len(words) != reg.words:
            raise PlcMapError(f"register {name}: needs {reg.words} words, got {len(words)}")
        return (words[0] << 16) | words[1] if reg.words == 2 else words[0]

    def view(self, image: Sequence[int]) -> ImageView:
        """The named values of a full image of ``size`` words (e.g. one FC3 read of the map),
        each decoded when it is read. Raises :class:`PlcMapError` for a short image."""
        if len(image) < self.size:
            raise PlcMapError(f"register map: image has {len(image)} words, map needs {self.size}")
        return ImageView(image, self._at)

    def decode_image(self, image: Sequence[int]) -> dict[str, int]:
        """All named values of a full image, decoded now (see :meth:`view`)."""
        return dict(self.view(image))

    def bits(self, name: str, value: int) -> dict[str, bool]:
        """Named bits of bit-field register ``name`` in ``value``."""
        reg = self[name]
        if reg.type is not RegType.BITFIELD:
            raise PlcMapError(f"register {name} is {reg.type.value}, not a bit field")
        return {b.name: bool(value >> b.index & 1) for b in reg.bits}

    def mask(self, name: str, *bits: str) -> int:
        """The mask of the named bits of bit-field register ``name`` (the constants a program
        tests a word against); an unknown bit -> error."""
        return self.with_bits(name, 0, dict.fromkeys(bits, True))

    def with_bits(self, name: str, value: int, flags: Mapping[str, bool]) -> int:
        """``value`` with the named bits of register ``name`` set/cleared; unknown bit -> error."""
        reg = self[name]
        index = {b.name: b.index for b in reg.bits}
        if reg.type is not RegType.BITFIELD:
            raise PlcMapError(f"register {name} is {reg.type.value}, not a bit field")
        for bit, on in flags.items():
            if bit not in index:
                raise PlcMapError(f"register {name}: no bit named {bit!r} (has {', '.join(index)})")
            value = value | (1 << index[bit]) if on else value & ~(1 << index[bit])
        return value

    def decode_plc_write(self, address: int, words: Sequence[int]) -> dict[str, int]:
        """Named values a PLC register write (FC6/FC16/FC23) of ``words`` at ``address`` sets.

        Raises :class:`IllegalDataAddress` (unknown/reserved address, RO register, half of a
        u32) or :class:`IllegalDataValue` (out of range); nothing is decided piecemeal, so the
        caller applies all values or none. Which registers a write of ``len(words)`` words at
        ``address`` covers is decided once (:meth:`_write_plan`); each write then decodes
        and range-checks only its values.
        """
        plan = self._write_plan(address, len(words))
        out: dict[str, int] = {}
        for reg, at in plan:
            out[reg.name] = (words[at] << 16) | words[at + 1] if reg.words == 2 else words[at]
        for reg, _ in plan:
            value = out[reg.name]
            if not reg.in_range(value):
                raise IllegalDataValue(f"PLC write to {reg.name}: value {value} outside {reg.range_text()}")
        return out

    def _write_plan(self, address: int, count: int) -> tuple[tuple[Register, int], ...]:
        """The registers a PLC write of ``count`` words at ``address`` sets, each with the
        index of its first word in the write, in address order; cached per (address, count)
        (at most ``size``² entries). Raises :class:`IllegalDataAddress` as
        :meth:`decode_plc_write` says (not cached: a refusal is rare and logged anyway)."""
        plan = self._plans.get((address, count))
        if plan is not None:
            return plan
        regs: list[tuple[Register, int]] = []
        end = address + count
        for a in range(address, end):
            hit = self.at(a)
            if hit is None:
                raise IllegalDataAddress(f"PLC write to address {a} ({MODICON_BASE + a}): no register there")
            reg, _ = hit
            if reg.access is not Access.RW:
                raise IllegalDataAddress(f"PLC write to {reg.name} at {a}: register is read-only")
            if reg.address < address or reg.address + reg.words > end:
                raise IllegalDataAddress(f"PLC write to {reg.name} at {a}: a 32-bit register must be "
                                         f"written whole (addresses {reg.address}..{reg.address + 1})")
            if not regs or regs[-1][0] is not reg:
                regs.append((reg, reg.address - address))
        plan = self._plans[(address, count)] = tuple(regs)
        return plan

    def decode_plc_bit_write(self, bit_address: int, bits: Sequence[bool],
                             current: Mapping[str, int]) -> dict[str, int]:
        """Named values a PLC coil write (FC5/FC15) of ``bits`` at coil ``bit_address`` sets.

        ``current`` holds the present register values (the bits not written keep theirs).
        Only RW bit-field registers take coil writes. Raises like :meth:`decode_plc_write`.
        """
        out: dict[str, int] = {}
        for i, on in enumerate(bits):
            a, n = divmod(bit_address + i, 16)
            hit = self.at(a)
            if hit is None or hit[0].type is not RegType.BITFIELD or hit[0].access is not Access.RW:
                raise IllegalDataAddress(f"PLC coil write to coil {bit_address + i} (register {a} bit "
                                         f"{n}): not a bit of a writable bit-field register")
            name = hit[0].name
            value = out.get(name, current[name])
            out[name] = value | (1 << n) if on else value & ~(1 << n)
        for name, value in out.items():
            if not self[name].in_range(value):
                raise IllegalDataValue(f"PLC coil write to {name}: undefined bit set "
                                       f"(value 0x{value:04X}, {self[name].range_text()})")
        return out

    # -- documents
    def rows(self) -> list[dict[str, str]]:
        """One dict per register and per bit (CSV columns), registers in address order."""
        rows = []
        for r in self:
            last = f"-{r.modicon + 1}" if r.words == 2 else ""
            rows.append({"address": str(r.address), "modicon": f"{r.modicon}{last}", "name": r.name,
                         "type": r.type.value, "words": str(r.words), "access": r.access.value,
                         "unit": r.unit, "scale": f"{r.scale:g}", "min": str(r.lo),
                         "max": str(r.max_value), "bit": "", "meaning": r.meaning})
            for b in r.bits:
                rows.append({"address": str(r.address), "modicon": str(r.modicon),
                             "name": f"{r.name}.{b.name}", "type": "bit", "words": "",
                             "access": r.access.value, "unit": "", "scale": "", "min": "0",
                             "max": "1", "bit": str(b.index), "meaning": b.meaning})
        return rows

    def to_csv(self) -> str:
        """The table as CSV (header row, then :meth:`rows`), for PLC tag import."""
        buf = io.StringIO()
        rows = self.rows()
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        return buf.getvalue()

    def to_markdown(self) -> str:
        """Register reference for docs/plc.md: address base, table, bit tables, handshake."""
        esc = lambda s: s.replace("|", "\\|")  # noqa: E731
        out = [f"### PLC register map (map_version {self.version})", "",
               "All entries are holding registers (FC3 read; the PLC writes RW entries with "
               "FC6/FC16). *Address* is the 0-based protocol address in the Modbus PDU; "
               f"*4x ref* is the 1-based Modicon reference ({MODICON_BASE} + address). u32 values "
               "take two registers, high word first, written together. Bit n of register r "
               "is coil/discrete input 16·r + n.", "",
               "| Address | 4x ref | Name | Type | Access | Unit | Scale | Range | Meaning |",
               "|---:|---:|---|---|---|---|---:|---|---|"]
        for r in self:
            addr = f"{r.address}-{r.address + 1}" if r.words == 2 else str(r.address)
            ref = f"{r.modicon}-{r.modicon + 1}" if r.words == 2 else str(r.modicon)
            out.append(f"| {addr} | {ref} | `{r.name}` | {r.type.value} | {r.access.value} | "
                       f"{r.unit} | {r.scale:g} | {r.range_text()} | {esc(r.meaning)} |")
        reserved = ", ".join(f"{a}-{b}" if a != b else str(a) for a, b in self.reserved())
        out += ["", f"Reserved (read 0, writes refused): {reserved}. Addresses >= {self.size} "
                "do not exist.", ""]
        for r in self:
            if r.bits:
                out += [f"#### `{r.name}` bits ({r.access.value})", "",
                        "| Bit | Coil/DI | Name | Meaning |", "|---:|---:|---|---|"]
                out += [f"| {b.index} | {16 * r.address + b.index} | `{b.name}` | {esc(b.meaning)} |"
                        for b in r.bits]
                out.append("")
        out += ["#### Handshake", "", "```", HANDSHAKE, "```", ""]
        return "\n".join(out)


#: The cell controller's register map: 70 registers, 0..69 (the named ones and the gaps
#: between its blocks).
PLC_MAP = RegisterMap(REGISTERS, size=70, version=MAP_VERSION)
