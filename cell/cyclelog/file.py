"""Opening the cycle log's SQLite file safely: one writer, checked before use, clear errors.

* **One writer.** The controller holds an exclusive ``flock`` on ``<log>.lock`` for as long
  as its log is open; a second controller on the same file is refused at once, naming the
  process that holds it. Readers (``report``, ``export``, ``diagnose``, ``log check``) take
  no lock and open the file read-only, so they work beside a running controller.
* **Checked before use.** The writer runs ``PRAGMA quick_check`` before it writes anything
  (a full ``integrity_check`` reads every row and is left to ``cellctl log check``).
* **Clear errors.** Every way the file can fail to open (damaged, not a database,
  read-only, disk full, in use) raises :class:`~cell.errors.LogError` with the path, what is
  wrong and how to recover; ``cellctl`` turns it into a message and exit status 2.
"""
from __future__ import annotations

import fcntl
import os
import sqlite3
from datetime import datetime, timezone
from pathlib import Path

from cell.errors import LogError

__all__ = ["LogLock", "connect", "explain", "damage", "recovery", "keep_previous"]

SIDECARS = ("-wal", "-shm")      #: SQLite's files beside a WAL-mode log: they move with it


def recovery(path: Path) -> str:
    """How to get a cell running again when its log cannot be used."""
    return (f"move it aside with its -wal and -shm files (e.g. mv {path} {path}.damaged) and start "
            f"again with a fresh log; 'cellctl log check --db {path}.damaged' names the damage")


def keep_previous(path: Path, now: datetime | None = None) -> Path | None:
    """Move the log at ``path`` (with its -wal and -shm files) aside as
    ``<stem>.prev-<UTC time><suffix>`` so a fresh log can start there; returns the new name,
    or None if there was no log. Never overwrites: a name already taken gets ``-2``, ``-3``…
    Call it only while holding the log's :class:`LogLock`: a log another controller writes
    must never move.

    :raises LogError: the file cannot be moved (permissions, another file system).
    """
    path = Path(path)
    if not path.exists():
        return None
    stamp = (now or datetime.now(timezone.utc)).strftime("%Y%m%dT%H%M%SZ")
    for n in range(1, 10_000):
        kept = path.with_name(f"{path.stem}.prev-{stamp}{'' if n == 1 else f'-{n}'}{path.suffix}")
        if not any(Path(str(kept) + s).exists() for s in ("", *SIDECARS)):
            break
    else:
        raise LogError(f"{path}: cannot keep the previous cycle log: 9999 logs of {stamp} already kept")
    names = [s for s in ("", *SIDECARS) if Path(str(path) + s).exists()]
    linked: list[str] = []
    try:
        for s in names:                    # link all first (link never overwrites) ...
            os.link(str(path) + s, str(kept) + s)
            linked.append(s)
    except OSError as exc:
        for s in linked:                   # ... so a failure leaves the log where it was
            os.unlink(str(kept) + s)
        raise LogError(f"{path}: cannot keep the previous cycle log as {kept.name}: {exc.strerror}; "
                       f"give the controller write access to {path.parent}, or pass --db") from None
    for s in sorted(names, key=lambda s: s == ""):   # then the old names go, the log itself last
        os.unlink(str(path) + s)
    return kept


def explain(path: Path, exc: sqlite3.Error, doing: str) -> LogError:
    """A :class:`LogError` for an SQLite failure while ``doing``, saying what it means."""
    text = str(exc)
    low = text.lower()
    if "not a database" in low:
        why = "it is not an SQLite database (its header is damaged, or it is another kind of file)"
    elif "malformed" in low or "corrupt" in low:
        why = f"the database is damaged ({text})"
    elif "readonly" in low or "read-only" in low or "unable to open" in low or "permission" in low:
        why = (f"it cannot be written ({text}): the file or its folder is read-only or belongs to "
               "another user")
        return LogError(f"{path}: cycle log: {doing}: {why}; give the controller write access to "
                        f"{path.parent} and the log file")
    elif "disk is full" in low or "disk i/o" in low:
        why = f"the disk is full or failing ({text})"
        return LogError(f"{path}: cycle log: {doing}: {why}; free space on the disk that holds "
                        f"{path.parent}")
    else:
        why = text
    return LogError(f"{path}: cycle log: {doing}: {why}; {recovery(path)}",
                    problem=f"{path}: cycle log: {doing}: {why}")


def damage(db: sqlite3.Connection, full: bool = False, limit: int = 20) -> list[str]:
    """Problems ``quick_check`` (or ``integrity_check`` if ``full``) finds; empty if sound."""
    pragma = "integrity_check" if full else "quick_check"
    rows = [r[0] for r in db.execute(f"PRAGMA {pragma}({int(limit)})")]
    if rows == ["ok"]:
        return []
    lines = [line.strip() for r in rows for line in str(r).splitlines()]
    return [line for line in lines if line and not line.startswith("*** in database")]


def connect(path: Path, readonly: bool) -> sqlite3.Connection:
    """An SQLite connection to ``path``; read-only connections never create or change it.

    :raises LogError: the file is missing (read-only), not a database, or cannot be opened.
    """
    try:
        if readonly:
            if not path.is_file():
                raise LogError(f"{path}: no cycle log here (run the cell first, or pass --db)")
            db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, check_same_thread=False,
                                 isolation_level=None)
        else:
            db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        db.execute("SELECT count(*) FROM sqlite_master").fetchone()     # reads the header
    except sqlite3.Error as exc:
        raise explain(path, exc, "cannot open") from None
    db.row_factory = sqlite3.Row
    return db


class LogLock:
    """An exclusive lock on ``<log>.lock``, held while the writer has the log open.

    The lock file holds the owner's pid and start time (for the message a second
    controller gets). ``flock`` locks go away with the process, so a killed controller
    never leaves a stale lock.
    """

    def __init__(self, log_path: Path):
        self.path = Path(str(log_path) + ".lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        """:raises LogError: another process holds the lock, or the lock file cannot be made."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise LogError(f"{self.path}: cannot create the cycle log's lock file: {exc.strerror}; "
                           f"give the controller write access to {self.path.parent}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "unknown process"
            os.close(fd)
            log_path = str(self.path)[:-len(".lock")]
            raise LogError(f"{log_path}: cycle log is in use by another controller ({holder}); stop "
                           "that one first, or give this one its own log (log.path)") from None
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()}, since {datetime.now(timezone.utc).isoformat(timespec='seconds')}\n"
                      .encode(), 0)
        except OSError as exc:
            os.close(fd)
            raise LogError(f"{self.path}: cannot write the cycle log's lock file: {exc.strerror} (is the "
                           f"disk full?); free space on the disk that holds {self.path.parent}") from None
        self._fd = fd

    def holder(self) -> str | None:
        """Who holds the lock (pid and start), or None if nobody does; takes nothing."""
        if not self.path.exists():
            return None
        fd = os.open(self.path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "unknown process"
        finally:
            os.close(fd)
        return None

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)          # closing drops the flock; the file stays (no unlink race)
            self._fd = None
