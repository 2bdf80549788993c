"""The historian's PostgreSQL side: its schema, migrated by itself, and one commit per batch.

Tables (``schema_version`` records which migrations of :data:`MIGRATIONS` are applied;
the historian applies the missing ones at connect, under an advisory lock so two
historians starting together do not both migrate):

* ``cycles``: one row per cycle record, keyed by ``(cell, log_id, cycle_id)`` (``cell`` is
  ``site/line/cell``; ``log_id`` tells a cell's logs apart, their ids restart at 1). The
  first copy of a record wins; a copy already there is a duplicate, dropped and counted in
  the row's ``duplicates`` (committed with the batch, so the count survives any crash and
  counts a copy once), except that a smaller ``prev_id`` replaces the stored one (the
  cell's log lost rows below it to retention since the first copy: the ids between never
  come). The record's fields are kept whole in ``record`` (jsonb) and the ones a query
  filters on in columns too.
* ``watermarks``: per ``(cell, log_id)``, the highest ``cycle_id`` such that every record
  of that log up to it is committed. It moves in the same transaction as the rows: from
  ``w`` it moves to the next committed id ``c`` whose ``prev_id <= w`` (no id between ``w``
  and ``c`` exists in the log), and on from there.
* ``cell_status`` (migration 2): each cell's latest retained ``status`` (online or its Last
  Will), one row per cell, written by :class:`cell.plant.status.StatusRecorder`; its
  ``state``, ``fault_code`` and ``fault_text`` (migration 4; null from a version-1 status
  or a Last Will).
* ``events`` (migration 4): the cells' events (``<cell>/event``), keyed by ``(cell,
  session, seq, at)``: a copy of one (the same message again) is dropped; committed in
  the batch that brought it, with the cycles.

:meth:`HistorianStore.commit` writes a batch in ONE transaction and returns what moved; a
connection lost before the commit raises ``psycopg.OperationalError`` and nothing of the
batch is committed (the caller acknowledges nothing of it). psycopg is imported when a
store connects.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

MIGRATIONS: tuple[tuple[int, str], ...] = (
    (1, """
CREATE TABLE cycles (
    cell text NOT NULL,
    log_id text NOT NULL,
    cycle_id bigint NOT NULL,
    prev_id bigint NOT NULL,
    session bigint NOT NULL,
    seq bigint NOT NULL,
    part_id bigint NOT NULL,
    recipe text NOT NULL,
    status text NOT NULL,
    fault_code integer NOT NULL,
    started_at text NOT NULL,
    finished_at text NOT NULL,
    final_error_mm double precision,
    cycle_time_s double precision NOT NULL,
    record jsonb NOT NULL,
    received_at timestamptz NOT NULL DEFAULT now(),
    PRIMARY KEY (cell, log_id, cycle_id)
);
CREATE INDEX cycles_finished ON cycles (cell, finished_at);
CREATE TABLE watermarks (
    cell text NOT NULL,
    log_id text NOT NULL,
    cycle_id bigint NOT NULL,
    updated_at timestamptz NOT NULL DEFAULT now(),
    PRIMARY KEY (cell, log_id)
);
"""),
    (2, """
CREATE TABLE cell_status (
    cell text PRIMARY KEY,
    online boolean NOT NULL,
    session bigint NOT NULL,
    log_id text,
    at text NOT NULL,
    changed_at timestamptz NOT NULL DEFAULT now(),
    received_at timestamptz NOT NULL DEFAULT now()
);
"""),
    (3, """
ALTER TABLE cycles ADD COLUMN duplicates integer NOT NULL DEFAULT 0;
"""),
    (4, """
ALTER TABLE cell_status ADD COLUMN state text, ADD COLUMN fault_code integer, ADD COLUMN fault_text text;
CREATE TABLE events (
    cell text NOT NULL,
    session bigint NOT NULL,
    seq bigint NOT NULL,
    at text NOT NULL,
    kind text NOT NULL,
    data jsonb NOT NULL,
    received_at timestamptz NOT NULL DEFAULT now(),
    PRIMARY KEY (cell, session, seq, at)
);
CREATE INDEX events_at ON events (cell, at);
"""),
)
SCHEMA_VERSION = MIGRATIONS[-1][0]
#: one record; a copy already there is counted in its row (returns True for a new row)
_INSERT = ("INSERT INTO cycles (cell, log_id, cycle_id, prev_id, session, seq, part_id, recipe, status,"
           " fault_code, started_at, finished_at, final_error_mm, cycle_time_s, record)"
           " VALUES (%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s::jsonb)"
           " ON CONFLICT (cell, log_id, cycle_id) DO UPDATE SET duplicates = cycles.duplicates + 1,"
           " prev_id = LEAST(cycles.prev_id, EXCLUDED.prev_id) RETURNING (xmax = 0)")
_INSERT_EVENT = ("INSERT INTO events (cell, session, seq, at, kind, data) VALUES (%s,%s,%s,%s,%s,%s::jsonb)"
                 " ON CONFLICT DO NOTHING")
_LOCK_KEY = 25_0001          # pg_advisory_xact_lock key of the migration


@dataclass
class CommitResult:
    """What one committed batch did."""

    inserted: int = 0
    duplicates: int = 0
    #: (cell, log_id) -> the watermark after the commit, for every log the batch touched
    watermarks: dict[tuple[str, str], int] = field(default_factory=dict)
    events: int = 0          #: events written (copies of one already there are not)


class HistorianStore:
    """One connection to the historian's database (``dsn``, a libpq string)."""

    def __init__(self, dsn: str):
        self.dsn = dsn
        self.db = None

    def connect(self) -> None:
        """Connect and migrate; raises ``psycopg.OperationalError`` if the server is away."""
        import psycopg
        self.close()
        self.db = psycopg.connect(self.dsn, autocommit=False)
        self.migrate()

    def close(self) -> None:
        if self.db is not None:
            try:
                self.db.close()
            except Exception:                      # noqa: BLE001 -- a dead connection
                pass
            self.db = None

    def migrate(self) -> int:
        """Apply the missing migrations; returns the schema version now."""
        db = self.db
        with db.transaction():
            db.execute("SELECT pg_advisory_xact_lock(%s)", (_LOCK_KEY,))
            db.execute("CREATE TABLE IF NOT EXISTS schema_version (version integer PRIMARY KEY,"
                       " applied_at timestamptz NOT NULL DEFAULT now())")
            have = db.execute("SELECT COALESCE(MAX(version), 0) FROM schema_version").fetchone()[0]
            for version, sql in MIGRATIONS:
                if version > have:
                    db.execute(sql)
                    db.execute("INSERT INTO schema_version (version) VALUES (%s)", (version,))
        db.commit()
        return SCHEMA_VERSION

    def commit(self, messages, events=()) -> CommitResult:
        """Write ``messages`` (:class:`~cell.plant.schema.CycleMessage`) and ``events``
        (:class:`~cell.plant.schema.EventMessage`) and move the watermarks, in one
        transaction. Raises ``psycopg.Error``; then nothing is committed."""
        if self.db is None:
            self.connect()
        db, result = self.db, CommitResult()
        touched: set[tuple[str, str]] = set()
        try:
            with db.transaction():
                # one statement per record, sent in one pipeline (psycopg's executemany):
                # no round trip per record
                cur = db.cursor()
                if messages:
                    cur.executemany(_INSERT, [
                        (m.cell, m.log_id, m.cycle_id, m.prev_id, m.session, m.seq, m.record.part_id, m.record.recipe,
                         m.record.status, m.record.fault_code, m.record.started_at, m.record.finished_at,
                         m.record.final_error_mm, m.record.cycle_time_s, json.dumps(m.record.model_dump()))
                        for m in messages], returning=True)
                    for m in messages:
                        if cur.fetchone()[0]:
                            result.inserted += 1
                        else:
                            result.duplicates += 1
                        touched.add((m.cell, m.log_id))
                        cur.nextset()
                for cell, log_id in sorted(touched):
                    result.watermarks[(cell, log_id)] = self._advance(cell, log_id)
                for e in events:
                    result.events += db.execute(_INSERT_EVENT, (e.cell, e.session, e.seq, e.at, e.kind,
                                                                json.dumps(e.data))).rowcount
            db.commit()
        except BaseException:
            try:
                db.rollback()
            except Exception:                      # noqa: BLE001 -- the connection is gone
                pass
            raise
        return result

    def _advance(self, cell: str, log_id: str) -> int:
        db = self.db
        db.execute("INSERT INTO watermarks (cell, log_id, cycle_id) VALUES (%s, %s, 0)"
                   " ON CONFLICT DO NOTHING", (cell, log_id))
        w = db.execute("SELECT cycle_id FROM watermarks WHERE cell = %s AND log_id = %s FOR UPDATE",
                       (cell, log_id)).fetchone()[0]
        start = w
        for cycle_id, prev_id in db.execute(
                "SELECT cycle_id, prev_id FROM cycles WHERE cell = %s AND log_id = %s AND cycle_id > %s"
                " ORDER BY cycle_id", (cell, log_id, w)):
            if prev_id > w:
                break                              # a record between w and cycle_id is missing
            w = cycle_id
        if w != start:
            db.execute("UPDATE watermarks SET cycle_id = %s, updated_at = now() WHERE cell = %s AND log_id = %s",
                       (w, cell, log_id))
        return int(w)

    def latest_watermarks(self) -> dict[str, tuple[str, int]]:
        """cell -> (log_id, watermark) of the log each cell sent last (to publish again)."""
        if self.db is None:
            self.connect()
        rows = self.db.execute("SELECT DISTINCT ON (cell) cell, log_id, cycle_id FROM watermarks"
                               " ORDER BY cell, updated_at DESC").fetchall()
        self.db.commit()
        return {cell: (log_id, int(w)) for cell, log_id, w in rows}
