"""``cellctl audit``: the tamper-evident trail in the cycle log (recipe activations and
refusals, resets, calibration writes, refused PLC writes), for the engineer or auditor.

    cellctl audit verify [--db var/cell.sqlite]          exit 0 the chain holds, 1 broken
    cellctl audit list [--db var/cell.sqlite] [--last N] [--json]

``verify`` re-computes every row's SHA-256 chain (:meth:`cell.cyclelog.CycleLog.audit_break`)
and names the first broken row and what is wrong with it. Both open the log read-only, so
they work beside a running controller and never change the file. No log: exit 2.
"""
from __future__ import annotations

import argparse
import json

from cell import paths
from cell.commands import open_log_readonly
from cell.errors import ConfigError

DEFAULT_DB = paths.DEFAULT_DB   #: in the project folder, whatever the shell's (cell.paths)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("audit", help="the tamper-evident audit trail: verify its chain, list it")
    asub = p.add_subparsers(dest="audit_command", required=True, metavar="ACTION")
    v = asub.add_parser("verify", help="check the hash chain; name the first broken row")
    v.add_argument("--db", default=str(paths.project(DEFAULT_DB)), help=f"cycle log (default: the project's {DEFAULT_DB})")
    v.set_defaults(func=run_verify)
    ls = asub.add_parser("list", help="the audit rows, oldest first")
    ls.add_argument("--db", default=str(paths.project(DEFAULT_DB)), help=f"cycle log (default: the project's {DEFAULT_DB})")
    ls.add_argument("--last", type=int, metavar="N", help="only the last N rows")
    ls.add_argument("--json", action="store_true", help="print the rows as JSON")
    ls.set_defaults(func=run_list)


def run_verify(args: argparse.Namespace) -> int:
    log = open_log_readonly(args.db)
    try:
        rows = log.audit_rows()
        broken = log.audit_break()
    finally:
        log.close()
    if broken is None:
        last = rows[-1]["row_hash"][:16] if rows else "-"
        print(f"{args.db}: audit chain holds: {len(rows)} rows, last row hash {last}…")
        return 0
    rid, why = broken
    row = next((r for r in rows if int(r["id"]) == rid), None)
    where = (f"row {rid} ({row['at']}, {row['who']} {row['action']} {row['target']})"
             if row else f"row {rid}")
    print(f"{args.db}: audit chain BROKEN at {where}: {why}")
    return 1


def run_list(args: argparse.Namespace) -> int:
    if args.last is not None and args.last < 1:
        raise ConfigError(f"--last {args.last} must be ≥ 1")
    log = open_log_readonly(args.db)
    try:
        rows = log.audit_rows()
    finally:
        log.close()
    if args.last is not None:
        rows = rows[-args.last:]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("| id | at | who | action | target | result |")
    print("|---:|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['id']} | {r['at']} | {r['who']} | {r['action']} | {r['target']} | {r['result']} |")
    return 0
