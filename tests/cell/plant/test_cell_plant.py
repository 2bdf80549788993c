"""The plant section of the cell config: off by default (the main job needs no broker),
checked at load, and a simulated cell with it sends its cycles to the historian."""
from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from cell.config import CellConfig, PlantSection
from cell.errors import ConfigError
from cell.plant.historian import Historian
from cell.plant.outbox import PlantOutbox
from tests.cell.plant.helpers import historian_settings, log_ids, pg_ids
from tests.waiting import wait_for


def events(dsn: str, cell: str) -> list:
    import psycopg
    with psycopg.connect(dsn) as db:
        return db.execute("SELECT kind, data FROM events WHERE cell = %s ORDER BY session, seq", (cell,)).fetchall()


def test_no_plant_section_by_default_and_a_bad_one_is_refused_at_load(tmp_path):
    assert CellConfig().plant is None
    s = PlantSection(host="broker", site="site1", line="line2")
    assert s.outbox_settings("cell-1").topics.path == "site1/line2/cell-1"
    path = tmp_path / "cell.yaml"
    for bad, says in ((dict(host="b", site="s/1", line="l"), "plant.site"),
                      (dict(host="b", site="s", line="l", qos=2), "qos"),
                      (dict(host="b", site="s", line="l", port=0), "port")):
        path.write_text(yaml.safe_dump({"format": "cell-config/1", "plant": bad}))
        with pytest.raises(ConfigError, match=says):
            CellConfig.load(path)


def test_a_simulated_cell_with_a_plant_section_sends_its_cycles(tmp_path, broker, historian_db):
    from tests.system.conftest import REPO, make_config
    cfg = make_config(tmp_path, heartbeat_timeout_s=5.0)
    cfg = cfg.model_copy(update={"plant": PlantSection(host=broker.host, port=broker.port, site="site1",
                                                       line="line2")})
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json", exclude_none=True)))
    historian = Historian(historian_settings(broker, historian_db, client_id="h-cell"))
    historian.start()
    try:
        out = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                              "--recipe", "fast-a", "--cycles", "4", "--db", str(tmp_path / "cell.sqlite")],
                             cwd=REPO, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        assert "plant_outbox_error" not in out.stderr
        db = tmp_path / "cell.sqlite"
        # what the run did not get delivered before it stopped stays in its log: the next
        # start of the cell (here its outbox alone) sends it
        outbox = PlantOutbox(db, cfg.plant.outbox_settings(cfg.name))
        outbox.start()
        try:
            wait_for(lambda: outbox.backlog == 0, 120, "the log's cycles delivered")
        finally:
            outbox.stop()
        assert len(log_ids(db)) == 4 and pg_ids(historian_db, "site1/line2/cell-1") == log_ids(db)
        # the cell's events: its recipe files activated at start-up (before its outbox had
        # started) and the recipe the run selected
        kinds = {k for k, _ in events(historian_db, "site1/line2/cell-1")}
        assert {"recipe_changed", "recipe_selected"} <= kinds, kinds
        assert any(d["action"] == "activate" and d["target"].endswith(".yaml")
                   for k, d in events(historian_db, "site1/line2/cell-1") if k == "recipe_changed")
    finally:
        historian.stop()


def test_the_plc_reads_the_plant_backlog_while_the_historian_is_away(tmp_path, broker, historian_db):
    # a cell with a plant section: its cycles wait in the log while no historian confirms
    # them, and the PLC sees how many (plant_backlog); once the historian is back it drops to 0
    from tests.system.conftest import Harness

    class PlantHarness(Harness):
        def new_cell(self, port: int = 0):
            self.config = self.config.model_copy(update={"plant": PlantSection(
                host=broker.host, port=broker.port, site="site1", line="line2", cell="cell-bk")})
            return super().new_cell(port)

    h = PlantHarness(tmp_path)
    historian = None
    try:
        for _ in range(2):
            assert h.cycle()["final_error_um"] >= 0
        backlog = lambda: h.plc.inputs()["plant_backlog"]        # noqa: E731
        wait_for(lambda: (h.sleep(0.05), backlog() == 2)[1], 60, "the PLC to read a backlog of 2")
        historian = Historian(historian_settings(broker, historian_db, client_id="h-backlog"))
        historian.start()
        wait_for(lambda: (h.sleep(0.05), backlog() == 0)[1], 120, "the backlog to drain")
        assert pg_ids(historian_db, "site1/line2/cell-bk") == {1, 2}
    finally:
        if historian is not None:
            historian.stop()
        h.close()
