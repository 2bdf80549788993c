"""The whole cell under a rogue client (issue 12, "done when"): the sim cell with an allow-list
and its simulated PLC owning the link; a host outside the list and a second, allowed client
that is not the owner. Neither can write nor keep the link alive; what they tried, and the
PLC's reset, land in the hash-chained audit trail with the client's address."""
from __future__ import annotations

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from cell.faults import Fault
from drivers.plc.register_map import PLC_MAP
from tests.system.conftest import Harness

HB, CMD, RECIPE = (PLC_MAP[n].address for n in ("plc_heartbeat", "command_word", "recipe_select"))


@pytest.fixture
def guarded(tmp_path):
    h = Harness(tmp_path, allow=["127.0.0.1"])
    yield h
    h.close()


def _client(port: int, source: str) -> ModbusTcpClient:
    return ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0, source_address=(source, 0))


def _cannot_write(c: ModbusTcpClient, address: int, value: int) -> bool:
    """The write did not land: refused at connect, the connection closed, or an exception."""
    try:
        if not c.connect():
            return True
        return c.write_register(address, value).isError()
    except (OSError, ModbusException):
        return True


def test_rogue_clients_can_neither_drive_the_cell_nor_keep_its_link_alive(guarded):
    h = guarded
    h.cycle()                                               # the PLC owns the link and runs a part
    owner = h.cell.plc.owner
    assert owner is not None and owner.startswith("127.0.0.1:")
    outsider, second = _client(h.port, "127.0.0.2"), _client(h.port, "127.0.0.1")
    try:
        assert _cannot_write(outsider, RECIPE, 8) and _cannot_write(outsider, HB, 77)
        assert second.connect()
        for address, value in ((RECIPE, 8), (CMD, 1), (CMD, 2), (HB, 4242)):
            rr = second.write_register(address, value)
            assert rr.isError() and rr.exception_code == 1, (address, value)
        assert second.read_holding_registers(0, count=1).registers == [PLC_MAP.version]   # reads: yes
        # the PLC goes silent; the second client's heartbeat keeps nothing alive (within the
        # 0.4 s time-out it is refused; after it, the watchdog has tripped whoever beats next)
        h.plc.pause_heartbeat()
        for k in range(3):
            assert second.write_register(HB, 5000 + k).exception_code == 1
            h.sleep(0.1)
        h.wait(lambda: h.controller.fault_code == Fault.PLC_HEARTBEAT_LOST, 5.0, "fault 101")
        assert h.plc.inputs()["recipe_ack"] == 7
    finally:
        outsider.close()
        second.close()
    h.plc.resume_heartbeat()
    h.wait(lambda: h.status()["plc_link_ok"], 5.0, "link back")
    h.plc.reset()
    h.wait(lambda: any(r["action"] == "plc_write_refused" for r in h.cell.cyclelog.audit_rows()), 15.0,
           "the refusals' audit row (written every 10 s)")
    h.wait(lambda: any(r["action"] == "reset" for r in h.cell.cyclelog.audit_rows()), 5.0, "reset row")
    rows = h.cell.cyclelog.audit_rows()
    refused = [r for r in rows if r["action"] == "plc_write_refused"]
    assert refused and all(r["who"].startswith("plc 127.0.0.1") for r in refused)
    assert sum(int(r["result"].split()[0]) for r in refused) >= 7
    reset = [r for r in rows if r["action"] == "reset"]
    assert reset[-1]["who"].startswith("127.0.0.1:") and reset[-1]["result"] == "accepted"
    assert reset[-1]["target"] == f"fault {int(Fault.PLC_HEARTBEAT_LOST)}"
    assert h.cell.cyclelog.audit_break() is None            # the chain holds
