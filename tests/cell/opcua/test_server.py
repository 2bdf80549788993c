"""The OPC UA server against a real asyncua client on loopback, fed from a bare
:class:`~cell.publish.Publisher` (the whole cell is in test_cell.py): what it shows, that
it is read-only, and who may connect."""
from __future__ import annotations

import asyncio
import math
import shutil

import pytest
from asyncua import ua

from cell.cyclelog import CycleRecord
from cell.opcua.config import OpcuaSection
from cell.opcua.server import OpcuaServer
from tests.cell.opcua.conftest import client_certificate, connect, node
from tests.waiting import wait_for

AXES = "MotionDeviceSystem.MotionDevices.Robot.Axes"
PARAMS = "MotionDeviceSystem.Controllers.Controller.ParameterSet"
RESULTS = "MotionDeviceSystem.Controllers.Controller.ResultManagement"
STATUS = {"state": "idle", "fault_code": 0, "fault_text": "", "cycle_count": 4, "recipe_number": 1,
          "recipe_name": "bracket-a", "recalibration_due": False, "plc_owner": None,
          "joints": [10.5, -20.25, -35.0, 90.0]}


def _record(**kw) -> CycleRecord:
    base = dict(id=9, part_id=41, recipe="bracket-a", recipe_hash="h", started_at="t0",
                finished_at="2026-01-01T00:00:09Z", status="done", cycle_time_s=3.25, final_error_mm=0.012,
                verify_error_mm=0.011, moves=2)
    return CycleRecord(**{**base, **kw})


@pytest.fixture
def served(tmp_path):
    """``make(insecure)``: a started server on a free port with its publisher."""
    from cell.publish import Publisher
    made = []

    def make(insecure: bool):
        pub = Publisher()
        srv = OpcuaServer(OpcuaSection(port=0, pki=str(tmp_path / "pki"), poll_s=0.02), pub, "cell-t",
                          "SCARA seed000 (nominal)", insecure=insecure)
        srv.start()
        made.append(srv)
        return srv, pub
    yield make
    for srv in made:
        srv.stop()


class Events:
    def __init__(self):
        self.got = []

    def event_notification(self, event):
        self.got.append(event)


def test_a_sim_client_browses_the_robotics_subset_reads_values_calls_and_gets_events(served, aio):
    srv, pub = served(insecure=True)

    async def before_any_status():
        c = await connect(srv.url)                             # anonymous, no security: sim only
        try:
            robot = await node(c, "MotionDeviceSystem.MotionDevices.Robot")
            names = {(await ch.read_browse_name()).Name for ch in await robot.get_children()}
            axes = await node(c, AXES)
            joints = sorted([(await ch.read_browse_name()).Name for ch in await axes.get_children()])
            pos = await node(c, f"{AXES}.j1.ParameterSet.ActualPosition")
            dv = await pos.read_data_value(raise_on_bad_status=False)
            eu = await (await pos.get_child(["0:EngineeringUnits"])).read_value()
            eu3 = await (await (await node(c, f"{AXES}.j3.ParameterSet.ActualPosition"))
                         .get_child(["0:EngineeringUnits"])).read_value()
            profile = await (await node(c, f"{AXES}.j3.MotionProfile")).read_value()
            category = await (await node(c, "MotionDeviceSystem.MotionDevices.Robot.MotionDeviceCategory")).read_value()
            rm = await node(c, RESULTS)
            with pytest.raises(ua.UaStatusCodeError) as none_yet:
                await rm.call_method(f"{rm.nodeid.NamespaceIndex}:GetLatestResult")
            return names, joints, dv.StatusCode, eu, eu3, profile, category, none_yet.value.code
        finally:
            await c.disconnect()
    names, joints, status, eu, eu3, profile, category, none_yet = aio.run(before_any_status())
    assert {"Axes", "MotionDeviceCategory", "Model"} <= names and joints == ["j1", "j2", "j3", "j4"]
    assert status.value == ua.StatusCodes.BadWaitingForInitialData
    assert (eu.DisplayName.Text, eu.UnitId) == ("°", 0x4444)       # UNECE "DD"
    assert (eu3.DisplayName.Text, eu3.UnitId) == ("mm", 0x4D4D54)  # UNECE "MMT"
    assert profile == 3 and category == 2                           # LINEAR; SCARA_ROBOT
    assert none_yet == ua.StatusCodes.BadNoData

    pub.status(1.0, STATUS)

    async def with_status_and_a_cycle():
        c = await connect(srv.url)
        try:
            async def axes():
                dvs = [await (await node(c, f"{AXES}.{j}.ParameterSet.ActualPosition"))
                       .read_data_value(raise_on_bad_status=False) for j in ("j1", "j2", "j3", "j4")]
                return [dv.Value.Value if dv.StatusCode.is_good() else None for dv in dvs]
            for _ in range(600):                               # the server takes messages every poll_s
                if (await axes()) == STATUS["joints"]:
                    break
                await asyncio.sleep(0.05)
            values = {name: await (await node(c, f"{PARAMS}.{name}")).read_value()
                      for name in ("State", "FaultCode", "CyclesDone", "ActiveRecipeNumber", "ActiveRecipe")}
            events = Events()
            sub = await c.create_subscription(20, events)
            idx = (await node(c, RESULTS)).nodeid.NamespaceIndex
            etype = await c.nodes.base_event_type.get_child([f"{idx}:ResultReadyEventType"])
            await sub.subscribe_events(await node(c, RESULTS), etype)
            pub.cycle(2.0, _record())
            pub.cycle(3.0, _record(id=10, part_id=42, status="aborted", fault_code=301, fault_text="no frame",
                                   final_error_mm=None, verify_error_mm=None, moves=None))
            for _ in range(600):
                if len(events.got) >= 2:
                    break
                await asyncio.sleep(0.05)
            rm = await node(c, RESULTS)
            latest = await rm.call_method(f"{idx}:GetLatestResult")
            return await axes(), values, events.got, latest
        finally:
            await c.disconnect()
    axes, values, got, latest = aio.run(with_status_and_a_cycle())
    assert axes == STATUS["joints"]
    assert values == {"State": "idle", "FaultCode": 0, "CyclesDone": 4, "ActiveRecipeNumber": 1,
                      "ActiveRecipe": "bracket-a"}
    assert [(e.PartId, e.Status, e.FaultCode) for e in got] == [(41, "done", 0), (42, "aborted", 301)]
    assert got[0].FinalErrorMm == 0.012 and got[0].Moves == 2 and got[0].Recipe == "bracket-a"
    result_id, part, status, final, verify, moves, recipe, code, text, cycle_s, finished = latest
    assert (result_id, part, status, moves, recipe, code, text) == (10, 42, "aborted", 0, "bracket-a", 301, "no frame")
    assert math.isnan(final) and math.isnan(verify) and cycle_s == 3.25
    assert srv.results == 2 and srv.dropped == 0


def test_a_client_write_is_refused_and_changes_nothing(served, aio):
    srv, pub = served(insecure=True)
    pub.status(1.0, STATUS)
    wait_for(lambda: srv._fold.status is not None, 60, "the status taken")

    async def write():
        c = await connect(srv.url)
        try:
            pos = await node(c, f"{AXES}.j1.ParameterSet.ActualPosition")
            access = await pos.read_attribute(ua.AttributeIds.AccessLevel)
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await pos.write_value(ua.DataValue(ua.Variant(0.0, ua.VariantType.Double)))
            state = await node(c, f"{PARAMS}.State")
            with pytest.raises(ua.UaStatusCodeError):
                await state.write_value(ua.DataValue(ua.Variant("idle-ish", ua.VariantType.String)))
            with pytest.raises(ua.UaStatusCodeError):                     # no node management either
                await (await node(c, PARAMS)).add_variable(2, "Injected", 1.0)
            return access.Value.Value, refused.value.code, await pos.read_value(), await state.read_value()
        finally:
            await c.disconnect()
    access, code, value, state = aio.run(write())
    assert access == ua.AccessLevel.CurrentRead.mask
    assert code == ua.StatusCodes.BadUserAccessDenied
    assert value == STATUS["joints"][0] and state == "idle"


def test_a_plant_server_serves_only_trusted_certificates_over_sign_and_encrypt(served, aio, tmp_path):
    srv, pub = served(insecure=False)
    pki = tmp_path / "pki"
    mes = client_certificate(tmp_path / "mes")
    stranger = client_certificate(tmp_path / "stranger", name="stranger")
    shutil.copy(mes[0], pki / "trusted" / "mes.der")                   # the integrator trusts the MES
    pub.status(1.0, STATUS)
    server_cert = pki / "server-cert.der"

    async def attempts():
        out = {}
        for name, kw in (("anonymous, no security", {}),
                         ("stranger's certificate", {"cert": stranger, "server_cert": server_cert}),
                         ("trusted channel, anonymous user", {"cert": mes, "user_cert": False,
                                                              "server_cert": server_cert})):
            try:
                c = await connect(srv.url, **kw)
            except Exception as exc:                   # noqa: BLE001 -- what the refusal looks like varies
                out[name] = type(exc).__name__
            else:
                await c.disconnect()
                out[name] = "connected"
        c = await connect(srv.url, cert=mes, server_cert=server_cert)
        try:
            pos = await node(c, f"{AXES}.j2.ParameterSet.ActualPosition")
            for _ in range(600):
                dv = await pos.read_data_value(raise_on_bad_status=False)
                if dv.StatusCode.is_good():
                    break
                await asyncio.sleep(0.05)
            endpoints = await c.get_endpoints()
            with pytest.raises(ua.UaStatusCodeError):
                await pos.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
            out["trusted"] = (await pos.read_value(), c.security_policy.Mode)
            out["endpoints"] = {(e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode) for e in endpoints}
        finally:
            await c.disconnect()
        return out
    out = aio.run(attempts())
    assert out["anonymous, no security"] != "connected"
    assert out["stranger's certificate"] != "connected"
    assert out["trusted channel, anonymous user"] != "connected"
    assert out["trusted"] == (STATUS["joints"][1], ua.MessageSecurityMode.SignAndEncrypt)
    assert out["endpoints"] == {("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt)}


def test_a_port_already_taken_refuses_the_start_with_the_reason(served, tmp_path):
    import socket
    from cell.errors import CellError
    from cell.publish import Publisher
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        srv = OpcuaServer(OpcuaSection(port=port, pki=str(tmp_path / "pki")), Publisher(), "cell-t")
        with pytest.raises(CellError, match=f"127.0.0.1:{port}"):
            srv.start()
