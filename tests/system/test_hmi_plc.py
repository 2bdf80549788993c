"""The HMI reads the controller's status registers over Modbus TCP as a read-only client,
beside ``cellctl serve --sim`` (a real process; waits are bounded polls of state)."""
from __future__ import annotations

from starlette.testclient import TestClient

from cell.hmi.app import create_app
from cell.hmi.server import settings_from
from cell.hmi.status import plc_status
from tests.system.hmi_cell import idle_cell
from tests.system.test_cli import free_port, write_config


def test_status_registers_are_read_without_taking_the_link(tmp_path):
    cfg, path = write_config(tmp_path)
    port = free_port()
    with idle_cell(path, port, 120) as s:
        assert s["fault_code"] == 0 and s["status"]["auto"] and not s["status"]["plc_link_ok"]   # no PLC yet
        app = create_app(settings_from(str(path), str(tmp_path / "users.json"), str(tmp_path / "reports"),
                                       ("127.0.0.1", port)))
        out = TestClient(app, base_url="http://127.0.0.1:8080", client=("127.0.0.1", 5000)).get("/api/status").json()
        assert out["plc"]["reachable"] and out["plc"]["state"] == "idle"
        assert out["plc"]["plant_backlog"] == 0                              # no plant path
        assert not plc_status("127.0.0.1", port)["status"]["plc_link_ok"]   # reads never feed the watchdog
    gone = plc_status("127.0.0.1", port)
    assert not gone["reachable"] and gone["error"]
