"""CAN bus factory (backends by name) and classic-CAN bit timing.

:func:`open_bus` builds the bus named in the config: ``"virtual"`` is the simulated cell's
wire (:mod:`cell.sim.canbus`, python-can's ``virtual`` interface with a bitrate, on the
simulated clock), imported only when a config names it; every other name goes to
python-can's own interface registry (``socketcan``, ``pcan``, ``kvaser``, ...), imported
lazily by python-can. :func:`connect_network` hooks a canopen ``Network`` to either. The
driver never asks which one it got.

:func:`frame_bits` counts a frame's bits on the wire exactly (stuff bits included): the
simulated wire uses it for slot times, the driver for the wire part of seed 002's delay.
"""
from __future__ import annotations

import functools
import importlib
from typing import Any

import can
import canopen

from cell.errors import ConfigError

# ------------------------------------------------------------------------------ bit timing
_FIXED_TAIL_BITS = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, EOF, intermission
_ERROR_FRAME_BITS = 6 + 8 + 3      # error flag, error delimiter, intermission


def _crc15(bits: list[int]) -> int:
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def frame_bits(msg: can.Message) -> int:
    """Bits a classic CAN frame occupies on the wire, stuff bits and inter-frame space included.

    Stuffing is counted exactly over SOF..CRC (a complementary bit after five equal ones).
    Error frames count 17 bits. :raises ValueError: for CAN FD frames (not modelled).
    """
    if msg.is_fd:
        raise ValueError("CAN FD frames are not modelled by the virtual wire")
    if msg.is_error_frame:
        return _ERROR_FRAME_BITS
    dlc = min(len(msg.data), 8) if not msg.is_remote_frame else min(msg.dlc, 8)
    data = b"" if msg.is_remote_frame else bytes(msg.data[:dlc])
    return _data_frame_bits(msg.arbitration_id, bool(msg.is_extended_id), bool(msg.is_remote_frame), dlc, data)


@functools.lru_cache(maxsize=4096)
def _data_frame_bits(arbitration_id: int, extended: bool, remote: bool, dlc: int, data: bytes) -> int:
    rtr = 1 if remote else 0
    if extended:
        aid = arbitration_id & 0x1FFFFFFF
        bits = [0] + _bits(aid >> 18, 11) + [1, 1] + _bits(aid & 0x3FFFF, 18) + [rtr, 0, 0]
    else:
        bits = [0] + _bits(arbitration_id & 0x7FF, 11) + [rtr, 0, 0]
    bits += _bits(dlc, 4)
    for byte in data:
        bits += _bits(byte, 8)
    bits += _bits(_crc15(bits), 15)
    stuffed, run, last = 0, 0, -1
    for b in bits:
        if b == last:
            run += 1
        else:
            run, last = 1, b
        if run == 5:  # insert the complement; it starts a new run of length 1
            stuffed += 1
            last, run = 1 - b, 1
    return len(bits) + stuffed + _FIXED_TAIL_BITS


def frame_time_s(msg: can.Message, bitrate: int) -> float:
    """Seconds ``msg`` occupies a bus running at ``bitrate`` bit/s."""
    return frame_bits(msg) / bitrate


# ------------------------------------------------------------------------------ factory
#: our own backends by name ("module:function"), imported only when a config names them
BACKENDS = {"virtual": "cell.sim.canbus:open_virtual_bus"}


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
        module, func = BACKENDS[interface].split(":")
        return getattr(importlib.import_module(module), func)(channel, bitrate, clock=clock, **kwargs)
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
