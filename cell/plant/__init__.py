"""The plant path: every cycle record of the cell's log to the plant historian's PostgreSQL
through an MQTT broker, nothing lost (contract: ``cell/plant.md``).

The cell's SQLite log is the outbox and the historian's watermark says what is delivered:

* :mod:`cell.plant.topics`: the topic tree ``<site>/<line>/<cell>/<kind>``;
* :mod:`cell.plant.schema`: the JSON payloads, version 1, checked with pydantic;
* :mod:`cell.plant.mqtt`: the one adapter to paho-mqtt (MQTT 5);
* :mod:`cell.plant.outbox`: the cell side, a thread that sends the log above the watermark;
* :mod:`cell.plant.historian` and :mod:`cell.plant.store`: ``cellctl historian``, broker to
  PostgreSQL, acknowledging only what is committed;
* :mod:`cell.plant.events`: the cell's state and its events (fault, reset, recipe, calibration);
* :mod:`cell.plant.status`: each cell's retained status (online, Last Will, state) into ``cell_status``;
* :mod:`cell.plant.servers`: a real mosquitto and PostgreSQL on loopback, for tests and trials,
  the mosquitto also as deployed (``deploy/mosquitto/``: TLS, logins, ACL), with
  certificates from :mod:`cell.plant.pki`.

Read back from PostgreSQL: :mod:`cell.plant.fleet` (``cellctl fleet report``, the HMI's
line view), and :mod:`cell.plant.demo` runs a fleet on one machine (``dev.py fleet``). The
backlog reaches the PLC's ``plant_backlog`` register and the HMI. Architecture, tests,
deployment and speed: ``docs/plant.md``.
Nothing here is imported by ``cellctl --help`` (paho and psycopg load when used).
"""
