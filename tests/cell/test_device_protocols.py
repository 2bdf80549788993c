"""The device interfaces are typed (``typing.Protocol``) and the real and simulated devices
give the same ones: the controller calls ``plc.owner``, ``plc.take_refusals()`` and
``motion.fault`` directly, no ``getattr`` fallbacks."""
from __future__ import annotations

import inspect

from cell.config import CellConfig, SimSection
from cell.devices import Devices, HardwareDevices, open_devices
from cell.motion.mover import JointMotion
from drivers.camera.base import Camera
from drivers.plc import PlcPort
from drivers.plc.server import PlcLink
from drivers.stations import JointStations


def _members(protocol) -> set[str]:
    """A protocol's methods and properties (data members aside), its bases' included."""
    out = set()
    for klass in protocol.__mro__:
        if klass is object or not getattr(klass, "_is_protocol", False):
            continue
        out |= {n for n, v in vars(klass).items()
                if not n.startswith("_") and (inspect.isfunction(v) or isinstance(v, property))}
    return out


def test_the_simulated_cell_gives_every_device_interface(tmp_path):
    cfg = CellConfig(sim=SimSection()).model_copy(update={"log": CellConfig().log.model_copy(
        update={"path": str(tmp_path / "x.sqlite")})}).with_paths()
    devices = open_devices(cfg, "sim")
    try:
        assert isinstance(devices, Devices)
        assert isinstance(devices.motion, JointMotion) and isinstance(devices.motion, JointStations)
        assert isinstance(devices.camera, Camera)
        assert isinstance(devices.hand_camera, Camera)
    finally:
        devices.stop()
        getattr(devices.clock, "close", lambda: None)()


def test_the_hardware_devices_and_the_driver_classes_define_every_member():
    assert _members(Devices) - {"start", "stop", "calibration", "hand_camera", "hand_calibration",
                                "place_fixture"} == set()
    missing = {n for n in _members(Devices) if not hasattr(HardwareDevices, n)}
    assert not missing, f"HardwareDevices lacks {missing}"
    missing = {n for n in _members(JointMotion) if not hasattr(JointStations, n)}
    assert not missing, f"JointStations lacks {missing}"
    assert {"owner", "take_refusals", "drain_writes"} <= _members(PlcPort)
    assert isinstance(PlcLink(), PlcPort)


def test_the_hardware_devices_set_every_data_member_without_touching_hardware():
    """The protocol's data members (clock, robot, motion, camera, and whatever a new device
    adds) are instance attributes, which the class-level check above cannot see: build the
    devices of the shipped hardware config, which must not touch hardware in __init__, and
    ask the instance."""
    from pathlib import Path

    from cell.commands.run import load_config
    cfg = load_config(str(Path(__file__).resolve().parents[2] / "deploy" / "cell.yaml"), False)
    devices = HardwareDevices(cfg)
    data = set(Devices.__annotations__)
    assert {"clock", "robot", "motion", "camera"} <= data
    missing = {n for n in data if not hasattr(devices, n)}
    assert not missing, f"HardwareDevices instances lack {missing}"
    assert isinstance(devices.motion, JointMotion) and isinstance(devices.camera, Camera)


def test_every_registry_names_an_unknown_backend_and_the_known_ones():
    import pytest

    from cell.errors import ConfigError
    from drivers import camera
    from drivers.plc import open_link
    from drivers.stations.bus import open_bus
    with pytest.raises(ConfigError, match=r"devices: unknown backend 'gazebo' \(known: hardware, sim\)"):
        open_devices(CellConfig(sim=SimSection()), "gazebo")
    with pytest.raises(ConfigError, match=r"plc.backend: unknown backend 'profinet' \(known: modbus_tcp\)"):
        open_link("profinet")
    with pytest.raises(ConfigError, match=r"camera.backend: unknown backend 'gige'"):
        camera.create("gige")
    with pytest.raises(ConfigError, match="'nosuchcan' is not a known CAN interface"):
        open_bus("nosuchcan", "x")
