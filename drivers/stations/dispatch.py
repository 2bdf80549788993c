"""The controller network's first listener: frames with a direct handler skip canopen.

canopen hands every received frame to ``Network.notify``, which looks up its subscribers;
a TPDO then passes through the PDO map's ``on_message`` (its reception condition taken and
notified, its period and data kept) before the driver's callback sees it. The driver is the
only reader of its stations' TPDOs and nobody waits on that condition, so
:class:`FrameDispatch` gives those frames (about 630 per part) to the driver's handler at
once and everything else (SDO answers, EMCY, NMT heartbeats) to canopen's own listener,
unchanged. It takes canopen's place at the head of ``Network.listeners``, so the bus
monitor still sees every frame after it, in the same order as before.
"""
from __future__ import annotations

from typing import Callable

import can

from cell.log import get_logger

log = get_logger("stations.driver")

#: a direct handler: (data bytes, bus timestamp s)
FrameHandler = Callable[[bytearray, float], None]


class FrameDispatch(can.Listener):
    """``handlers``: arbitration id → handler, called for each data frame with that id
    (error and remote frames go nowhere, as canopen drops them); every other frame goes to
    ``fallback`` (canopen's ``MessageListener``). A handler that raises is logged and the
    frame is not handed on: as canopen's listener does for its callbacks."""

    def __init__(self, fallback: can.Listener, handlers: dict[int, FrameHandler] | None = None):
        self.fallback = fallback
        self.handlers: dict[int, FrameHandler] = dict(handlers or {})

    def on_message_received(self, msg: can.Message) -> None:
        handler = self.handlers.get(msg.arbitration_id)
        if handler is None:
            self.fallback.on_message_received(msg)
            return
        if msg.is_error_frame or msg.is_remote_frame:
            return
        try:
            handler(msg.data, msg.timestamp)
        except Exception as exc:                 # noqa: BLE001 -- a callback never stops reception
            log.error("frame_handler_failed", cob_id=f"0x{msg.arbitration_id:03X}", error=repr(exc))

    def stop(self) -> None:
        self.fallback.stop()
