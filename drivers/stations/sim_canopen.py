"""The simulated drive's side of canopen: its network, the listener that feeds it and its
PDO encoding. The device side is ours, so a drive takes the short way through canopen
where the library's generic path only costs time: a drive sends or takes a PDO every few
ms of simulated time, a thousand frames per simulated second for the four of them.

Used by :class:`drivers.stations.sim.SimStation`; nothing here is part of the controller.
"""
from __future__ import annotations

import struct
from typing import Callable

import can
import canopen
from canopen.objectdictionary.datatypes import INTEGER_TYPES


class DriveNetwork(canopen.Network):
    """The station's side of the bus: a send the wire refuses puts the node bus-off.

    ``send_message`` builds the frame as canopen's does and hands it to the bus's
    ``send_own`` where it has one (:class:`~drivers.stations.sim_bus.VirtualCanBus`: the
    wire delivers that frame, no copy, as nothing else holds it), else to ``send``. It
    skips canopen's ``check`` of a notifier: the drive's bus feeds its listener directly
    and has none. Every (un)subscribe tells the bus (``reroute``), which a
    :class:`~drivers.stations.sim_bus.VirtualCanBus` whose ``wants`` are the subscriptions
    needs."""

    def __init__(self, bus: can.BusABC, on_tx_failure: Callable[[Exception], None]):
        super().__init__(bus)
        self._on_tx_failure = on_tx_failure

    def subscribe(self, can_id: int, callback) -> None:
        super().subscribe(can_id, callback)
        self._reroute()

    def unsubscribe(self, can_id, callback=None) -> None:
        super().unsubscribe(can_id, callback)
        self._reroute()

    def _reroute(self) -> None:
        reroute = getattr(self.bus, "reroute", None)   # the bus asks the subscriptions (wants)
        if reroute is not None:
            reroute()

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        bus = self.bus
        if not bus:
            raise RuntimeError("Not connected to CAN bus")
        msg = can.Message(is_extended_id=can_id > 0x7FF, arbitration_id=can_id, data=data,
                          is_remote_frame=remote)
        try:
            with self.send_lock:
                getattr(bus, "send_own", bus.send)(msg)
        except can.CanError as exc:
            self._on_tx_failure(exc)
            raise


class DriveListener(can.Listener):
    """Hands each frame the drive's bus receives straight to its network's subscribers:
    canopen's ``MessageListener`` and ``Network.notify`` in one step, without the node
    scanner (which notes every sender for a node scan a drive never makes). Error and
    remote frames are dropped, as canopen drops them."""

    def __init__(self, net: canopen.Network):
        self._subscribers = net.subscribers

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            return
        callbacks = self._subscribers.get(msg.arbitration_id)
        if callbacks:
            can_id, data, timestamp = msg.arbitration_id, msg.data, msg.timestamp
            for callback in callbacks:
                callback(can_id, data, timestamp)


class PdoCodec:
    """A PDO's mapped objects as one ``struct.Struct``: ``pack(*values)`` gives, and
    ``unpack_from(data)`` reads, the same bytes as canopen's ``encode_raw`` / ``decode_raw``
    per variable, in one call (a drive sends or takes a PDO every few ms).

    ``indices``: the mapped objects' indices in map order; ``struct``: little-endian, their
    integer types one after the other. Built by :func:`pdo_codec`.
    """

    __slots__ = ("indices", "struct")

    def __init__(self, indices: tuple[int, ...], fmt: str):
        self.indices = indices
        self.struct = struct.Struct(fmt)


def pdo_codec(pdo_map) -> PdoCodec | None:
    """The codec of ``pdo_map``, or None when a mapped variable is not an integer type on
    whole bytes, the variables leave a gap, or nothing is mapped (then canopen's own
    per-variable path is taken)."""
    fmt, indices, at = "<", [], 0
    for v in pdo_map.map:
        if not v.length:
            continue
        st = v.od.STRUCT_TYPES.get(v.od.data_type)
        if (v.od.data_type not in INTEGER_TYPES or not isinstance(st, struct.Struct)
                or v.offset != at or v.length != 8 * st.size or len(v.od) != v.length):
            return None
        fmt += st.format.lstrip("<")
        indices.append(v.index)
        at += v.length
    if not indices or at != pdo_map.length:
        return None
    return PdoCodec(tuple(indices), fmt)
