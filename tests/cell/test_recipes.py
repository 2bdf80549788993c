"""Recipes: validation messages name file, line and field; atomic activation; audit trail."""
import json
import re

import pytest

from cell.errors import ConfigError
from cell.recipe_store import RecipeStore
from cell.recipes import parse_recipe, recipe_schema

from tests.cell.conftest import REPO_RECIPES


def test_shipped_recipes_are_valid(rdir):
    store = RecipeStore(rdir)
    entries = store.refresh()
    assert {e.result for e in entries} == {"ok"}
    assert set(store.active) == {"bracket-a", "pin-b"}
    assert store.by_number(2).recipe.name == "pin-b"


def test_committed_schema_is_current():
    assert json.loads((REPO_RECIPES / "recipe.schema.json").read_text()) == recipe_schema()


@pytest.mark.parametrize("old, new, words", [
    ("  fiducial_radius_mm: 1.5", "  fiducial_radius_mm: -1.5", r":{line}: part.fiducial_radius_mm: .*greater than 0.2"),
    ("  max_moves: 4", "  max_moves: 4\n  max_movez: 5", r":{line2}: compensation.max_movez: Extra inputs"),
    ("  method: lattice ", "  method: magic ", r":{line}: compensation.method"),
    ("number: 1", "number: one", r":{line}: number"),
    ("name: bracket-a", "name: [bracket", r":\d+: malformed YAML"),
    ("name: bracket-a", "name: other-name", r":{line}: name: .*must match the file name 'bracket-a'"),
    ("number: 1", "number: 2", r":{line}: number: recipe number 2 is already used"),
])
def test_bad_edit_is_rejected_and_last_good_stays(rdir, old, new, words):
    audit = []
    store = RecipeStore(rdir, commit=audit.extend)
    store.refresh()
    good = store.active["bracket-a"]
    path = rdir / "bracket-a.yaml"
    text = path.read_text()
    assert old in text
    line = text[:text.index(old)].count("\n") + 1
    words = words.format(line=line, line2=line + 1)
    path.write_text(text.replace(old, new, 1))
    entries = store.refresh()
    assert [e.action for e in entries] == ["reject"]
    assert str(path) in entries[0].result
    assert re.search(words, entries[0].result), entries[0].result
    assert store.active["bracket-a"] is good           # the last good version stays active
    e = entries[0]
    assert audit[-1] == (e.who, "recipe_reject", e.target, e.hash, e.result, None) and e.who
    assert store.last_rejection == entries[0].result


def test_valid_edit_swaps_whole_mapping(rdir):
    store = RecipeStore(rdir)
    store.refresh()
    before = store.active
    path = rdir / "bracket-a.yaml"
    path.write_text(path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: 0.05"))
    entries = store.refresh()
    assert [(e.action, e.recipe) for e in entries] == [("activate", "bracket-a")]
    assert before["bracket-a"].recipe.verify.tolerance_mm == 0.08     # old mapping untouched
    assert store.active["bracket-a"].recipe.verify.tolerance_mm == 0.05
    assert store.active["bracket-a"].hash != before["bracket-a"].hash
    assert store.refresh() == []                                     # unchanged: nothing to do


def test_removed_recipe_is_deactivated_and_audited(rdir):
    store = RecipeStore(rdir)
    store.refresh()
    (rdir / "pin-b.yaml").unlink()
    entries = store.refresh()
    assert [(e.action, e.recipe) for e in entries] == [("remove", "pin-b")]
    assert "pin-b" not in store.active


def test_binary_garbage_is_rejected(rdir):
    store = RecipeStore(rdir)
    store.refresh()
    (rdir / "pin-b.yaml").write_bytes(b"\xff\xfe\x00\x81")
    entries = store.refresh()
    assert entries[0].action == "reject" and "cannot read" in entries[0].result
    assert "pin-b" in store.active


def test_parse_recipe_top_level_must_be_mapping():
    with pytest.raises(ConfigError, match=r"<text>:1: \(top level\): the recipe must be a mapping"):
        parse_recipe("- a\n- b\n", "<text>")


def test_missing_directory(tmp_path):
    with pytest.raises(ConfigError, match="nope: recipe directory cannot be read: No such file"):
        RecipeStore(tmp_path / "nope").refresh()
