"""The HMI's recipe desk: list, view, diff against the active version, validate, save.

Validation is ``cellctl recipe validate``'s (:mod:`cell.recipes.validation`): the schema,
the cell's checks (the robot's reach; with a cell config, the joint stations) and a number
no other file uses. Saving goes the way of every edit: the controller's
:class:`~cell.recipes.store.RecipeStore` settles, validates, activates between cycles and
writes the audit row; the desk only writes the file, atomically (a temporary file made with
:func:`cell.recipes.notes.temp_file`, fsync, rename over the recipe, fsync of the folder), after an edit note
(:mod:`cell.recipes.notes`) that puts the user and role in that audit row. Nothing is written
for text that fails validation, is too big, or for a file changed since it was loaded.

The active version is read from the cycle log (read-only): the last version the controller
activated, and the audit row that decided on a saved hash.
"""
from __future__ import annotations

import contextlib
import difflib
import hashlib
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path

from cell.errors import CellError, ConfigError
from cell.recipes.notes import temp_file, write_note
from cell.recipes.validation import check_file, check_text, field_errors, number_clashes

NAME = re.compile(r"^[a-z0-9][a-z0-9_-]{0,39}$")


class SaveRefused(CellError):
    """A save that wrote nothing: ``status`` (HTTP), ``errors`` (field errors)."""

    def __init__(self, status: int, message: str, errors: list[dict] | None = None):
        super().__init__(message)
        self.status, self.errors = status, errors or [{"line": None, "field": "(file)", "message": message}]


@dataclass(frozen=True)
class Saved:
    name: str
    sha256: str
    path: str


class RecipeDesk:
    """Recipes of ``directory`` for the HMI.

    :param cell_check: the cell's checks (:func:`cell.recipes.validation.checks_for`).
    :param log_path: the cycle log, opened read-only for the active versions and the audit.
    :param max_bytes: the controller's ``recipes.max_bytes``; bigger text is refused.
    """

    def __init__(self, directory: Path | str, cell_check, log_path: Path | str, max_bytes: int):
        self.directory = Path(directory)
        self.cell_check = cell_check
        self.log_path = Path(log_path)
        self.max_bytes = int(max_bytes)
        self._save_lock = threading.Lock()

    # ------------------------------------------------------------------ reading
    def path(self, name: str) -> Path:
        """The file of recipe ``name``; ConfigError for a name no recipe can have or no file."""
        if not NAME.match(name):
            raise ConfigError(f"{name!r}: not a recipe name")
        p = self.directory / f"{name}.yaml"
        if not p.is_file():
            raise ConfigError(f"{p}: no such recipe")
        return p

    def list(self) -> list[dict]:
        """Every recipe file: name, number, sha256, valid, description or error, whether it
        is for production (False: a shipped example, ``production: false``), and what the
        controller made of it (``state``, ``active_sha256``: see :meth:`file_state`)."""
        files = sorted(f for f in self.directory.glob("*.yaml") if not f.name.startswith("."))
        checked = {f: check_file(f, self.cell_check) for f in files}
        clashes = number_clashes(checked, self.directory)
        out = []
        for f, (h, err, rec, _) in checked.items():
            err = err or clashes.get(f)
            production = _production(rec)
            out.append({"name": f.stem, "number": rec.number if rec else None, "sha256": h,
                        "valid": err is None, "description": rec.description if rec and not err else "",
                        "error": err, "production": production,
                        **self.file_state(f.stem, h, err is None, production)})
        return out

    def view(self, name: str) -> dict:
        """Recipe ``name``: its text, sha256, validation errors, whether it is for production
        and what the controller made of it (:meth:`file_state`)."""
        p = self.path(name)
        data = p.read_bytes()
        text = data.decode("utf-8", errors="replace")
        h = hashlib.sha256(data).hexdigest()
        checked = self.validate(name, text)
        return {"name": name, "path": str(p), "text": text, "sha256": h, "errors": checked["errors"],
                "production": checked["production"],
                **self.file_state(name, h, checked["ok"], checked["production"])}

    def file_state(self, name: str, sha256: str, valid: bool, production: bool) -> dict:
        """``{"state", "active_sha256", "audit"}`` of the file's version ``sha256``: ``invalid``;
        ``example`` (``production: false``: activated only where the cell allows examples);
        ``active``; ``rejected`` by the controller (``audit``: the row with the reason);
        ``pending`` (saved after the active version, not decided yet); ``replaced`` (activated
        once, another version since); ``new`` (never activated, no active version)."""
        active = self.active_version(name)
        out = {"active_sha256": active[0] if active else None, "audit": None}
        if not valid:
            return {**out, "state": "invalid"}
        if not production:
            return {**out, "state": "example"}
        if active and active[0] == sha256:
            return {**out, "state": "active"}
        dec = self.decision(name, sha256)
        state = dec["state"] if dec["audit"] is not None or active else "new"
        return {**out, "state": state, "audit": dec["audit"]}

    def diff(self, name: str, text: str | None = None) -> str:
        """Unified diff from the active version to ``text`` (default: the file), as
        ``cellctl recipe diff NAME`` prints it; '' when they are the same."""
        p = self.path(name)
        if text is None:
            text = p.read_text(encoding="utf-8", errors="replace")
        active = self.active_version(name)
        if active is None:
            return ""
        return "".join(difflib.unified_diff(active[1].splitlines(True), text.splitlines(True),
                                            f"{name} (active, {active[0][:12]})", str(p)))

    def active_version(self, name: str) -> tuple[str, str] | None:
        """(sha256, text) of the version the controller last activated; None if none (or no log)."""
        log = self._open_log()
        if log is None:
            return None
        try:
            return log.last_recipe_version(name)
        finally:
            log.close()

    def decision(self, name: str, sha256: str) -> dict:
        """What the controller made of a saved version: ``pending`` (not decided yet),
        ``active``, or ``rejected`` with the reason, and the audit row that says so."""
        log = self._open_log()
        if log is None:
            return {"state": "pending", "audit": None}
        try:
            rows = [r for r in log.audit_rows(hash_=sha256) if r["action"] in ("recipe_activate", "recipe_reject")]
            active = log.last_recipe_version(name)
        finally:
            log.close()
        row = rows[-1] if rows else None
        if row is None:
            return {"state": "pending", "audit": None}
        if row["action"] == "recipe_reject":
            return {"state": "rejected", "audit": row}
        return {"state": "active" if active and active[0] == sha256 else "replaced", "audit": row}

    # ------------------------------------------------------------------ checking and saving
    def validate(self, name: str, text: str) -> dict:
        """``{"ok", "sha256", "errors": [{"line", "field", "message"}]}`` for ``text`` as
        the new content of recipe ``name``: the checks of ``cellctl recipe validate``."""
        p = self.path(name)
        size = len(text.encode("utf-8"))
        if size > self.max_bytes:
            msg = f"{size} bytes, over the limit of {self.max_bytes} bytes (recipes.max_bytes)"
            return {"ok": False, "sha256": "", "errors": [{"line": None, "field": "(file)", "message": msg}],
                    "production": True}
        h, err, rec = check_text(text, str(p), self.cell_check)
        if err is None:
            err = number_clashes({p: (h, None, rec, text)}, self.directory).get(p)
        return {"ok": err is None, "sha256": h, "errors": field_errors(err, str(p)) if err else [],
                "production": _production(rec)}

    def save(self, name: str, text: str, base_sha256: str, user: str, role: str) -> Saved:
        """Write ``text`` as recipe ``name`` for ``user`` (``role``), if it validates and the
        file still is the version the editor loaded (``base_sha256``).

        :raises SaveRefused: 422 invalid (nothing written), 409 the file changed meanwhile.
        """
        with self._save_lock:
            p = self.path(name)
            result = self.validate(name, text)
            if not result["ok"]:
                raise SaveRefused(422, "invalid recipe: nothing written", result["errors"])
            current = hashlib.sha256(p.read_bytes()).hexdigest()
            if current != base_sha256:
                raise SaveRefused(409, f"{p} changed since it was loaded (now {current[:12]}): "
                                       "reload it, then edit again; nothing written")
            data = text.encode("utf-8")
            sha = hashlib.sha256(data).hexdigest()
            if sha == current:
                return Saved(name, sha, str(p))
            mode = os.stat(p).st_mode & 0o777          # the controller may be another user: keep access
            dfd = os.open(self.directory, os.O_RDONLY | os.O_DIRECTORY)
            try:
                fd, tmp = temp_file(dfd, p.name, mode)
                try:
                    with os.fdopen(fd, "wb") as f:
                        f.write(data)
                        f.flush()
                        os.fsync(f.fileno())
                    write_note(self.directory / tmp, p, user, role, sha)
                    os.replace(tmp, p.name, src_dir_fd=dfd, dst_dir_fd=dfd)
                except BaseException:
                    with contextlib.suppress(OSError):
                        os.unlink(tmp, dir_fd=dfd)
                    raise
                os.fsync(dfd)
            except OSError as exc:
                raise SaveRefused(500, f"{p}: cannot write it: {exc.strerror or exc}; nothing changed") from None
            finally:
                os.close(dfd)
            return Saved(name, sha, str(p))

    # ------------------------------------------------------------------ log
    def _open_log(self):
        from cell.cyclelog import CycleLog
        if not self.log_path.is_file():
            return None
        try:
            return CycleLog(self.log_path, readonly=True)
        except CellError:
            return None


def _production(recipe) -> bool:
    """Whether a parsed recipe is for production (True for one that did not parse)."""
    return recipe.production if recipe is not None else True
