"""CAN bus factory (backends by name) and classic-CAN bit timing.

:func:`open_bus` builds the bus named in the config: ``"virtual"`` is the simulated cell's
wire (:mod:`drivers.stations.sim_bus`, python-can's ``virtual`` interface with a bitrate, on the
simulated clock), imported only when a config names it; every other name goes to
python-can's own interface registry (``socketcan``, ``pcan``, ``kvaser``, ...), imported
lazily by python-can. :func:`connect_network` hooks a canopen ``Network`` to either. The
driver never asks which one it got.

:func:`frame_bits` counts a frame's bits on the wire exactly (stuff bits included): the
simulated wire uses it for slot times, the driver for the wire part of seed 002's delay;
:class:`FrameLayout` counts the frames that differ only in their last bytes.
"""
from __future__ import annotations

import functools
from typing import Any

import can
import canopen

from cell.errors import ConfigError
from drivers import registry

# ------------------------------------------------------------------------------ bit timing
_FIXED_TAIL_BITS = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, EOF, intermission
_ERROR_FRAME_BITS = 6 + 8 + 3      # error flag, error delimiter, intermission


_CRC15_POLY = 0x4599


def _crc15_table() -> list[int]:
    table = []
    for i in range(256):
        reg = i << 7
        for _ in range(8):
            reg = ((reg << 1) ^ _CRC15_POLY) & 0x7FFF if reg & 0x4000 else (reg << 1) & 0x7FFF
        table.append(reg)
    return table


_CRC15_TABLE = _crc15_table()


def _crc15(value: int, nbits: int) -> int:
    """CAN's CRC-15 of the ``nbits``-bit sequence ``value`` (most significant bit first):
    the leading ``nbits % 8`` bits one at a time, the rest a byte at a time by table."""
    crc = 0
    lead = nbits % 8
    for i in range(lead):
        bit = (value >> (nbits - 1 - i)) & 1
        crc = (((crc << 1) & 0x7FFF) ^ _CRC15_POLY) if bit ^ (crc >> 14) else (crc << 1) & 0x7FFF
    rest = nbits - lead
    for byte in (value & ((1 << rest) - 1)).to_bytes(rest // 8, "big"):
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15_TABLE[((crc >> 7) ^ byte) & 0xFF]
    return crc


def _stuff_step(state: int, bit: int) -> tuple[int, int]:
    """One bit through CAN's stuffing: (next state, stuff bits inserted). A state is 0
    (no bit yet) or 1 + 4·value + (run length − 1) for a run of 1..4 equal bits; the fifth
    equal bit is followed by a complementary stuff bit, which starts a run of one."""
    if state and (state - 1) // 4 == bit:
        run = (state - 1) % 4 + 2
        if run == 5:
            return 1 + 4 * (1 - bit), 1
        return 1 + 4 * bit + run - 1, 0
    return 1 + 4 * bit, 0


def _stuff_table(bit_table: list[list[tuple[int, int]]], width: int) -> list[list[tuple[int, int]]]:
    """Per stuffing state: the (next state, stuff bits) of each ``width``-bit value, MSB
    first, carried through ``bit_table``."""
    table = []
    for st0 in range(9):
        row = []
        for value in range(1 << width):
            st, n = st0, 0
            for k in range(width - 1, -1, -1):
                st, d = bit_table[st][(value >> k) & 1]
                n += d
            row.append((st, n))
        table.append(row)
    return table


_STUFF_BIT = [[_stuff_step(st, b) for b in (0, 1)] for st in range(9)]   # per state, of one bit
_STUFF_BYTE = _stuff_table(_STUFF_BIT, 8)


def _stuff_bits(value: int, nbits: int) -> int:
    """Stuff bits CAN inserts in the ``nbits``-bit sequence ``value`` (MSB first): one after
    every 5 equal bits; a stuff bit counts towards the run that follows it when that run
    has its value. The leading ``nbits % 8`` bits go one at a time, the rest a byte at a
    time through a table of the stuffing's states."""
    return _stuff_run(0, value, nbits)[1]


def _stuff_run(state: int, value: int, nbits: int) -> tuple[int, int]:
    """:func:`_stuff_bits` from the stuffing's ``state`` on: (state after, stuff bits)."""
    stuffed = 0
    lead = nbits % 8
    for i in range(lead):
        state, d = _STUFF_BIT[state][(value >> (nbits - 1 - i)) & 1]
        stuffed += d
    rest = nbits - lead
    for byte in (value & ((1 << rest) - 1)).to_bytes(rest // 8, "big"):
        state, d = _STUFF_BYTE[state][byte]
        stuffed += d
    return state, stuffed


def frame_bits(msg: can.Message) -> int:
    """Bits a classic CAN frame occupies on the wire, stuff bits and inter-frame space included.

    Stuffing is counted exactly over SOF..CRC (a complementary bit after five equal ones).
    Error frames count 17 bits. :raises ValueError: for CAN FD frames (not modelled).
    """
    if msg.is_fd:
        raise ValueError("CAN FD frames are not modelled by the virtual wire")
    if msg.is_error_frame:
        return _ERROR_FRAME_BITS
    if not (msg.is_remote_frame or msg.is_extended_id):
        # the usual frame, counted at once: its data rarely repeats, a cache would only churn
        data = msg.data if len(msg.data) <= 8 else msg.data[:8]
        return _layout(msg.arbitration_id, len(data)).bits(data)
    dlc = min(len(msg.data), 8) if not msg.is_remote_frame else min(msg.dlc, 8)
    data = b"" if msg.is_remote_frame else bytes(msg.data[:dlc])
    return _data_frame_bits(msg.arbitration_id, bool(msg.is_extended_id), bool(msg.is_remote_frame), dlc, data)


def data_frame_bits(arbitration_id: int, data: bytes) -> int:
    """:func:`frame_bits` of a standard-identifier data frame, without building a Message."""
    return _data_frame_bits(arbitration_id, False, False, len(data), bytes(data))


@functools.lru_cache(maxsize=8192)
def _data_frame_bits(arbitration_id: int, extended: bool, remote: bool, dlc: int, data: bytes) -> int:
    if not (extended or remote):
        return _layout(arbitration_id, dlc).bits(data)
    rtr = 1 if remote else 0
    if extended:      # SOF, base id 11, SRR, IDE, id extension 18, RTR, r1, r0
        aid = arbitration_id & 0x1FFFFFFF
        head, n = (((aid >> 18) << 2 | 0b11) << 18 | (aid & 0x3FFFF)) << 3 | rtr << 2, 1 + 11 + 2 + 18 + 3
    else:             # SOF, id 11, RTR, IDE, r0
        head, n = (arbitration_id & 0x7FF) << 3 | rtr << 2, 1 + 11 + 3
    value = (head << 4 | dlc) << 8 * len(data) | int.from_bytes(data, "big")
    n += 4 + 8 * len(data)
    value, n = value << 15 | _crc15(value, n), n + 15
    return n + _stuff_bits(value, n) + _FIXED_TAIL_BITS


_STUFF_CRC7 = _stuff_table(_STUFF_BIT, 7)   # a CRC-15's first 7 bits (its last 8: the byte table)


@functools.lru_cache(maxsize=4096)
def _frame_start(arbitration_id: int, dlc: int) -> tuple[int, int, int]:
    """(CRC register, stuffing state, stuff bits so far) after a standard data frame's SOF,
    identifier, RTR, IDE, r0 and DLC: where every frame with that identifier and length
    goes on from."""
    value, nbits = ((arbitration_id & 0x7FF) << 3) << 4 | dlc, 1 + 11 + 3 + 4
    return (_crc15(value, nbits), *_stuff_run(0, value, nbits))


class FrameLayout:
    """:func:`data_frame_bits` of the standard data frames with one identifier, one length
    and the same leading data bytes, for any trailing bytes: the CRC register and the
    stuffing's state after the fixed part are computed once (from the identifier's and
    length's, cached, on through the head's bytes), so a frame costs only its own trailing
    bytes and its CRC (a set-point's velocity tried against its own frame length,
    :meth:`~drivers.stations.streaming.StreamingMixin.corrected_velocities`). CRC and
    stuffing are bit-serial state machines: carried on a byte (or 7 bits) at a time by
    table, they count exactly what :func:`data_frame_bits` counts.

    :param arbitration_id: 11-bit identifier.
    :param head: the leading data bytes every frame shares.
    :param dlc: data bytes per frame, head included (0..8).
    :raises ValueError: ``head`` longer than ``dlc``, or ``dlc`` beyond 8.
    """

    __slots__ = ("_crc", "_state", "_stuffed", "_tail", "_fixed")

    def __init__(self, arbitration_id: int, head: bytes, dlc: int):
        if not 0 <= len(head) <= dlc <= 8:
            raise ValueError(f"FrameLayout: {len(head)} head bytes in a frame of {dlc} (at most 8)")
        crc, state, stuffed = _frame_start(arbitration_id & 0x7FF, dlc)
        crc_table, stuff_byte = _CRC15_TABLE, _STUFF_BYTE
        for byte in head:
            crc = ((crc << 8) & 0x7FFF) ^ crc_table[((crc >> 7) ^ byte) & 0xFF]
            state, d = stuff_byte[state][byte]
            stuffed += d
        self._crc, self._state, self._stuffed = crc, state, stuffed
        self._tail = dlc - len(head)
        self._fixed = 1 + 11 + 3 + 4 + 8 * dlc + 15 + _FIXED_TAIL_BITS   # SOF..DLC, data, CRC, tail

    def bits(self, tail: bytes) -> int:
        """Bits on the wire of the frame ending in ``tail`` (``dlc - len(head)`` bytes), as
        :func:`data_frame_bits` counts them. :raises ValueError: a tail of another length."""
        if len(tail) != self._tail:
            raise ValueError(f"FrameLayout: a tail of {len(tail)} bytes, the layout has {self._tail}")
        crc, state, stuffed = self._crc, self._state, self._stuffed
        crc_table, stuff_byte = _CRC15_TABLE, _STUFF_BYTE
        for byte in tail:
            crc = ((crc << 8) & 0x7FFF) ^ crc_table[((crc >> 7) ^ byte) & 0xFF]
            state, d = stuff_byte[state][byte]
            stuffed += d
        state, d = _STUFF_CRC7[state][crc >> 8]       # the CRC's first 7 bits, then its last byte
        return self._fixed + stuffed + d + stuff_byte[state][crc & 0xFF][1]


@functools.lru_cache(maxsize=4096)
def _layout(arbitration_id: int, dlc: int) -> FrameLayout:
    return FrameLayout(arbitration_id, b"", dlc)


def frame_time_s(msg: can.Message, bitrate: int) -> float:
    """Seconds ``msg`` occupies a bus running at ``bitrate`` bit/s."""
    return frame_bits(msg) / bitrate


# ------------------------------------------------------------------------------ factory
#: our own backends by name ("module:function"), imported only when a config names them
BACKENDS = {"virtual": "drivers.stations.sim_bus:open_virtual_bus"}


def open_bus(interface: str, channel: str, bitrate: int | None = 1_000_000, *,
             clock=None, **kwargs: Any) -> can.BusABC:
    """Open the CAN bus the config names.

    :param interface: ``"virtual"`` (the simulated cell's wire) or any python-can
        interface name (``socketcan``, ``pcan``, ``kvaser``, ``vector``, ...).
    :param channel: channel name (``"can0"``, ``"PCAN_USBBUS1"``, any name for virtual).
    :param bitrate: bit/s, passed to the interface.
    :param clock: the clock the bus runs on; the virtual wire needs the simulated clock,
        hardware interfaces ignore it (their frames are stamped by the interface).
    :raises ConfigError: unknown interface name, or a bad value for the virtual wire.
    :raises can.CanError: the interface exists but could not be opened.
    """
    if interface in BACKENDS:
        return registry.load(BACKENDS, interface, "stations.interface")(channel, bitrate, clock=clock, **kwargs)
    from can.interfaces import VALID_INTERFACES
    if interface not in VALID_INTERFACES:
        raise ConfigError(f"stations.interface = {interface!r} is not a known CAN interface; "
                          f"known: {sorted(VALID_INTERFACES | set(BACKENDS))}")
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    return can.Bus(interface=interface, channel=channel, **kwargs)


def connect_network(net: canopen.Network) -> None:
    """Start delivering ``net.bus``'s frames to ``net``'s listeners: pushed by the bus
    itself where it can (the simulated wire delivers on its clock), else through
    python-can's notifier thread (``Network.connect``)."""
    attach = getattr(net.bus, "attach_listeners", None)
    if attach is not None:
        attach(net.listeners)
    else:
        net.connect()
