"""What the HMI's pages say (Starlette's in-process client against the real app, the real
recipe desk, and the real recipe store and cycle log as the controller's side): what the
controller made of a saved recipe, an example recipe, an empty log, the PLC's recipe
registers in words, one time format."""
from __future__ import annotations

import os
import re
import subprocess
from datetime import datetime, timezone
from pathlib import Path

from cell.cyclelog import CycleRecord
from cell.recipes.store import RecipeStore
from cell.recipes import motion_check
from tests.cell.test_hmi import cell, client, editor, hmi, login  # noqa: F401 -- fixtures

TIME = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d")
REPO = Path(__file__).resolve().parents[2]


def state_of(page: str) -> str:
    return re.sub(r"<[^>]+>", "", re.search(r'id="active-state"[^>]*>(.*?)</span>', page, re.S).group(1)).strip()


def diff_of(page: str) -> tuple[str, str]:
    title = re.search(r'id="diff-title">(.*?)</h3>', page, re.S).group(1)
    return title, re.search(r'<pre id="diff">(.*?)</pre>', page, re.S).group(1)


def test_the_recipe_page_says_what_the_controller_made_of_a_save(hmi, rdir, cell):
    store, log = cell
    path = rdir / "bracket-a.yaml"
    c = client(hmi)
    login(c)
    assert state_of(c.get("/recipes/bracket-a").text) == "active"
    text = path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: 0.09")
    token, sha = editor(c, "bracket-a")
    assert c.post("/api/recipes/bracket-a/save", json={"text": text, "base_sha256": sha},
                  headers={"X-CSRF-Token": token}).status_code == 200
    page = c.get("/recipes/bracket-a").text
    assert state_of(page).startswith("pending: saved, the controller has not decided yet")
    title, diff = diff_of(page)
    assert title.startswith("Pending change") and "+  tolerance_mm: 0.09" in diff
    store.refresh()                                    # the controller, between cycles
    page = c.get("/recipes/bracket-a").text
    assert state_of(page) == "active" and diff_of(page) == ("Diff against the active version", "no differences")
    assert "active" in re.search(r'<tr[^>]*id="row-bracket-a".*?</tr>', c.get("/recipes").text, re.S).group(0)
    # a version the controller rejects (on drives without SYNC): said so, with its reason; the
    # diff is the rejected change
    store = RecipeStore(rdir, commit=log.record_recipe_changes, check=motion_check(False, [0.001] * 4))
    store.refresh()
    token, sha = editor(c, "bracket-a")
    rejected = text.replace("sync: corrected", "sync: sync")
    assert c.post("/api/recipes/bracket-a/save", json={"text": rejected, "base_sha256": sha},
                  headers={"X-CSRF-Token": token}).status_code == 200
    store.refresh()
    page = c.get("/recipes/bracket-a").text
    assert state_of(page).startswith("rejected by the controller at ") and TIME.search(state_of(page))
    assert "motion.sync" in re.search(r'id="rejection">(.*?)</p>', page, re.S).group(1)
    assert diff_of(page)[0].startswith("Rejected change")


def test_an_example_recipe_is_shown_as_not_for_production(hmi):
    c = client(hmi)
    row = re.search(r'<tr[^>]*id="row-pin-b".*?</tr>', c.get("/recipes").text, re.S).group(0)
    assert "example — not for production" in row and 'class="example"' in row and ">active<" not in row
    assert state_of(c.get("/recipes/pin-b").text) == "example — not for production"


def test_an_empty_log_shows_a_text_not_a_picture_that_is_not_there(hmi, tmp_path, cell):
    store, log = cell                                  # a log without cycles
    page = client(hmi).get("/").text
    assert "no cycles logged yet" in page and '<img id="trend"' not in page
    log.add_cycle(CycleRecord(part_id=1, recipe="bracket-a", recipe_hash="0" * 64, status="done",
                              started_at="2026-11-23T10:00:00+00:00", finished_at="2026-11-23T10:00:40+00:00",
                              cycle_time_s=1.0, initial_error_mm=0.3, final_error_mm=0.02, verify_error_mm=0.021,
                              moves=2))
    page = client(hmi).get("/").text
    assert '<img id="trend"' in page and "no cycles logged yet" not in page


def test_the_plc_recipe_registers_are_said_in_words():
    from cell.hmi.status import recipe_line
    assert recipe_line(0, 0) == "no recipe selected"
    assert recipe_line(1, 0) == "recipe 1: ok"
    assert recipe_line(3, 2) == "recipe 3: last edit rejected"
    assert recipe_line(3, 9) == "recipe 3: status 9"


def test_server_written_times_are_local_24_hour(hmi, tmp_path):
    from cell.hmi.pages import local_time
    at = datetime(2026, 11, 25, 21, 7, 29, tzinfo=timezone.utc)
    assert local_time(at.isoformat()) == at.astimezone().strftime("%Y-%m-%d %H:%M:%S")
    report = tmp_path / "reports" / "gap-1" / "index.html"
    report.parent.mkdir(parents=True)
    report.write_text("<h1>gap</h1>")
    os.utime(report, (at.timestamp(), at.timestamp()))
    page = client(hmi).get("/reports").text
    assert at.astimezone().strftime("%Y-%m-%d %H:%M:%S") in page and not re.search(r"\b[AP]M\b", page)


def test_edit_notes_are_not_committed():
    out = subprocess.run(["git", "check-ignore", "-q", "recipes/.edits/bracket-a.yaml.json"], cwd=REPO)
    assert out.returncode == 0
