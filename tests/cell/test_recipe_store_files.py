"""RecipeStore against what a recipe folder can hold: huge files, symlinks out of the folder,
unreadable and non-UTF-8 files, files still being written, and an audit trail that cannot
be written. Each case reproduces a field-probe finding (see each test's doc)."""
import os
import shutil
import sqlite3
from pathlib import Path

import pytest

from cell.clock import ManualClock
from cell.cyclelog import CycleLog
from cell.errors import ConfigError
from cell.recipes.store import RecipeAuditError, RecipeStore
from tests.privileges import as_unprivileged, give_to_nobody, nobody_dir


class Audit(list):
    """The commit sink: keeps every change set it was given."""

    def __call__(self, changes):
        self.extend(changes)


class Disk(Audit):
    """A commit sink on a disk that can be full (``full``): then it writes nothing and raises."""

    full = False

    def __call__(self, changes):
        if self.full:
            raise sqlite3.OperationalError("database or disk is full")
        super().__call__(changes)


def store_with(rdir, commit=None, **kw):
    audit = commit if commit is not None else Audit()
    store = RecipeStore(rdir, commit=audit, **{"allow_examples": True, **kw})
    store.refresh()
    audit.clear()
    return store, audit


def test_a_huge_recipe_is_refused_from_its_size_and_never_read(rdir):
    """Probe: a valid 50 MB recipe froze the scan loop for 139 s and was stored in the log."""
    store, audit = store_with(rdir)
    big = rdir / "pin-b.yaml"
    with open(big, "r+b") as f:                        # 50 MB: a sparse file, cheap to make
        f.truncate(50_000_000)
    opened = store.files_opened
    assert opened > 0                                  # the first refresh read the recipes
    entries = store.refresh()
    assert store.files_opened == opened                # refused from its size alone, never opened
    assert [(e.action, e.hash) for e in entries] == [("reject", "")]
    assert "50000000 bytes, over the limit of 65536 bytes (recipes.max_bytes)" in entries[0].result
    assert "pin-b" in store.active                     # the last good version stays
    assert store.refresh() == []                       # audited once, not at every refresh


def test_a_symlink_out_of_the_folder_is_refused_and_its_target_never_copied(rdir, tmp_path):
    """Probe: a symlinked recipe to a system file copied its lines into the audit table."""
    secret = tmp_path / "secret.txt"
    secret.write_text("root:x:0:0:root:/root:/bin/bash\n")
    store, audit = store_with(rdir)
    (rdir / "evil.yaml").symlink_to(secret)
    [e] = store.refresh()
    assert e.action == "reject" and "outside the recipe folder" in e.result and e.hash == ""
    assert "root:x" not in repr(audit)


def test_a_symlink_inside_the_folder_is_followed(rdir):
    (rdir / "pin-b.yaml").rename(rdir / "pin-b.real")
    (rdir / "pin-b.yaml").symlink_to(rdir / "pin-b.real")
    store, _ = store_with(rdir)
    assert store.active["pin-b"].recipe.number == 2


def test_a_fifo_is_refused_without_blocking(rdir):
    store, _ = store_with(rdir)
    os.mkfifo(rdir / "pipe.yaml")                      # opening it for reading would block
    [e] = store.refresh()
    assert e.action == "reject" and "not a regular file" in e.result


def test_an_unreadable_file_is_audited_as_unreadable(rdir):
    """Probe: an unreadable file hashed like an empty one, so a bad edit went unaudited."""
    store, audit = store_with(rdir)
    (rdir / "loop.yaml").symlink_to("loop.yaml")      # unreadable whoever runs the test (even root)
    [e] = store.refresh()
    assert e.action == "reject" and "cannot read" in e.result and e.hash == ""
    assert audit[-1][1] == "recipe_reject"


def test_a_file_without_read_permission_is_audited_as_unreadable(rdir):
    """The refresh runs as ``nobody`` (tests/privileges.py): root reads any file whatever
    its mode. The recipes are copied where ``nobody`` may go (``rdir`` may not be)."""
    with nobody_dir() as folder:
        rdir = Path(shutil.copytree(rdir, folder / "recipes"))
        give_to_nobody(rdir)
        store, audit = store_with(rdir)
        (rdir / "pin-b.yaml").chmod(0)

        def check():
            with pytest.raises(PermissionError):        # the condition itself, for this user
                open(rdir / "pin-b.yaml", "rb")
            entries = store.refresh()
            return [(e.action, e.result, e.hash) for e in entries], "pin-b" in store.active, list(audit)
        entries, kept, audited = as_unprivileged(check)
    [(action, result, digest)] = entries
    assert action == "reject" and "cannot read: Permission denied" in result and digest == ""
    assert kept                                        # the last good version stays active
    assert [a[1] for a in audited] == ["recipe_reject"]


def test_binary_garbage_is_rejected_naming_the_line(rdir):
    store, _ = store_with(rdir)
    (rdir / "pin-b.yaml").write_bytes(b"name: pin-b\nnumber: 2\n\xff\xfe\x00\x81")
    [e] = store.refresh()
    assert e.action == "reject" and ":3: cannot read: not UTF-8 text (byte 0xff at column 1;" in e.result


def test_an_edit_whose_check_fails_unforeseen_is_still_rejected_and_audited(rdir):
    """Probe: one bad edit (binary garbage) left no audit row. Any failure inside a check,
    not only a ConfigError, must decide the edit: rejected, audited, last good version kept."""
    calls = []

    def check(recipe, text, source):
        if calls:                              # the start-up set passes; the edit trips it
            raise ZeroDivisionError("float division by zero")
        calls.append(source)

    store, audit = store_with(rdir, check=lambda r, t, s: check(r, t, s) if "pin-b" in s else None)
    before = store.active["pin-b"]
    text = (rdir / "pin-b.yaml").read_text().replace("# ", "#  ", 1) + "\n# edited\n"
    (rdir / "pin-b.yaml").write_text(text)
    [e] = store.refresh()
    assert e.action == "reject" and "could not be checked (ZeroDivisionError: float division by zero)" in e.result
    assert [c[1] for c in audit] == ["recipe_reject"]
    assert store.active["pin-b"] is before
    assert store.refresh() == []               # decided once, not retried at every refresh


def test_a_file_still_being_written_is_not_activated_until_stable(rdir):
    """Probe: 4 truncated files (an editor saving in place) became the active recipe."""
    clock = ManualClock(0.0)
    store, audit = store_with(rdir, settle_s=1.0, clock=clock)
    path = rdir / "bracket-a.yaml"
    full = path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: 0.07")
    cut = full[:full.index("compensation:")]          # a valid recipe on its own: defaults after
    before = store.active["bracket-a"].hash
    path.write_text(cut)                               # the editor has written half
    assert store.refresh() == []                       # seen once: not yet stable
    clock.advance(0.5)
    path.write_text(full)                              # ... and now the rest
    assert store.refresh() == []                       # changed since: not stable
    clock.advance(0.9)
    assert store.refresh() == [] and store.active["bracket-a"].hash == before   # 0.9 s < settle_s
    clock.advance(0.1)
    [e] = store.refresh()
    assert e.action == "activate" and store.active["bracket-a"].text == full
    assert [c[4] for c in audit] == ["ok"] and audit[0][5][2] == full   # only the whole file


def test_when_the_audit_cannot_be_written_nothing_is_activated_and_it_is_retried(rdir):
    """Probe: a recipe activated while the disk was full had no audit row, yet later cycles
    carried its hash."""
    store, disk = store_with(rdir, commit=Disk())
    path = rdir / "bracket-a.yaml"
    before = store.active["bracket-a"]
    path.write_text(path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: 0.07"))

    disk.full = True
    with pytest.raises(RecipeAuditError, match="not applied: the audit trail could not be written"):
        store.refresh()
    assert store.active["bracket-a"] is before and disk == []
    disk.full = False                                  # space again: the change goes through
    [e] = store.refresh()
    assert e.action == "activate" and store.active["bracket-a"].recipe.verify.tolerance_mm == 0.07


def test_activation_and_audit_are_one_transaction_in_the_real_log(rdir, tmp_path):
    log = CycleLog(tmp_path / "cell.sqlite")
    try:
        store = RecipeStore(rdir, commit=log.record_recipe_changes, allow_examples=True)
        store.refresh()
        rows = log.audit_rows()
        assert sorted(r["target"].rsplit("/", 1)[-1] for r in rows) == ["bracket-a.yaml", "pin-b.yaml"]
        assert log.last_recipe_version("pin-b")[0] == store.active["pin-b"].hash
        assert log.verify_audit() is None
    finally:
        log.close()


def test_editor_temporary_files_are_ignored(rdir):
    store, _ = store_with(rdir)
    (rdir / ".bracket-a.yaml.swp").write_text("garbage")
    (rdir / "bracket-a.yaml~").write_text("garbage")
    assert store.refresh() == []


def test_a_missing_folder_keeps_the_last_good_set(rdir):
    store, _ = store_with(rdir)
    rdir.rename(rdir.with_name("gone"))
    with pytest.raises(ConfigError, match="recipe directory cannot be read"):
        store.refresh()
    assert set(store.active) == {"bracket-a", "pin-b"}
