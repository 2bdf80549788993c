"""The test servers are real and come back after a crash on the same port."""
from __future__ import annotations

import os
import socket


def test_postgres_runs_unprivileged_and_comes_back_after_an_immediate_stop(postgres):
    import psycopg
    with psycopg.connect(postgres.dsn) as db:
        assert db.execute("SELECT current_setting('server_version_num')::int").fetchone()[0] >= 150000
        db.execute("CREATE TABLE IF NOT EXISTS t (x int)")
        db.execute("INSERT INTO t VALUES (1)")
    postgres.kill()
    assert not postgres.running()
    postgres.start()
    with psycopg.connect(postgres.dsn) as db:
        assert db.execute("SELECT count(*) FROM t").fetchone()[0] == 1    # committed: kept
        assert db.execute("SELECT current_setting('data_directory')").fetchone()[0].startswith(str(postgres.folder))
        db.execute("DROP TABLE t")
    pid = int((postgres.data / "postmaster.pid").read_text().split()[0])
    assert os.stat(f"/proc/{pid}").st_uid != 0         # PostgreSQL refuses root: it runs as another user


def test_broker_accepts_mqtt5_on_loopback(broker):
    import paho.mqtt.client as mqtt
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    assert client.connect(broker.host, broker.port) == mqtt.MQTT_ERR_SUCCESS
    client.disconnect()
    with socket.create_connection((broker.host, broker.port), timeout=5):
        pass
