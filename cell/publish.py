"""The one place cycle records and cell status leave the controller for the plant.

Plant integration (an OPC UA server, the HMI) subscribes here instead of reaching into the
controller or polling the log (the plant historian's path, which must lose nothing, reads
the log itself: :mod:`cell.plant.outbox`):

* topic ``cycle``: one message per cycle, published once the PLC has been told its outcome
  and the log row is settled (so a consumer sees what the log and the PLC see): the
  :class:`~cell.cyclelog.CycleRecord` fields as a JSON-ready dict (``trace`` left out:
  it is large and stays in the log);
* topic ``status``: one message whenever what a PLC or an operator would look at changes:
  state, fault code and text, cycles done, active recipe number, recalibration due, and
  the PLC client that owns the link;
* topic ``event``: something that happened to the cell that is not a cycle nor a state,
  as ``kind`` and ``data`` (the kinds: :data:`cell.plant.events.EVENT_KINDS`), e.g. a
  calibration applied or a recipe file activated.

Publishing never blocks the publisher (the controller's scan and its log worker): every
subscription is a bounded queue of its own; when a slow consumer lets it fill, the oldest
messages are dropped and counted (:attr:`Subscription.dropped`), never the controller
delayed. Messages carry ``topic``, ``seq`` (per publisher, gap-free) and ``clock_s`` (the
cell's injected clock). Thread-safe; no I/O.
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import asdict
from typing import Iterable

TOPICS = ("cycle", "status", "event")
DEFAULT_MAXLEN = 1000


class Subscription:
    """Messages of the subscribed ``topics``, oldest first; at most ``maxlen`` kept."""

    def __init__(self, publisher: "Publisher", topics: Iterable[str], maxlen: int):
        self.topics = frozenset(topics)
        self._q: deque[dict] = deque()
        self._maxlen = maxlen
        self._cv = threading.Condition()
        self._publisher = publisher
        self.dropped = 0          #: messages lost because this subscriber fell behind

    def _put(self, msg: dict) -> None:
        with self._cv:
            if len(self._q) >= self._maxlen:
                self._q.popleft()
                self.dropped += 1
            self._q.append(msg)
            self._cv.notify_all()

    def pending(self) -> list[dict]:
        """A copy of the messages waiting, oldest first (they stay queued)."""
        with self._cv:
            return list(self._q)

    def drain(self) -> list[dict]:
        """Every message waiting, oldest first (none: an empty list; never blocks)."""
        with self._cv:
            out = list(self._q)
            self._q.clear()
            return out

    def get(self, timeout: float | None = None) -> dict | None:
        """The oldest message, waiting up to ``timeout`` wall seconds (None: forever) for
        one; None if none came. For consumer threads of their own (an MQTT bridge)."""
        with self._cv:
            if not self._cv.wait_for(lambda: self._q, timeout):
                return None
            return self._q.popleft()

    def close(self) -> None:
        self._publisher._unsubscribe(self)


class Publisher:
    """Fans messages out to :class:`Subscription` queues; see the module doc."""

    def __init__(self):
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()
        self._seq = 0
        self._last_status: dict | None = None

    def subscribe(self, topics: Iterable[str] = TOPICS, maxlen: int = DEFAULT_MAXLEN) -> Subscription:
        """A new subscription to ``topics`` (a subset of :data:`TOPICS`).

        :raises ValueError: an unknown topic or ``maxlen`` < 1."""
        topics = tuple(topics)
        bad = [t for t in topics if t not in TOPICS]
        if bad or not topics:
            raise ValueError(f"unknown topic(s) {bad}; known: {', '.join(TOPICS)}")
        if maxlen < 1:
            raise ValueError(f"maxlen {maxlen} must be ≥ 1")
        sub = Subscription(self, topics, int(maxlen))
        with self._lock:
            self._subs.append(sub)
        return sub

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)

    def publish(self, topic: str, clock_s: float, payload: dict) -> None:
        """Send ``payload`` on ``topic`` to every subscriber of it (never blocks)."""
        with self._lock:
            self._seq += 1
            msg = {"topic": topic, "seq": self._seq, "clock_s": round(float(clock_s), 6), **payload}
            subs = [s for s in self._subs if topic in s.topics]
            for s in subs:            # under the lock: every subscriber sees seq in order
                s._put(msg)

    def status(self, clock_s: float, snapshot: dict) -> bool:
        """Publish ``snapshot`` on ``status`` if it differs from the last one; True if sent."""
        with self._lock:
            if snapshot == self._last_status:
                return False
            self._last_status = dict(snapshot)
        self.publish("status", clock_s, snapshot)
        return True

    def event(self, clock_s: float, kind: str, data: dict) -> None:
        """Publish that ``kind`` happened, with ``data`` (JSON-ready), on ``event``."""
        self.publish("event", clock_s, {"kind": kind, "data": dict(data)})

    def last_status(self) -> dict | None:
        """A copy of the last status snapshot published (None: none yet), for a subscriber
        that comes after it."""
        with self._lock:
            return None if self._last_status is None else dict(self._last_status)

    def cycle(self, clock_s: float, record) -> None:
        """Publish a settled :class:`~cell.cyclelog.CycleRecord` on ``cycle``."""
        row = asdict(record)
        row.pop("trace", None)
        if row.get("target_mm") is not None:
            row["target_mm"] = list(row["target_mm"])
        self.publish("cycle", clock_s, {"cycle": row})
