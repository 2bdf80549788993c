"""What ``cellctl recipe validate`` checks, for the command and the maintenance HMI alike.

:func:`check_text` runs the recipe schema (:func:`~cell.recipes.parse_recipe`, pydantic)
and the cell's checks (:func:`cell_checks`: the robot's reach and, with a cell config, the
joint stations); :func:`number_clashes` finds a recipe number another file of the folder
already uses (the controller would take only one of them). Every error is a line
``source:line: field: message``; :func:`field_errors` splits such lines for a user interface.
"""
from __future__ import annotations

import re
from pathlib import Path

from cell.errors import ConfigError


def check_text(text: str, source: str, cell_check=None):
    """(hash, error or None, recipe or None) of recipe ``text`` that would be file ``source``."""
    from cell.recipes import content_hash, parse_recipe
    try:
        recipe = parse_recipe(text, source)
        if cell_check is not None:
            cell_check(recipe, text, source)
    except ConfigError as exc:
        return content_hash(text), str(exc), None
    return content_hash(text), None, recipe


def check_file(path: Path, cell_check=None):
    """(hash, error or None, recipe or None, text) for one recipe file."""
    from cell.yamlio import read_text
    try:
        text = read_text(path, "recipe")
    except ConfigError as exc:
        return "", str(exc), None, ""
    return (*check_text(text, str(path), cell_check), text)


def cell_checks(config: str | None):
    """(check, complete): the checks the controller makes against its cell: the robot's reach
    (the config's robot, else the built-in one) and, with a config, the joint stations.
    ``complete`` is False when the stations' latency is measured at start-up, so the segment
    time is checked against the wire time only (the controller checks again)."""
    from cell.config import CellConfig
    cfg = CellConfig.load(config) if config else CellConfig().with_paths()
    return checks_for(cfg, with_stations=bool(config))


def checks_for(cfg, with_stations: bool = True):
    """:func:`cell_checks` for a loaded :class:`~cell.config.CellConfig`."""
    from cell.kinematics import Scara
    from cell.recipes import all_checks, motion_check_from_config, reach_check
    r = cfg.robot
    robot = Scara(r.geometry) if r.geometry is not None else Scara.preset(r.preset)
    motion, complete = motion_check_from_config(cfg.stations) if with_stations else (None, True)
    return all_checks(motion, reach_check(robot, r.elbow)), complete


def number_clashes(checked: dict[Path, tuple], rdir: Path) -> dict[Path, str]:
    """A recipe number used by two recipes (the controller takes only one of them): the
    error for each file of the pair that was checked, naming the other file. ``checked``:
    path -> (hash, error, recipe or None, text); files of ``rdir`` not in it are read."""
    from cell.recipes import line_of, parse_recipe
    from cell.yamlio import read_text
    numbers: dict[Path, tuple[int, str]] = {}
    for f, (_, err, rec, _) in checked.items():
        if rec is not None:
            numbers[f.resolve()] = (rec.number, rec.name)
    for f in sorted(rdir.glob("*.yaml")) if rdir.is_dir() else []:
        if f.resolve() not in numbers and not f.name.startswith("."):
            try:
                rec = parse_recipe(read_text(f, "recipe"), str(f))
            except ConfigError:
                continue
            numbers[f.resolve()] = (rec.number, rec.name)
    out = {}
    for f, (_, err, rec, text) in checked.items():
        if rec is None:
            continue
        other = [g for g, (n, name) in numbers.items() if n == rec.number and g != f.resolve()]
        if other:
            out[f] = (f"{f}:{line_of(text, 'number')}: number: recipe number {rec.number} is also "
                      f"used by {other[0]}; the controller would take only one of them")
    return out


_LINE = re.compile(r"^(?P<line>\d+|None)?:? ?(?P<field>[^:\s][^:]*?): (?P<message>.*)$")


def field_errors(error: str, source: str) -> list[dict]:
    """``source:line: field: message`` lines as ``{"line", "field", "message"}`` dicts
    (``line`` None when unknown; a line that does not follow the pattern is kept whole as
    the message, field ``(file)``)."""
    out = []
    for raw in error.splitlines():
        rest = raw[len(source) + 1:] if raw.startswith(source + ":") else None
        m = _LINE.match(rest) if rest is not None else None
        if m is None:
            out.append({"line": None, "field": "(file)", "message": raw})
            continue
        line = m["line"]
        out.append({"line": int(line) if line and line != "None" else None,
                    "field": m["field"], "message": m["message"]})
    return out
