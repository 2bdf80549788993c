"""The simulated CAN wire: python-can's ``virtual`` bus with a bitrate and a clock.

python-can's :class:`~can.interfaces.virtual.VirtualBus` hands a frame to every other
bus on its channel at once and without limit. :class:`VirtualCanBus` is that bus, and
every one opened on a channel also shares one :class:`VirtualWire` on the simulated clock
(:class:`cell.sim.clock.VirtualClock`):

* each frame occupies the wire for ``frame_bits(msg) / bitrate`` seconds of clock time,
  with the bit stuffing computed exactly from the frame's bits, so an 8-byte standard data
  frame takes 111..135 µs at 1 Mbit/s;
* frames go out one after another in the order ``send`` was called (FIFO; real CAN
  arbitrates by identifier, which only matters under contention and is not modelled);
* at the *end* of its slot the frame reaches the other buses that want it (a bus's
  ``wants``, e.g. a drive's subscriptions), stamped with that clock time, in the order
  they joined; a bus with listeners attached (a canopen ``Network``
  and our bus monitor) hands it to them at once — the clock's thread plays the part of
  python-can's notifier thread, so delivery never waits for a thread to get the CPU —
  and a bus without puts a copy in its ``VirtualBus`` queue for ``recv``. Listeners share
  one read-only copy of the frame, or the sender's frame itself when it was sent with
  ``send_own`` (``VirtualBus.send`` deep-copies per receiver, ten times the cost, which
  the simulated cell's thousand frames per simulated second cannot afford);
* ``send`` never blocks: the frame is queued, as in a CAN controller's transmit mailboxes.
  A frame the wire cannot carry — a CAN FD frame, more than 8 data bytes, an identifier
  beyond 11 (29) bits, or a send while ``tx_queue`` frames already wait — raises
  ``can.CanOperationError`` naming the frame and the reason, as a real interface refuses
  it; the sender treats that as its own transmit failure (the controller latches a
  send-failed fault, a simulated drive falls silent as a bus-off node does).

Periodic frames (a heartbeat producer, ``bus.send_periodic``) are clock callbacks too.
"""
from __future__ import annotations

import queue
import threading
from copy import copy
from typing import Any, Callable, Sequence

import can
from can.interfaces.virtual import VirtualBus

from cell.errors import ConfigError
from cell.log import get_logger
from cell.sim.clock import VirtualClock
from drivers.stations.bus import frame_bits

log = get_logger("sim.canbus")


class VirtualWire:
    """One channel's wire: slot reservation on the clock and timed delivery.

    ``frames`` and ``bits`` count every frame carried. Created by the first
    :class:`VirtualCanBus` on a channel, dropped when the last one leaves.
    """

    BITS_KEEP = 4096     #: standard data frames whose bit count :meth:`_frame_bits` remembers

    def __init__(self, channel: str, bitrate: int, clock: VirtualClock):
        self.channel, self.bitrate, self.clock = channel, bitrate, clock
        self.frames = 0
        self.bits = 0
        self.buses: list[VirtualCanBus] = []
        self.free_at = clock.now()
        self._bits: dict[tuple[int, bytes], int] = {}
        self._routes: dict[int, tuple[VirtualCanBus, ...]] = {}   # identifier -> buses that take it

    def reserve(self, msg: can.Message, sender: "VirtualCanBus", own: bool = False) -> float:
        """Queue ``msg``; returns the clock time its slot ends (its receive timestamp). The
        frame delivered is a copy of ``msg``, or with ``own`` ``msg`` itself (a frame its
        sender built for this send alone, see :meth:`VirtualCanBus.send_own`)."""
        bits = self._frame_bits(msg)
        start = self.clock.now()
        if self.free_at > start:                   # a busy wire: after the frame on it
            start = self.free_at
        end = start + bits / self.bitrate
        self.free_at = end
        self.frames += 1
        self.bits += bits
        stamped = msg if own else msg.__copy__()   # copy(msg), less the copy module's dispatch
        # the data as it is now, as a CAN controller copies a frame into its transmit mailbox:
        # python-can's Message (and its copy) shares a bytearray it is given, and a sender's
        # PDO buffer changes with its next frame, which may be sent before this one's slot ends
        stamped.data = bytearray(msg.data)
        stamped.timestamp = end
        sender._pending += 1
        self.clock.call_at(end, self._deliver, stamped, sender)
        return end

    def _frame_bits(self, msg: can.Message) -> int:
        """:func:`~drivers.stations.bus.frame_bits`, remembered per standard data frame
        (identifier, data): a drive at rest sends the same TPDO frame again and again, most
        set-points repeat, and a frame's bits depend on nothing else. The memory is
        forgotten whenever it holds :attr:`BITS_KEEP` frames."""
        if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or msg.is_fd:
            return frame_bits(msg)
        key = (msg.arbitration_id, bytes(msg.data))
        bits = self._bits.get(key)
        if bits is None:
            if len(self._bits) >= self.BITS_KEEP:
                self._bits.clear()
            bits = self._bits[key] = frame_bits(msg)
        return bits

    def reroute(self) -> None:
        """Forget which buses take which identifiers: a bus joined or left, or what a bus
        :attr:`~VirtualCanBus.wants` changed."""
        self._routes = {}

    def _deliver(self, msg: can.Message, sender: "VirtualCanBus") -> None:
        """The frame's slot ended: hand it to every other bus that wants its identifier
        (asked once per identifier until :meth:`reroute`), in the order they joined."""
        sender._pending -= 1
        msg.is_rx = True
        aid = msg.arbitration_id
        routes = self._routes          # a reroute meanwhile (a bus joining from another thread)
        route = routes.get(aid)        # leaves this answer in the dict it replaced
        if route is None:
            route = routes[aid] = tuple(b for b in self.buses if b.wants is None or b.wants(aid))
        for bus in route:
            if bus is not sender:
                bus._receive(msg)


_wires: dict[str, VirtualWire] = {}
_wires_lock = threading.Lock()


def wire_stats(channel: str) -> tuple[int, int] | None:
    """(frames, bits) carried so far on a channel's wire, ``None`` if nobody is on it."""
    with _wires_lock:
        w = _wires.get(channel)
        return (w.frames, w.bits) if w else None


class ClockCyclicTask:
    """``bus.send_periodic`` on the clock: the first frame at once, then every ``period``
    seconds (counted from the start, no drift), until :meth:`stop` or ``duration``."""

    def __init__(self, bus: "VirtualCanBus", msgs: Sequence[can.Message], period: float,
                 duration: float | None, modifier: Callable[[can.Message], None] | None):
        self.bus, self.period, self.modifier = bus, float(period), modifier
        self.messages = list(msgs)
        self.t0 = bus.clock.now()
        self.end = None if duration is None else self.t0 + duration
        self._k = 0
        self._timer = None
        self.stopped = False
        self._tick()

    def _tick(self) -> None:
        if self.stopped or self.bus._closed:
            return
        msg = self.messages[self._k % len(self.messages)]
        if self.modifier is not None:
            self.modifier(msg)
        try:
            self.bus.send(msg)
        except can.CanError as exc:
            log.info("periodic_frame_not_sent", channel=self.bus._wire.channel, error=str(exc))
        self._k += 1
        t = self.t0 + self._k * self.period
        if self.end is None or t <= self.end:
            self._timer = self.bus.clock.call_at(t, self._tick)

    def modify_data(self, msgs: can.Message | Sequence[can.Message]) -> None:
        self.messages = [msgs] if isinstance(msgs, can.Message) else list(msgs)

    def start(self) -> None:
        if self.stopped:
            self.stopped = False
            self.t0, self._k = self.bus.clock.now(), 0
            self._tick()

    def stop(self) -> None:
        self.stopped = True
        if self._timer is not None:
            self._timer.cancel()


class VirtualCanBus(VirtualBus):
    """python-can's virtual bus on the simulated wire of ``channel``.

    :param channel: buses with the same name share one wire.
    :param bitrate: bit/s (10 k .. 1 M); all buses on a channel must agree.
    :param tx_queue: frames this bus may have waiting for the wire.
    :param clock: the simulated clock; all buses on a channel share it.
    :raises ConfigError: bad bitrate or queue size, a clock that is not a
        :class:`VirtualClock`, or a bitrate/clock differing from the channel's.
    """

    def __init__(self, channel: str = "cell0", bitrate: int = 1_000_000, tx_queue: int = 8,
                 clock: VirtualClock | None = None, **kwargs: Any):
        if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not 10_000 <= bitrate <= 1_000_000:
            raise ConfigError(f"virtual CAN bitrate = {bitrate!r} must be an integer in 10000..1000000 bit/s")
        if isinstance(tx_queue, bool) or not isinstance(tx_queue, int) or tx_queue < 1:
            raise ConfigError(f"virtual CAN tx_queue = {tx_queue!r} must be an integer ≥ 1")
        if not isinstance(clock, VirtualClock):
            raise ConfigError(f"virtual CAN {channel!r} runs on the simulated clock; got "
                              f"{type(clock).__name__} (the virtual bus exists only in the simulated cell)")
        with _wires_lock:
            wire = _wires.get(channel)
            if wire is None:
                wire = _wires[channel] = VirtualWire(channel, bitrate, clock)
            elif wire.bitrate != bitrate:
                raise ConfigError(f"virtual CAN channel {channel!r} runs at {wire.bitrate} bit/s; "
                                  f"cannot open it at {bitrate} bit/s")
            elif wire.clock is not clock:
                raise ConfigError(f"virtual CAN channel {channel!r} is already on another clock")
            self._wire = wire
            self._wants: Callable[[int], bool] | None = None
            wire.buses.append(self)
            wire.reroute()
        self.clock = clock
        self._listeners: list | None = None
        self._rx = clock.event()
        self._pending = 0
        self._tx_queue = tx_queue
        self._closed = False
        self._state = can.BusState.ACTIVE
        self.bitrate = bitrate
        self.last_tx_timestamp: float | None = None
        super().__init__(channel=f"vw:{channel}", preserve_timestamps=True, **kwargs)
        self.channel_info = f"virtual CAN {channel!r} at {bitrate} bit/s (simulated clock)"

    @property
    def wants(self) -> Callable[[int], bool] | None:
        """``wants(arbitration_id) -> bool``: frames this bus's owner ignores are not handed
        to it at all (None: every frame). A simulated station sets its network's
        subscriptions, so the four drives do not each run canopen's receive path for every
        other drive's frames. The wire asks once per identifier: whoever changes the
        answers calls :meth:`reroute` (setting ``wants`` does)."""
        return self._wants

    @wants.setter
    def wants(self, wants: Callable[[int], bool] | None) -> None:
        self._wants = wants
        self._wire.reroute()

    def reroute(self) -> None:
        """What :attr:`wants` answers has changed (a subscription came or went)."""
        self._wire.reroute()

    # ------------------------------------------------------------------ sending
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._admit(msg)
        self.last_tx_timestamp = self._wire.reserve(msg, self)

    def send_own(self, msg: can.Message) -> None:
        """:meth:`send` of a frame its caller built for this send alone and never touches
        again (a simulated drive's network): the wire stamps and delivers ``msg`` itself
        instead of a copy. Same refusals as :meth:`send`."""
        self._admit(msg)
        self.last_tx_timestamp = self._wire.reserve(msg, self, own=True)

    def _admit(self, msg: can.Message) -> None:
        self._check_if_open()
        why = _cannot_carry(msg)
        if why is None and self._pending >= self._tx_queue:
            why = f"transmit queue full ({self._tx_queue} frames waiting for the wire)"
        if why is not None:
            raise can.CanOperationError(f"virtual CAN {self._wire.channel!r}: frame "
                                        f"0x{msg.arbitration_id:X} not sent: {why}")

    def _send_periodic_internal(self, msgs, period, duration=None, autostart=True, modifier_callback=None):
        return ClockCyclicTask(self, msgs if not isinstance(msgs, can.Message) else [msgs],
                               period, duration, modifier_callback)

    # ------------------------------------------------------------------ receiving
    def attach_listeners(self, listeners: list) -> None:
        """Deliver every received frame at once to ``listeners`` (``can.Listener`` objects,
        the list is read at each delivery), instead of queueing it for :meth:`recv`."""
        self._listeners = listeners

    def _receive(self, msg: can.Message) -> None:
        if self._closed:
            return
        if self._listeners is None:
            m = copy(msg)
            m.channel = self.channel_id
            self.queue.put(m)                # python-can's own receive queue, for recv()
            self._rx.set()
            return
        for listener in list(self._listeners):
            try:
                listener.on_message_received(msg)
            except Exception:                # noqa: BLE001 -- like python-can's notifier: keep delivering
                log.exception("can_listener_failed", channel=self._wire.channel)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame that passes the filters, waiting up to ``timeout`` clock seconds
        (python-can's ``BusABC.recv`` counts its time-out on the wall clock)."""
        deadline = None if timeout is None else self.clock.now() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - self.clock.now())
            msg, already_filtered = self._recv_internal(left)
            if msg is not None and (already_filtered or self._matches_filters(msg)):
                return msg
            if deadline is not None and self.clock.now() >= deadline:
                return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        """Pull mode (no listeners attached): wait in clock time for the next frame."""
        self._check_if_open()
        deadline = None if timeout is None else self.clock.now() + timeout
        while True:
            self._rx.clear()
            try:
                return self.queue.get_nowait(), False
            except queue.Empty:
                pass
            left = None if deadline is None else deadline - self.clock.now()
            if left is not None and left <= 0:
                return None, False
            self._rx.wait(left)

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> can.BusState:
        return self._state

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        # the interface's error state; ERROR (bus-off) is what the controller's watchdog detects
        self._state = new_state

    def shutdown(self) -> None:
        """Leave the wire; frames already queued still go out (a thread that keeps the
        clock's time waits for them, others leave them to the clock). Idempotent."""
        if self._closed:
            return
        if self._pending and self.clock.keeps_time():
            self.clock.sleep_until(self._wire.free_at)
        self._closed = True
        super().shutdown()
        with _wires_lock:
            if self in self._wire.buses:
                self._wire.buses.remove(self)
                self._wire.reroute()
            if not self._wire.buses and _wires.get(self._wire.channel) is self._wire:
                del _wires[self._wire.channel]


def _cannot_carry(msg: can.Message) -> str | None:
    if msg.is_fd:
        return "CAN FD frames are not carried by this wire"
    if len(msg.data) > 8:
        return f"{len(msg.data)} data bytes (a classic CAN frame holds at most 8)"
    limit = 0x1FFFFFFF if msg.is_extended_id else 0x7FF
    if not 0 <= msg.arbitration_id <= limit:
        return f"identifier beyond {29 if msg.is_extended_id else 11} bits"
    return None


def open_virtual_bus(channel: str, bitrate: int | None, clock: VirtualClock | None = None,
                     **kwargs: Any) -> VirtualCanBus:
    """Backend ``"virtual"`` of :func:`drivers.stations.bus.open_bus`."""
    return VirtualCanBus(channel=channel, bitrate=bitrate or 1_000_000, clock=clock, **kwargs)
