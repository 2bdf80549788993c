"""Recipes: validation messages name file, line and field; atomic activation; audit trail."""
import json
import re

import pytest

from cell.errors import ConfigError
from cell.recipes.store import RecipeStore
from cell.recipes import parse_recipe, recipe_schema

from tests.cell.conftest import REPO_RECIPES


def test_shipped_recipes_are_valid(rdir):
    store = RecipeStore(rdir, allow_examples=True)
    entries = store.refresh()
    assert {e.result for e in entries} == {"ok"}
    assert set(store.active) == {"bracket-a", "pin-b"}
    assert store.by_number(2).recipe.name == "pin-b"


def test_an_example_recipe_is_refused_unless_the_cell_allows_examples(rdir):
    """pin-b is shipped as ``production: false``: valid, but a production cell (the default)
    does not activate it, and says why in the audit trail."""
    audit = []
    store = RecipeStore(rdir, commit=audit.extend)
    entries = {e.target.rsplit("/", 1)[-1]: e for e in store.refresh()}
    assert set(store.active) == {"bracket-a"} and store.by_number(2) is None
    refused = entries["pin-b.yaml"]
    assert refused.action == "reject"
    assert re.search(r"pin-b.yaml:\d+: production: pin-b is an example, not for production", refused.result)
    assert ("recipe_reject", refused.result) in {(a[1], a[4]) for a in audit}
    assert store.last_rejection is None                   # by design: not a fault to report


@pytest.mark.parametrize("name", sorted(p.stem for p in REPO_RECIPES.glob("*.yaml")))
def test_a_recipe_cut_short_at_any_line_is_refused(name):
    """A file cut at a line boundary (a save cut short, a bad copy) must never validate: every
    section and every limit is stated, never taken from a default."""
    text = (REPO_RECIPES / f"{name}.yaml").read_text()
    parse_recipe(text, f"{name}.yaml")
    lines = text.splitlines(keepends=True)
    last = max(i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#"))
    accepted = []
    for cut in range(last + 1):                 # keep lines[:cut]: everything up to the last value
        try:
            parse_recipe("".join(lines[:cut]), f"{name}.yaml")
        except ConfigError:
            continue
        accepted.append(cut)
    assert accepted == []


@pytest.mark.parametrize("section", ["approach", "place", "compensation", "motion", "verify"])
def test_a_missing_section_is_an_error_not_a_default(section):
    text = (REPO_RECIPES / "bracket-a.yaml").read_text()
    lines = text.splitlines(keepends=True)
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"{section}:"))
    end = next((i for i in range(start + 1, len(lines)) if lines[i][:1].isalpha()), len(lines))
    with pytest.raises(ConfigError, match=rf"bracket-a.yaml:\d+: {section}: required, but missing"):
        parse_recipe("".join(lines[:start] + lines[end:]), "bracket-a.yaml")


@pytest.mark.parametrize("section, field, words", [
    ("verify", "tolerance_mm", r"verify: empty section: write out its fields \(tolerance_mm\)"),
    ("motion", "segment_ms", r"motion.segment_ms: required, but missing"),
    ("approach", "joint_speed_deg_s", r"approach.joint_speed_deg_s: required, but missing"),
    ("part", "search_radius_mm", r"part.search_radius_mm: required, but missing"),
])
def test_a_missing_limit_is_an_error_not_a_default(section, field, words):
    text = (REPO_RECIPES / "bracket-a.yaml").read_text()
    cut = "".join(ln for ln in text.splitlines(keepends=True) if not ln.strip().startswith(f"{field}:"))
    line = 1 + next(i for i, ln in enumerate(cut.splitlines()) if ln.startswith(f"{section}:"))
    with pytest.raises(ConfigError, match=f"bracket-a.yaml:{line}: " + words):    # at the section's key
        parse_recipe(cut, "bracket-a.yaml")


def test_a_typo_names_the_field_meant():
    text = (REPO_RECIPES / "bracket-a.yaml").read_text().replace("verify:", "verfy:")
    with pytest.raises(ConfigError) as exc:
        parse_recipe(text, "bracket-a.yaml")
    assert "verfy: unknown field; did you mean 'verify'?" in str(exc.value)
    assert "verify: required, but missing" in str(exc.value)
    assert "Extra inputs" not in str(exc.value) and "Field required" not in str(exc.value)


def test_yaml_aliases_and_deep_nesting_are_refused_before_any_work():
    """A 2.7 KB "billion laughs" document would expand to ~10^9 nodes for every walk of the
    tree (the line finder, the duplicate-key check, pydantic); it is refused from the parser's
    events alone, as is nesting no recipe needs."""
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(9))
    with pytest.raises(ConfigError, match=r"bracket-a.yaml:1: \(file\): YAML anchors and aliases \(&a\)"):
        parse_recipe(bomb, "bracket-a.yaml")
    deep = "name: " + "[" * 40 + "]" * 40 + "\n"
    with pytest.raises(ConfigError, match=r"nested deeper than 16 levels"):
        parse_recipe(deep, "bracket-a.yaml")


def test_committed_schema_is_current():
    assert json.loads((REPO_RECIPES / "recipe.schema.json").read_text()) == recipe_schema()


@pytest.mark.parametrize("old, new, words", [
    ("  fiducial_radius_mm: 1.5", "  fiducial_radius_mm: -1.5", r":{line}: part.fiducial_radius_mm: .*greater than 0.2"),
    ("  max_moves: 4", "  max_moves: 4\n  max_movez: 5", r":{line2}: compensation.max_movez: unknown field; did you mean 'max_moves'\?"),
    ("  method: lattice ", "  method: magic ", r":{line}: compensation.method"),
    ("  max_moves: 4", "  max_moves: 4\n  extra_moves: 9", r":{line2}: compensation.extra_moves: .*less than or equal to 5"),
    ("  max_moves: 4", "  max_moves: 4\n  extra_moves: -1", r":{line2}: compensation.extra_moves: .*greater than or equal to 0"),
    ("number: 1", "number: one", r":{line}: number"),
    ("name: bracket-a", "name: [bracket", r":\d+: malformed YAML"),
    ("name: bracket-a", "name: other-name", r":{line}: name: .*must match the file name 'bracket-a'"),
    ("number: 1", "number: 2", r":{line}: number: recipe number 2 is already used"),
])
def test_bad_edit_is_rejected_and_last_good_stays(rdir, old, new, words):
    audit = []
    store = RecipeStore(rdir, commit=audit.extend, allow_examples=True)
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
    store = RecipeStore(rdir, allow_examples=True)
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
    store = RecipeStore(rdir, allow_examples=True)
    store.refresh()
    (rdir / "pin-b.yaml").unlink()
    entries = store.refresh()
    assert [(e.action, e.recipe) for e in entries] == [("remove", "pin-b")]
    assert "pin-b" not in store.active


def test_binary_garbage_is_rejected(rdir):
    store = RecipeStore(rdir, allow_examples=True)
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


@pytest.mark.parametrize("text, tol", [
    ("name: a\nnumber: 1\nverify:\n  tolerance_mm: 0.05\n", 0.05),
    ("name: a\nnumber: 1\npart: {nominal_xy_mm: [1, 2], fiducial_radius_mm: 1}\n", 0.08),   # before 2026-11
    ("name: a\nverify: {tolerance_mm: -1}\n", None),
    ("a: &x 1\nb: *x\n", None),
    ("- not a recipe\n", None),
])
def test_a_logged_version_keeps_the_tolerance_it_ran_with(text, tol):
    """Versions activated before every limit had to be written out ran with the old default
    (0.08 mm, the schema of that time); the trend must still draw their tolerance."""
    from cell.recipes import recorded_tolerance
    assert recorded_tolerance(text) == tol
