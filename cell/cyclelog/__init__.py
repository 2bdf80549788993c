"""Per-cycle accuracy log and audit trail in one SQLite file.

Durability: WAL journal with ``synchronous=FULL``, so a cycle the PLC was told is done
survives a power cut. Each cycle is ONE row written in ONE transaction when the cycle ends
(done, fault or aborted): a crash at any moment leaves either the whole row or nothing,
never a half-written cycle. The controller writes the row *before* it raises Done to the PLC.

A row records what the PLC was told. The ``open_cycle`` table holds the one cycle in
flight: :meth:`CycleLog.begin_cycle` before its first move, ``logged`` when its row is
written, gone once the PLC has been told the outcome (:meth:`CycleLog.settle_cycle`, which
also corrects the row if the PLC was told something else, e.g. a heartbeat fault while the
row was being written). A controller that died with a cycle in flight finds it at the next
start (:meth:`CycleLog.recover_interrupted`): the cycle is recorded as aborted with fault 503,
and stays pending (``interrupted``) until the PLC has reset that fault.

Opening (:mod:`cell.cyclelog.file`): the controller's log is locked against a second controller
and checked (``quick_check``) before use; readers open it read-only.

The ``audit`` table is hash-chained (each row stores the SHA-256 of the previous row's hash
and its own content): recipe activations and refusals, applied calibrations;
:meth:`CycleLog.audit_break` checks the chain (``cellctl audit verify``).
"""
from __future__ import annotations

import hashlib
import enum
import json
import sqlite3
import threading
import uuid
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from cell.cyclelog import file as logfile
from cell.errors import LogError
from cell.faults import Fault
from cell.cyclelog.file import LogLock

SCHEMA_VERSION = 4     #: 2 added cycles.motion_json (how the cycle's moves were streamed),
                       #: 3 the open_cycle table (the cycle in flight), 4 cycles.calibration
                       #: (the robot calibration the cycle ran with; '' = the nominal model)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS cycles (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    part_id INTEGER NOT NULL,
    recipe TEXT NOT NULL,
    recipe_hash TEXT NOT NULL,
    started_at TEXT NOT NULL,
    finished_at TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('done', 'fault', 'aborted')),
    method TEXT,
    target_x_mm REAL, target_y_mm REAL,
    initial_error_mm REAL,
    final_error_mm REAL,
    verify_error_mm REAL,
    moves INTEGER,
    cycle_time_s REAL NOT NULL,
    step_times_json TEXT NOT NULL,
    fault_code INTEGER NOT NULL DEFAULT 0,
    fault_text TEXT NOT NULL DEFAULT '',
    temp_c REAL,
    trace_json TEXT NOT NULL DEFAULT '[]',
    motion_json TEXT NOT NULL DEFAULT '{}',
    calibration TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS cycles_finished ON cycles (finished_at);
CREATE TABLE IF NOT EXISTS audit (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at TEXT NOT NULL,
    who TEXT NOT NULL,
    action TEXT NOT NULL,
    target TEXT NOT NULL,
    hash TEXT NOT NULL,
    result TEXT NOT NULL,
    prev_hash TEXT NOT NULL,
    row_hash TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS open_cycle (
    slot INTEGER PRIMARY KEY CHECK (slot = 1),
    part_id INTEGER NOT NULL,
    recipe TEXT NOT NULL,
    recipe_hash TEXT NOT NULL,
    started_at TEXT NOT NULL,
    stage TEXT NOT NULL CHECK (stage IN ('running', 'logged', 'interrupted')),
    cycle_id INTEGER
);
CREATE TABLE IF NOT EXISTS recipe_versions (
    hash TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    content TEXT NOT NULL,
    first_active_at TEXT NOT NULL
);
"""


class CycleStatus(enum.StrEnum):
    """How a cycle (or a calibration run in its place) ended: the log's ``status`` column
    (its CHECK constraint holds the same three)."""

    DONE = "done"
    FAULT = "fault"
    ABORTED = "aborted"


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


@dataclass
class CycleRecord:
    """One part's cycle as logged. Errors in mm; ``trace`` is the compensation trace
    (list of step dicts with joints_deg, point_mm, error_mm, moved)."""

    part_id: int
    recipe: str
    recipe_hash: str
    started_at: str
    finished_at: str
    status: CycleStatus
    cycle_time_s: float
    step_times: dict[str, float] = field(default_factory=dict)
    method: str | None = None
    target_mm: tuple[float, float] | None = None
    initial_error_mm: float | None = None
    final_error_mm: float | None = None
    verify_error_mm: float | None = None
    moves: int | None = None
    fault_code: int = 0
    fault_text: str = ""
    temp_c: float | None = None
    trace: list[dict] = field(default_factory=list)
    #: how the moves were streamed: mode, moves, segments, segment_ms, time_law, delays_ms (j1..j4)
    motion: dict = field(default_factory=dict)
    #: id of the robot calibration the cycle ran with (``v<N>-<sha8>``), '' for the nominal model
    calibration: str = ""
    id: int | None = None


@dataclass(frozen=True)
class Interrupted:
    """A cycle a controller restart interrupted: the PLC must hear of it once."""

    cycle_id: int
    part_id: int
    recipe: str
    started_at: str


class CycleLog:
    """The SQLite log. Thread-safe: one connection guarded by a lock.

    :param readonly: open for reading only: no lock, no check, nothing created or changed
        (``report``, ``export``, ``diagnose``; works beside a running controller).
    :param fresh: start an empty log (the simulated cell starts from power-on): the file
        there is kept under a time-stamped name (:func:`cell.cyclelog.file.keep_previous`) — only
        once this writer holds the lock, so a refused start moves nothing.
    :raises LogError: the file is damaged, not a database, cannot be written (writer), is
        missing (reader), or another controller holds it (writer); see :mod:`cell.cyclelog.file`.
    """

    def __init__(self, path: Path | str, readonly: bool = False, fresh: bool = False):
        self.path = Path(path)
        self.readonly = readonly
        self._lock = threading.Lock()
        self._file_lock: LogLock | None = None
        if readonly:
            self._db = logfile.connect(self.path, readonly=True)
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise LogError(f"{self.path}: cannot create the cycle log's folder: {exc.strerror}") from None
        self._file_lock = LogLock(self.path)
        self._file_lock.acquire()
        #: where the previous log was kept (``fresh``), or None
        self.previous: Path | None = None
        try:
            if fresh:
                self.previous = logfile.keep_previous(self.path)
            self._db = logfile.connect(self.path, readonly=False)
            self._open_for_writing()
        except BaseException:
            self._file_lock.release()
            raise

    def _open_for_writing(self) -> None:
        db = self._db
        try:
            problems = logfile.damage(db)
        except sqlite3.Error as exc:
            db.close()
            raise logfile.explain(self.path, exc, "quick_check failed") from None
        if problems:
            db.close()
            problem = f"{self.path}: cycle log is damaged (quick_check: {'; '.join(problems[:3])})"
            raise LogError(f"{problem}; {logfile.recovery(self.path)}", problem=problem)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=FULL")
            db.execute("PRAGMA busy_timeout=5000")
            db.executescript(_SCHEMA)
            columns = {r[1] for r in db.execute("PRAGMA table_info(cycles)")}
            if "motion_json" not in columns:       # a version 1 log: add the column, keep the rows
                db.execute("ALTER TABLE cycles ADD COLUMN motion_json TEXT NOT NULL DEFAULT '{}'")
            if "calibration" not in columns:       # before version 4: rows ran on the nominal model
                db.execute("ALTER TABLE cycles ADD COLUMN calibration TEXT NOT NULL DEFAULT ''")
            db.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            # this file's identity, made once: a fresh log starts its row ids at 1 again
            db.execute("INSERT OR IGNORE INTO meta VALUES ('log_id', ?)", (uuid.uuid4().hex,))
        except sqlite3.Error as exc:
            db.close()
            raise logfile.explain(self.path, exc, "cannot prepare it for writing") from None

    def close(self) -> None:
        with self._lock:
            self._db.close()
            if self._file_lock is not None:
                self._file_lock.release()

    def check(self, full: bool = True) -> list[str]:
        """What ``integrity_check`` (``quick_check`` if not ``full``) finds; empty if sound."""
        with self._lock:
            return logfile.damage(self._db, full=full)

    def _tx(self):
        if self.readonly:
            raise LogError(f"{self.path}: cycle log opened read-only")
        return _Transaction(self._db, self._lock)

    # ------------------------------------------------------------------ cycles
    def add_cycle(self, rec: CycleRecord) -> int:
        """Insert one cycle in one durable transaction; returns its id."""
        row = asdict(rec)
        tx, ty = rec.target_mm if rec.target_mm else (None, None)
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO cycles (part_id, recipe, recipe_hash, started_at, finished_at, status,"
                " method, target_x_mm, target_y_mm, initial_error_mm, final_error_mm, verify_error_mm,"
                " moves, cycle_time_s, step_times_json, fault_code, fault_text, temp_c, trace_json,"
                " motion_json, calibration) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (row["part_id"], row["recipe"], row["recipe_hash"], row["started_at"], row["finished_at"],
                 row["status"], row["method"], tx, ty, row["initial_error_mm"], row["final_error_mm"],
                 row["verify_error_mm"], row["moves"], row["cycle_time_s"],
                 json.dumps(row["step_times"]), row["fault_code"], row["fault_text"], row["temp_c"],
                 json.dumps(row["trace"]), json.dumps(row["motion"]), row["calibration"]))
            cycle_id = int(cur.lastrowid)
            db.execute("UPDATE open_cycle SET stage = 'logged', cycle_id = ? WHERE stage = 'running'"
                       " AND started_at = ?", (cycle_id, rec.started_at))
            return cycle_id

    # ------------------------------------------------------------------ the cycle in flight
    def begin_cycle(self, part_id: int, recipe: str, recipe_hash: str, started_at: str) -> None:
        """Record that a cycle is starting, before its first move (one durable transaction)."""
        with self._tx() as db:
            db.execute("INSERT OR REPLACE INTO open_cycle VALUES (1, ?, ?, ?, ?, 'running', NULL)",
                       (part_id, recipe, recipe_hash, started_at))

    def settle_cycle(self, started_at: str, cycle_id: int | None, status: CycleStatus,
                     fault_code: int, fault_text: str) -> bool:
        """The PLC has been told ``status``/``fault_code`` for the cycle that started at
        ``started_at``: correct its row if it says otherwise, and close the cycle. Returns
        True if the row was corrected."""
        with self._tx() as db:
            changed = 0
            if cycle_id is not None:
                changed = db.execute(
                    "UPDATE cycles SET status = ?, fault_code = ?, fault_text = CASE WHEN fault_text = ''"
                    " THEN ? ELSE fault_text || '; ' || ? END WHERE id = ? AND (status != ? OR fault_code != ?)",
                    (status, fault_code, fault_text, fault_text, cycle_id, status, fault_code)).rowcount
            db.execute("DELETE FROM open_cycle WHERE started_at = ? AND stage != 'interrupted'", (started_at,))
        return bool(changed)

    def recover_interrupted(self) -> Interrupted | None:
        """At start: a cycle the last controller left in flight is recorded as aborted with
        fault 503 (a row is added if it had none; a logged row is corrected, since the PLC was
        never told its outcome) and kept pending until :meth:`clear_interrupted`. Returns the
        pending interruption, or None."""
        with self._tx() as db:
            r = db.execute("SELECT * FROM open_cycle WHERE slot = 1").fetchone()
            if r is None:
                return None
            cycle_id = r["cycle_id"]
            if r["stage"] == "running":
                text = (f"interrupted by a controller restart (the cycle started at {r['started_at']} "
                        "and was never finished)")
                cycle_id = int(db.execute(
                    "INSERT INTO cycles (part_id, recipe, recipe_hash, started_at, finished_at, status,"
                    " cycle_time_s, step_times_json, fault_code, fault_text) VALUES (?,?,?,?,?,'aborted',"
                    " 0.0, '{}', ?, ?)", (r["part_id"], r["recipe"], r["recipe_hash"], r["started_at"],
                                         utc_now(), Fault.INTERRUPTED, text)).lastrowid)
            elif r["stage"] == "logged":
                db.execute("UPDATE cycles SET fault_text = fault_text || CASE WHEN fault_text = '' THEN ''"
                           " ELSE '; ' END || 'controller restarted before the PLC was told: was ' || status,"
                           " status = 'aborted', fault_code = ? WHERE id = ?", (Fault.INTERRUPTED, cycle_id))
            db.execute("UPDATE open_cycle SET stage = 'interrupted', cycle_id = ?", (cycle_id,))
            return Interrupted(int(cycle_id), int(r["part_id"]), r["recipe"], r["started_at"])

    def clear_interrupted(self) -> None:
        """The PLC has reset the fault that reported the interrupted cycle."""
        with self._tx() as db:
            db.execute("DELETE FROM open_cycle WHERE stage = 'interrupted'")

    def open_cycle(self) -> dict | None:
        """The cycle in flight (or pending as interrupted), as a dict; None if none."""
        with self._lock:
            try:
                r = self._db.execute("SELECT * FROM open_cycle").fetchone()
            except sqlite3.OperationalError:           # a log from before schema version 3
                return None
        return dict(r) if r else None

    def cycles(self, limit: int | None = None, status: CycleStatus | None = None
               ) -> list[CycleRecord]:
        """Cycles in id order (the last ``limit`` if given)."""
        where = " WHERE status = ?" if status else ""
        args: tuple = (status,) if status else ()
        if limit:                                 # only the last rows are read, however long the log
            sql = f"SELECT * FROM (SELECT * FROM cycles{where} ORDER BY id DESC LIMIT ?) ORDER BY id"
            args += (int(limit),)
        else:
            sql = f"SELECT * FROM cycles{where} ORDER BY id"
        rows = self._read(sql, args)
        return [self._record(r) for r in rows]

    def cycle(self, cycle_id: int) -> CycleRecord | None:
        """The cycle with id ``cycle_id``, or None."""
        rows = self._read("SELECT * FROM cycles WHERE id = ?", (int(cycle_id),))
        return self._record(rows[0]) if rows else None

    def _read(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        """Rows of one query, under the lock. Damage met only now (pages the opening checks
        did not touch) raises :class:`LogError` saying what it means, not sqlite3's error."""
        with self._lock:
            try:
                return self._db.execute(sql, args).fetchall()
            except sqlite3.OperationalError:
                raise                                  # e.g. a table from a later schema: the caller's
            except sqlite3.DatabaseError as exc:
                raise logfile.explain(self.path, exc, "cannot read") from None

    def count(self) -> int:
        return int(self._read("SELECT COUNT(*) FROM cycles")[0][0])

    # ------------------------------------------------------------------ for the plant outbox
    @property
    def log_id(self) -> str | None:
        """This log file's identity (a random hex string made when a writer first opened
        it; ids restart at 1 in a fresh log, so a row is named by log_id and id). None for a
        log no writer of this version has opened."""
        rows = self._read("SELECT value FROM meta WHERE key = 'log_id'")
        return rows[0][0] if rows else None

    def cycles_after(self, after_id: int, limit: int, below: int | None = None) -> list[CycleRecord]:
        """Up to ``limit`` cycles with ids above ``after_id`` (and below ``below`` if given),
        in id order."""
        if below is None:
            rows = self._read("SELECT * FROM cycles WHERE id > ? ORDER BY id LIMIT ?", (int(after_id), int(limit)))
        else:
            rows = self._read("SELECT * FROM cycles WHERE id > ? AND id < ? ORDER BY id LIMIT ?",
                              (int(after_id), int(below), int(limit)))
        return [self._record(r) for r in rows]

    def settled_after(self, after_id: int, limit: int) -> list[CycleRecord]:
        """Up to ``limit`` cycles with ids above ``after_id``, in id order, stopping before a
        row the PLC has not been told of (the ``open_cycle`` row in stage ``logged``:
        :meth:`settle_cycle` may still correct it). One statement, so one snapshot: a cycle
        logged, or settled and corrected, between a read of ``open_cycle`` and a read of
        ``cycles`` cannot pass as settled, nor its row be read from before its correction."""
        rows = self._read("SELECT * FROM cycles WHERE id > ? AND id < COALESCE((SELECT cycle_id FROM open_cycle"
                          " WHERE stage = 'logged' AND cycle_id IS NOT NULL), 9223372036854775807)"
                          " ORDER BY id LIMIT ?", (int(after_id), int(limit)))
        return [self._record(r) for r in rows]

    def id_before(self, cycle_id: int) -> int:
        """The id of the row before ``cycle_id`` (0: none)."""
        return int(self._read("SELECT COALESCE(MAX(id), 0) FROM cycles WHERE id < ?", (int(cycle_id),))[0][0])

    def count_after(self, after_id: int) -> int:
        """How many cycles have ids above ``after_id``."""
        return int(self._read("SELECT COUNT(*) FROM cycles WHERE id > ?", (int(after_id),))[0][0])

    def delete_older_than(self, iso_time: str, keep_above: int | None = None) -> int:
        """Retention: delete cycles finished before ``iso_time``, but none with an id above
        ``keep_above`` (None: no such limit; the plant historian's watermark: a record the
        plant has not received stays, whatever its age); returns how many."""
        with self._tx() as db:
            if keep_above is None:
                return db.execute("DELETE FROM cycles WHERE finished_at < ?", (iso_time,)).rowcount
            return db.execute("DELETE FROM cycles WHERE finished_at < ? AND id <= ?",
                              (iso_time, int(keep_above))).rowcount

    def count_older_than(self, iso_time: str, above: int = 0) -> int:
        """How many cycles finished before ``iso_time`` have ids above ``above``."""
        return int(self._read("SELECT COUNT(*) FROM cycles WHERE finished_at < ? AND id > ?",
                              (iso_time, int(above)))[0][0])

    @staticmethod
    def _record(r: sqlite3.Row) -> CycleRecord:
        tgt = (r["target_x_mm"], r["target_y_mm"]) if r["target_x_mm"] is not None else None
        return CycleRecord(
            id=r["id"], part_id=r["part_id"], recipe=r["recipe"], recipe_hash=r["recipe_hash"],
            started_at=r["started_at"], finished_at=r["finished_at"], status=CycleStatus(r["status"]),
            method=r["method"], target_mm=tgt, initial_error_mm=r["initial_error_mm"],
            final_error_mm=r["final_error_mm"], verify_error_mm=r["verify_error_mm"], moves=r["moves"],
            cycle_time_s=r["cycle_time_s"], step_times=json.loads(r["step_times_json"]),
            fault_code=r["fault_code"], fault_text=r["fault_text"], temp_c=r["temp_c"],
            trace=json.loads(r["trace_json"]),
            motion=json.loads(r["motion_json"]) if "motion_json" in r.keys() else {},
            calibration=r["calibration"] if "calibration" in r.keys() else "")

    # ------------------------------------------------------------------ audit
    def audit(self, who: str, action: str, target: str, hash_: str, result: str) -> None:
        """Append one hash-chained audit row."""
        with self._tx() as db:
            _append_audit(db, who, action, target, hash_, result)

    def record_recipe_changes(self, changes) -> None:
        """Audit rows for recipe changes, and the text of each activated version, in ONE
        transaction: all of them are on disk, or none (then the caller must not apply them).

        :param changes: ``(who, action, target, hash, result, version)`` tuples, ``version``
            ``(name, hash, text)`` for an activation, else None.
        """
        with self._tx() as db:
            for who, action, target, hash_, result, version in changes:
                _append_audit(db, who, action, target, hash_, result)
                if version is not None:
                    name, vhash, text = version
                    db.execute("INSERT OR IGNORE INTO recipe_versions (hash, name, content, first_active_at)"
                               " VALUES (?,?,?,?)", (vhash, name, text, utc_now()))

    def audit_rows(self, last: int | None = None, hash_: str | None = None) -> list[dict]:
        """Audit rows in id order: all, only the last ``last``, or only those for ``hash_``."""
        where, args = (" WHERE hash = ?", (hash_,)) if hash_ is not None else ("", ())
        if last:
            return [dict(r) for r in self._read(f"SELECT * FROM (SELECT * FROM audit{where} ORDER BY id DESC "
                                                "LIMIT ?) ORDER BY id", args + (int(last),))]
        return [dict(r) for r in self._read(f"SELECT * FROM audit{where} ORDER BY id", args)]

    def verify_audit(self) -> int | None:
        """Id of the first audit row whose chain is broken, or None if the chain holds."""
        broken = self.audit_break()
        return None if broken is None else broken[0]

    def audit_break(self) -> tuple[int, str] | None:
        """(id, what is wrong) of the first audit row that breaks the chain, or None.

        A row is broken when its ``prev_hash`` is not the previous row's ``row_hash`` (a row
        was deleted or inserted before it), when its ``row_hash`` does not match its own
        content (it was edited), when ids skip, or when SQLite's id sequence says rows
        after the last one were written (the end of the trail was cut off). Someone who
        rewrites the whole chain and the sequence is not caught here: that needs a copy of
        the last row hash kept elsewhere (the plant historian)."""
        prev, last_id = "0" * 64, 0
        for r in self.audit_rows():
            rid = int(r["id"])
            want = _chain(prev, r["at"], r["who"], r["action"], r["target"], r["hash"], r["result"])
            if r["prev_hash"] != prev:
                return rid, ("its prev_hash is not the row_hash of the row before it: a row "
                             "before it was removed, inserted or edited")
            if r["row_hash"] != want:
                return rid, "its content does not match its row_hash: the row was edited"
            if rid != last_id + 1:
                return rid, f"ids jump from {last_id} to {rid}: rows were removed"
            prev, last_id = r["row_hash"], rid
        seq = next(iter(self._read("SELECT seq FROM sqlite_sequence WHERE name = 'audit'")), None)
        if seq is not None and int(seq[0]) > last_id:
            return last_id + 1, (f"rows {last_id + 1}..{int(seq[0])} were written and are gone: "
                                 "the end of the trail was removed")
        return None

    # ------------------------------------------------------------------ recipe versions
    def remember_recipe(self, name: str, hash_: str, content: str) -> None:
        with self._tx() as db:
            db.execute("INSERT OR IGNORE INTO recipe_versions VALUES (?,?,?,?)",
                       (hash_, name, content, utc_now()))

    def last_recipe_version(self, name: str) -> tuple[str, str] | None:
        """(hash, content) of the most recently activated version of recipe ``name``."""
        with self._lock:
            r = self._db.execute("SELECT hash, content FROM recipe_versions WHERE name = ?"
                                 " ORDER BY first_active_at DESC, rowid DESC LIMIT 1", (name,)).fetchone()
        return (r[0], r[1]) if r else None

    def recipe_text(self, hash_: str) -> str | None:
        """Text of the recipe version with content hash ``hash_`` (what a cycle's
        ``recipe_hash`` names), or None if the log never activated it."""
        try:
            rows = self._read("SELECT content FROM recipe_versions WHERE hash = ?", (hash_,))
        except sqlite3.OperationalError:          # a log without the table
            return None
        return rows[0][0] if rows else None


def _append_audit(db: sqlite3.Connection, who: str, action: str, target: str, hash_: str, result: str) -> None:
    last = db.execute("SELECT row_hash FROM audit ORDER BY id DESC LIMIT 1").fetchone()
    prev = last[0] if last else "0" * 64
    at = utc_now()
    row_hash = _chain(prev, at, who, action, target, hash_, result)
    db.execute("INSERT INTO audit (at, who, action, target, hash, result, prev_hash, row_hash)"
               " VALUES (?,?,?,?,?,?,?,?)", (at, who, action, target, hash_, result, prev, row_hash))


def _chain(prev: str, *fields: str) -> str:
    h = hashlib.sha256(prev.encode())
    for f in fields:
        h.update(b"\x1f" + str(f).encode())
    return h.hexdigest()


class _Transaction:
    """``with`` block = one IMMEDIATE transaction under the connection lock."""

    def __init__(self, db: sqlite3.Connection, lock: threading.Lock):
        self.db, self.lock = db, lock

    def __enter__(self) -> sqlite3.Connection:
        self.lock.acquire()
        try:
            self.db.execute("BEGIN IMMEDIATE")
        except BaseException:            # no transaction was opened: do not keep the lock
            self.lock.release()
            raise
        return self.db

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.db.execute("ROLLBACK" if exc_type else "COMMIT")
        finally:
            self.lock.release()
