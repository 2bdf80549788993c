"""The server's address space, built once at start; :class:`Space` then writes what the
Publisher's messages say into it. Imports asyncua: only :mod:`cell.opcua.server` imports
this module.

Layout (browse names; node ids are ``ns=<ours>;s=<dotted path>``, e.g.
``s=MotionDeviceSystem.MotionDevices.Robot.Axes.j1.ParameterSet.ActualPosition``)::

    Objects/DeviceSet/MotionDeviceSystem                     OPC 40010 subset
      MotionDevices/Robot                                    the SCARA
        MotionDeviceCategory  Int32 2 (SCARA_ROBOT), Model   String (the robot model)
        Axes/j1..j4
          MotionProfile      Int32 1 ROTARY / 3 LINEAR (AxisMotionProfileEnumeration)
          ParameterSet/ActualPosition  Double, deg (mm for j3)
            EngineeringUnits  EUInformation (UNECE: DD degree, MMT millimetre)
      Controllers/Controller/ParameterSet                    vendor-specific (not 40010)
        State String, FaultCode Int32, FaultText String, CyclesDone Int64,
        ActiveRecipeNumber Int32, ActiveRecipe String, RecalibrationDue Boolean
      Controllers/Controller/ResultManagement                OPC 40001-101 in spirit
        GetLatestResult() -> ResultId, PartId, Status, FinalErrorMm, ... (model.RESULT_FIELDS)
        emits ResultReadyEventType (fields: the same) once per settled cycle

The browse names are the companion specifications'; the type definitions are
BaseObjectType/FolderType and BaseDataVariableType, because the DI and Robotics nodesets
are not loaded (a client finds the nodes by path, not by type). Every variable is
CurrentRead only; a value not known yet (no status message, no station report) has the
status Bad_WaitingForInitialData.
"""
from __future__ import annotations

from asyncua import Server, ua

from cell.opcua.model import AXES, RESULT_FIELDS, CellStatus, Result

NAMESPACE = "urn:cell-controller:opcua"
UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
#: OPC 40010 MotionDeviceCategoryEnumeration: SCARA_ROBOT
SCARA_ROBOT = 2
#: OPC 40010 AxisMotionProfileEnumeration
MOTION_PROFILE = {"OTHER": 0, "ROTARY": 1, "ROTARY_ENDLESS": 2, "LINEAR": 3, "LINEAR_ENDLESS": 4}
_UNITS = {"deg": ("DD", "°", "degree"), "mm": ("MMT", "mm", "millimetre")}
#: (status field, browse name, variant type) of Controller/ParameterSet
STATUS_VARS = (("state", "State", ua.VariantType.String), ("fault_code", "FaultCode", ua.VariantType.Int32),
               ("fault_text", "FaultText", ua.VariantType.String),
               ("cycle_count", "CyclesDone", ua.VariantType.Int64),
               ("recipe_number", "ActiveRecipeNumber", ua.VariantType.Int32),
               ("recipe_name", "ActiveRecipe", ua.VariantType.String),
               ("recalibration_due", "RecalibrationDue", ua.VariantType.Boolean))
WAITING = ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)
_ZERO = {ua.VariantType.Double: 0.0, ua.VariantType.String: "", ua.VariantType.Int32: 0,
         ua.VariantType.Int64: 0, ua.VariantType.Boolean: False}


def _waiting(vtype: ua.VariantType) -> ua.DataValue:
    """A value not known yet: typed, with status Bad_WaitingForInitialData."""
    return ua.DataValue(ua.Variant(_ZERO[vtype], vtype), StatusCode=WAITING)


def eu_information(unit: str) -> ua.EUInformation:
    """OPC 10000-8 EUInformation of ``unit`` (``deg``, ``mm``) from its UNECE common code."""
    code, shown, words = _UNITS[unit]
    unit_id = 0
    for ch in code:
        unit_id = (unit_id << 8) | ord(ch)
    return ua.EUInformation(NamespaceUri=UNECE, UnitId=unit_id, DisplayName=ua.LocalizedText(shown),
                            Description=ua.LocalizedText(words))


class Space:
    """The nodes of one server and the writes that keep them current."""

    def __init__(self, server: Server, idx: int):
        self.server, self.idx = server, idx
        self.axes: list = []             #: ActualPosition nodes, j1..j4
        self.status: dict[str, object] = {}
        self.latest: Result | None = None
        self._shown: CellStatus | None = None
        self._events: list = []

    def _id(self, path: str) -> ua.NodeId:
        return ua.NodeId(path, self.idx)

    async def _object(self, parent, path: str, name: str, folder: bool = False):
        nid, qn = self._id(f"{path}.{name}" if path else name), ua.QualifiedName(name, self.idx)
        return await (parent.add_folder(nid, qn) if folder else parent.add_object(nid, qn))

    async def _variable(self, parent, path: str, name: str, vtype: ua.VariantType, value=None):
        node = await parent.add_variable(self._id(f"{path}.{name}"), ua.QualifiedName(name, self.idx),
                                         ua.Variant(_ZERO[vtype] if value is None else value, vtype), vtype)
        if value is None:
            await self.server.write_attribute_value(node.nodeid, _waiting(vtype))
        return node

    @classmethod
    async def build(cls, server: Server, robot_model: str) -> "Space":
        idx = await server.register_namespace(NAMESPACE)
        self = cls(server, idx)
        objects = server.nodes.objects
        device_set = await objects.add_folder(ua.NodeId("DeviceSet", idx), ua.QualifiedName("DeviceSet", idx))
        p = "MotionDeviceSystem"
        system = await device_set.add_object(self._id(p), ua.QualifiedName(p, idx))
        devices = await self._object(system, p, "MotionDevices", folder=True)
        p += ".MotionDevices"
        robot = await self._object(devices, p, "Robot")
        p += ".Robot"
        await self._variable(robot, p, "MotionDeviceCategory", ua.VariantType.Int32, SCARA_ROBOT)
        await self._variable(robot, p, "Model", ua.VariantType.String, robot_model)
        axes = await self._object(robot, p, "Axes", folder=True)
        for joint, unit, profile in AXES:
            ap = f"{p}.Axes.{joint}"
            axis = await self._object(axes, f"{p}.Axes", joint)
            await self._variable(axis, ap, "MotionProfile", ua.VariantType.Int32, MOTION_PROFILE[profile])
            params = await self._object(axis, ap, "ParameterSet")
            pos = await self._variable(params, f"{ap}.ParameterSet", "ActualPosition", ua.VariantType.Double)
            await pos.add_property(self._id(f"{ap}.ParameterSet.ActualPosition.EngineeringUnits"),
                                   ua.QualifiedName("EngineeringUnits", 0), eu_information(unit),
                                   ua.VariantType.ExtensionObject, ua.NodeId(ua.ObjectIds.EUInformation))
            self.axes.append(pos)
        controllers = await self._object(system, "MotionDeviceSystem", "Controllers", folder=True)
        cp = "MotionDeviceSystem.Controllers.Controller"
        controller = await self._object(controllers, "MotionDeviceSystem.Controllers", "Controller")
        params = await self._object(controller, cp, "ParameterSet")
        for key, name, vtype in STATUS_VARS:
            self.status[key] = await self._variable(params, f"{cp}.ParameterSet", name, vtype)
        results = await self._object(controller, cp, "ResultManagement")
        await results.add_method(self._id(f"{cp}.ResultManagement.GetLatestResult"),
                                 ua.QualifiedName("GetLatestResult", idx), self._get_latest, [],
                                 [_argument(name, vtype, unit) for _, name, vtype, unit in RESULT_FIELDS])
        etype = await server.create_custom_event_type(
            idx, "ResultReadyEventType", ua.ObjectIds.BaseEventType,
            [(name, getattr(ua.VariantType, vtype)) for _, name, vtype, _ in RESULT_FIELDS])
        for emitter in (results, server.nodes.server):      # clients often watch the Server object
            self._events.append(await server.get_event_generator(etype, emitter))
        return self

    # ------------------------------------------------------------------ updates
    async def show_status(self, st: CellStatus) -> None:
        """Write what changed since the last status shown."""
        old = self._shown
        for key, _, vtype in STATUS_VARS:
            value = getattr(st, key)
            if old is None or getattr(old, key) != value:
                await self.server.write_attribute_value(self.status[key].nodeid,
                                                        ua.DataValue(ua.Variant(value, vtype)))
        if old is None or old.joints != st.joints:
            for k, node in enumerate(self.axes):
                dv = ua.DataValue(ua.Variant(st.joints[k], ua.VariantType.Double)) if st.joints is not None \
                    else _waiting(ua.VariantType.Double)
                await self.server.write_attribute_value(node.nodeid, dv)
        self._shown = st

    async def result_ready(self, r: Result) -> None:
        """A cycle settled: it becomes the latest result, and every emitter sends an event."""
        self.latest = r
        for gen in self._events:
            for (_, name, vtype, _), value in zip(RESULT_FIELDS, r.values()):
                setattr(gen.event, name, ua.Variant(value, getattr(ua.VariantType, vtype)))
            gen.event.Severity = 100 if r.status == "done" else 500
            await gen.trigger(message=f"part {r.part_id}: {r.status}"
                                      + (f", fault {r.fault_code}" if r.fault_code else ""))

    async def _get_latest(self, parent):
        """GetLatestResult: the last settled cycle's fields; Bad_NoData before the first."""
        r = self.latest
        if r is None:
            return ua.StatusCode(ua.StatusCodes.BadNoData)
        return [ua.Variant(v, getattr(ua.VariantType, vtype)) for (_, _, vtype, _), v in zip(RESULT_FIELDS, r.values())]


def _argument(name: str, vtype: str, unit: str) -> ua.Argument:
    arg = ua.Argument()
    arg.Name = name
    arg.DataType = ua.NodeId(getattr(ua.ObjectIds, vtype))
    arg.ValueRank = -1
    arg.Description = ua.LocalizedText(f"{name} ({unit})" if unit else name)
    return arg
