"""The truth's own writer of campaign files in the exchange format (``cell/measurements.md``):
``model.yaml`` and the CSV tables, written from plain Python values with the standard
library. It shares no code with the project's writer (:mod:`cell.measurements`), so the
validation, which reads these files with the project's reader, also tests that reader
against the document.

Numbers are written with ``repr`` (shortest round-trip form), integers and ±1 directions
as integers, text cells as they are. The YAML is the small subset the format's examples
use: ``key: value`` lines, flow lists ``[a, b]`` and flow maps ``{k: v, ...}``.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence


def _scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"{v!r}: the format holds finite numbers only")
        return repr(v)
    if isinstance(v, str):
        plain = v and all(c.isalnum() or c in "_-./" for c in v) and not v[0].isdigit()
        return v if plain else '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise TypeError(f"cannot write {v!r} ({type(v).__name__}) as YAML")


def _flow(v) -> str:
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k}: {_flow(x)}" for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_flow(x) for x in v) + "]"
    return _scalar(v)


def yaml_text(model: Mapping) -> str:
    """``model`` as YAML: one ``key: value`` line per top-level key; a list of maps (a
    chain's ``joints``) as one ``- {…}`` line per entry, anything else in flow style."""
    out = []
    for k, v in model.items():
        if isinstance(v, (list, tuple)) and v and all(isinstance(x, Mapping) for x in v):
            out.append(f"{k}:")
            out += [f"  - {_flow(x)}" for x in v]
        else:
            out.append(f"{k}: {_flow(v)}")
    return "\n".join(out) + "\n"


def _cell(v) -> str:
    if isinstance(v, str):
        if any(c in v for c in ',"\n'):
            raise ValueError(f"text cell {v!r} would need CSV quoting")
        return v
    if isinstance(v, bool):
        raise TypeError(f"{v!r}: write directions and flags as the integers the format names")
    if isinstance(v, int):
        return str(v)
    f = float(v)
    if not math.isfinite(f):
        raise ValueError(f"{f!r}: the format holds finite numbers only")
    return repr(f)


def csv_text(columns: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A CSV table: header line, one line per row (``\\n`` line ends, no quoting needed).
    Cells are Python ``str``, ``int`` or ``float`` (``.tolist()`` numpy arrays first)."""
    lines = [",".join(columns)]
    for r in rows:
        if len(r) != len(columns):
            raise ValueError(f"row {list(r)} has {len(r)} cells for {len(columns)} columns")
        lines.append(",".join(_cell(v) for v in r))
    return "\n".join(lines) + "\n"


def write(directory: Path | str, files: Mapping[str, str]) -> Path:
    """Write ``files`` (name → text) into ``directory`` (created if needed; files of the
    same names are replaced). Returns the directory."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (d / name).write_text(text, encoding="utf-8")
    return d
