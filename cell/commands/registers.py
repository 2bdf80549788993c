"""``cellctl registers``: print the PLC register map (Markdown for docs/plc.md, CSV for PLC tools).

Generated from :data:`drivers.plc.register_map.PLC_MAP`, the one table the Modbus server
serves, so the printed reference cannot drift from what the PLC sees.
"""
from __future__ import annotations

import argparse
import sys


def register(subparsers) -> None:
    """Add ``registers [--format md|csv]`` to the ``cellctl`` sub-parsers."""
    p = subparsers.add_parser(
        "registers", help="print the PLC register map",
        description="Print the PLC register map: protocol (0-based) address, Modicon 4x "
                    "reference, name, type, access, unit, scale, range, meaning.")
    p.add_argument("--format", choices=("md", "csv"), default="md",
                   help="md: Markdown reference (default); csv: one row per register and bit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the table in ``args.format`` to stdout; return 0."""
    from drivers.plc.register_map import PLC_MAP

    text = PLC_MAP.to_markdown() if args.format == "md" else PLC_MAP.to_csv()
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0
