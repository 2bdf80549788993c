"""Every cycle record of the log reaches PostgreSQL through a real mosquitto, nothing lost
(issue 25): the log is the outbox, the historian's watermark says what is delivered.

Servers are real (``conftest.py``); a test that kills one starts its own. Waits are on
conditions with generous bounds, never on time."""
from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from cell.plant.historian import Historian
from cell.plant.outbox import PlantOutbox
from tests.cell.plant.helpers import (TOPICS, historian_settings, log_ids, mqtt_client, outbox_settings,
                                      pg_ids, record, write_log)
from tests.waiting import wait_for

REPO = Path(__file__).resolve().parents[3]


def test_every_record_of_the_log_reaches_postgres_and_gaps_are_not_waited_for(tmp_path, broker,
                                                                               historian_db, running):
    db = tmp_path / "cell.sqlite"
    log = write_log(db, 120)
    sqlite3.connect(db).execute("DELETE FROM cycles WHERE id BETWEEN 30 AND 39").connection.commit()
    historian = running.add(Historian(historian_settings(broker, historian_db, client_id="h-e2e")))
    outbox = running.add(PlantOutbox(db, outbox_settings(broker)))
    wait_for(lambda: outbox.backlog == 0, 120, "the watermark to cover the log")
    for k in range(30):                                # rows written while it runs go too
        log.add_cycle(record(1000 + k))
    wait_for(lambda: outbox.backlog == 0 and outbox.watermark == 150, 120, "the new rows")
    assert pg_ids(historian_db) == log_ids(db)
    assert len(log_ids(db)) == 140
    assert historian.rejected == 0 and historian.watermarks[(TOPICS.path, log.log_id)] == 150
    import psycopg

    from cell.plant.store import SCHEMA_VERSION
    with psycopg.connect(historian_db) as pg:
        assert pg.execute("SELECT max(version) FROM schema_version").fetchone()[0] == SCHEMA_VERSION
        rec = pg.execute("SELECT record FROM cycles WHERE cycle_id = 1").fetchone()[0]
    assert rec["part_id"] == 1 and rec["recipe"] == "bracket-a" and "trace" not in rec
    log.close()


def test_a_row_the_plc_was_not_told_of_waits_and_a_restarted_cell_sends_only_what_is_not_covered(
        tmp_path, broker, historian_db, running):
    db = tmp_path / "cell.sqlite"
    log = write_log(db, 20)
    running.add(Historian(historian_settings(broker, historian_db, client_id="h-restart")))
    first = PlantOutbox(db, outbox_settings(broker))
    first.start()
    wait_for(lambda: first.backlog == 0, 120, "the first 20 records")
    first.stop()
    assert first.sent >= 20
    # a cycle logged but not yet settled (the PLC not told) is held back until it is
    rec = record(99)
    log.begin_cycle(rec.part_id, rec.recipe, rec.recipe_hash, rec.started_at)
    held = log.add_cycle(rec)
    for k in range(5):
        log.add_cycle(record(100 + k))
    second = running.add(PlantOutbox(db, outbox_settings(broker)))
    wait_for(lambda: second.backlog == 6 and second.watermark == 20, 120, "the retained watermark")
    assert second.sent == 0 and held not in pg_ids(historian_db)
    log.settle_cycle(rec.started_at, held, rec.status, 0, "")
    wait_for(lambda: second.backlog == 0, 120, "the settled row and those after it")
    assert second.sent == 6                            # the 20 the watermark covers were not sent again
    assert second.session == first.session + 1
    assert pg_ids(historian_db) == log_ids(db)
    log.close()


def test_a_malformed_payload_or_an_unknown_schema_version_is_refused_and_writes_nothing(
        broker, historian_db, running):
    import psycopg
    historian = running.add(Historian(historian_settings(broker, historian_db, client_id="h-bad")))
    wait_for(historian.link.subscribed.is_set, 60, "the historian's subscription")
    with mqtt_client(broker) as client:
        client.publish(TOPICS.cycle, b"{\"schema\": 1, \"cell\": ", qos=1).wait_for_publish(30)
        wait_for(lambda: historian.rejected == 1, 60, "the malformed payload refused")
        assert "payload is not JSON" in historian.last_refusal and TOPICS.cycle in historian.last_refusal
        client.publish(TOPICS.cycle, b'{"schema": 7, "cell": "site1/line2/cell-1"}', qos=1).wait_for_publish(30)
        wait_for(lambda: historian.rejected == 2, 60, "the unknown version refused")
        assert "unknown schema version 7" in historian.last_refusal
    with psycopg.connect(historian_db) as pg:
        assert pg.execute("SELECT count(*) FROM cycles").fetchone()[0] == 0
        assert pg.execute("SELECT count(*) FROM watermarks").fetchone()[0] == 0
    assert historian.acked == 2                        # refused, not left to come back forever


def test_postgres_going_away_mid_batch_acknowledges_nothing_not_committed(tmp_path, broker):
    """Records published once, no outbox to send them again: only the broker's copy of an
    unacknowledged record can bring it back, so a record acknowledged before its commit
    would be lost."""
    from cell.plant import schema
    from cell.plant.servers import Postgres
    pg = Postgres()
    pg.start()
    try:
        h1 = Historian(historian_settings(broker, pg.dsn, client_id="h-pgaway"))
        h1.start()
        wait_for(h1.link.subscribed.is_set, 60, "the historian's subscription")
        with mqtt_client(broker) as client:

            def send(first: int, n: int, prev: int) -> None:
                for k in range(first, first + n):
                    rec = record(k)
                    rec.id = k
                    info = client.publish(TOPICS.cycle, schema.cycle_payload(TOPICS.path, "log-pg", rec, k - 1, 1, k),
                                          qos=1)
                    info.wait_for_publish(30)
            send(1, 50, 0)
            wait_for(lambda: len(pg_ids(pg.dsn)) == 50 and h1.acked == 50, 120, "the first 50 committed")
            pg.kill()
            send(51, 50, 50)
            # the broker sends at most its in-flight limit (20) unacknowledged: the batch it holds
            wait_for(lambda: h1.received > 50 and h1.failed_commits >= 2, 120, "commits failing")
            assert h1.acked == 50                          # none of the uncommitted ones
            h1.stop()                                      # what is not committed stays at the broker
            pg.start()
            h2 = Historian(historian_settings(broker, pg.dsn, client_id="h-pgaway"))
            h2.start()
            try:
                wait_for(lambda: len(pg_ids(pg.dsn)) == 100, 120, "the other 50 from the broker")
            finally:
                h2.stop()
        assert pg_ids(pg.dsn) == set(range(1, 101))
    finally:
        pg.stop()


def _historian_process(broker, dsn: str, client_id: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cell.cli", "historian", "--broker",
                             f"{broker.host}:{broker.port}", "--dsn", dsn, "--client-id", client_id],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


@pytest.mark.slow
def test_kill_9_of_the_historian_and_then_of_the_broker_mid_stream_loses_nothing(tmp_path, historian_db,
                                                                                 running):
    from cell.plant.servers import Mosquitto
    broker = Mosquitto()
    broker.start()
    proc = None
    try:
        db = tmp_path / "cell.sqlite"
        log = write_log(db, 1500)
        proc = _historian_process(broker, historian_db, "h-kill")
        outbox = running.add(PlantOutbox(db, outbox_settings(broker, window=200, resend_s=3.0)))
        wait_for(lambda: 100 < len(pg_ids(historian_db)), 120, "the stream under way")
        os.kill(proc.pid, signal.SIGKILL)              # the historian, mid-stream
        proc.wait(30)
        assert len(pg_ids(historian_db)) < 1500
        proc = _historian_process(broker, historian_db, "h-kill")
        wait_for(lambda: len(pg_ids(historian_db)) > 600, 180, "the stream going on after the restart")
        broker.kill()                                  # the broker, mid-stream: its queue and session go
        for k in range(200):                           # the cell goes on logging meanwhile
            log.add_cycle(record(5000 + k))
        broker.start()                                 # same port: both clients reconnect on their own
        wait_for(lambda: outbox.backlog == 0, 300, "the watermark to cover the whole log")
        assert pg_ids(historian_db) == log_ids(db)
        assert len(log_ids(db)) == 1700 and outbox.resends + outbox.link.generation >= 2
        log.close()
    finally:
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
        broker.stop()


def test_retention_deletes_only_what_the_historians_watermark_covers(tmp_path, broker, historian_db):
    # the cell's retention job with the outbox's real watermark: delivered records may go,
    # records written while the historian is away stay however old they are
    from datetime import datetime, timedelta, timezone

    from cell.jobs import retain
    path = tmp_path / "cell.sqlite"
    log = write_log(path, 6)
    historian = Historian(historian_settings(broker, historian_db, client_id="h-retain"))
    historian.start()
    outbox = PlantOutbox(path, outbox_settings(broker))
    outbox.start()
    try:
        wait_for(lambda: outbox.backlog == 0, 120, "six records delivered")
        historian.stop()
        for k in range(3):
            log.add_cycle(record(7 + k))
        wait_for(lambda: outbox.backlog == 3, 60, "three records waiting for the historian")
        later = datetime.now(timezone.utc) + timedelta(days=31)     # every record is old then
        assert retain(log, 30, outbox.watermark, now=later) == 6
        assert sorted(c.id for c in log.cycles()) == [7, 8, 9]
    finally:
        outbox.stop()
        log.close()


def test_state_updates_flowing_at_every_turn_neither_make_a_connection_ready_nor_resend_what_is_covered(
        tmp_path, broker, historian_db, running):
    # the birth's echo is what makes a connection ready (the retained watermark is in then);
    # a retained status of the cell's own carrying its state must not stand in for it
    import threading

    from cell.publish import Publisher
    db = tmp_path / "cell.sqlite"
    log = write_log(db, 20)
    running.add(Historian(historian_settings(broker, historian_db, client_id="h-ready")))
    publisher, stop = Publisher(), threading.Event()

    def flip():
        k = 0
        while not stop.is_set():
            k += 1
            publisher.status(float(k), {"state": ("idle", "approach", "capture")[k % 3], "fault_code": 0,
                                        "fault_text": "", "recipe_number": 1})
            stop.wait(0.002)
    flipper = threading.Thread(target=flip, daemon=True)
    flipper.start()
    try:
        first = PlantOutbox(db, outbox_settings(broker), publisher=publisher)
        first.start()
        wait_for(lambda: first.backlog == 0 and first.status_sent >= 3, 120, "the 20 records, and state updates")
        first.stop()
        for k in range(5):
            log.add_cycle(record(100 + k))
        for _ in range(3):                              # each restart: a new session, the last one's retained
            second = PlantOutbox(db, outbox_settings(broker), publisher=publisher)
            second.start()
            try:
                wait_for(lambda: second.backlog == 0 and second.status_sent >= 3, 120, "the rest, and updates")
                assert second.sent <= 5                 # never the 20 the watermark covers
            finally:
                second.stop()
    finally:
        stop.set()
        flipper.join(10)
        log.close()
    assert pg_ids(historian_db) == log_ids(db)
