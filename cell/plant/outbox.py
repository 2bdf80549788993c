"""The cell side of the plant path: the cell's own SQLite cycle log is the outbox.

Nothing is queued in memory as "to be sent" and nothing is forgotten when the broker
acknowledges it. A record counts as delivered only when the historian's retained
watermark (``<cell>/watermark``, :mod:`cell.plant.historian`) covers it: the historian
has committed it, and every record of the log before it, to PostgreSQL. So:

* :class:`PlantOutbox` runs in a thread of its own, ``plant-outbox``, with its own
  read-only connection to the log (WAL: it never blocks the controller's writes, and the
  controller's scan and cycle never wait for it or for the broker);
* it reads rows above what it has sent and publishes each as one ``<cell>/cycle``
  message at QoS 1 (:func:`cell.plant.schema.cycle_payload`), at most ``window`` records
  beyond the watermark at a time;
* a row the PLC has not yet been told of (the log's ``open_cycle`` row in stage
  ``logged``: :meth:`~cell.cyclelog.CycleLog.settle_cycle` may still correct it) is not
  sent, nor any row after it, until it is settled;
* it subscribes to its own watermark and status, and starts sending on a connection only
  once its own birth has come back (the broker has then handled the subscriptions, so
  the retained watermark, if there is one, has arrived); after every connect (a broker restart, a network
  drop) and whenever the watermark has not moved for ``resend_s`` while records are
  out, it sends again everything the watermark does not cover (the historian drops
  duplicates by key). After a restart of the cell it starts from the retained watermark
  of its log (:attr:`~cell.cyclelog.CycleLog.log_id`; another log's watermark covers
  nothing of this one).

The backlog, the log's records the watermark does not cover, is :attr:`PlantOutbox.backlog`;
the outbox logs it (``plant_backlog``) when it changes, at most every ``report_s``, and the
cell's health report carries it, and the controller writes it to the PLC's ``plant_backlog``
register (docs/plc.md), which the HMI's PLC line shows.

Birth and death (Sparkplug B's idea, in JSON): at each connect the outbox publishes a
retained ``<cell>/status`` ``online: true`` with a session number, and the broker
publishes the Last Will, ``online: false`` with the same number, if the cell goes without
a goodbye; a clean stop publishes it itself. The session number goes up by one at every
connect, kept in ``<log>.plant-session`` beside the log, so it keeps going up across
restarts; ``seq`` numbers the messages of a session from 1.

The cell's state and events (given the controller's :class:`~cell.publish.Publisher`):
the outbox's thread drains a subscription to the publisher's ``status`` and ``event``
topics at every turn (a bounded queue: the scan and the cycle never wait for it, nor for
the broker). The state (:func:`cell.plant.events.cell_state`) goes into the birth and, when
it changes, into a new retained status of the same session, published from the outbox's
thread, at most once a turn (the latest state; one in between may be skipped), and only on
a connection whose birth has come back: so the first status of the session on the
broker is the birth, and the birth's echo stays what makes a connection ready (a state
update with the session's number comes only after it, on the same connection; one built
before a drop carries the old number, which readiness ignores). A check of the connection
and the publish are made under one lock with the session's change at a drop. The events
(:func:`cell.plant.events.state_events` from consecutive states, and the publisher's
``event`` messages) are published on ``<cell>/event`` at QoS 1 with the session's
``seq``; while the link is down they wait in memory, at most ``events_held`` of them (the
oldest dropped and counted in ``events_dropped``): events are best effort, not kept in the
log, and a restart of the cell loses those waiting.
"""
from __future__ import annotations

import os
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from cell.plant import events, schema
from cell.plant.mqtt import Security
from cell.plant.topics import CellTopics


@dataclass(frozen=True)
class OutboxSettings:
    """Where and how the outbox publishes (:class:`cell.config.PlantSection` builds it).

    :param window: records sent beyond the watermark at most (flow control: a historian
        that is away costs the broker at most this many queued records per re-send).
    :param resend_s: wall seconds without the watermark moving, with records out, after
        which they are sent again.
    :param poll_s: how often the log is read for new rows (wall seconds).
    :param report_s: the backlog is logged at most this often.
    :param security: TLS and the cell's login (:class:`~cell.plant.mqtt.Security`; None:
        plain TCP, anonymous).
    :param events_held: events kept in memory while the link is down, at most.
    """

    host: str
    port: int
    topics: CellTopics
    keepalive_s: int = 10
    window: int = 500
    resend_s: float = 30.0
    poll_s: float = 0.2
    report_s: float = 10.0
    security: Security | None = None
    events_held: int = 1000


class PlantOutbox:
    """Publishes the cycle log ``log_path`` to the plant (see the module doc).

    ``start()`` opens the log read-only and starts the thread and the MQTT link; ``stop()``
    says goodbye (status offline) and ends both. Counters (read them from any thread):
    ``sent`` (cycle messages published), ``resends`` (times it went back to the
    watermark), ``events_sent``, ``events_dropped`` and ``status_sent`` (state updates
    after the birth).

    :param publisher: the controller's :class:`~cell.publish.Publisher`, whose status and
        events the outbox publishes (module doc), subscribed to here (what comes before
        ``start()`` is kept, and sent once connected); None: births and goodbyes without a
        state. A clean ``stop()`` sends what it still holds before its goodbye.
    """

    def __init__(self, log_path: Path | str, settings: OutboxSettings, logger=None, publisher=None):
        self.log_path = Path(log_path)
        self.s = settings
        self.topics = settings.topics
        self._logger = logger
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self.link = None
        self.log = None
        self.log_id: str | None = None
        self._watermark = 0            # for this log
        self._backlog: int | None = None
        self._session_file = Path(str(self.log_path) + ".plant-session")
        self.session = 0
        self._seq = 0
        self._ready_gen = 0            # the connection on which our birth came back
        self.sent = 0
        self.resends = 0
        self._publisher = publisher
        self._sub = None
        self._status_lock = threading.Lock()   # the session and what status is on the broker
        self._state: dict | None = None        # the cell's state (events.cell_state), None: not known
        self._status_on: tuple | None = None   # (connection, state) of the last status published
        self._last_status: dict | None = None  # the last publisher status message taken
        self._events: deque = deque()
        self.events_sent = self.events_dropped = self.status_sent = 0
        if publisher is not None:                # from now on: what happens before start() is kept too
            self._sub = publisher.subscribe(("status", "event"), maxlen=max(100, settings.events_held))
            last = publisher.last_status()       # the state before the subscription, if any
            if last is not None:
                self._last_status, self._state = last, events.cell_state(last)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        from cell.cyclelog import CycleLog
        from cell.plant.mqtt import MqttLink

        self.log = CycleLog(self.log_path, readonly=True)
        self.log_id = self.log.log_id
        if self.log_id is None:
            self.log.close()
            raise ValueError(f"{self.log_path}: the log has no log_id yet (open it once as the controller)")
        self.session = self._next_session()
        self.link = MqttLink(self.s.host, self.s.port, f"{self.topics.path}/outbox", clean_start=True,
                             subscriptions=((self.topics.watermark, 1), (self.topics.status, 1)),
                             will=self._will(),
                             keepalive_s=self.s.keepalive_s, on_up=self._up, on_down=self._down,
                             on_message=self._message, security=self.s.security)
        self.link.start()
        self._thread = threading.Thread(target=self._run, name="plant-outbox", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        if self.link is not None and self._ready_gen == self.link.generation and self.link.connected.is_set():
            try:                                         # a clean stop sends what it still holds
                self._take_cell()
                self._send_cell(self.link, self._ready_gen)
            except Exception as exc:                     # noqa: BLE001 -- the goodbye must still go
                self._say("plant_outbox_error", error=repr(exc))
        if self.link is not None:
            self.link.stop(final=(self.topics.status, schema.status_payload(
                self.topics.path, False, self.session, self.log_id), True))
        if self.log is not None:
            self.log.close()
        if self._sub is not None:
            self._sub.close()

    # ------------------------------------------------------------------ what it shows
    @property
    def watermark(self) -> int:
        """The historian's watermark for this log (0: nothing committed, or not heard yet)."""
        return self._watermark

    @property
    def state(self) -> dict | None:
        """The cell's state as last taken from the publisher (None: none yet)."""
        return self._state

    @property
    def backlog(self) -> int | None:
        """Records in the log the watermark does not cover (None before the first read)."""
        return self._backlog

    # ------------------------------------------------------------------ sessions
    def _next_session(self) -> int:
        try:
            n = int(self._session_file.read_text().strip() or 0) + 1
        except (OSError, ValueError):
            n = 1
        tmp = self._session_file.with_name(self._session_file.name + ".tmp")
        try:
            tmp.write_text(f"{n}\n")
            os.replace(tmp, self._session_file)
        except OSError as exc:
            self._say("plant_session_not_kept", error=str(exc))
        return n

    def _will(self):
        from cell.plant.mqtt import Will
        return Will(self.topics.status, schema.status_payload(self.topics.path, False, self.session, self.log_id))

    # paho's thread ------------------------------------------------------------------
    def _up(self, generation: int, session_present: bool) -> None:
        with self._status_lock:
            state = self._state
            self.link.publish(self.topics.status, schema.status_payload(self.topics.path, True, self.session,
                                                                        self.log_id, state), retain=True)
            self._status_on = (generation, state)
        self._wake.set()

    def _down(self) -> None:
        # the next connect is a new session: its Last Will carries the new number
        with self._status_lock:
            self.session = self._next_session()
            self.link.set_will(self._will())

    def _message(self, generation: int, message) -> None:
        if message.topic == self.topics.status:
            self._own_status(generation, message)
            return
        try:
            wm = schema.parse("watermark", message.topic, message.payload, self.topics.path)
        except schema.PayloadError as exc:
            self._say("plant_watermark_refused", error=str(exc))
            return
        if wm.log_id == self.log_id:
            with self._lock:
                self._watermark = max(self._watermark, wm.cycle_id)
            self._wake.set()

    def _own_status(self, generation: int, message) -> None:
        """Our own birth, echoed: the broker handled our subscriptions before it, so the
        retained watermark (if any) has arrived. Sending starts only then: a restarted cell
        does not send again what the watermark covers."""
        try:
            st = schema.parse("status", message.topic, message.payload, self.topics.path)
        except schema.PayloadError as exc:
            self._say("plant_status_refused", error=str(exc))
            return
        if st.online and st.session == self.session:
            self._ready_gen = generation
            self._wake.set()

    # the outbox's thread --------------------------------------------------------------
    def _run(self) -> None:
        cursor, out, gen = 0, [], 0       # last id sent, ids sent beyond the watermark, connection
        moved = time.monotonic()
        reported, last_backlog, refused = 0.0, None, None
        while not self._stop.is_set():
            self._wake.wait(self.s.poll_s)
            self._wake.clear()
            try:
                self._take_cell()
                # readiness before the watermark: paho's thread sets the retained watermark
                # before the birth's echo makes the connection ready, so a ready read first
                # is never paired with a watermark read before the retained one came
                link = self.link
                ready_gen = self._ready_gen if link.connected.is_set() else -1
                wm = self._watermark
                if out and out[0] <= wm:
                    moved = time.monotonic()
                out = [i for i in out if i > wm]
                self._backlog = self.log.count_after(wm)
                now = time.monotonic()
                if self._backlog != last_backlog and now - reported >= self.s.report_s:
                    self._say("plant_backlog", backlog=self._backlog, watermark=wm, log_id=self.log_id)
                    reported, last_backlog = now, self._backlog
                if link.refused != refused:
                    refused = link.refused
                    if refused is not None:
                        self._say("plant_connect_refused", reason=refused)
                if ready_gen != link.generation:
                    continue
                if gen != ready_gen:                     # a new connection: send again from the watermark
                    gen, cursor, out, moved = ready_gen, wm, [], now
                    self._seq = 0
                self._send_cell(link, gen)
                if out and now - moved > self.s.resend_s:
                    cursor, out, moved = wm, [], now
                    self.resends += 1
                    self._say("plant_resend", watermark=wm, log_id=self.log_id)
                cursor = max(cursor, wm)
                room = self.s.window - len(out)
                if room <= 0:
                    continue
                rows = self.log.settled_after(cursor, room)
                if not rows:
                    continue
                prev = self.log.id_before(rows[0].id)
                if not out:
                    moved = now                          # the resend clock starts with the first out
                for rec in rows:
                    self._seq += 1
                    payload = schema.cycle_payload(self.topics.path, self.log_id, rec, prev, self.session,
                                                   self._seq)
                    if not link.publish(self.topics.cycle, payload, qos=1):
                        break                            # connection gone: the next one starts over
                    out.append(rec.id)
                    cursor = prev = rec.id
                    self.sent += 1
                if len(rows) == room:
                    self._wake.set()                     # more may be waiting: read again at once
            except Exception as exc:                     # noqa: BLE001 -- the outbox must keep going
                self._say("plant_outbox_error", error=repr(exc))
                self._stop.wait(1.0)

    def _take_cell(self) -> None:
        """Take what the publisher sent: the latest state, and the events to send."""
        if self._sub is None:
            return
        for m in self._sub.drain():
            if m["topic"] == "status":
                found = events.state_events(self._last_status, m)
                self._last_status = m
                state = events.cell_state(m)
                if state != self._state:
                    with self._status_lock:
                        self._state = state
            else:
                found = [(str(m.get("kind", "")), dict(m.get("data") or {}))]
            for kind, data in found:
                if len(self._events) >= self.s.events_held:
                    self._events.popleft()
                    self.events_dropped += 1
                self._events.append((kind, data, schema.utc_now()))

    def _send_cell(self, link, gen: int) -> None:
        """On a ready connection ``gen``: the state if it is not the one on the broker, then
        the events waiting (module doc)."""
        with self._status_lock:
            if link.generation != gen or not link.connected.is_set():
                return
            state = self._state
            if self._status_on != (gen, state):
                payload = schema.status_payload(self.topics.path, True, self.session, self.log_id, state)
                if not link.publish(self.topics.status, payload, retain=True):
                    return
                self._status_on = (gen, state)
                self.status_sent += 1
            while self._events:
                kind, data, at = self._events[0]
                try:
                    payload = schema.event_payload(self.topics.path, self.session, self._seq + 1, kind, data, at)
                except ValueError as exc:                # an event the schema refuses: say so, drop it
                    self._events.popleft()
                    self.events_dropped += 1
                    self._say("plant_event_refused", kind=kind, error=str(exc)[:300])
                    continue
                if not link.publish(self.topics.event, payload, qos=1):
                    return
                self._seq += 1
                self._events.popleft()
                self.events_sent += 1

    def _say(self, event: str, **kw) -> None:
        if self._logger is None:
            from cell.log import get_logger
            self._logger = get_logger("plant")
        level = self._logger.warning if event.endswith(("error", "refused", "resend")) else self._logger.info
        level(event, cell=self.topics.path, **kw)
