"""The active recipes of one folder, and the rules by which an edit reaches them.

:class:`RecipeStore` keeps the *active* set as one immutable mapping, replaced in a single
assignment, so a reader always sees wholly the old or wholly the new set. The controller
runs :meth:`RecipeStore.refresh` off its scan thread, between cycles. An edit is taken only
when all of these hold:

* **Inside the folder.** A recipe is a regular file ``<name>.yaml`` in the folder (names
  starting with ``.`` are editors' temporary files and are ignored). A symlink is followed
  only to a regular file inside the folder; a FIFO, a device or a folder is refused.
* **Small.** At most ``max_bytes`` (default 64 KiB); a bigger file is refused from its size
  alone, never read.
* **Complete and stable.** A change is looked at again after ``settle_s`` of the injected
  clock and taken only if the file (inode, size, modification and change times) has not
  changed in between: an editor that saves in place leaves a half-written file only for a
  moment, and that moment is never activated. The first refresh (at start-up) takes the
  files as they are.
* **Valid.** :func:`~cell.recipes.parse_recipe`, the cell's check (``check``), and a recipe
  number not used by another file; otherwise the edit is rejected with a message naming
  file, line and field, and the last good version stays active.
* **For production.** A recipe marked ``production: false`` (a shipped example) is rejected
  the same way unless the store allows examples (``allow_examples``).
* **Always decided.** A check that fails in a way nobody foresaw (any exception, not only
  a ``ConfigError``) rejects the edit with that reason; no edit is left undecided.
* **Attributed.** The audit row names the file's owner, or — when an edit note
  (:mod:`cell.recipes.notes`) describes exactly the bytes and file taken — the user and role
  the maintenance HMI saved it for.
* **Audited first.** Every decision (activate, reject — unreadable, too big, outside the
  folder, invalid — or remove) goes to ``commit`` with the activated text, in one
  transaction. If that fails (disk full), nothing is applied and the change is tried again
  at the next refresh: no recipe is ever active without its audit row.
"""
from __future__ import annotations

import hashlib
import os
import pwd
import stat
import threading
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Mapping

from cell.clock import Clock, MonotonicClock
from cell.errors import ConfigError
from cell.log import get_logger
from cell.recipes.notes import attribution
from cell.recipes import (ActiveRecipe, AuditEntry, CellCheck, RecipeAction, example_refusal, line_of,
                          parse_recipe)
from cell.yamlio import decode_utf8

log = get_logger("recipes")

DEFAULT_MAX_BYTES = 64 * 1024

#: a change set for the audit trail: (who, action, target, hash, result, version), version
#: (name, hash, text) for an activation; ``commit`` writes all or none, or raises
Commit = Callable[[list], None]


class RecipeAuditError(ConfigError):
    """The audit trail could not be written: the changes found were not applied."""


@dataclass(frozen=True)
class _Look:
    """What one look at a file found, before reading it."""

    signature: tuple            #: (inode, size, mtime_ns, ctime_ns, mode): any edit changes it
    error: str | None = None    #: why it cannot be a recipe (outside the folder, too big, ...)
    open_path: str = ""         #: what to open (the symlink's target inside the folder)


class RecipeStore:
    """The active recipes of ``directory``; see the module doc for the rules.

    :param commit: writes the audit rows and activated versions of one refresh atomically
        (:meth:`cell.cyclelog.CycleLog.record_recipe_changes`); raises if it cannot.
    :param check: validates each recipe against the cell (e.g. :func:`~cell.recipes.motion_check`).
    :param max_bytes: the largest recipe file, bytes.
    :param settle_s: how long a changed file must stay unchanged before it is taken (clock s).
    :param allow_examples: also activate recipes marked ``production: false``.
    """

    def __init__(self, directory: Path | str, commit: Commit | None = None, check: CellCheck | None = None,
                 max_bytes: int = DEFAULT_MAX_BYTES, settle_s: float = 0.0, clock: Clock | None = None,
                 allow_examples: bool = False):
        self.directory = Path(directory)
        self.allow_examples = bool(allow_examples)
        self._commit = commit if commit is not None else (lambda changes: None)
        self.check = check
        self.max_bytes = int(max_bytes)
        self.settle_s = float(settle_s)
        self.clock = clock or MonotonicClock()
        self._active: Mapping[str, ActiveRecipe] = MappingProxyType({})
        self._decided: dict[str, tuple] = {}     # path -> signature of the last look decided on
        self._hashes: dict[str, str] = {}        # path -> hash of the content last decided on
        self._pending: dict[str, tuple] = {}     # path -> (signature, clock time first seen)
        self._first = True
        self.last_rejection: str | None = None
        #: refreshes run so far, by the name of the thread that ran them: the controller runs
        #: the first in its start-up thread, every later one in its log worker (``cell-log``),
        #: never in the scan task
        self.refreshes: Counter[str] = Counter()
        #: files opened for reading so far; a file refused from its look (too big, outside
        #: the folder, not a regular file) is never opened
        self.files_opened = 0

    @property
    def active(self) -> Mapping[str, ActiveRecipe]:
        """Read-only name -> ActiveRecipe mapping; replaced whole on every change."""
        return self._active

    def by_number(self, number: int) -> ActiveRecipe | None:
        for a in self._active.values():
            if a.recipe.number == number:
                return a
        return None

    # ------------------------------------------------------------------ refresh
    def refresh(self) -> list[AuditEntry]:
        """Look at the folder; apply the changes that are stable, valid and audited. Returns
        the audit entries written (empty if nothing changed).

        :raises ConfigError: the folder is gone (the last good set stays active).
        :raises RecipeAuditError: the audit trail could not be written; nothing was applied.
        """
        self.refreshes[threading.current_thread().name] += 1
        try:
            names = sorted(e.name for e in os.scandir(self.directory)
                           if e.name.endswith(".yaml") and not e.name.startswith("."))
        except OSError as exc:
            raise ConfigError(f"{self.directory}: recipe directory cannot be read: "
                              f"{exc.strerror or exc}") from None
        now = self.clock.now()
        new = dict(self._active)
        entries: list[AuditEntry] = []
        versions: dict[int, tuple] = {}
        decided: dict[str, tuple] = {}
        hashes: dict[str, str] = {}
        present = {str(self.directory / n) for n in names}
        for path in sorted(present):
            look = self._look(Path(path))
            if look is None or self._decided.get(path) == look.signature:
                continue
            if not self._first and self.settle_s > 0:
                seen = self._pending.get(path)
                if seen is None or seen[0] != look.signature:
                    self._pending[path] = (look.signature, now)
                    continue
                if now - seen[1] < self.settle_s:
                    continue
            entry, active, h = self._decide(Path(path), look, new)
            decided[path] = look.signature
            if entry is None:                      # same content as before (e.g. touched)
                continue
            hashes[path] = h
            entries.append(entry)
            if active is not None:
                new[active.recipe.name] = active
                versions[len(entries) - 1] = (active.recipe.name, active.hash, active.text)
        for name, a in list(new.items()):
            if a.path not in present:
                del new[name]
                entries.append(AuditEntry("unknown", RecipeAction.REMOVE, a.path, a.hash, "ok", name))
        if entries:
            changes = [(e.who, f"recipe_{e.action}", e.target, e.hash, e.result, versions.get(i))
                       for i, e in enumerate(entries)]
            try:
                self._commit(changes)
            except Exception as exc:               # noqa: BLE001 -- e.g. disk full: apply nothing
                log.error("recipe_audit_failed", error=repr(exc), changes=len(changes))
                raise RecipeAuditError(f"recipe changes not applied: the audit trail could not be "
                                       f"written ({exc}); they are tried again at the next refresh") from exc
        self._first = False
        for path in present | set(self._decided):
            if path not in present:                # gone: forget it
                self._decided.pop(path, None)
                self._hashes.pop(path, None)
                self._pending.pop(path, None)
        self._decided.update(decided)
        self._hashes.update(hashes)
        for path in decided:
            self._pending.pop(path, None)
        for e in entries:
            if e.example:                          # refused by design, not an edit gone wrong
                log.info("recipe_example_not_activated", file=e.target)
            elif e.action == RecipeAction.REJECT:
                self.last_rejection = e.result
                log.warning("recipe_rejected", file=e.target, error=e.result)
            elif e.action == RecipeAction.ACTIVATE:
                log.info("recipe_activated", recipe=e.recipe, hash=e.hash[:12])
            else:
                log.info("recipe_removed", recipe=e.recipe)
        self._active = MappingProxyType(new)       # the atomic swap
        return entries

    # ------------------------------------------------------------------ one file
    def _look(self, path: Path) -> _Look | None:
        """lstat the file (and its target if a symlink); None if it vanished meanwhile."""
        try:
            st = os.lstat(path)
            open_path = str(path)
            if stat.S_ISLNK(st.st_mode):
                target = Path(os.path.realpath(path))
                inside = target.parent == Path(os.path.realpath(self.directory))
                if not inside:
                    return _Look(_signature(st) + (str(target),),
                                 f"{path}: a symlink to {target}, outside the recipe folder "
                                 f"{self.directory}: refused")
                st, open_path = os.stat(target), str(target)
        except FileNotFoundError:
            return None
        except OSError as exc:
            return _Look((exc.errno,), f"{path}: cannot read: {exc.strerror}")
        sig = _signature(st)
        if not stat.S_ISREG(st.st_mode):
            return _Look(sig, f"{path}: not a regular file: refused")
        if st.st_size > self.max_bytes:
            return _Look(sig, f"{path}: {st.st_size} bytes, over the limit of {self.max_bytes} bytes "
                              "(recipes.max_bytes): not read")
        return _Look(sig, None, open_path)

    def _decide(self, path: Path, look: _Look, new: dict) -> tuple[AuditEntry | None, ActiveRecipe | None, str]:
        """Read, validate and judge one changed file: (entry, activated recipe, content hash)."""
        who = _owner(path)
        data, error = (b"", look.error) if look.error else self._read(path, look.open_path)
        h = hashlib.sha256(data).hexdigest() if error is None else ""
        if error is None and self._hashes.get(str(path)) == h:
            return None, None, h
        note = attribution(path, look.signature, h) if error is None else None
        if note is not None:                       # saved by a tool for a logged-in user (the HMI)
            who = note.who(who)
        try:
            if error:
                raise ConfigError(error)
            text = decode_utf8(data, str(path))
            recipe = parse_recipe(text, str(path))
            if self.check is not None:
                self.check(recipe, text, str(path))
            if not recipe.production and not self.allow_examples:
                return AuditEntry(who, RecipeAction.REJECT, str(path), h, example_refusal(recipe, text, str(path)),
                                  recipe.name, example=True), None, h
            clash = next((a for a in new.values() if a.recipe.number == recipe.number
                          and a.recipe.name != recipe.name), None)
            if clash:
                raise ConfigError(f"{path}:{line_of(text, 'number')}: number: recipe number "
                                  f"{recipe.number} is already used by {clash.path}")
        except ConfigError as exc:
            return AuditEntry(who, RecipeAction.REJECT, str(path), h, str(exc)), None, h
        except Exception as exc:                   # noqa: BLE001 -- a check's own failure
            # an edit is never left undecided (and so unaudited, retried forever): whatever
            # stopped the check, the file is rejected with the reason and the last good
            # version stays active
            log.error("recipe_check_failed", file=str(path), error=repr(exc))
            return AuditEntry(who, RecipeAction.REJECT, str(path), h,
                              f"{path}: could not be checked ({type(exc).__name__}: {exc}); "
                              "the last good version stays active"), None, h
        active = ActiveRecipe(recipe, h, text, str(path))
        return AuditEntry(who, RecipeAction.ACTIVATE, str(path), h, "ok", recipe.name), active, h

    def _read(self, path: Path, open_path: str) -> tuple[bytes, str | None]:
        """At most ``max_bytes`` + 1 bytes of a regular file (never follows a symlink, never
        blocks on a FIFO): (data, error)."""
        try:
            fd = os.open(open_path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except OSError as exc:
            return b"", f"{path}: cannot read: {exc.strerror}"
        self.files_opened += 1
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                return b"", f"{path}: not a regular file: refused"
            chunks, size = [], 0
            while size <= self.max_bytes:
                chunk = os.read(fd, self.max_bytes + 1 - size)
                if not chunk:
                    break
                chunks.append(chunk)
                size += len(chunk)
        except OSError as exc:
            return b"", f"{path}: cannot read: {exc.strerror}"
        finally:
            os.close(fd)
        if size > self.max_bytes:
            return b"", f"{path}: over the limit of {self.max_bytes} bytes (recipes.max_bytes): not read"
        return b"".join(chunks), None


def _signature(st: os.stat_result) -> tuple:
    return (st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_mode)


def _owner(path: Path) -> str:
    try:
        return pwd.getpwuid(path.lstat().st_uid).pw_name
    except (KeyError, OSError):
        return "unknown"
