"""``cellctl fleet report``: accuracy, parts and faults of every cell, per recipe and shift,
from the plant historian's PostgreSQL.

It reads the ``cycles`` table ``cellctl historian`` writes (``--dsn``, or
``CELL_HISTORIAN_DSN``) and prints one row per cell, recipe and shift: parts done, faults,
aborted cycles, and the 50th and 95th percentiles of the final and of the verify error in
mm. Shifts are three 8-hour shifts in UTC: early 06:00-14:00, late 14:00-22:00, night
22:00-06:00 (counted to the date it starts on). ``--json`` prints the same as JSON; ``--png``
writes a picture of the final error per cell and shift. A database it cannot reach, or
one with no historian tables or no records, is an error (exit status 2). Definitions:
:mod:`cell.plant.fleet`.
"""
from __future__ import annotations

import argparse
import os
from datetime import datetime, timedelta, timezone

from cell.commands.historian import DSN_ENV
from cell.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    from cell.commands import summary
    p = sub.add_parser("fleet", help="every cell's accuracy per recipe and shift, from the plant historian",
                       description=summary(__doc__))
    fs = p.add_subparsers(dest="fleet_cmd", metavar="ACTION", required=True)
    r = fs.add_parser("report", help="per cell, recipe and shift: parts, faults, p50/p95 of final and verify error",
                      description=summary(__doc__))
    r.add_argument("--dsn", help=f"the historian's PostgreSQL connection string (default: ${DSN_ENV})")
    r.add_argument("--days", type=float, help="only cycles finished in the last DAYS days (default: all)")
    r.add_argument("--cells", metavar="PATTERN",
                   help="only cells whose id (site/line/cell) matches this SQL LIKE pattern, e.g. 'site1/line2/%%'")
    r.add_argument("--json", action="store_true", help="print JSON instead of a Markdown table")
    r.add_argument("--png", default="", metavar="FILE",
                   help="also write a picture of the final error per cell and shift (a file, or a folder "
                        "for fleet.png)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cell.commands import plot_file
    from cell.plant import fleet
    dsn = args.dsn or os.environ.get(DSN_ENV)
    if not dsn:
        raise ConfigError(f"fleet report: give --dsn or set {DSN_ENV}")
    if args.days is not None and not args.days > 0:
        raise ConfigError(f"--days {args.days} must be > 0")
    png = plot_file(args.png, "fleet.png")
    since = datetime.now(timezone.utc) - timedelta(days=args.days) if args.days else None
    groups = fleet.summarise(fleet.read_cycles(dsn, since, args.cells))
    if png is not None:
        try:
            fleet.figure(groups).savefig(png)
        except OSError as exc:
            raise ConfigError(f"--png {png}: cannot write the picture: {exc.strerror or exc}") from None
    if args.json:
        print(fleet.to_json(groups))
        return 0
    cells = sorted({g.cell for g in groups})
    print(f"{len(cells)} cell(s), {sum(g.parts for g in groups)} parts; shifts in UTC: "
          + ", ".join(f"{n} {h:02d}:00-{(h + fleet.SHIFT_H) % 24:02d}:00" for n, h in fleet.SHIFTS))
    print()
    print(fleet.markdown(groups))
    if png is not None:
        print(f"\npicture written to {png}")
    return 0
