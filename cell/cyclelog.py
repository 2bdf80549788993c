"""Per-cycle accuracy log and audit trail in one SQLite file.

Durability: WAL journal with ``synchronous=FULL``, so a cycle the PLC was told is done
survives a power cut. Each cycle is ONE row written in ONE transaction when the cycle ends
(done, fault or aborted): a crash at any moment leaves either the whole row or nothing,
never a half-written cycle. The controller writes the row *before* it raises Done to the PLC.

The ``audit`` table is hash-chained (each row stores the SHA-256 of the previous row's hash
and its own content), the first brick of the tamper-evident audit trail to come;
:meth:`CycleLog.verify_audit` checks the chain.
"""
from __future__ import annotations

import hashlib
import json
import sqlite3
import threading
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

SCHEMA_VERSION = 2     #: 2 added cycles.motion_json (how the cycle's moves were streamed)

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
    motion_json TEXT NOT NULL DEFAULT '{}'
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
CREATE TABLE IF NOT EXISTS recipe_versions (
    hash TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    content TEXT NOT NULL,
    first_active_at TEXT NOT NULL
);
"""


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
    status: str
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
    id: int | None = None


class CycleLog:
    """The SQLite log. Thread-safe: one connection guarded by a lock."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA busy_timeout=5000")
        self._db.executescript(_SCHEMA)
        columns = {r[1] for r in self._db.execute("PRAGMA table_info(cycles)")}
        if "motion_json" not in columns:           # a version 1 log: add the column, keep the rows
            self._db.execute("ALTER TABLE cycles ADD COLUMN motion_json TEXT NOT NULL DEFAULT '{}'")
        self._db.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _tx(self):
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
                " motion_json) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (row["part_id"], row["recipe"], row["recipe_hash"], row["started_at"], row["finished_at"],
                 row["status"], row["method"], tx, ty, row["initial_error_mm"], row["final_error_mm"],
                 row["verify_error_mm"], row["moves"], row["cycle_time_s"],
                 json.dumps(row["step_times"]), row["fault_code"], row["fault_text"], row["temp_c"],
                 json.dumps(row["trace"]), json.dumps(row["motion"])))
            return int(cur.lastrowid)

    def cycles(self, limit: int | None = None, status: str | None = None) -> list[CycleRecord]:
        """Cycles in id order (the last ``limit`` if given)."""
        sql = "SELECT * FROM cycles" + (" WHERE status = ?" if status else "") + " ORDER BY id"
        args: tuple = (status,) if status else ()
        with self._lock:
            rows = self._db.execute(sql, args).fetchall()
        recs = [self._record(r) for r in rows]
        return recs[-limit:] if limit else recs

    def count(self) -> int:
        with self._lock:
            return int(self._db.execute("SELECT COUNT(*) FROM cycles").fetchone()[0])

    def delete_older_than(self, iso_time: str) -> int:
        """Retention: delete cycles finished before ``iso_time``; returns how many."""
        with self._tx() as db:
            return db.execute("DELETE FROM cycles WHERE finished_at < ?", (iso_time,)).rowcount

    @staticmethod
    def _record(r: sqlite3.Row) -> CycleRecord:
        tgt = (r["target_x_mm"], r["target_y_mm"]) if r["target_x_mm"] is not None else None
        return CycleRecord(
            id=r["id"], part_id=r["part_id"], recipe=r["recipe"], recipe_hash=r["recipe_hash"],
            started_at=r["started_at"], finished_at=r["finished_at"], status=r["status"],
            method=r["method"], target_mm=tgt, initial_error_mm=r["initial_error_mm"],
            final_error_mm=r["final_error_mm"], verify_error_mm=r["verify_error_mm"], moves=r["moves"],
            cycle_time_s=r["cycle_time_s"], step_times=json.loads(r["step_times_json"]),
            fault_code=r["fault_code"], fault_text=r["fault_text"], temp_c=r["temp_c"],
            trace=json.loads(r["trace_json"]), motion=json.loads(r["motion_json"]))

    # ------------------------------------------------------------------ audit
    def audit(self, who: str, action: str, target: str, hash_: str, result: str) -> None:
        """Append one hash-chained audit row."""
        with self._tx() as db:
            last = db.execute("SELECT row_hash FROM audit ORDER BY id DESC LIMIT 1").fetchone()
            prev = last[0] if last else "0" * 64
            at = utc_now()
            row_hash = _chain(prev, at, who, action, target, hash_, result)
            db.execute("INSERT INTO audit (at, who, action, target, hash, result, prev_hash, row_hash)"
                       " VALUES (?,?,?,?,?,?,?,?)", (at, who, action, target, hash_, result, prev, row_hash))

    def audit_rows(self) -> list[dict]:
        with self._lock:
            return [dict(r) for r in self._db.execute("SELECT * FROM audit ORDER BY id")]

    def verify_audit(self) -> int | None:
        """Id of the first audit row whose chain is broken, or None if the chain holds."""
        prev = "0" * 64
        for r in self.audit_rows():
            want = _chain(prev, r["at"], r["who"], r["action"], r["target"], r["hash"], r["result"])
            if r["prev_hash"] != prev or r["row_hash"] != want:
                return int(r["id"])
            prev = r["row_hash"]
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
