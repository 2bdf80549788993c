"""The status page beside an idle controller (``cellctl serve --sim``, a real process, no
cycle run yet), read over its PLC link, in a real headless Chromium: the recipe registers
in words ("no recipe selected", not "recipe 0 (status 0)"), a text where the trend would
be (no picture that is not there), and times as ``YYYY-MM-DD HH:MM:SS``, 24-hour. Waits
are bounded polls of state."""
from __future__ import annotations

import re

import pytest

from cell.hmi.server import settings_from
from tests.browser import chromium, require_browser
from tests.system.hmi_cell import hmi_server, idle_cell, poll
from tests.system.test_cli import free_port, write_config

TIME = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d")
WAIT_S = 90
pytestmark = pytest.mark.timeout(300)


def test_an_idle_controller_is_shown_in_words_without_a_broken_picture(tmp_path):
    require_browser()
    cfg, path = write_config(tmp_path)
    port = free_port()
    with idle_cell(path, port, 240, WAIT_S):
        settings = settings_from(str(path), str(tmp_path / "users.json"), str(tmp_path / "reports"),
                                 ("127.0.0.1", port))
        with hmi_server(settings) as (url, _), chromium(tmp_path, 1400, 900) as driver:
            driver.get(url + "/")

            def text(element_id: str) -> str:
                return driver.execute_script(f"const e = document.getElementById('{element_id}');"
                                             "return e ? e.textContent : ''")
            poll(lambda: "PLC link" in text("plc-line"), WAIT_S, "the PLC registers on the page")
            line = text("plc-line")
            assert "no recipe selected" in line and "recipe 0" not in line and "status 0" not in line, line
            assert text("trend-none") == "no cycles logged yet"
            assert driver.execute_script("return [...document.images].every((i) => i.complete && i.naturalWidth > 0)")
            poll(lambda: TIME.search(text("updated")), WAIT_S, "the page's update time")
            assert not re.search(r"\b[AP]M\b", driver.find_element("tag name", "main").text)
