"""A campaign folder written atomically, by every writer of the measurement format (v1 and
chains): :func:`staged_dir` stages the files beside the folder and puts them in its place
in one rename, so a reader never sees a half-written campaign, and it never deletes a file
it did not write (its :data:`MANIFEST` lists what it wrote)."""
from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from pathlib import Path

from cell.errors import CellError


#: the list of files a campaign writer put in its folder (so that it replaces only those)
MANIFEST = ".written-by-cellctl"


class FolderNotEmptyError(CellError):
    """A campaign would be written into a folder that holds files it did not write."""


def _ours(d: Path) -> set[str] | None:
    """Names this writer put in ``d`` (its manifest), or None without a manifest."""
    try:
        return set((d / MANIFEST).read_text(encoding="utf-8").split())
    except (OSError, UnicodeDecodeError):
        return None


@contextmanager
def staged_dir(d: Path, force: bool = False):
    """Yield a fresh temporary folder beside ``d`` to write a campaign into; when the block
    ends without an exception its files go to ``d``, else it is removed and ``d`` stays.

    * ``d`` missing, empty, or holding only files an earlier write put there (its
      :data:`MANIFEST`): the staged folder replaces it by rename, so a reader never sees a
      half-written campaign.
    * ``d`` holding anything else: :class:`FolderNotEmptyError` naming a few entries, unless
      ``force``; then each file is moved in beside the others (one rename each), and of the
      old files only those listed in the manifest and not written again are removed.

    Nothing this writer did not write is ever deleted. Folders get the umask's mode."""
    d.parent.mkdir(parents=True, exist_ok=True)
    entries = sorted(p.name for p in d.iterdir()) if d.is_dir() else []
    ours = _ours(d) if entries else set()
    foreign = [e for e in entries if e != MANIFEST and (ours is None or e not in ours)]
    if d.exists() and not d.is_dir():
        raise FolderNotEmptyError(f"{d}: is a file, not a folder; nothing written")
    if foreign and not force:
        shown = ", ".join(e + ("/" if (d / e).is_dir() else "") for e in foreign[:5])
        raise FolderNotEmptyError(
            f"{d}: folder is not empty ({shown}{', …' if len(foreign) > 5 else ''}); nothing "
            "written. Choose a new or empty folder, or pass --force to write beside those files "
            "(none of them is deleted)")
    tmp = d.parent / f".{d.name}.{os.getpid()}.{os.urandom(4).hex()}"
    tmp.mkdir()                                   # the umask's mode, not mkdtemp's 0700
    try:
        yield tmp
        written = sorted(p.name for p in tmp.iterdir())
        (tmp / MANIFEST).write_text("\n".join(written) + "\n", encoding="utf-8")
        if not foreign:
            _replace_ours(d, tmp, ours or set())
        else:
            for name in written + [MANIFEST]:
                os.replace(tmp / name, d / name)
            for name in (ours or set()) - set(written):
                (d / name).unlink(missing_ok=True)
            tmp.rmdir()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _replace_ours(d: Path, tmp: Path, ours: set[str]) -> None:
    """Put ``tmp`` in the place of ``d``, which holds nothing but ``ours`` (and the manifest)."""
    if not d.exists():
        os.rename(tmp, d)
        return
    old = d.with_name(f".{d.name}.old.{os.urandom(4).hex()}")
    os.rename(d, old)
    os.rename(tmp, d)
    for name in ours | {MANIFEST}:
        p = old / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink(missing_ok=True)
    old.rmdir()                                   # empty now: only our files were in it
