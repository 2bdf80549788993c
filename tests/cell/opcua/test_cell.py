"""The OPC UA server in the simulated cell (``cell.app.Cell`` with an ``opcua`` section):
it shows the cell's own axis positions and results, and the scan keeps serving the PLC
while a client reads as fast as it can.

The cell runs on the simulated clock the test thread keeps; the server and the client run
on wall time in threads of their own, so the test thread lets simulated time pass
(``h.sleep``) before it waits, on wall time, for what the server shows."""
from __future__ import annotations

import asyncio
import threading

import pytest

from tests.cell.opcua.conftest import connect, node
from tests.system.conftest import Harness
from tests.waiting import wait_for

AXES = "MotionDeviceSystem.MotionDevices.Robot.Axes"
PARAMS = "MotionDeviceSystem.Controllers.Controller.ParameterSet"
RESULTS = "MotionDeviceSystem.Controllers.Controller.ResultManagement"


class OpcuaHarness(Harness):
    """The system harness's cell with the OPC UA server on a free loopback port."""

    def __init__(self, tmp_path):
        self._opcua_pki = str(tmp_path / "opcua")
        super().__init__(tmp_path)

    def new_cell(self, port: int = 0):
        from cell.opcua.config import OpcuaSection
        self.config = self.config.model_copy(update={"opcua": OpcuaSection(port=0, pki=self._opcua_pki,
                                                                           poll_s=0.02)})
        return super().new_cell(port)


@pytest.fixture
def h(tmp_path):
    harness = OpcuaHarness(tmp_path)
    yield harness
    harness.close()


async def _axes(c):
    out = []
    for j in ("j1", "j2", "j3", "j4"):
        dv = await (await node(c, f"{AXES}.{j}.ParameterSet.ActualPosition")).read_data_value(
            raise_on_bad_status=False)
        out.append(dv.Value.Value if dv.StatusCode.is_good() else None)
    return out


def test_the_server_shows_the_cells_axes_and_its_settled_cycles(h, aio):
    url = h.cell.opcua.url
    client = aio.run(connect(url))
    try:
        events = []

        class Handler:
            def event_notification(self, event):
                events.append(event)

        async def watch():
            rm = await node(client, RESULTS)
            etype = await client.nodes.base_event_type.get_child([f"{rm.nodeid.NamespaceIndex}:ResultReadyEventType"])
            sub = await client.create_subscription(20, Handler())
            await sub.subscribe_events(rm, etype)
        aio.run(watch())
        results = [h.cycle() for _ in range(2)]
        assert all(r["done"] for r in results)
        h.sleep(0.5)                                   # the arm at rest, sampled, published
        want = [round(float(q), 3) for q in h.joints()]
        got = wait_for(lambda: (lambda a: a if a == want else None)(aio.run(_axes(client))), 60,
                       f"the cell's joints {want} shown")
        assert got == want
        wait_for(lambda: len(events) >= 2, 60, "two result-ready events")
        logged = h.cell.cyclelog.cycles()

        async def latest_and_status():
            rm = await node(client, RESULTS)
            latest = await rm.call_method(f"{rm.nodeid.NamespaceIndex}:GetLatestResult")
            status = {n: await (await node(client, f"{PARAMS}.{n}")).read_value()
                      for n in ("State", "CyclesDone", "ActiveRecipe", "FaultCode")}
            return latest, status
        latest, status = aio.run(latest_and_status())
        assert [e.ResultId for e in events] == [c.id for c in logged]
        assert [e.PartId for e in events] == [c.part_id for c in logged]
        last = logged[-1]
        assert latest[:4] == [last.id, last.part_id, "done", last.final_error_mm]
        assert abs(latest[3] * 1000 - results[-1]["final_error_um"]) <= 1      # what the PLC was told
        assert latest[5:7] == [last.moves, "fast-a"]
        assert status == {"State": "idle", "CyclesDone": 2, "ActiveRecipe": "fast-a", "FaultCode": 0}
    finally:
        aio.run(client.disconnect())


def test_the_scan_keeps_serving_the_plc_while_a_client_reads_as_fast_as_it_can(h, aio):
    url = h.cell.opcua.url
    stop, reads, errors = threading.Event(), [0], []

    async def hammer():
        c = await connect(url)
        try:
            system = await node(c, "MotionDeviceSystem")
            while not stop.is_set():
                nodes = [system]
                for n in nodes:                      # browse the whole subset, read every variable
                    nodes.extend(await n.get_children())
                    if (await n.read_node_class()).name == "Variable":
                        await n.read_data_value(raise_on_bad_status=False)
                        reads[0] += 1
        finally:
            await c.disconnect()

    def client_thread():
        try:
            asyncio.run(hammer())
        except Exception as exc:                     # noqa: BLE001 -- reported below
            errors.append(exc)
    t = threading.Thread(target=client_thread, name="test-opcua-hammer", daemon=True)
    t.start()
    try:
        wait_for(lambda: reads[0] > 200 or errors, 120, "the client reading")
        scans0, reads0 = h.controller.scans, reads[0]
        results = [h.cycle() for _ in range(3)]
        assert all(r["done"] for r in results) and h.controller.fault_code == 0
        assert h.controller.scans > scans0 and reads[0] > reads0        # both went on side by side
    finally:
        stop.set()
        t.join(60)
    assert not errors and h.cell.opcua.dropped == 0
