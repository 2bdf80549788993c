"""Input a plant historian must live with: a cell whose clock jumps back, and a record
that comes twice, malformed events. Servers are real (``conftest.py``); waits are on conditions."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

from cell.cyclelog import CycleLog
from cell.plant import schema
from cell.plant.historian import Historian
from cell.plant.outbox import PlantOutbox
from tests.cell.plant.helpers import (TOPICS, historian_settings, log_ids, mqtt_client, outbox_settings,
                                      pg_ids, record)
from tests.waiting import wait_for


class Said:
    """A logger that keeps what it is told: ``events`` is a list of (event, fields)."""

    def __init__(self):
        self.events: list[tuple[str, dict]] = []

    def info(self, event, **kw):
        self.events.append((event, kw))

    warning = error = info


def _stamped(part_id: int, at: datetime):
    rec = record(part_id)
    rec.started_at = (at - timedelta(seconds=2)).isoformat(timespec="milliseconds")
    rec.finished_at = at.isoformat(timespec="milliseconds")
    return rec


def test_a_cell_whose_clock_jumps_back_is_recorded_by_id_with_its_own_times_and_the_historian_says_so(
        tmp_path, broker, historian_db):
    import psycopg
    db = tmp_path / "cell.sqlite"
    log = CycleLog(db)
    t0 = datetime(2026, 11, 27, 8, 0, tzinfo=timezone.utc)
    times = [t0 + timedelta(seconds=3 * k) for k in range(30)]            # ids 1..30
    times += [t0 - timedelta(hours=1) + timedelta(seconds=3 * k) for k in range(20)]   # 31..50: an hour back
    for k, at in enumerate(times):
        log.add_cycle(_stamped(k + 1, at))
    said = Said()
    historian = Historian(historian_settings(broker, historian_db, client_id="h-clock"), logger=said)
    historian.start()
    outbox = PlantOutbox(db, outbox_settings(broker))
    outbox.start()
    try:
        wait_for(lambda: outbox.backlog == 0, 120, "the whole log delivered")
        assert pg_ids(historian_db) == log_ids(db) == set(range(1, 51))
        assert outbox.watermark == 50                   # the watermark goes by ids, not times
        with psycopg.connect(historian_db) as pg:
            stored = dict(pg.execute("SELECT cycle_id, finished_at FROM cycles WHERE cell = %s",
                                     (TOPICS.path,)).fetchall())
        assert stored == {k + 1: at.isoformat(timespec="milliseconds") for k, at in enumerate(times)}
        assert historian.clock_backwards == 1
        [(event, fields)] = [e for e in said.events if e[0] == "plant_clock_backwards"]
        assert fields["cell"] == TOPICS.path and fields["log_id"] == log.log_id
        assert (fields["previous_id"], fields["cycle_id"]) == (30, 31)
        assert fields["back_s"] == 3600 + 3 * 29       # from 08:01:27 back to 07:00:00
    finally:
        outbox.stop()
        historian.stop()
        log.close()


def test_a_record_that_comes_twice_is_kept_once_and_the_copy_is_counted(broker, historian_db, running):
    import psycopg
    historian = running.add(Historian(historian_settings(broker, historian_db, client_id="h-dup")))
    with mqtt_client(broker) as client:
        wait_for(historian.link.subscribed.is_set, 60, "the historian's subscription")
        rec = record(7)
        rec.id = 1
        for session in (1, 2):                          # the second from a later session of the cell
            payload = schema.cycle_payload(TOPICS.path, "log-dup", rec, 0, session, 1)
            client.publish(TOPICS.cycle, payload, qos=1).wait_for_publish(30)
            wait_for(lambda: historian.received == session, 60, f"copy {session}")
        wait_for(lambda: historian.acked == 2, 60, "both copies acknowledged")
        assert historian.inserted == 1 and historian.duplicates == 1
        with psycopg.connect(historian_db) as pg:
            assert pg.execute("SELECT session, duplicates FROM cycles").fetchall() == [(1, 1)]


def test_a_malformed_event_or_one_of_an_unknown_version_is_refused_and_writes_nothing(
        broker, historian_db, running):
    import psycopg
    historian = running.add(Historian(historian_settings(broker, historian_db, client_id="h-bad-event")))
    good = schema.event_payload(TOPICS.path, 2, 1, "reset", {"code": 31, "state": "idle"})
    bad = [(b'{"schema": 1, "cell": ', "payload is not JSON"),
           (good.replace(b'"schema":1', b'"schema":9'), "unknown schema version 9 for event"),
           (good.replace(b'"code":31', b'"code":"thirty-one"'), "reset event: data.code: Input should be a valid"),
           (good.replace(b'"state":"idle"', b'"state":"idle","colour":"red"'),
            "invalid event message: reset event: data.colour: Extra inputs are not permitted"),
           (good.replace(b'"seq":1', b'"seq":0'), "invalid event message: seq")]
    with mqtt_client(broker) as client:
        wait_for(historian.link.subscribed.is_set, 60, "the historian's subscriptions")
        for k, (payload, says) in enumerate(bad, 1):
            client.publish(TOPICS.event, payload, qos=1).wait_for_publish(30)
            wait_for(lambda: historian.rejected == k, 60, f"bad event {k} refused")
            assert says in historian.last_refusal and historian.last_refusal.startswith(TOPICS.event)
        with psycopg.connect(historian_db) as pg:
            assert pg.execute("SELECT count(*) FROM events").fetchone()[0] == 0
        client.publish(TOPICS.event, good, qos=1).wait_for_publish(30)      # a good one, twice: kept once
        client.publish(TOPICS.event, good, qos=1).wait_for_publish(30)
        wait_for(lambda: historian.acked == len(bad) + 2, 60, "all acknowledged")
        with psycopg.connect(historian_db) as pg:
            assert pg.execute("SELECT kind, data FROM events").fetchall() == [("reset", {"code": 31, "state": "idle"})]
        assert historian.events == 1
