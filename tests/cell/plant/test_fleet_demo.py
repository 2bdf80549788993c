"""``python3 dev.py fleet`` briefly (slow tier): the demo it runs (``cell/plant/demo.py``, a
real process) starts mosquitto, PostgreSQL, the historian, three simulated cells and the HMI;
every cell's records arrive in PostgreSQL, the line view in Chromium shows the three cells,
and SIGTERM stops everything it started, the servers included, and removes its folder."""
from __future__ import annotations

import json
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import pytest

from tests.browser import chromium, require_browser
from tests.tools import skip_unless_ci
from tests.waiting import wait_for

REPO = Path(__file__).resolve().parents[3]
WAIT_S = 240
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


def _lines(proc: subprocess.Popen) -> queue.Queue:
    q: queue.Queue = queue.Queue()

    def read():
        for line in proc.stdout:
            q.put(line.rstrip("\n"))
    threading.Thread(target=read, daemon=True).start()
    return q


def test_the_fleet_demo_fills_postgres_shows_three_cells_and_stops_cleanly(tmp_path):
    from cell.plant.servers import ServerMissing, mosquitto_binary, postgres_bindir
    try:
        mosquitto_binary(), postgres_bindir()
    except ServerMissing as exc:
        skip_unless_ci(str(exc))
    require_browser()
    import dev
    assert dev.FLEET_JOB == ["-m", "cell.plant.demo"]      # what `dev.py fleet` runs, with the venv's python
    proc = subprocess.Popen([sys.executable, *dev.FLEET_JOB, "--parts", "3", "--pause-s", "2"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ, PYTHONPATH=str(REPO)))
    out: list[str] = []
    lines = _lines(proc)

    def said(pattern: str):
        while True:
            for text in out:
                if m := re.search(pattern, text):
                    return m
            try:
                out.append(lines.get(timeout=1))
            except queue.Empty:
                assert proc.poll() is None, "\n".join(out)
    try:
        wait_for(lambda: said(r"running; Ctrl-C stops everything"), WAIT_S, "the fleet started")
        dsn = said(r"DSN\s+(host=.*)$").group(1)
        line_url = said(r"line view\s+(http://\S+)").group(1)
        folder = Path(said(r"and the HMI in (\S+)").group(1))
        pg_port = int(re.search(r"port=(\d+)", dsn).group(1))
        broker_port = int(said(r"broker\s+mqtt://127.0.0.1:(\d+)").group(1))

        import psycopg

        def per_cell() -> dict:
            try:
                with psycopg.connect(dsn) as db:
                    if db.execute("SELECT to_regclass('cycles')").fetchone()[0] is None:
                        return {}
                    return dict(db.execute("SELECT cell, count(*) FROM cycles GROUP BY cell").fetchall())
            except psycopg.OperationalError:
                return {}
        cells = ["demo/line1/cell-1", "demo/line1/cell-2", "demo/line1/cell-3"]
        wait_for(lambda: all(per_cell().get(c, 0) >= 3 for c in cells), WAIT_S, "records of every cell in PostgreSQL")

        doc = json.loads(urllib.request.urlopen(line_url.replace("/line", "/api/line"), timeout=60).read())
        assert [c["cell"] for c in doc["cells"]] == cells and doc["error"] is None
        assert all(c["session"] for c in doc["cells"]), doc        # each cell's status recorded
        with chromium(tmp_path, 1600, 900) as driver:
            driver.get(line_url)
            wait_for(lambda: len(driver.find_elements("css selector", "#line tbody tr")) == 3, WAIT_S,
                     "three cells on the line view")
            names = [a.text for a in driver.find_elements("css selector", "a.cell-link")]
            assert names == cells
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
    out.extend(iter(lambda: lines.get(timeout=5) if not lines.empty() else None, None))
    assert code == 0, "\n".join(out)
    assert any("fleet: stopped" in text for text in out), "\n".join(out)
    assert not folder.exists()
    for port in (pg_port, broker_port, int(re.search(r":(\d+)/", line_url).group(1))):
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
