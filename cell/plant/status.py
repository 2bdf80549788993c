"""Each cell's online/offline into the historian's database: table ``cell_status``.

A cell's ``<site>/<line>/<cell>/status`` is retained (``cell/plant.md``): its birth
(``online: true``) at each connect, its goodbye or the Last Will the broker publishes for
it (``online: false``) when it goes. The latest one is the cell's state, so
:class:`StatusRecorder` needs no persistent session: it subscribes to ``+/+/+/status``
with a clean one, every connect brings every cell's retained status again, and what came
while it was away is the retained one it gets then.

Each valid message upserts the cell's one row (``cell_status``, migration 2 of
:mod:`cell.plant.store`): ``online``, ``session``, ``log_id``, ``at`` (the payload's time:
for a Last Will the time the cell connected, when it was made), ``received_at`` and
``changed_at`` (when ``online`` last changed, as this recorder saw it), and the cell's
``state``, ``fault_code`` and ``fault_text`` (status version 2; null from a version-1 status
and from a Last Will, which knows no state). The last message
received wins: the broker keeps one order per topic. A payload that is not a valid status
message is logged (``plant_status_refused``) and dropped.

Threads: paho's network thread only queues; ``status-writer`` upserts, keeping the latest
message per cell while PostgreSQL is away and writing it when it is back. ``cellctl
historian`` runs one beside the :class:`~cell.plant.historian.Historian`.
"""
from __future__ import annotations

import queue
import threading

from cell.plant import schema
from cell.plant.topics import TopicError, parse as parse_topic, subscription

UPSERT = ("INSERT INTO cell_status (cell, online, session, log_id, at, state, fault_code, fault_text)"
          " VALUES (%s, %s, %s, %s, %s, %s, %s, %s)"
          " ON CONFLICT (cell) DO UPDATE SET online = EXCLUDED.online, session = EXCLUDED.session,"
          " log_id = EXCLUDED.log_id, at = EXCLUDED.at, state = EXCLUDED.state, fault_code = EXCLUDED.fault_code,"
          " fault_text = EXCLUDED.fault_text, received_at = now(),"
          " changed_at = CASE WHEN cell_status.online = EXCLUDED.online THEN cell_status.changed_at"
          " ELSE now() END")


class StatusRecorder:
    """See the module doc. ``start()``/``stop()``; ``written``, ``refused``: counters.

    :param topic_filter: whose status to take (default every cell's).
    :param security: TLS and login (:class:`cell.plant.mqtt.Security`; None: plain, anonymous),
        the historian's against the plant's broker.
    """

    def __init__(self, host: str, port: int, dsn: str, client_id: str = "plant-historian-status",
                 topic_filter: str = subscription("status"), keepalive_s: int = 10, retry_max_s: float = 5.0,
                 logger=None, security=None):
        from cell.plant.store import HistorianStore
        self.security = security
        self.host, self.port, self.client_id = host, port, client_id
        self.topic_filter, self.keepalive_s, self.retry_max_s = topic_filter, keepalive_s, retry_max_s
        self.store = HistorianStore(dsn)
        self._q: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._logger = logger
        self.link = None
        self.written = self.refused = 0

    def start(self) -> None:
        from cell.plant.mqtt import MqttLink
        self.link = MqttLink(self.host, self.port, self.client_id, clean_start=True,
                             subscriptions=((self.topic_filter, 1),), keepalive_s=self.keepalive_s,
                             security=self.security,
                             on_message=lambda _gen, m: self._q.put((m.topic, bytes(m.payload))))
        self._thread = threading.Thread(target=self._run, name="status-writer", daemon=True)
        self._thread.start()
        self.link.start()

    def stop(self) -> None:
        self._stop.set()
        if self.link is not None:
            self.link.stop()
        if self._thread is not None:
            self._thread.join(timeout=30)
        self.store.close()

    def _run(self) -> None:
        import psycopg
        pending: dict[str, schema.StatusMessage] = {}
        wait = 0.2
        while not self._stop.is_set():
            try:
                topic, payload = self._q.get(timeout=0.2 if not pending else wait)
                self._take(pending, topic, payload)
                while True:                                    # whatever else has come, too
                    self._take(pending, *self._q.get_nowait())
            except queue.Empty:
                pass
            if not pending:
                continue
            try:
                self._write(pending)
                pending.clear()
                wait = 0.2
            except psycopg.OperationalError as exc:
                self.store.close()
                self._say("status_write_failed", error=str(exc).strip()[:300], cells=len(pending), retry_in_s=wait)
                wait = min(wait * 2, self.retry_max_s)

    def _take(self, pending: dict, topic: str, payload: bytes) -> None:
        try:
            cell, what = parse_topic(topic)
            if what != "status":
                raise schema.PayloadError(f"{topic}: not a status topic")
            pending[cell.path] = schema.parse("status", topic, payload, cell.path)
        except (schema.PayloadError, TopicError) as exc:
            self.refused += 1
            self._say("plant_status_refused", error=str(exc))

    def _write(self, pending: dict) -> None:
        if self.store.db is None:
            self.store.connect()
        db = self.store.db
        with db.transaction():
            for cell, m in pending.items():
                db.execute(UPSERT, (cell, m.online, m.session, m.log_id, m.at, m.state, m.fault_code, m.fault_text))
        db.commit()
        self.written += len(pending)

    def _say(self, event: str, **kw) -> None:
        if self._logger is None:
            from cell.log import get_logger
            self._logger = get_logger("historian")
        self._logger.warning(event, **kw)
