"""CAN bus factory (backends by name) and a rate-limited virtual bus.

:func:`open_bus` builds the bus named in the config (STYLE habit 3): ``"virtual"`` is
:class:`RateLimitedVirtualBus` (python-can's in-process ``virtual`` interface behind a
shared wire model), every other name goes to python-can's own interface registry
(``socketcan``, ``pcan``, ``kvaser``, ...), imported lazily by python-can. The driver
never asks which one it got.

Wire model (virtual only). python-can's ``VirtualBus`` delivers frames instantly and
without limit. Here all buses opened on one channel share one :class:`Wire`:

* each frame occupies the wire for ``frame_bits(msg) / bitrate`` seconds, with the
  bit-stuffing computed exactly from the frame's bits (SOF..CRC, CRC-15 included), so an
  8-byte standard data frame takes 111..135 µs at 1 Mbit/s;
* frames go out one after another in the order ``send`` was called (FIFO; real CAN
  arbitrates by identifier, which only matters under contention and is not modelled);
* a frame reaches the other buses at the *end* of its slot, stamped with that wire time
  (``time.time()`` base, like ``VirtualBus``), so received timestamps show the bitrate;
* ``send`` returns once the frame is queued, like a CAN controller with
  ``tx_queue`` transmit mailboxes, and blocks while this bus already has ``tx_queue``
  frames waiting: no sender can push frames faster than the wire carries them.

The sent frame's wire end time is kept in :attr:`RateLimitedVirtualBus.last_tx_timestamp`
(the driver uses it to measure station delays; on hardware it falls back to the time
``send`` returned).
"""
from __future__ import annotations

import threading
import time
from collections import deque
from copy import copy
from typing import Any

import can
from can.interfaces.virtual import VirtualBus

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
    rtr = 1 if msg.is_remote_frame else 0
    if msg.is_extended_id:
        aid = msg.arbitration_id & 0x1FFFFFFF
        bits = [0] + _bits(aid >> 18, 11) + [1, 1] + _bits(aid & 0x3FFFF, 18) + [rtr, 0, 0]
    else:
        bits = [0] + _bits(msg.arbitration_id & 0x7FF, 11) + [rtr, 0, 0]
    bits += _bits(dlc, 4)
    if not msg.is_remote_frame:
        for byte in bytes(msg.data[:dlc]):
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


# ------------------------------------------------------------------------------ the wire
class Wire:
    """One shared virtual CAN wire per channel: slot reservation and timed delivery.

    A delivery thread hands each frame to the receivers when its slot ends. Statistics
    (``frames``, ``bits``) count every frame carried. Created and closed by
    :class:`RateLimitedVirtualBus`; one per channel while any bus is open on it.
    """

    def __init__(self, channel: str, bitrate: int):
        self.channel = channel
        self.bitrate = bitrate
        self.frames = 0
        self.bits = 0
        self._cond = threading.Condition()
        self._free_at = 0.0        # perf_counter time the wire becomes free
        self._queue: deque = deque()  # (end_perf, msg, sender)
        self._epoch = time.time() - time.perf_counter()
        self._users = 0
        self._stop = False
        self._thread = threading.Thread(target=self._deliver, name=f"can-wire-{channel}", daemon=True)
        self._thread.start()

    def reserve(self, msg: can.Message, sender: "RateLimitedVirtualBus") -> float:
        """Queue ``msg`` for the wire; returns its end time as a ``time.time()`` timestamp."""
        bits = frame_bits(msg)
        with self._cond:
            start = max(time.perf_counter(), self._free_at)
            end = start + bits / self.bitrate
            self._free_at = end
            self.frames += 1
            self.bits += bits
            stamped = copy(msg)
            stamped.timestamp = self._epoch + end
            self._queue.append((end, stamped, sender))
            sender._pending += 1
            self._cond.notify_all()
        return self._epoch + end

    def _deliver(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop:
                    self._cond.wait()
                if self._stop and not self._queue:
                    return
                end, msg, sender = self._queue[0]
            delay = end - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            with self._cond:
                self._queue.popleft()
                sender._pending -= 1
                self._cond.notify_all()
            try:
                sender._inner.send(msg)
            except can.CanError:
                pass  # the sender was unplugged mid-frame: the frame is lost, as on a wire

    def wait_slot(self, sender: "RateLimitedVirtualBus", depth: int, timeout: float | None) -> None:
        with self._cond:
            if not self._cond.wait_for(lambda: sender._pending < depth, timeout):
                raise can.CanOperationError(
                    f"virtual CAN {self.channel!r}: transmit queue full ({depth} frames) for {timeout} s")

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout=2.0)


_wires: dict[str, Wire] = {}
_wires_lock = threading.Lock()


def wire_stats(channel: str) -> tuple[int, int] | None:
    """(frames, bits) carried so far on a virtual channel's wire, ``None`` if not open."""
    with _wires_lock:
        w = _wires.get(channel)
        return (w.frames, w.bits) if w else None


class RateLimitedVirtualBus(can.BusABC):
    """python-can ``virtual`` bus whose frames share one bitrate-limited :class:`Wire`.

    :param channel: virtual channel name; buses with the same name see each other.
    :param bitrate: bit/s (10 k .. 1 M); all buses on a channel must agree.
    :param tx_queue: frames this bus may have waiting for the wire before ``send`` blocks.
    :raises ConfigError: bad bitrate or a bitrate differing from the channel's.
    """

    def __init__(self, channel: str = "cell0", bitrate: int = 1_000_000, tx_queue: int = 8, **kwargs: Any):
        if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not 10_000 <= bitrate <= 1_000_000:
            raise ConfigError(f"virtual CAN bitrate = {bitrate!r} must be an integer in 10000..1000000 bit/s")
        if not isinstance(tx_queue, int) or tx_queue < 1:
            raise ConfigError(f"virtual CAN tx_queue = {tx_queue!r} must be an integer ≥ 1")
        with _wires_lock:
            wire = _wires.get(channel)
            if wire is None:
                wire = _wires[channel] = Wire(channel, bitrate)
            elif wire.bitrate != bitrate:
                raise ConfigError(f"virtual CAN channel {channel!r} runs at {wire.bitrate} bit/s; "
                                  f"cannot open it at {bitrate} bit/s")
            wire._users += 1
        self._wire = wire
        self._inner = VirtualBus(channel=f"rl:{channel}", preserve_timestamps=True)
        self._pending = 0
        self._tx_queue = tx_queue
        self._closed = False
        self._state = can.BusState.ACTIVE
        self.bitrate = bitrate
        self.last_tx_timestamp: float | None = None
        self.channel_info = f"rate-limited virtual CAN {channel!r} at {bitrate} bit/s"
        super().__init__(channel=channel, **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._closed:
            raise can.CanOperationError("Cannot operate on a closed bus")
        self._wire.wait_slot(self, self._tx_queue, timeout)
        self.last_tx_timestamp = self._wire.reserve(msg, self)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._inner._recv_internal(timeout)

    @property
    def state(self) -> can.BusState:
        return self._state

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        # The virtual controller's error state; ERROR (bus-off) is what the watchdog detects.
        self._state = new_state

    def shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        super().shutdown()
        # let this bus's queued frames leave before unplugging
        try:
            self._wire.wait_slot(self, 1, 1.0)
        except can.CanOperationError:
            pass
        self._inner.shutdown()
        with _wires_lock:
            self._wire._users -= 1
            if self._wire._users == 0:
                _wires.pop(self._wire.channel, None)
                last = self._wire
            else:
                last = None
        if last is not None:
            last.close()


# ------------------------------------------------------------------------------ factory
def _open_virtual(channel: str, bitrate: int | None, rate_limited: bool = True, **kw: Any) -> can.BusABC:
    if not rate_limited:
        return VirtualBus(channel=f"ul:{channel}", **kw)
    return RateLimitedVirtualBus(channel=channel, bitrate=bitrate or 1_000_000, **kw)


#: our own backends by name; every other name goes to python-can's registry.
BACKENDS = {"virtual": _open_virtual}


def open_bus(interface: str, channel: str, bitrate: int | None = 1_000_000,
             rate_limited: bool = True, **kwargs: Any) -> can.BusABC:
    """Open the CAN bus the config names.

    :param interface: ``"virtual"`` (the rate-limited in-process wire) or any python-can
        interface name (``socketcan``, ``pcan``, ``kvaser``, ``vector``, ...).
    :param channel: channel name (``"can0"``, ``"PCAN_USBBUS1"``, any name for virtual).
    :param bitrate: bit/s, passed to the interface.
    :param rate_limited: virtual only; ``False`` gives python-can's unlimited virtual
        bus on the same channel name space (for benchmarks), isolated from limited buses.
    :raises ConfigError: unknown interface name, or a bad value for the virtual wire.
    :raises can.CanError: the interface exists but could not be opened.
    """
    if interface in BACKENDS:
        return BACKENDS[interface](channel, bitrate, rate_limited=rate_limited, **kwargs)
    from can.interfaces import VALID_INTERFACES
    if interface not in VALID_INTERFACES:
        raise ConfigError(f"stations.interface = {interface!r} is not a known CAN interface; "
                          f"known: {sorted(VALID_INTERFACES)}")
    if not rate_limited:
        raise ConfigError(f"stations.rate_limited = False only applies to the virtual interface, "
                          f"not {interface!r}")
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    return can.Bus(interface=interface, channel=channel, **kwargs)
