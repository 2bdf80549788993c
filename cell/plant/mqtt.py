"""The one adapter to paho-mqtt (2.2, MQTT 5, callback API version 2) for the plant path.

:class:`MqttLink` is one client with paho's network thread (``loop_start``): it connects
in the background and reconnects on its own after a drop (1 to ``max_backoff_s`` s apart),
subscribes again on every connect, and counts connections (:attr:`MqttLink.generation`).
:attr:`MqttLink.subscribed` is set once the broker has granted every subscription of the
current connection.

Callbacks run in paho's thread and must not block: ``on_up(generation, session_present)``
after each connect and subscribe request, ``on_down()`` after a drop,
``on_message(generation, message)`` for each message. With ``manual_ack`` a QoS 1 message
is acknowledged only by :meth:`MqttLink.ack` (paho's ``manual_ack``), and only on the
connection it came on: a message of an earlier connection is not acknowledged (the broker
sends it again; its PUBACK on another connection would acknowledge a different message
with the same packet id). :meth:`publish` and :meth:`ack` may be called from any thread.

A link with :class:`Security` connects over TLS (the broker's certificate checked against
a CA, and its name against the host's) and logs in with a user name and password; a
broker that refuses the login (or any connect) leaves the reason in :attr:`MqttLink.refused`
and paho keeps trying.

paho is imported when a link is made, not when this module is.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class Will:
    """A Last Will: what the broker publishes when the client goes without a DISCONNECT."""

    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = True


def read_password(path, what: str) -> str:
    """The password alone in the file at ``path``, whitespace stripped. Raises ConfigError
    naming ``what`` (the option or config key) and the file when it cannot be read or is
    empty."""
    from pathlib import Path

    from cell.errors import ConfigError
    try:
        password = Path(path).read_text().strip()
    except OSError as exc:
        raise ConfigError(f"{what} {path}: {exc.strerror}") from None
    if not password:
        raise ConfigError(f"{what} {path} is empty")
    return password


@dataclass(frozen=True)
class Security:
    """How a link proves itself and checks the broker.

    :param tls: connect over TLS, checking the broker's certificate and host name.
    :param ca_file: the CA (PEM) that signed the broker's certificate (None: the system's).
    :param username: the login (None: anonymous); ``password`` its password.
    """

    tls: bool = False
    ca_file: str | None = None
    username: str | None = None
    password: str | None = field(default=None, repr=False)


class MqttLink:
    """One MQTT 5 client and its network thread; see the module doc.

    :param clean_start: False for a persistent session (the broker keeps the subscriptions
        and queues QoS 1 messages while the client is away, ``session_expiry_s`` long).
    :param subscriptions: ``(topic filter, qos)`` pairs, subscribed at every connect.
    :param will: the Last Will, set at every connect (:meth:`set_will` changes it).
    :param security: TLS and login (None: plain TCP, anonymous).
    :param receive_maximum: QoS 1 messages the broker may send unacknowledged (MQTT 5
        Receive Maximum; None: the broker's default, mosquitto's 20). A client that
        acknowledges after a batch's commit needs room for a batch.
    """

    def __init__(self, host: str, port: int, client_id: str, *, clean_start: bool = True,
                 session_expiry_s: int = 0, subscriptions: tuple[tuple[str, int], ...] = (),
                 will: Will | None = None, manual_ack: bool = False, keepalive_s: int = 10,
                 max_inflight: int = 100, max_backoff_s: int = 5, security: Security | None = None,
                 receive_maximum: int | None = None,
                 on_up: Callable[[int, bool], None] | None = None,
                 on_down: Callable[[], None] | None = None,
                 on_message: Callable[[int, object], None] | None = None):
        import paho.mqtt.client as mqtt
        from paho.mqtt.packettypes import PacketTypes
        from paho.mqtt.properties import Properties

        self.host, self.port, self.client_id = host, int(port), client_id
        self.subscriptions = tuple(subscriptions)
        self.generation = 0                    #: connections made so far
        self.connected = threading.Event()
        self.subscribed = threading.Event()    #: every subscription of this connection granted
        self.refused: str | None = None        #: why the broker refused the last connect (None: it did not)
        self._pending: set[int] = set()
        self._on_up, self._on_down, self._on_message = on_up, on_down, on_message
        self._mqtt = mqtt
        c = self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id,
                                      protocol=mqtt.MQTTv5, manual_ack=manual_ack)
        c.max_inflight_messages_set(max_inflight)
        c.max_queued_messages_set(0)
        c.reconnect_delay_set(1, max_backoff_s)
        c.on_connect, c.on_disconnect, c.on_message = self._connected, self._disconnected, self._message
        c.on_subscribe = self._granted
        if security is not None and security.tls:
            import ssl
            c.tls_set(ca_certs=security.ca_file, tls_version=ssl.PROTOCOL_TLS_CLIENT)
        if security is not None and security.username is not None:
            c.username_pw_set(security.username, security.password)
        if will is not None:
            self.set_will(will)
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = int(session_expiry_s)
        if receive_maximum is not None:
            props.ReceiveMaximum = int(receive_maximum)
        self._connect_args = dict(keepalive=keepalive_s, clean_start=clean_start, properties=props)
        self._lock = threading.Lock()

    def set_will(self, will: Will) -> None:
        """The Last Will of the next connect."""
        self.client.will_set(will.topic, will.payload, qos=will.qos, retain=will.retain)

    def start(self) -> None:
        """Connect in the background (retrying until :meth:`stop`)."""
        self.client.connect_async(self.host, self.port, **self._connect_args)
        self.client.loop_start()

    def stop(self, final: tuple[str, bytes, bool] | None = None) -> None:
        """Publish ``final`` (topic, payload, retain; QoS 1) if connected, then disconnect
        cleanly (no Last Will) and end the network thread."""
        if final is not None and self.connected.is_set():
            info = self.client.publish(final[0], final[1], qos=1, retain=final[2])
            try:
                info.wait_for_publish(timeout=5)
            except (RuntimeError, ValueError):
                pass
        self.client.disconnect()
        self.client.loop_stop()
        self.connected.clear()

    def publish(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> bool:
        """Queue one message; False if paho refused it (not connected)."""
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        return info.rc == self._mqtt.MQTT_ERR_SUCCESS

    def ack(self, mid: int, generation: int, qos: int = 1) -> bool:
        """Acknowledge message ``mid`` received on connection ``generation``; False (nothing
        sent) if that connection is gone."""
        with self._lock:
            if generation != self.generation or not self.connected.is_set():
                return False
            return self.client.ack(mid, qos) == self._mqtt.MQTT_ERR_SUCCESS

    # paho's thread ------------------------------------------------------------------
    def _connected(self, client, userdata, flags, reason_code, properties) -> None:
        if reason_code.is_failure:
            self.refused = str(reason_code)
            return
        self.refused = None
        with self._lock:
            self.generation += 1
            generation = self.generation
        self.subscribed.clear()
        self._pending = set()
        for topic, qos in self.subscriptions:
            rc, mid = client.subscribe(topic, qos=qos)
            if rc == self._mqtt.MQTT_ERR_SUCCESS:
                self._pending.add(mid)
        if not self.subscriptions:
            self.subscribed.set()
        self.connected.set()
        if self._on_up is not None:
            self._on_up(generation, bool(flags.session_present))

    def _granted(self, client, userdata, mid, reason_codes, properties) -> None:
        if mid in self._pending and not any(rc.is_failure for rc in reason_codes):
            self._pending.discard(mid)
            if not self._pending:
                self.subscribed.set()

    def _disconnected(self, client, userdata, flags, reason_code, properties) -> None:
        self.connected.clear()
        self.subscribed.clear()
        if self._on_down is not None:
            self._on_down()

    def _message(self, client, userdata, message) -> None:
        if self._on_message is not None:
            self._on_message(self.generation, message)
