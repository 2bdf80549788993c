"""Edit notes: a recipe the maintenance HMI saved is audited with the user and role it was
saved for, and only the exact file it wrote."""
import hashlib
import os

from cell.recipes.notes import attribution, note_path, write_note
from cell.recipes.store import RecipeStore


class Audit(list):
    def __call__(self, changes):
        self.extend(changes)


def save_as(rdir, name, text, user="alice", role="maintenance"):
    """What the HMI does: temp file, note, rename over the recipe."""
    final = rdir / f"{name}.yaml"
    tmp = rdir / f".{name}.yaml.tmp"
    data = text.encode()
    tmp.write_bytes(data)
    write_note(tmp, final, user, role, hashlib.sha256(data).hexdigest())
    os.replace(tmp, final)
    return final


def test_the_activation_row_names_the_user_and_role_of_the_note(rdir):
    audit = Audit()
    store = RecipeStore(rdir, commit=audit, allow_examples=True)
    store.refresh()
    audit.clear()
    text = (rdir / "pin-b.yaml").read_text().replace("tolerance_mm: 0.1", "tolerance_mm: 0.075")
    assert "0.075" in text
    save_as(rdir, "pin-b", text)
    [(who, action, target, h, result, version)] = store.refresh()and audit
    assert action == "recipe_activate" and result == "ok"
    assert who.startswith("alice (maintenance, hmi; file owner ")
    assert h == hashlib.sha256(text.encode()).hexdigest()


def test_a_later_hand_edit_back_to_the_same_bytes_is_not_attributed_to_the_note(rdir):
    audit = Audit()
    store = RecipeStore(rdir, commit=audit, allow_examples=True)
    store.refresh()
    original = (rdir / "pin-b.yaml").read_text()
    edited = original.replace("tolerance_mm: 0.1", "tolerance_mm: 0.075")
    save_as(rdir, "pin-b", edited)
    store.refresh()
    (rdir / "pin-b.yaml").write_text(original)          # by hand, in place
    store.refresh()
    audit.clear()
    path = rdir / "pin-b.yaml"
    path.write_text(edited)                             # the note's bytes again, by hand
    st = os.stat(path)
    assert attribution(path, (st.st_ino, st.st_size, st.st_mtime_ns), hashlib.sha256(edited.encode()).hexdigest()) is None
    [(who, action, *_)] = store.refresh() and audit
    assert action == "recipe_activate" and "hmi" not in who


def test_a_malformed_or_oversized_note_is_ignored(rdir):
    path = rdir / "pin-b.yaml"
    data = path.read_bytes()
    st = os.stat(path)
    sig, h = (st.st_ino, st.st_size, st.st_mtime_ns), hashlib.sha256(data).hexdigest()
    note = note_path(path)
    note.parent.mkdir()
    for junk in (b"{not json", b'{"file": "pin-b.yaml"}', b"x" * 10_000):
        note.write_bytes(junk)
        assert attribution(path, sig, h) is None
