"""The HMI's line view in a real headless Chromium, reading a real PostgreSQL that the
historian's own store (cycles) and status recorder (retained status through a real
mosquitto) filled: three cells with online/offline, state, last part, this shift's
p50/p95, what the historian knows of delivery, and one click to a cell's own trend. Off
(404, no menu entry) when the HMI has no DSN. Waits are bounded polls of state."""
from __future__ import annotations

import re
import urllib.error
import urllib.request
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from cell.hmi.line import parse_links
from cell.hmi.server import settings_from
from cell.errors import ConfigError
from cell.plant.status import StatusRecorder
from tests.browser import chromium, require_browser
from tests.cell.plant.helpers import cycle_message, fill_store
from tests.system.hmi_cell import hmi_server, poll

TIME = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d")
WAIT_S = 90
pytestmark = pytest.mark.timeout(300)
ERRORS = [0.002, 0.004, 0.006, 0.008, 0.030]


def status(cell: str, online: bool, session: int, state: str | None = None) -> bytes:
    """A status of version 1, or of version 2 with the cell's ``state``."""
    v2 = f',"state":"{state}","fault_code":0,"fault_text":""' if state else ""
    return (f'{{"schema":{2 if state else 1},"cell":"{cell}","online":{str(online).lower()},"session":{session},'
            f'"log_id":"{"a" * 32}","at":"2026-01-01T00:00:00Z"{v2}}}').encode()


def fill(broker, dsn: str) -> None:
    """cell-1 online, 5 done parts in this shift (ERRORS) and a fault last; cell-2 offline
    (its Last Will), 3 parts with record 3 missing (held above the watermark); cell-3 online
    and idle (a status of version 2, which says the cell's state), no record yet."""
    import paho.mqtt.client as mqtt
    from cell.plant.fleet import shift_of, shift_start
    now = datetime.now(timezone.utc).replace(microsecond=0)
    first = max(now - timedelta(seconds=60), shift_start(*shift_of(now)))    # all in this shift
    at = [(first + timedelta(seconds=k)).isoformat() for k in range(10)]
    msgs = [cycle_message("s1/l2/cell-1", k + 1, at[k], final_mm=e) for k, e in enumerate(ERRORS)]
    msgs.append(cycle_message("s1/l2/cell-1", 6, at[6], status="fault", fault_code=31, part_id=106))
    msgs += [cycle_message("s1/l2/cell-2", 1, at[1]), cycle_message("s1/l2/cell-2", 2, at[2]),
             cycle_message("s1/l2/cell-2", 4, at[4]).model_copy(update={"prev_id": 3})]
    fill_store(dsn, msgs)
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    c.connect(broker.host, broker.port)
    c.loop_start()
    try:
        for cell, online, state in (("s1/l2/cell-1", True, None), ("s1/l2/cell-2", False, None),
                                    ("s1/l2/cell-3", True, "idle")):
            c.publish(f"{cell}/status", status(cell, online, 3, state), qos=1, retain=True).wait_for_publish(10)
        recorder = StatusRecorder(broker.host, broker.port, dsn, client_id="line-view-status", keepalive_s=5,
                                  topic_filter="s1/l2/+/status")
        recorder.start()
        try:
            poll(lambda: recorder.written >= 3, WAIT_S, "three statuses written")
        finally:
            recorder.stop()
        for cell in ("s1/l2/cell-1", "s1/l2/cell-2", "s1/l2/cell-3"):
            c.publish(f"{cell}/status", b"", qos=1, retain=True).wait_for_publish(10)
    finally:
        c.loop_stop()
        c.disconnect()


def test_the_line_view_shows_every_cell_and_leads_to_its_trend(tmp_path, broker, historian_db):
    require_browser()
    fill(broker, historian_db)
    settings = settings_from(None, str(tmp_path / "users.json"), str(tmp_path / "reports"), db=str(tmp_path / "c.sqlite"),
                             line_dsn=historian_db,
                             line_links=parse_links(["s1/l2/cell-3=http://127.0.0.1:9/"]))
    with hmi_server(settings) as (url, _), chromium(tmp_path, 1600, 900) as driver:
        driver.get(url + "/")
        assert driver.find_element("id", "line-nav").get_attribute("href") == url + "/line"
        driver.get(url + "/line")

        def rows() -> dict:
            return driver.execute_script(
                "const out = {}; for (const tr of document.querySelectorAll('#line tbody tr'))"
                " out[tr.dataset.cell] = [...tr.cells].map((td) => td.textContent); return out;")
        got = poll(lambda: len(rows()) == 3 and rows(), WAIT_S, "three cells on the line view")
        c1, c2, c3 = got["s1/l2/cell-1"], got["s1/l2/cell-2"], got["s1/l2/cell-3"]
        assert c1[1] == "online, last cycle faulted" and c2[1] == "offline" and c3[1] == "online, idle"
        assert c1[3].startswith("106 (bracket-a, fault) 31") and TIME.fullmatch(c1[4])
        p50, p95 = np.percentile(ERRORS, [50, 95]) * 1000
        assert c1[5] == f"{p50:.1f} / {p95:.1f}" and c1[7] == "5 · 1"
        # delivery: cell-2 has 1, 2 and 4 (3 missing): watermark 2, one record held above it
        assert (c2[8], c2[9], c2[10]) == ("3", "2", "1") and (c1[8], c1[9], c1[10]) == ("6", "6", "0")
        assert c3[8] == "0" and c3[3] == "–" and re.fullmatch(r"\d+ s ago|\d+ min ago", c1[11])
        assert all(TIME.fullmatch(r[2]) for r in (c1, c2, c3))
        assert "early 06:00-14:00" in driver.find_element("id", "shifts").text
        assert not re.search(r"\b[AP]M\b", driver.find_element("tag name", "main").text)
        links = {a.text: a.get_attribute("href") for a in driver.find_elements("css selector", "a.cell-link")}
        assert links["s1/l2/cell-3"] == "http://127.0.0.1:9/"
        # one click to a cell's own trend
        driver.find_element("link text", "s1/l2/cell-1").click()
        poll(lambda: driver.find_elements("id", "cell-trend"), WAIT_S, "the cell's page")
        assert driver.find_element("id", "cell-id").text == "s1/l2/cell-1"
        poll(lambda: driver.execute_script("const i = document.getElementById('cell-trend');"
                                           " return i.complete && i.naturalWidth > 0"), WAIT_S, "the trend drawn")
        assert len(driver.find_elements("css selector", "#cell-cycles tbody tr")) == 6


def test_the_line_view_is_off_without_a_dsn_and_says_when_the_database_is_away(tmp_path):
    from cell.plant.servers import free_port
    base = dict(users=str(tmp_path / "users.json"), reports=str(tmp_path / "reports"), db=str(tmp_path / "c.sqlite"))
    with hmi_server(settings_from(None, **base)) as (url, _):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(url + "/line", timeout=30)
        assert err.value.code == 404
        assert 'id="line-nav"' not in urllib.request.urlopen(url + "/", timeout=30).read().decode()
    away = f"host=127.0.0.1 port={free_port()} user=cell dbname=historian connect_timeout=3"
    with hmi_server(settings_from(None, **base, line_dsn=away)) as (url, _):
        import json
        doc = json.loads(urllib.request.urlopen(url + "/api/line", timeout=60).read())
        assert doc["cells"] == [] and "cannot reach the historian's database" in doc["error"]
    for bad in ("s1/l2=http://x/", "s1/l2/c=javascript:alert(1)", "s1/l2/c"):
        with pytest.raises(ConfigError, match="--line-link"):
            parse_links([bad])
