"""Who wrote a recipe file: the note an editor that knows its user leaves beside the file.

The running controller holds the cycle log's single-writer lock, so a tool that edits
recipes for a logged-in user (the maintenance HMI, :mod:`cell.hmi`) cannot write the audit
row itself. It saves the recipe through the same path as any editor (a new file renamed
over the old one; the controller's :class:`~cell.recipes.store.RecipeStore` settles,
validates and activates it between cycles) and leaves a note
``<recipes>/.edits/<file>.json`` (:class:`EditNote`): user, role, tool, time, and what
identifies the exact file it wrote: SHA-256 of the bytes, inode, size and modification
time (ns). When the store audits a version, :func:`attribution` names the note's user and
role in the audit row's ``who`` — only if all of those still match, so a later hand edit,
even one back to the same bytes, is attributed to the file's owner as before, never to the
note's user.

Trust: the note is as trustworthy as write access to the recipe folder, which is the
access that lets anyone change a recipe at all; the audit row keeps the file owner's name
too (``alice (maintenance, hmi; file owner cell)``).

There is one note per recipe file, replaced at every save; ``.edits`` starts with a dot,
so the store never takes it for a recipe. Notes are written through :func:`temp_file` into
``.edits`` opened without following a symlink, so a link planted in the folder cannot send
the write elsewhere.
"""
from __future__ import annotations

import contextlib
import json
import os
import secrets
import stat
from datetime import datetime, timezone
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

NOTES_DIR = ".edits"
MAX_NOTE_BYTES = 4096          #: a note is a few hundred bytes; anything bigger is not one
FORMAT = "cell-recipe-edit/1"


class EditNote(BaseModel):
    """One save of a recipe file by a tool that knows its user."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    format: str = Field(default=FORMAT, pattern=r"^cell-recipe-edit/1$")
    file: str = Field(pattern=r"^[^/\\]+\.yaml$", description="the recipe's file name in the folder")
    user: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,40}$")
    role: str = Field(pattern=r"^[a-z]{1,20}$")
    tool: str = Field(default="hmi", pattern=r"^[a-z]{1,20}$")
    at: str = Field(description="UTC time of the save, ISO 8601")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="SHA-256 of the file's bytes")
    inode: int = Field(ge=0)
    size: int = Field(ge=0)
    mtime_ns: int = Field(ge=0)

    def who(self, owner: str) -> str:
        """The audit row's ``who``: user, role, tool, and the file's owner."""
        return f"{self.user} ({self.role}, {self.tool}; file owner {owner})"


def note_path(recipe: Path) -> Path:
    return recipe.parent / NOTES_DIR / f"{recipe.name}.json"


def temp_file(dir_fd: int, name: str, mode: int) -> tuple[int, str]:
    """``(fd, tmp_name)``: a new file beside ``name`` in the folder open as ``dir_fd``, open
    for writing, to rename over ``name``. Created with ``O_CREAT | O_EXCL | O_NOFOLLOW``
    under a random dot-name: nothing planted in the folder (a symlink at any name) can make
    it write anywhere else. The one way this module and the HMI's recipe desk make their
    temporary files."""
    while True:
        tmp = f".{name}.{secrets.token_hex(8)}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, mode,
                         dir_fd=dir_fd)
        except FileExistsError:
            continue
        os.fchmod(fd, mode)                     # the umask does not decide who may read it
        return fd, tmp


def write_note(recipe_tmp: Path, final: Path, user: str, role: str, sha256: str, tool: str = "hmi") -> EditNote:
    """Write the note for the file ``recipe_tmp`` that is about to be renamed to ``final``
    (call it before the rename: the note must exist when the controller sees the file).
    Atomic: a temporary file (:func:`temp_file`) in ``.edits`` renamed over the old note,
    with the recipe file's mode (the controller may run as another user).

    :raises OSError: ``.edits`` is not a folder (a symlink is refused), or the write failed.
    """
    st = os.stat(recipe_tmp, follow_symlinks=False)
    note = EditNote(file=final.name, user=user, role=role, tool=tool, sha256=sha256, inode=st.st_ino,
                    size=st.st_size, mtime_ns=st.st_mtime_ns,
                    at=datetime.now(timezone.utc).isoformat(timespec="milliseconds"))
    name = note_path(final).name
    rfd = os.open(final.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        try:
            os.mkdir(NOTES_DIR, 0o755, dir_fd=rfd)
        except FileExistsError:
            pass
        dfd = os.open(NOTES_DIR, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=rfd)
    finally:
        os.close(rfd)
    try:
        fd, tmp = temp_file(dfd, name, stat.S_IMODE(st.st_mode))
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(note.model_dump_json())
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, name, src_dir_fd=dfd, dst_dir_fd=dfd)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp, dir_fd=dfd)
            raise
    finally:
        os.close(dfd)
    return note


def attribution(recipe: Path, signature: tuple, sha256: str) -> EditNote | None:
    """The note for ``recipe`` if it describes exactly this file: ``signature`` is the
    store's (inode, size, mtime_ns, ...) of the file it read, ``sha256`` of its bytes.
    None when there is no note, it is unreadable, malformed, or for other bytes."""
    path = note_path(recipe)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        data = os.read(fd, MAX_NOTE_BYTES + 1)
    except OSError:
        return None
    finally:
        os.close(fd)
    if len(data) > MAX_NOTE_BYTES:
        return None
    try:
        note = EditNote.model_validate(json.loads(data))
    except (ValueError, ValidationError):
        return None
    inode, size, mtime_ns = signature[:3]
    if (note.file, note.sha256, note.inode, note.size, note.mtime_ns) != (recipe.name, sha256, inode, size, mtime_ns):
        return None
    return note
