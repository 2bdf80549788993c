"""The plant historian: cycle records from the broker into PostgreSQL, nothing lost; the
cells' events beside them.

:class:`Historian` subscribes to ``+/+/+/cycle`` (any cell) with a persistent MQTT 5
session (``clean_start=False``, ``session_expiry_s``): while it is away the broker keeps
its subscription and queues the records. It acknowledges a record to the broker only
after the record is committed (paho's manual ack): a historian killed at any moment
leaves every record either committed or unacknowledged, and the broker sends an
unacknowledged one again. PostgreSQL going away mid-batch rolls the batch back and
acknowledges none of it; the batch is retried until the database is back (or the
historian stops, leaving the records to the broker).

Threads: paho's network thread only queues what arrives (the broker may send up to
``batch_max`` records unacknowledged: the MQTT 5 Receive Maximum the historian asks
for, so a batch is not cut to mosquitto's default of 20); ``historian-writer`` takes
batches (up to ``batch_max`` records, gathered for at most ``batch_s``), checks each
(:func:`cell.plant.schema.parse`), commits the good ones in one transaction
(:class:`cell.plant.store.HistorianStore`), then acknowledges the batch in the order it
arrived and publishes each touched cell's watermark, retained, on ``<cell>/watermark``.
After every connect to the broker it publishes every cell's latest watermark again (a
broker restarted without persistence has lost the retained ones).

Events (``+/+/+/event``, ``event_filter``) come on the same persistent session and go
through the same batches: checked, committed with the batch's records into ``events``
(a copy of one already there dropped), acknowledged after the commit. They carry no
watermark: a cell does not send an event again (``cell/plant.md``: their guarantee).

A payload that is not a valid cycle or event message (not JSON, an unknown schema
version, a field wrong, an event's data not its kind's, another cell's id) is refused:
logged (``plant_record_refused``, naming the topic and what was wrong), counted in
``rejected``, acknowledged (sending it again cannot mend it) and never written. A connect the broker refuses (a wrong password, a login the ACL does
not know) is logged as ``historian_connect_refused`` with the broker's reason; paho keeps
trying.

A cell's clock may jump back (an NTP step, a replaced battery): its records' timestamps
then go backwards while their ids go forwards. The historian records them as they are: a
record is named by ``(cell, log_id, cycle_id)`` and ordered by ``cycle_id``, the watermark
moves by ids alone, and ``started_at``/``finished_at`` are stored as the cell wrote them,
never corrected (a historian cannot know which of two clocks was right). What it saw it
says: a committed record whose ``finished_at`` is earlier than that of the record before
it in the same log (the highest lower id this process has committed) is logged as
``plant_clock_backwards`` with both ids, both times and how far back (``back_s``), and
counted in ``clock_backwards``. The comparison is per historian process: the first record
of a log after a restart of the historian is compared with nothing.

``cellctl historian`` (:mod:`cell.commands.historian`) runs one.
"""
from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone

from cell.plant import schema
from cell.plant.mqtt import Security
from cell.plant.store import HistorianStore
from cell.plant.topics import TopicError, parse as parse_topic, subscription


@dataclass(frozen=True)
class HistorianSettings:
    """:param topic_filter: which cells' records to take (default every cell's).
    :param security: TLS and the historian's login (:class:`~cell.plant.mqtt.Security`)."""

    host: str
    port: int
    dsn: str
    client_id: str = "plant-historian"
    topic_filter: str = subscription("cycle")
    event_filter: str | None = subscription("event")
    session_expiry_s: int = 7 * 24 * 3600
    keepalive_s: int = 10
    batch_max: int = 500
    batch_s: float = 0.05
    retry_max_s: float = 5.0
    security: Security | None = None


class Historian:
    """See the module doc. ``start()``/``stop()``; counters readable from any thread:
    ``received``, ``inserted``, ``duplicates``, ``events``, ``rejected``, ``acked``, ``commits``,
    ``failed_commits``, ``clock_backwards``; ``last_refusal``: the text of the last refused
    payload."""

    def __init__(self, settings: HistorianSettings, logger=None):
        self.s = settings
        self.store = HistorianStore(settings.dsn)
        self._q: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._logger = logger
        self.link = None
        self.received = self.inserted = self.duplicates = self.rejected = self.events = 0
        self.acked = self.commits = self.failed_commits = self.clock_backwards = 0
        #: (cell, log_id) -> (cycle_id, finished_at) of the highest id committed by this process
        self._last: dict[tuple[str, str], tuple[int, str]] = {}
        self.last_refusal: str | None = None
        self.watermarks: dict[tuple[str, str], int] = {}

    def start(self) -> None:
        """Migrate the database if it is there (else at the first commit), then subscribe."""
        import psycopg
        from cell.plant.mqtt import MqttLink
        try:
            self.store.connect()
        except psycopg.OperationalError as exc:
            self._say("historian_commit_failed", error=str(exc).strip()[:300], records=0, retry_in_s=0)
        self.link = MqttLink(self.s.host, self.s.port, self.s.client_id, clean_start=False,
                             session_expiry_s=self.s.session_expiry_s,
                             subscriptions=((self.s.topic_filter, 1),)
                             + (((self.s.event_filter, 1),) if self.s.event_filter else ()), manual_ack=True,
                             keepalive_s=self.s.keepalive_s, on_up=self._up, on_message=self._message,
                             security=self.s.security, receive_maximum=self.s.batch_max)
        self._thread = threading.Thread(target=self._run, name="historian-writer", daemon=True)
        self._thread.start()
        self.link.start()

    def stop(self) -> None:
        """Stop taking records; what is not committed stays unacknowledged at the broker."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
        if self.link is not None:
            self.link.stop()
        self.store.close()

    # paho's thread ------------------------------------------------------------------
    def _up(self, generation: int, session_present: bool) -> None:
        self._q.put(("republish", generation, None))

    def _message(self, generation: int, message) -> None:
        self._q.put(("message", generation, message))

    # the writer ---------------------------------------------------------------------
    def _run(self) -> None:
        refused = None
        while not self._stop.is_set():
            if self.link.refused != refused:          # the broker refused the login: say why, once
                refused = self.link.refused
                if refused is not None:
                    self._say("historian_connect_refused", reason=refused)
            try:
                first = self._q.get(timeout=0.2)
            except queue.Empty:
                continue
            items = [first]
            deadline = time.monotonic() + self.s.batch_s
            while len(items) < self.s.batch_max:
                try:
                    items.append(self._q.get(timeout=max(0.0, deadline - time.monotonic())))
                except queue.Empty:
                    break
            try:
                self._batch(items)
            except Exception as exc:                  # noqa: BLE001 -- the writer must keep going
                self._say("historian_error", error=repr(exc))

    def _batch(self, items: list) -> None:
        good, events, taken, republish = [], [], [], False
        for kind, generation, message in items:
            if kind == "republish":
                republish = True
                continue
            self.received += 1
            taken.append((generation, message))
            try:
                cell, what = parse_topic(message.topic)
                if what == "event":
                    events.append(schema.parse("event", message.topic, message.payload, cell.path))
                    continue
                if what != "cycle":
                    raise schema.PayloadError(f"{message.topic}: not a cycle or event topic")
                good.append(schema.parse("cycle", message.topic, message.payload, cell.path))
            except (schema.PayloadError, TopicError) as exc:
                self.rejected += 1
                self.last_refusal = str(exc)
                self._say("plant_record_refused", error=str(exc))
        result = self._commit(good, events) if good or events else None
        if self._stop.is_set() and (good or events) and result is None:
            return                                      # not committed: leave it to the broker
        for generation, message in taken:
            if message.qos >= 1 and self.link.ack(message.mid, generation, message.qos):
                self.acked += 1
        if result is not None:
            self.inserted += result.inserted
            self.duplicates += result.duplicates
            self.events += result.events
            for (cell, log_id), w in result.watermarks.items():
                self.watermarks[(cell, log_id)] = w
                self._publish_watermark(cell, log_id, w)
            self._check_clocks(good)
        if republish:
            self._republish()

    def _check_clocks(self, good: list) -> None:
        """Say which committed records finished before the record before them (module doc)."""
        for m in sorted(good, key=lambda m: (m.cell, m.log_id, m.cycle_id)):
            key = (m.cell, m.log_id)
            last = self._last.get(key)
            if last is not None and m.cycle_id <= last[0]:
                continue                                # a copy, or older than what was seen
            self._last[key] = (m.cycle_id, m.record.finished_at)
            if last is None:
                continue
            back = _seconds_between(m.record.finished_at, last[1])
            if back is not None and back > 0:
                self.clock_backwards += 1
                self._say("plant_clock_backwards", cell=m.cell, log_id=m.log_id, cycle_id=m.cycle_id,
                          finished_at=m.record.finished_at, previous_id=last[0], previous_finished_at=last[1],
                          back_s=round(back, 3))

    def _commit(self, good: list, events: list = ()):
        """Commit ``good`` and ``events``, retrying while the database is away; None if
        stopped first."""
        import psycopg
        wait = 0.2
        while not self._stop.is_set():
            try:
                result = self.store.commit(good, events)
                self.commits += 1
                return result
            except psycopg.OperationalError as exc:
                self.failed_commits += 1
                self._say("historian_commit_failed", error=str(exc).strip()[:300], records=len(good),
                          retry_in_s=wait)
                self.store.close()
                self._stop.wait(wait)
                wait = min(wait * 2, self.s.retry_max_s)
        return None

    def _publish_watermark(self, cell: str, log_id: str, w: int) -> None:
        self.link.publish(f"{cell}/watermark", schema.watermark_payload(cell, log_id, w), qos=1, retain=True)

    def _republish(self) -> None:
        import psycopg
        try:
            latest = self.store.latest_watermarks()
        except psycopg.OperationalError as exc:
            self.store.close()
            self._say("historian_commit_failed", error=str(exc).strip()[:300], records=0, retry_in_s=0)
            return
        for cell, (log_id, w) in latest.items():
            self._publish_watermark(cell, log_id, w)

    def _say(self, event: str, **kw) -> None:
        if self._logger is None:
            from cell.log import get_logger
            self._logger = get_logger("historian")
        level = self._logger.info if event == "historian_started" else self._logger.warning
        level(event, **kw)


def _seconds_between(earlier: str, later: str) -> float | None:
    """``later - earlier`` in seconds for two ISO 8601 times (naive ones taken as UTC);
    None if either is not one."""
    try:
        a, b = datetime.fromisoformat(earlier), datetime.fromisoformat(later)
    except (TypeError, ValueError):
        return None
    a = a if a.tzinfo else a.replace(tzinfo=timezone.utc)
    b = b if b.tzinfo else b.replace(tzinfo=timezone.utc)
    return (b - a).total_seconds()
