"""A silent PLC does not hand the cell to another host: on the default link (no allow-list)
a client on another loopback address can neither reset the heartbeat fault nor start a
cycle once the PLC has gone quiet; the PLC, back on its own host, can."""
from __future__ import annotations

from pymodbus.client import ModbusTcpClient

from cell.cycle.statemachine import State
from cell.faults import Fault
from drivers.plc.register_map import PLC_MAP


def _rogue(port: int) -> ModbusTcpClient:
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0, source_address=("127.0.0.2", 0))
    assert c.connect()
    return c


def _write(client, name: str, value: int) -> bool:
    """Write register ``name`` whole; True if the link took it."""
    reg = PLC_MAP[name]
    rr = client.write_registers(reg.address, PLC_MAP.to_words(name, value))
    return not rr.isError()


def test_another_host_cannot_take_a_silent_link_over(harness):
    h = harness
    h.cycle()
    cycles = h.controller.cycle_count
    h.plc.pause_heartbeat()
    h.wait(lambda: h.controller.fault_code == Fault.PLC_HEARTBEAT_LOST, what="fault 101")
    assert h.cell.plc.owner is None                        # silent past the time-out
    rogue = _rogue(h.port)
    try:
        part = h.present()
        hb = h.cell.plc.read("plc_heartbeat")
        reset = PLC_MAP.with_bits("command_word", 0, {"reset": True})
        execute = PLC_MAP.with_bits("command_word", 0, {"execute": True})
        for beat in range(1, 6):                           # a rogue "PLC": beats, resets, executes
            assert not _write(rogue, "plc_heartbeat", hb + 100 + beat)
            assert not _write(rogue, "part_id", part)
            assert not _write(rogue, "command_word", reset if beat % 2 else execute)
            h.sleep(0.05)
        assert h.cell.plc.owner is None
        assert h.controller.fault_code == Fault.PLC_HEARTBEAT_LOST
        assert h.controller.sm.state is State.FAULT and h.controller.cycle_count == cycles
    finally:
        rogue.close()
    # the PLC, from its own host, takes the link back and resets the fault
    h.plc.resume_heartbeat()
    h.wait(lambda: h.status()["plc_link_ok"], what="link ok")
    assert h.cell.plc.owner.startswith("127.0.0.1:")
    h.plc.set_command(reset=True)
    h.wait(lambda: h.controller.fault_code == 0, what="fault cleared by the PLC's reset")
    h.plc.set_command(reset=False)
    assert h.cycle()["done"]
