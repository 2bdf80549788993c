"""One module per ``cellctl`` sub-command; see :mod:`cell.cli`."""
from __future__ import annotations

import argparse


def float_list(n: int | None = None):
    """argparse type: comma-separated floats (``"60,30"``), optionally exactly ``n`` of them."""
    def parse(text: str) -> list[float]:
        try:
            values = [float(v) for v in text.split(",") if v.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers") from None
        if n is not None and len(values) != n:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {n} comma-separated numbers, got {len(values)}")
        return values
    return parse


def preset_name(text: str) -> str:
    """argparse type: the name of a robot preset of :data:`cell.robots.PRESETS`. Imported
    only when a value is parsed, so ``--help`` does not load the kinematics (numpy, pydantic)."""
    from cell.robots import PRESETS
    if text not in PRESETS:
        raise argparse.ArgumentTypeError(f"unknown robot preset {text!r}; known: "
                                         f"{', '.join(sorted(PRESETS))}")
    return text


def open_log_readonly(db: str):
    """The cycle log at ``db`` opened read-only (never changes the file; works beside a
    running controller). Raises ConfigError when there is no log there."""
    from pathlib import Path

    from cell.cyclelog import CycleLog
    from cell.errors import ConfigError
    if not Path(db).is_file():
        raise ConfigError(f"{db}: no cycle log here (run the cell first, or pass --db)")
    return CycleLog(db, readonly=True)


def summary(doc: str) -> str:
    """The first paragraph of a command module's docstring as plain help text: whole
    sentences, joined lines, no reST backticks (``cellctl X --help`` shows it)."""
    first = doc.strip().split("\n\n")[0]
    return " ".join(first.split()).replace("``", "")


def png_path(given: str, name: str):
    """The file a ``--png`` option means: ``given`` itself, ``given/name`` when it is a
    folder (existing, or written with a trailing slash), with ``.png`` added when it has
    no suffix (as the plotting library would, silently)."""
    from pathlib import Path
    p = Path(given)
    if p.is_dir() or given.endswith(("/", "\\")):
        p = p / name
    return p if p.suffix else p.with_suffix(".png")


def plot_file(given: str, name: str, option: str = "--png"):
    """The plot file a plot option means (:func:`png_path`; None for ''),
    refused with ConfigError naming ``option`` when it cannot be written: a format the
    plotting library does not write, or a place below a file. Call it before any output."""
    if not given:
        return None
    png = png_path(given, name)
    from matplotlib.figure import Figure

    from cell.errors import ConfigError
    kinds = Figure().canvas.get_supported_filetypes()
    if png.suffix[1:].lower() not in kinds:
        raise ConfigError(f"{option} {given}: cannot write a {png.suffix} plot; use one of "
                          f"{', '.join('.' + k for k in sorted(kinds))}")
    blocker = file_in_the_way(png)
    if blocker is not None:
        raise ConfigError(f"{option} {given}: {blocker} is not a folder")
    return png


def file_in_the_way(path):
    """The nearest existing parent of ``path`` when it is not a folder (``path`` cannot be
    written below it), else None."""
    from pathlib import Path
    parent = next((p for p in Path(path).parents if p.exists()), None)
    return parent if parent is not None and not parent.is_dir() else None
