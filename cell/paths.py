"""Where a relative path points: one rule for every command, whatever the shell's folder.

Three kinds of path, three bases:

* **Defaults** (``recipes/``, ``var/cell.sqlite``, ``deploy/plants/default.yaml`` …) are
  the project's: :func:`project` resolves them against :data:`PROJECT`, the folder that
  holds the ``cell`` package (the repository root in a checkout, ``/opt/cell-controller``
  in the systemd unit).
* **Paths written in a config file** are that file's: :func:`from_file` resolves them
  against the file's folder (``plc.tls`` certificates always were).
* **Paths typed on the command line** (``--db ./x.sqlite``, ``export DIR``) are the user's,
  relative to the shell's folder as for any Unix tool: they are left as given.

Standard library only: ``cellctl --help`` imports this module.
"""
from __future__ import annotations

from pathlib import Path

#: the project's folder: the one holding the ``cell`` package
PROJECT = Path(__file__).resolve().parent.parent

#: the cycle log when neither a config nor ``--db`` names one
DEFAULT_DB = "var/cell.sqlite"
DEFAULT_RECIPES = "recipes"
DEFAULT_PLANT = "deploy/plants/default.yaml"


def project(path: str | Path) -> Path:
    """``path`` against the project folder (an absolute path is returned unchanged)."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else PROJECT / p


def from_file(path: str | Path, file: str | Path) -> Path:
    """``path`` as written in ``file`` (a config): against the file's folder."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else Path(file).resolve().parent / p


def shown(path: str | Path) -> str:
    """``path`` for a message: relative to the shell's folder when it lies below it (short
    and copy-pasteable), absolute otherwise."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError):
        return str(p)


def temp_beside(path: str | Path, suffix: str = ".tmp") -> tuple[int, str]:
    """``(fd, name)`` of a new file beside ``path``, open for writing, to rename over it
    (an atomic write), like ``tempfile.mkstemp`` but with the umask's mode as any file a
    command writes: ``mkstemp``'s 0600 made a calibration written by root (deploy/INSTALL.md)
    unreadable to the service user."""
    import os
    path = Path(path)
    while True:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{os.urandom(4).hex()}{suffix}")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), str(tmp)
        except FileExistsError:
            continue
