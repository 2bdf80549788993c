"""Assembles a running cell from its config: devices (real or simulated), cycle log, recipe
store, cycle runner, controller and background jobs. ``cellctl serve`` and ``cellctl run``
use :class:`Cell`; so do the system tests.
"""
from __future__ import annotations

import json
from pathlib import Path

from cell import log as cell_log
from cell.clock import MonotonicClock
from cell.config import CellConfig, SimSection
from cell.controller import CellController, ControllerSettings
from cell.cycle import CycleRunner, CycleSettings, OffsetMemory
from cell.cyclelog import CycleLog
from cell.errors import ConfigError
from cell.jobs import CellJobs
from cell.measure import MeasuringCamera
from cell.recipes import RecipeStore
from cell.statemachine import StateMachine
from cell.vision.calibration import PlaneCalibration
from drivers.plc import open_link

log = cell_log.get_logger("app")


class Cell:
    """One cell: ``start()`` brings everything up (PLC link last, so a PLC never talks to a
    half-built controller); ``stop()`` takes it down in reverse order."""

    def __init__(self, config: CellConfig, sim: bool = False, plc_port: int | None = None,
                 jobs: bool = True):
        self.config = config
        self.sim = None
        if sim:
            if config.sim is None:
                config = config.model_copy(update={"sim": SimSection()})
                self.config = config
            from cell.sim import SimDevices
            self.sim = SimDevices(config, config.vision.tool_radius_mm)
            self.clock, self.robot, self.motion = self.sim.clock, self.sim.robot, self.sim.motion
            self.camera = self.sim.camera
        else:
            from drivers import camera as cameras
            from drivers.stations import JointStations
            self.clock = MonotonicClock()
            self.robot = config.robot.scara()
            self.motion = JointStations.from_config(config.stations, clock=self.clock)
            self.camera = cameras.from_config(config.camera)
        self.plc = open_link(config.plc.backend, clock=self.clock)
        self.plc_port = config.plc.port if plc_port is None else plc_port
        self.cyclelog = CycleLog(config.log.path)
        self.recipes = RecipeStore(config.recipes.directory)
        self.with_jobs = jobs
        self.controller: CellController | None = None
        self.jobs: CellJobs | None = None

    def _calibration(self) -> PlaneCalibration:
        if self.sim is not None:
            cal = self.sim.calibrate_camera()
            log.info("sim_camera_calibrated", rms_px=round(cal.rms_px, 4), rms_mm=round(cal.rms_mm, 5))
            return cal
        path = Path(self.config.vision.calibration)
        try:
            return PlaneCalibration.from_dict(json.loads(path.read_text(encoding="utf-8")))
        except FileNotFoundError:
            raise ConfigError(f"{path}: camera calibration not found (vision.calibration)") from None
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}, line {exc.lineno}: not valid JSON: {exc.msg}") from None

    def start(self) -> int:
        """Start devices, controller and jobs; returns the PLC link's TCP port."""
        if self.sim is not None:
            self.sim.start()
        else:
            self.motion.start()
            self.camera.open()
        camera = MeasuringCamera(self.camera, self._calibration(), self.config.vision.tool_radius_mm,
                                 self.config.vision.radius_tolerance)
        c = self.config.cycle
        sm = StateMachine()
        runner = CycleRunner(self.robot, self.motion, camera, self.cyclelog, sm,
                             CycleSettings(c.move_timeout_s, c.reach_tol_deg, c.tool_phi_deg,
                                           self.config.robot.elbow),
                             OffsetMemory.from_log(self.cyclelog, self.robot, self.config.robot.elbow))
        settings = ControllerSettings(self.config.controller.scan_s, self.config.plc.heartbeat_timeout_s,
                                      self.config.controller.recipe_refresh_s)
        self.controller = CellController(self.plc, self.motion, runner, self.cyclelog, self.recipes,
                                         settings, clock=self.clock)
        self.controller.start()
        port = self.plc.start(self.config.plc.host, self.plc_port)
        if self.with_jobs:
            self.jobs = CellJobs(self.controller, self.config.scheduler, self.config.log.retention_days)
            self.jobs.start()
        log.info("cell_started", name=self.config.name, sim=self.sim is not None, plc_port=port)
        return port

    def stop(self) -> None:
        for step in (lambda: self.jobs and self.jobs.stop(), self.plc.stop,
                     lambda: self.controller and self.controller.stop()):
            try:
                step()
            except Exception as exc:               # noqa: BLE001 -- keep going down
                log.error("stop_step_failed", error=repr(exc))
        if self.sim is not None:
            self.sim.stop()
        else:
            for step in (self.camera.close, self.motion.shutdown):
                try:
                    step()
                except Exception as exc:           # noqa: BLE001
                    log.error("stop_step_failed", error=repr(exc))
        self.cyclelog.close()
