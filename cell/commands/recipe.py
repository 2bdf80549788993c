"""``cellctl recipe list|show|validate|diff|schema``: the maintenance technician's recipe tools.

``validate`` checks files without activating anything (the running controller activates a
valid edit between cycles by itself); with ``--config`` also against the cell's joint
stations (SYNC support, the segment time against the stations' delays). ``diff NAME`` compares the file on disk with the
version the controller last activated (kept in the cycle log database); ``diff A B``
compares two files. The checks live in :mod:`cell.recipes.validation`, which the maintenance
HMI runs too.
"""
from __future__ import annotations

import argparse
import difflib
import json
from pathlib import Path

from cell import paths
from cell.errors import ConfigError

DEFAULT_DIR = paths.DEFAULT_RECIPES
DEFAULT_DB = paths.DEFAULT_DB   #: in the project folder, whatever the shell's (cell.paths)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("recipe", help="list, show, validate and diff recipes")
    p.add_argument("--dir", default=str(paths.project(DEFAULT_DIR)), help=f"recipe directory (default: the project's {DEFAULT_DIR}/)")
    rs = p.add_subparsers(dest="recipe_cmd", required=True, metavar="ACTION")
    rs.add_parser("list", help="every recipe file with its number, hash and validity")
    s = rs.add_parser("show", help="print one recipe with its hash")
    s.add_argument("name")
    v = rs.add_parser("validate", help="validate recipe files (exit 2 if any is invalid)")
    v.add_argument("files", nargs="*", help="files to check (default: every file in --dir)")
    v.add_argument("--config", help="cell config whose joint stations the recipes must suit "
                                    "(e.g. deploy/cell.yaml)")
    d = rs.add_parser("diff", help="diff a recipe against its last activated version, or two files")
    d.add_argument("a", help="recipe name, or a file")
    d.add_argument("b", nargs="?", help="second file")
    d.add_argument("--db", default=str(paths.project(DEFAULT_DB)), help=f"cycle log with activated versions (default: the project's {DEFAULT_DB})")
    sc = rs.add_parser("schema", help="print (or write) the recipe JSON schema for editors")
    sc.add_argument("--out", help="write to this file instead of printing")
    p.set_defaults(func=run)


def _check(path: Path, cell_check=None):
    from cell.recipes.validation import check_file
    return check_file(path, cell_check)


def _cell_checks(config: str | None):
    from cell.recipes.validation import cell_checks
    check, complete = cell_checks(config)
    if config and not complete:
        print(f"{config}: the stations' latency is measured at start-up; the segment time is "
              "checked against the wire time only (the controller checks again when it starts)")
    return check


def _number_clashes(checked: dict[Path, tuple], rdir: Path) -> dict[Path, str]:
    from cell.recipes.validation import number_clashes
    return number_clashes(checked, rdir)


def run(args: argparse.Namespace) -> int:
    from cell.recipes import recipe_schema
    rdir = Path(args.dir)
    if args.recipe_cmd == "schema":
        text = json.dumps(recipe_schema(), indent=2) + "\n"
        if args.out:
            Path(args.out).write_text(text, encoding="utf-8")
        else:
            print(text, end="")
        return 0
    if args.recipe_cmd in ("list", "validate"):
        files = ([Path(f) for f in args.files] if args.recipe_cmd == "validate" and args.files
                 else sorted(rdir.glob("*.yaml")))
        if not files:
            raise ConfigError(f"{rdir}: no recipe files (*.yaml)")
        cell_check = _cell_checks(args.config) if args.recipe_cmd == "validate" else None
        checked = {f: _check(f, cell_check) for f in files}
        clashes = _number_clashes(checked, rdir)
        bad = 0
        for f, (h, err, rec, _) in checked.items():
            err = err or clashes.get(f)
            bad += err is not None
            state = "INVALID" if err is not None else ("EXAMPLE" if not rec.production else "ok")
            if args.recipe_cmd == "list":
                note = err if err is not None else rec.description + (
                    " [example, not for production: activated only with recipes.allow_examples]"
                    if not rec.production else "")
                print(f"{f.stem:<20} {rec.number if rec else '-':>4}  {h[:12]:<12}  {state:<7}  {note}")
            else:
                print(err if err is not None else f"{f}: ok ({h[:12]})" + (
                    "; an example, not for production: the controller activates it only with "
                    "recipes.allow_examples" if not rec.production else ""))
        return 2 if (bad and args.recipe_cmd == "validate") else 0
    if args.recipe_cmd == "show":
        path = rdir / f"{args.name}.yaml"
        if not path.is_file():
            raise ConfigError(f"{path}: no such recipe")
        h, err, rec, _ = _check(path)
        state = "INVALID: " + err if err is not None else (
            "valid; an example, not for production" if not rec.production else "valid")
        print(f"# {path}  sha256 {h}  {state}")
        print(path.read_text(encoding="utf-8"), end="")
        return 0
    # diff
    if args.b:
        a_path, b_path = Path(args.a), Path(args.b)
        a_text, b_text = _read(a_path), _read(b_path)
        a_name, b_name = str(a_path), str(b_path)
    else:
        from cell.cyclelog import CycleLog
        path = rdir / f"{args.a}.yaml"
        b_text, b_name = _read(path), str(path)
        if not Path(args.db).is_file():
            raise ConfigError(f"{args.db}: no cycle log, so no activated version of {args.a!r} to compare")
        reader = CycleLog(args.db, readonly=True)
        try:
            last = reader.last_recipe_version(args.a)
        finally:
            reader.close()
        if last is None:
            raise ConfigError(f"{args.db}: recipe {args.a!r} was never activated")
        a_text, a_name = last[1], f"{args.a} (active, {last[0][:12]})"
    diff = list(difflib.unified_diff(a_text.splitlines(True), b_text.splitlines(True), a_name, b_name))
    print("".join(diff) if diff else "no differences", end="" if diff else "\n")
    return 1 if diff else 0


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
