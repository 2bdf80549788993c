"""Each cell's retained status reaches ``cell_status``: online at the birth, offline at a
clean stop and at the Last Will the broker publishes for a cell that vanished; a status
that came while the recorder was away is the retained one it gets at its connect."""
from __future__ import annotations

import subprocess
import sys

from cell.plant.outbox import PlantOutbox
from cell.plant.status import StatusRecorder
from tests.cell.plant.helpers import TOPICS, outbox_settings, write_log
from tests.waiting import wait_for


def status_rows(dsn: str) -> dict:
    import psycopg
    with psycopg.connect(dsn) as db:
        if db.execute("SELECT to_regclass('cell_status')").fetchone()[0] is None:
            return {}
        return {r[0]: r[1:] for r in db.execute("SELECT cell, online, session, log_id FROM cell_status")}


def test_birth_goodbye_and_last_will_are_recorded(tmp_path, broker, historian_db):
    log = write_log(tmp_path / "cell.sqlite", 3)
    log_id = log.log_id
    log.close()
    outbox = PlantOutbox(tmp_path / "cell.sqlite", outbox_settings(broker))
    outbox.start()
    recorder = StatusRecorder(broker.host, broker.port, historian_db, client_id="status-1", keepalive_s=5)
    try:
        recorder.start()
        wait_for(lambda: status_rows(historian_db).get(TOPICS.path, (False,))[0], 60, "the cell online")
        assert status_rows(historian_db)[TOPICS.path] == (True, outbox.session, log_id)
        outbox.stop()
        wait_for(lambda: status_rows(historian_db)[TOPICS.path][0] is False, 60, "the goodbye")
        # a cell that vanishes without a goodbye: the broker publishes its Last Will
        will = (b'{"schema":1,"cell":"site1/line2/cell-9","online":false,"session":7,"log_id":null,'
                b'"at":"2026-01-01T00:00:00+00:00"}')
        birth = will.replace(b"false", b"true")
        code = ("import os, paho.mqtt.client as m\n"
                "c = m.Client(m.CallbackAPIVersion.VERSION2, protocol=m.MQTTv5)\n"
                f"c.will_set('site1/line2/cell-9/status', {will!r}, qos=1, retain=True)\n"
                f"c.connect('{broker.host}', {broker.port}, keepalive=5)\n"
                f"c.publish('site1/line2/cell-9/status', {birth!r}, qos=1, retain=True).wait_for_publish(10)\n"
                "os._exit(0)\n")
        subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
        wait_for(lambda: status_rows(historian_db).get("site1/line2/cell-9", (True,))[0] is False, 60,
                 "the Last Will recorded")
        assert status_rows(historian_db)["site1/line2/cell-9"] == (False, 7, None)
    finally:
        outbox.stop()
        recorder.stop()


def test_a_status_sent_while_the_recorder_was_away_and_a_bad_one(tmp_path, broker, historian_db):
    import paho.mqtt.client as mqtt
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    c.connect(broker.host, broker.port)
    c.loop_start()
    try:
        ok = b'{"schema":1,"cell":"s/l/cell-5","online":true,"session":3,"log_id":"ab","at":"2026-01-01T00:00:00Z"}'
        c.publish("s/l/cell-5/status", ok, qos=1, retain=True).wait_for_publish(10)
        c.publish("s/l/cell-6/status", b"not json", qos=1, retain=True).wait_for_publish(10)
        recorder = StatusRecorder(broker.host, broker.port, historian_db, client_id="status-2", keepalive_s=5,
                                  topic_filter="s/l/+/status")
        recorder.start()
        try:
            wait_for(lambda: status_rows(historian_db).get("s/l/cell-5"), 60, "the retained status")
            wait_for(lambda: recorder.refused == 1, 60, "the bad one refused")
            assert status_rows(historian_db) == {"s/l/cell-5": (True, 3, "ab")}
        finally:
            recorder.stop()
        for topic in ("s/l/cell-5/status", "s/l/cell-6/status"):
            c.publish(topic, b"", qos=1, retain=True).wait_for_publish(10)
    finally:
        c.loop_stop()
        c.disconnect()


def _state(state: str, code: int = 0, text: str = "", recipe: int = 1) -> dict:
    """A status snapshot as the controller publishes it (cell.controller status_snapshot)."""
    return {"state": state, "fault_code": code, "fault_text": text, "cycle_count": 0, "recipe_number": recipe,
            "recipe_name": f"recipe-{recipe}", "recalibration_due": False, "plc_owner": None, "joints": None}


def cell_state(dsn: str, cell: str = TOPICS.path):
    import psycopg
    with psycopg.connect(dsn) as db:
        if db.execute("SELECT to_regclass('cell_status')").fetchone()[0] is None:
            return None
        return db.execute("SELECT online, state, fault_code, fault_text FROM cell_status WHERE cell = %s",
                          (cell,)).fetchone()


def event_rows(dsn: str, cell: str = TOPICS.path) -> list:
    import psycopg
    with psycopg.connect(dsn) as db:
        if db.execute("SELECT to_regclass('events')").fetchone()[0] is None:
            return []
        return db.execute("SELECT kind, data, session FROM events WHERE cell = %s ORDER BY session, seq",
                          (cell,)).fetchall()


def test_the_cells_state_and_its_events_reach_postgres_and_the_line_view(tmp_path, broker, historian_db):
    from cell.hmi.line import line_rows
    from cell.plant.historian import Historian
    from cell.publish import Publisher
    from tests.cell.plant.helpers import historian_settings, log_ids, pg_ids
    log = write_log(tmp_path / "cell.sqlite", 3)
    log.close()
    publisher = Publisher()
    publisher.status(0.0, _state("idle"))                  # before the outbox: its birth says it
    historian = Historian(historian_settings(broker, historian_db, client_id="h-events"))
    recorder = StatusRecorder(broker.host, broker.port, historian_db, client_id="status-3", keepalive_s=5)
    outbox = PlantOutbox(tmp_path / "cell.sqlite", outbox_settings(broker), publisher=publisher)
    try:
        historian.start()
        recorder.start()
        wait_for(historian.link.subscribed.is_set, 60, "the historian's subscriptions")
        outbox.start()
        wait_for(lambda: cell_state(historian_db) == (True, "idle", 0, ""), 60, "online and idle")
        publisher.status(1.0, _state("approach"))
        publisher.status(1.1, _state("fault", 31, "camera lost the part"))
        publisher.event(1.2, "calibration_applied", {"calibration": "cal-0002", "sha256": "00ff"})
        wait_for(lambda: cell_state(historian_db) == (True, "fault", 31, "camera lost the part"), 60,
                 "the fault in the cell's status")
        publisher.status(2.0, _state("resetting", 31, "camera lost the part"))
        publisher.status(2.1, _state("idle"))
        publisher.status(2.2, _state("idle", recipe=2))
        wait_for(lambda: len(event_rows(historian_db)) == 4, 60, "four events")
        wait_for(lambda: cell_state(historian_db) == (True, "idle", 0, ""), 60, "idle again")
        assert [(k, d) for k, d, _ in event_rows(historian_db)] == [
            ("fault", {"code": 31, "text": "camera lost the part", "state": "fault"}),
            ("calibration_applied", {"calibration": "cal-0002", "sha256": "00ff"}),
            ("reset", {"code": 31, "state": "idle"}),
            ("recipe_selected", {"number": 2, "name": "recipe-2"})]
        assert {s for _, _, s in event_rows(historian_db)} == {outbox.session}
        assert outbox.events_sent == 4 and outbox.events_dropped == 0 and historian.events == 4
        [row] = [c for c in line_rows(historian_db, {})["cells"] if c["cell"] == TOPICS.path]
        assert row["state"] == "online, idle" and row["cell_state"] == "idle"
        # the cycles went on as before
        wait_for(lambda: outbox.backlog == 0, 60, "the log delivered")
        assert pg_ids(historian_db) == log_ids(tmp_path / "cell.sqlite")
        outbox.stop()
        wait_for(lambda: cell_state(historian_db) == (False, None, None, None), 60,
                 "the goodbye, which knows no state")
    finally:
        outbox.stop()
        recorder.stop()
        historian.stop()
