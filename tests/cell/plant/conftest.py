"""Real servers for the plant path's tests: one mosquitto and one PostgreSQL per test module,
started by the project's own code (:mod:`cell.plant.servers`), never mocked.

Missing binaries skip the tests that need them, naming the Debian package; under
``CI=true`` they fail instead (:func:`tests.tools.skip_unless_ci`). A test that kills a server
gets servers of its own (``Mosquitto()`` / ``Postgres()`` in the test), so a crash never
reaches the module's shared ones.
"""
from __future__ import annotations

import pytest

from tests.tools import skip_unless_ci


def _start(factory):
    from cell.plant.servers import ServerMissing
    try:
        server = factory()
    except ServerMissing as exc:
        skip_unless_ci(str(exc))
    return server.start()


@pytest.fixture(scope="module")
def broker():
    """A mosquitto on a free loopback port (``.host``, ``.port``)."""
    from cell.plant.servers import Mosquitto
    server = _start(Mosquitto)
    yield server
    server.stop()


@pytest.fixture(scope="module")
def postgres():
    """A PostgreSQL 15 on a free loopback port (``.dsn``), run as an unprivileged user."""
    from cell.plant.servers import Postgres
    server = _start(Postgres)
    yield server
    server.stop()


@pytest.fixture
def historian_db(postgres):
    """``postgres.dsn`` with the historian's tables dropped first: each test starts empty."""
    import psycopg
    with psycopg.connect(postgres.dsn, autocommit=True) as db:
        db.execute("DROP SCHEMA public CASCADE")
        db.execute("CREATE SCHEMA public")
    return postgres.dsn


@pytest.fixture
def running():
    """Start and always stop what a test starts (``running.add(x)``; x.stop() at the end,
    last started first)."""
    started = []

    class Running:
        def add(self, thing):
            thing.start()
            started.append(thing)
            return thing
    yield Running()
    for thing in reversed(started):
        thing.stop()
