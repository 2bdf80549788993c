"""The devices a cell runs with, chosen by name in one registry.

* ``hardware`` — the joint stations, camera and camera calibration the cell config
  names (``stations``, ``camera``, ``vision.calibration``), on wall time.
* ``sim`` — the simulated cell (:mod:`cell.sim.assembly`): the plant behind simulated
  CANopen drives on the virtual wire and a rendering camera, on the simulated clock.

Backends are imported only when chosen, so the hardware path never loads a simulation
module. Every backend gives the same :class:`Devices` face to :class:`cell.app.Cell`.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from cell.clock import Clock, MonotonicClock
from cell.config import CellConfig
from cell.errors import ConfigError
from cell.kinematics import Scara
from cell.vision.calibration import PlaneCalibration
from drivers import registry

if TYPE_CHECKING:
    from cell.motion.mover import JointMotion
    from drivers.camera.base import Camera

#: backend name → "module:class" (:mod:`drivers.registry`), imported only when chosen
BACKENDS: dict[str, str] = {
    "hardware": "cell.devices:HardwareDevices",
    "sim": "cell.sim.assembly:SimDevices",
}


@runtime_checkable
class Devices(Protocol):
    """What a cell needs below the controller; :class:`HardwareDevices` and the simulated
    cell (``cell.sim.assembly.SimDevices``) both give it."""

    clock: Clock          #: the clock everything in the cell takes its time from
    robot: Scara          #: the nominal robot model
    motion: JointMotion   #: the joint stations (``drivers.stations.JointStations``)
    camera: Camera        #: the camera over the work plane (``drivers.camera.base.Camera``)

    def start(self) -> None:
        """Bring the devices up (stations enabled, camera open)."""
        ...

    def calibration(self) -> PlaneCalibration:
        """The camera's plane calibration (from file, or measured by the backend)."""
        ...

    def stop(self) -> None:
        """Take the devices down; never raises."""
        ...

    # ---- robot calibration (cell.calibration.service)
    @property
    def hand_camera(self) -> Camera | None:
        """The camera on the robot's hand, opened on first use; None if the cell has none."""
        ...

    def hand_calibration(self) -> PlaneCalibration:
        """The hand camera's plane calibration."""
        ...

    def place_fixture(self, kind: str, joint: str | None = None) -> None:
        """Lay the calibration fixture for ``kind`` (``"kinematics"`` or ``"joint"`` of
        ``joint``): the simulated cell places it; on hardware the operator has, and this
        does nothing."""
        ...


class HardwareDevices:
    """The devices the config names, on wall time (or on ``clock`` if given)."""

    def __init__(self, config: CellConfig, clock: Clock | None = None, pace: bool = False):
        from drivers import camera as cameras
        from drivers.stations import JointStations
        self.config = config
        self.clock = clock or MonotonicClock()
        self.robot = config.robot.scara()
        self.motion = JointStations.from_config(config.stations, clock=self.clock)
        self.camera = cameras.from_config({**config.camera, "clock": self.clock})
        self._hand_camera = None

    def start(self) -> None:
        self.motion.start()
        self.camera.open()

    def calibration(self) -> PlaneCalibration:
        return _plane_calibration(self.config.vision.calibration, "camera calibration",
                                  "vision.calibration")

    @property
    def hand_camera(self):
        """The hand camera of ``calibration.hand_camera`` (opened on first use), or None."""
        spec = self.config.calibration.hand_camera
        if spec is None:
            return None
        if self._hand_camera is None:
            from drivers import camera as cameras
            cam = cameras.from_config({**spec, "clock": self.clock})
            cam.open()
            self._hand_camera = cam
        return self._hand_camera

    def hand_calibration(self) -> PlaneCalibration:
        return _plane_calibration(self.config.calibration.hand_calibration, "hand camera calibration",
                                  "calibration.hand_calibration")

    def place_fixture(self, kind: str, joint: str | None = None) -> None:
        """On hardware the operator lays the fixture; nothing to do."""

    def stop(self) -> None:
        cams = [self._hand_camera.close] if self._hand_camera is not None else []
        for step in (self.camera.close, *cams, self.motion.shutdown):
            try:
                step()
            except Exception:                    # noqa: BLE001 -- best effort on the way down
                pass


def _plane_calibration(path, what: str, key: str) -> PlaneCalibration:
    """A plane calibration file; ConfigError naming the file (and line) if missing or not JSON."""
    path = Path(path)
    try:
        return PlaneCalibration.from_dict(json.loads(path.read_text(encoding="utf-8")))
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found ({key})") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}, line {exc.lineno}: not valid JSON: {exc.msg}") from None


def open_devices(config: CellConfig, name: str, *, clock: Clock | None = None, pace: bool = False) -> Devices:
    """Build (not start) the devices of backend ``name`` for ``config``.

    :param clock: use this clock instead of the backend's own (tests).
    :param pace: simulated devices only: keep the simulated clock to wall time (a cell
        serving an outside PLC).
    :raises ConfigError: unknown backend name, or a bad config value.
    """
    return registry.load(BACKENDS, name, "devices")(config, clock=clock, pace=pace)
