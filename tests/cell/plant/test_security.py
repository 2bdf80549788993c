"""The plant link secured as deployed (``deploy/mosquitto/plant.conf`` and ``plant.acl``):
MQTT over TLS only, a login per cell, and an ACL that lets a cell publish only under its
own topics while the historian reads everything. The broker is a real mosquitto started
from the deployed files (:class:`cell.plant.servers.Mosquitto` with ``users``)."""
from __future__ import annotations

import threading

import pytest

from cell.plant import schema
from cell.plant.historian import Historian
from cell.plant.mqtt import MqttLink, Security
from cell.plant.outbox import PlantOutbox
from cell.plant.topics import CellTopics
from tests.cell.plant.conftest import _start
from tests.cell.plant.helpers import historian_settings, log_ids, outbox_settings, pg_ids, record, write_log
from tests.waiting import wait_for

ONE = CellTopics("site1", "line2", "cell-1")
TWO = CellTopics("site1", "line2", "cell-2")
USERS = {ONE.path: "one-secret", TWO.path: "two-secret", "historian": "historian-secret"}


@pytest.fixture(scope="module")
def secure_broker():
    from cell.plant.servers import Mosquitto
    server = _start(lambda: Mosquitto(users=USERS))
    yield server
    server.stop()


def _security(broker, user: str | None, password: str | None = None) -> Security:
    return Security(tls=True, ca_file=str(broker.certificates.ca), username=user,
                    password=password if password is not None else USERS.get(user))


class Publisher:
    """A bare MQTT 5 client over TLS that remembers each publish's PUBACK reason code."""

    def __init__(self, broker, security: Security):
        self.acks: dict[int, object] = {}
        self._acked = threading.Condition()
        self.link = MqttLink(broker.host, broker.port, "test-publisher", security=security)
        self.link.client.on_publish = self._puback

    def _puback(self, client, userdata, mid, reason_code, properties):
        with self._acked:
            self.acks[mid] = reason_code
            self._acked.notify_all()

    def publish(self, topic: str, payload: bytes):
        """The broker's PUBACK reason code for one QoS 1 publish."""
        info = self.link.client.publish(topic, payload, qos=1)
        with self._acked:
            self._acked.wait_for(lambda: info.mid in self.acks, 30)
        return self.acks[info.mid]

    def __enter__(self):
        self.link.start()
        wait_for(self.link.connected.is_set, 60, "the publisher's TLS connection")
        return self

    def __exit__(self, *exc):
        self.link.stop()


def _cycle(topics: CellTopics, cycle_id: int) -> bytes:
    rec = record(cycle_id)
    rec.id = cycle_id
    return schema.cycle_payload(topics.path, "log-acl", rec, cycle_id - 1, 1, cycle_id)


def test_a_cell_with_its_login_sends_its_log_over_tls_to_a_historian_with_its_own(tmp_path, secure_broker,
                                                                                  historian_db):
    db = tmp_path / "cell.sqlite"
    log = write_log(db, 40)
    historian = Historian(historian_settings(secure_broker, historian_db, client_id="h-tls",
                                             security=_security(secure_broker, "historian")))
    historian.start()
    outbox = PlantOutbox(db, outbox_settings(secure_broker, ONE, security=_security(secure_broker, ONE.path)))
    outbox.start()
    try:
        wait_for(lambda: outbox.backlog == 0, 120, "the log delivered over TLS")
        assert pg_ids(historian_db, ONE.path) == log_ids(db) and len(log_ids(db)) == 40
        assert historian.rejected == 0 and outbox.link.refused is None
    finally:
        outbox.stop()
        historian.stop()
        log.close()


def test_the_acl_refuses_a_cell_publishing_under_another_cells_topics_or_a_watermark(secure_broker,
                                                                                     historian_db):
    historian = Historian(historian_settings(secure_broker, historian_db, client_id="h-acl",
                                             security=_security(secure_broker, "historian")))
    historian.start()
    try:
        wait_for(historian.link.subscribed.is_set, 60, "the historian's subscription")
        with Publisher(secure_broker, _security(secure_broker, ONE.path)) as cell_one:
            refused = cell_one.publish(TWO.cycle, _cycle(TWO, 1))          # cell 1 posing as cell 2
            assert refused.is_failure and refused.getName() == "Not authorized"
            forged = cell_one.publish(ONE.watermark, schema.watermark_payload(ONE.path, "log-acl", 10 ** 6))
            assert forged.is_failure and forged.getName() == "Not authorized"
            own = cell_one.publish(ONE.cycle, _cycle(ONE, 1))             # its own topic: taken
            assert not own.is_failure
        # the historian gets messages in the order they were published: cell 1's own record
        # came after the refused one, so had the refused one passed it would be there first
        wait_for(lambda: historian.received == 1 and historian.inserted == 1, 60, "cell 1's own record")
        assert pg_ids(historian_db, TWO.path) == set() and pg_ids(historian_db, ONE.path) == {1}
    finally:
        historian.stop()


@pytest.mark.parametrize("login", ["none", "wrong password", "plain tcp"])
def test_without_its_credentials_a_client_is_refused(secure_broker, login):
    if login == "plain tcp":                       # an MQTT CONNECT without TLS: no CONNACK, closed
        import socket
        with socket.create_connection((secure_broker.host, secure_broker.port), timeout=30) as s:
            s.sendall(b"\x10\x0c\x00\x04MQTT\x04\x02\x00\x3c\x00\x00")
            try:
                answer = s.recv(64)
            except ConnectionResetError:
                answer = b""
        assert answer == b"" or answer[:1] != b"\x20"   # never a CONNACK
        return
    security = _security(secure_broker, None) if login == "none" else _security(secure_broker, ONE.path, "guess")
    link = MqttLink(secure_broker.host, secure_broker.port, "test-intruder", security=security)
    link.start()
    try:
        wait_for(lambda: link.refused is not None, 60, "the broker's refusal")
        assert link.refused in ("Not authorized", "Bad user name or password") and not link.connected.is_set()
    finally:
        link.stop()


def test_the_plant_section_gives_the_cell_tls_and_its_login_from_a_file(tmp_path, secure_broker, historian_db):
    import yaml

    from cell.config import CellConfig
    from cell.errors import ConfigError
    (tmp_path / "plant.password").write_text(USERS[TWO.path] + "\n")
    (tmp_path / "ca.pem").write_bytes(secure_broker.certificates.ca.read_bytes())
    path = tmp_path / "cell.yaml"
    section = dict(host=secure_broker.host, port=secure_broker.port, site="site1", line="line2", tls=True,
                   ca_file="ca.pem", password_file="plant.password")
    path.write_text(yaml.safe_dump({"format": "cell-config/1", "name": "cell-2", "plant": section}))
    settings = CellConfig.load(path).plant.outbox_settings("cell-2")
    assert settings.security.username == TWO.path          # the cell id: the ACL's name for its topics
    assert settings.security.ca_file == str(tmp_path / "ca.pem") and "two-secret" not in repr(settings)
    db = tmp_path / "cell.sqlite"
    log = write_log(db, 5)
    historian = Historian(historian_settings(secure_broker, historian_db, client_id="h-config",
                                             security=_security(secure_broker, "historian")))
    historian.start()
    outbox = PlantOutbox(db, settings)
    outbox.start()
    try:
        wait_for(lambda: outbox.backlog == 0, 120, "the log delivered with the config's login")
        assert pg_ids(historian_db, TWO.path) == log_ids(db)
    finally:
        outbox.stop()
        historian.stop()
        log.close()
    for bad, says in ((dict(section, password_file=None, username="x"), "needs plant.password_file"),
                      (dict(section, tls=False), "only used with plant.tls")):
        path.write_text(yaml.safe_dump({"format": "cell-config/1", "plant": {k: v for k, v in bad.items()
                                                                              if v is not None}}))
        with pytest.raises(ConfigError, match=says):
            CellConfig.load(path)
    path.write_text(yaml.safe_dump({"format": "cell-config/1", "plant": dict(section, password_file="absent")}))
    with pytest.raises(ConfigError, match="plant.password_file .*absent"):
        CellConfig.load(path).plant.outbox_settings("cell-2")


def test_cellctl_historian_logs_in_over_tls(tmp_path, secure_broker, historian_db):
    import subprocess
    import sys

    from tests.cell.plant.test_plant_path import REPO
    (tmp_path / "historian.password").write_text(USERS["historian"])
    proc = subprocess.Popen([sys.executable, "-m", "cell.cli", "historian", "--broker",
                             f"{secure_broker.host}:{secure_broker.port}", "--dsn", historian_db,
                             "--client-id", "h-cli-tls", "--ca-file", str(secure_broker.certificates.ca),
                             "--password-file", str(tmp_path / "historian.password")],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=open(tmp_path / "historian.log", "wb"))
    db = tmp_path / "cell.sqlite"
    log = write_log(db, 3)
    outbox = PlantOutbox(db, outbox_settings(secure_broker, ONE, security=_security(secure_broker, ONE.path)))
    outbox.start()
    try:
        wait_for(lambda: outbox.backlog == 0, 120, "the records committed by cellctl historian")
        assert pg_ids(historian_db, ONE.path) == {1, 2, 3}
    finally:
        outbox.stop()
        log.close()
        proc.terminate()
        proc.wait(30)


def test_a_refused_login_is_logged_by_the_outbox_and_the_historian(tmp_path, secure_broker, historian_db):
    from tests.cell.plant.test_bad_input import Said
    db = tmp_path / "cell.sqlite"
    write_log(db, 1).close()
    said = Said()
    outbox = PlantOutbox(db, outbox_settings(secure_broker, ONE, security=_security(secure_broker, ONE.path, "old")),
                         logger=said)
    historian = Historian(historian_settings(secure_broker, historian_db, client_id="h-refused",
                                             security=_security(secure_broker, "historian", "old")), logger=said)
    outbox.start()
    historian.start()
    try:
        wait_for(lambda: {e for e, _ in said.events} >= {"plant_connect_refused", "historian_connect_refused"},
                 60, "both refusals logged")
        reasons = {kw["reason"] for e, kw in said.events if e.endswith("connect_refused")}
        assert reasons and reasons <= {"Bad user name or password", "Not authorized"}
        assert outbox.backlog == 1 and pg_ids(historian_db, ONE.path) == set()   # the record waits in the log
    finally:
        outbox.stop()
        historian.stop()


def test_a_password_file_that_is_absent_or_empty_is_refused_by_name(tmp_path):
    # the cell's plant section and cellctl historian read it the same way (mqtt.read_password)
    import argparse

    from cell.commands.historian import _security
    from cell.errors import ConfigError
    from cell.plant.mqtt import read_password
    empty = tmp_path / "empty.password"
    empty.write_text(" \n")
    (tmp_path / "good.password").write_text("s3cret\n")
    assert read_password(tmp_path / "good.password", "x") == "s3cret"
    with pytest.raises(ConfigError, match=r"plant.password_file .*empty.password is empty"):
        read_password(empty, "plant.password_file")
    args = argparse.Namespace(tls=True, ca_file=None, username="historian", password_file=str(empty))
    with pytest.raises(ConfigError, match=r"--password-file .*empty.password is empty"):
        _security(args)
    args.password_file = str(tmp_path / "absent")
    with pytest.raises(ConfigError, match=r"--password-file .*absent: No such file"):
        _security(args)
