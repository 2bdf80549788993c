"""``cellctl log check``: what is wrong with a cycle log, for the engineer who must recover it.

Opens the log read-only (it works beside a running controller and never changes the file)
and reports: size and counts, SQLite's full ``integrity_check``, the audit chain, the cycle
in flight or an interrupted one still to be reported, and who holds the writer's lock.
Exit status 0 when the log is sound, 1 when damage was found, 2 when there is no log.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from cell import paths
from cell.errors import ConfigError, LogError

DEFAULT_DB = paths.DEFAULT_DB   #: in the project folder, whatever the shell's (cell.paths)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("log", help="the cycle log: check it for damage")
    lsub = p.add_subparsers(dest="log_command", required=True, metavar="ACTION")
    c = lsub.add_parser("check", help="integrity check, audit chain, cycle in flight, lock holder")
    c.add_argument("--db", default=str(paths.project(DEFAULT_DB)), help=f"cycle log (default: the project's {DEFAULT_DB})")
    c.set_defaults(func=run_check)


def run_check(args: argparse.Namespace) -> int:
    import sqlite3
    from cell.cyclelog import CycleLog
    from cell.cyclelog.file import LogLock
    path = Path(args.db)
    if not path.is_file():
        raise ConfigError(f"{path}: no cycle log here (pass --db)")
    holder = LogLock(path).holder()
    print(f"{path}: {path.stat().st_size / 1e6:.2f} MB; writer lock: "
          f"{'held by ' + holder if holder else 'free'}")
    try:
        log = CycleLog(path, readonly=True)
    except LogError as exc:
        print(f"cannot be read: {exc.problem}")
        return _verdict(True, path)
    damaged = False
    try:
        problems = log.check(full=True)
        print("integrity_check: " + ("ok" if not problems else f"{len(problems)} problem(s)"))
        for line in problems:
            print(f"  {line}")
        damaged |= bool(problems)
        try:
            print(f"cycles: {log.count()}; audit rows: {len(log.audit_rows())}")
            broken = log.audit_break()
            print("audit chain: " + ("ok" if broken is None
                                     else f"broken at audit row {broken[0]}: {broken[1]}"))
            damaged |= broken is not None
            flight = log.open_cycle()
        except sqlite3.Error as exc:
            print(f"reading failed: {exc}")
            return _verdict(True, path)
        if flight is None:
            print("cycle in flight: none")
        elif flight["stage"] == "interrupted":
            print(f"interrupted cycle: part {flight['part_id']} (row {flight['cycle_id']}, started "
                  f"{flight['started_at']}); reported to the PLC as fault 503 until it resets")
        else:
            print(f"cycle in flight: part {flight['part_id']}, {flight['stage']} (started {flight['started_at']})"
                  + ("" if holder else "; the next controller start records it as interrupted"))
    except sqlite3.Error as exc:
        print(f"integrity_check cannot finish: {exc}")
        return _verdict(True, path)
    finally:
        log.close()
    return _verdict(damaged, path)


def _verdict(damaged: bool, path: Path) -> int:
    """Print the verdict; for a damaged log, the steps that get the cell running again."""
    if not damaged:
        print("verdict: sound")
        return 0
    side = f"{path}.damaged"
    print(f"verdict: DAMAGED. To run the cell again: stop the controller; move the log aside with its "
          f"-wal and -shm files (mv {path} {side}; mv {path}-wal {side}-wal; mv {path}-shm {side}-shm, "
          f"for those that exist); start the controller, which begins a fresh log. Keep {side}: "
          f"'sqlite3 {side} .recover' salvages the rows it still holds")
    return 1
