"""End to end in a real headless Chromium: the maintenance HMI beside a running simulated
cell (two real processes, see :mod:`tests.system.hmi_cell`). A maintenance user logs in,
a bad edit is refused with its field named and changes nothing, a good edit is activated
by the controller between cycles (then the page shows it active with no pending diff), the
next cycles run the new version, and the audit row of the activation names the user and
role. Every time on the pages reads ``YYYY-MM-DD HH:MM:SS``, local, 24-hour."""
from __future__ import annotations

import hashlib
import re

import pytest

from tests.browser import chromium, require_browser
from tests.system.hmi_cell import PASSWORD, ROLE, USER, SimCellWithHmi, poll, query

TIME = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d")
WAIT_S = 120          # bounded waits for state, in wall time (never asserted as timing)
pytestmark = pytest.mark.timeout(600)   # two processes and a browser on a loaded 2-core host


def text_of(driver, element_id: str) -> str:
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
    try:
        return driver.find_element("id", element_id).text
    except (NoSuchElementException, StaleElementReferenceException):
        return ""


def type_recipe(driver, text: str) -> None:
    """Replace the editor's text by typing, as a user would (select all, then the keys)."""
    from selenium.webdriver.common.keys import Keys
    editor = driver.find_element("id", "editor")
    editor.click()
    editor.send_keys(Keys.CONTROL, "a")
    editor.send_keys(Keys.DELETE)
    editor.send_keys(text)
    poll(lambda: driver.execute_script("return document.getElementById('editor').value") == text,
         WAIT_S, "the typed text in the editor")


@pytest.mark.slow
def test_login_bad_edit_refused_good_edit_activated_between_cycles(tmp_path):
    require_browser()
    with SimCellWithHmi(tmp_path / "cell") as cell, chromium(tmp_path, 1400, 1000) as driver:
        path = cell.recipes / "fast-a.yaml"
        original = path.read_bytes()
        old_sha = hashlib.sha256(original).hexdigest()
        # the status page shows the running cell's cycles, live
        driver.get(cell.url + "/")
        poll(lambda: driver.find_elements("css selector", "#cycles tbody tr"), WAIT_S, "cycles on the status page")
        assert "fast-a" in text_of(driver, "cycles")
        # every time on the page is local, 24-hour, YYYY-MM-DD HH:MM:SS
        poll(lambda: TIME.search(text_of(driver, "updated")), WAIT_S, "the page's update time")
        finished = driver.execute_script("return [...document.querySelectorAll('#cycles tbody tr')]"
                                         ".map((tr) => tr.lastElementChild.textContent)")
        assert finished and all(TIME.fullmatch(t) for t in finished), finished
        assert not re.search(r"\b[AP]M\b", driver.find_element("tag name", "main").text)

        # log in as the maintenance user
        driver.get(cell.url + "/login?next=/recipes/fast-a")
        driver.find_element("id", "user").send_keys(USER)
        driver.find_element("id", "password").send_keys("not the password")
        driver.find_element("id", "login").click()
        poll(lambda: "wrong password" in text_of(driver, "login-error"), WAIT_S, "the bad login refused")
        driver.find_element("id", "user").clear()
        driver.find_element("id", "user").send_keys(USER)
        driver.find_element("id", "password").send_keys(PASSWORD)
        driver.find_element("id", "login").click()
        poll(lambda: text_of(driver, "who") == f"{USER} ({ROLE})", WAIT_S, "logged in")
        assert driver.current_url.endswith("/recipes/fast-a")

        # a BAD edit: named while typing, refused on save, nothing written
        bad = original.decode().replace("fiducial_radius_mm: 1.5", "fiducial_radius_mm: 0.1")
        assert bad != original.decode()
        type_recipe(driver, bad)
        poll(lambda: "part.fiducial_radius_mm" in text_of(driver, "check"), WAIT_S, "the field named while typing")
        driver.find_element("id", "save").click()
        poll(lambda: "not saved" in text_of(driver, "save-state"), WAIT_S, "the save refused")
        assert "part.fiducial_radius_mm" in text_of(driver, "check")
        assert path.read_bytes() == original

        # a GOOD edit: saved, activated by the running controller between cycles
        good = original.decode().replace("tolerance_mm: 0.08", "tolerance_mm: 0.09")
        assert good != original.decode()
        type_recipe(driver, good)
        poll(lambda: text_of(driver, "check") == "valid", WAIT_S, "the edit valid")
        assert "+  tolerance_mm: 0.09" in text_of(driver, "diff")
        done_before = query(cell.db, "SELECT MAX(id) FROM cycles")[0][0]
        driver.find_element("id", "save").click()
        new_sha = hashlib.sha256(good.encode()).hexdigest()
        poll(lambda: "activated" in text_of(driver, "save-state"), WAIT_S, "the controller's activation")
        assert path.read_bytes() == good.encode()
        assert f"{USER} ({ROLE}, hmi" in text_of(driver, "save-state")
        # once active, nothing is left pending: the page says so and shows no diff
        assert text_of(driver, "active-state") == "active" and text_of(driver, "diff") == "no differences"
        assert TIME.search(text_of(driver, "save-state"))
        driver.refresh()
        poll(lambda: text_of(driver, "active-state") == "active", WAIT_S, "the reloaded page saying active")
        assert text_of(driver, "diff") == "no differences"

        # the audit row of the activation names user and role; the bad edit left no row
        [(audit_id, who, result)] = query(cell.db, "SELECT id, who, result FROM audit WHERE action = "
                                                   "'recipe_activate' AND hash = ?", (new_sha,))
        assert who.startswith(f"{USER} ({ROLE}, hmi; file owner ") and result == "ok"
        assert query(cell.db, "SELECT COUNT(*) FROM audit WHERE action = 'recipe_reject' "
                              "AND target LIKE '%fast-a.yaml'")[0][0] == 0
        # cycles go on, and a cycle after the activation runs the new version
        poll(lambda: query(cell.db, "SELECT id FROM cycles WHERE recipe_hash = ?", (new_sha,)), WAIT_S,
             "a cycle with the new version")
        hashes = [h for (h,) in query(cell.db, "SELECT recipe_hash FROM cycles ORDER BY id")]
        switch = hashes.index(new_sha)
        assert set(hashes[:switch]) == {old_sha} and set(hashes[switch:]) == {new_sha}   # wholly old, then new
        assert switch >= done_before                    # cycles ran with the old version up to the save
        statuses = {s for (s,) in query(cell.db, "SELECT status FROM cycles")}
        assert statuses == {"done"}
        assert cell.procs[0].poll() is None             # the cell ran on throughout
