"""Assembles a running cell from its config: devices (by name, :mod:`cell.devices`), cycle
log, robot calibration, recipe store, cycle runner, controller and background jobs.
``cellctl serve`` and ``cellctl run`` use :class:`Cell`; so do the system tests.

The robot the cycles plan with is the nominal one, or — if ``calibration.file`` exists —
the calibrated one (:mod:`cell.calibration.calfile`; a corrupt file or another robot's
refuses the start). A kinematic calibration the PLC starts is applied when it is written:
the runner plans with it from the next cycle and the learned offsets start afresh.
"""
from __future__ import annotations

from cell import log as cell_log
from cell.calibration.service import CellCalibrator, load_active
from cell.clock import Clock, MonotonicClock
from cell.config import CellConfig
from cell.controller import CellController, ControllerSettings
from cell.cycle.runner import CycleRunner, CycleSettings, OffsetMemory
from cell.cyclelog import CycleLog
from cell.devices import Devices, open_devices
from cell.jobs import CellJobs
from cell.publish import Publisher
from cell.recipes import all_checks, motion_check_from_config, reach_check
from cell.recipes.store import RecipeStore
from cell.vision.measure import MeasuringCamera
from drivers.plc import open_link

log = cell_log.get_logger("app")


class Cell:
    """One cell: ``start()`` brings everything up (PLC link last, so a PLC never talks to a
    half-built controller); ``stop()`` takes it down in reverse order.

    :param devices: device backend name (``hardware`` or ``sim``, see :mod:`cell.devices`).
    :param pace: simulated devices only: keep the simulated clock to wall time.
    :param clock: run on this clock instead of the devices' own (tests).
    :param file_clock: the clock recipe edits settle on (default: wall time; tests).
    :param fresh_log: start an empty cycle log, keeping the one there under a time-stamped
        name once this cell holds the log's lock (``run --sim``: a cell from power-on).
    """

    def __init__(self, config: CellConfig, devices: str = "hardware", plc_port: int | None = None,
                 jobs: bool = True, pace: bool = False, clock: Clock | None = None,
                 file_clock: Clock | None = None, fresh_log: bool = False):
        self.config = config
        # certificates before anything is opened: a bad one names its field and stops here
        tls = config.plc.tls.listener() if config.plc.tls.enabled else None
        # the log first: a log that cannot be used (damaged, read-only, in use by another
        # controller) refuses the start before any device is touched
        self.cyclelog = CycleLog(config.log.path, fresh=fresh_log)
        try:
            self.devices: Devices = open_devices(config, devices, clock=clock, pace=pace)
        except BaseException:
            self.cyclelog.close()
            raise
        self.clock = self.devices.clock
        self._own_clock = clock is None
        self.motion, self.camera = self.devices.motion, self.devices.camera
        try:
            self.robot, caldoc = load_active(config, self.devices.robot)
        except BaseException:
            self.devices.stop()
            self._close_own_clock()
            self.cyclelog.close()
            raise
        self.calibrator = CellCalibrator(config, self.devices, self.devices.robot,
                                         version=int(caldoc["version"]) if caldoc else 0,
                                         on_applied=self._use_calibration, robot=self.robot)
        self.runner: CycleRunner | None = None
        self.plc = open_link(config.plc.backend, clock=self.clock, access=config.plc.access_policy(),
                             heartbeat_timeout_s=config.plc.heartbeat_timeout_s, tls=tls,
                             plain=config.plc.plain_tcp)
        self.plc_port = config.plc.port if plc_port is None else plc_port
        #: settled cycles, status changes and events for the plant (OPC UA, MQTT, the HMI):
        #: subscribe before or after start (:mod:`cell.publish`)
        self.publisher = Publisher()
        #: the plant outbox (``plant`` section; None without it): :attr:`~cell.plant.outbox.PlantOutbox.backlog`;
        #: made here so its subscription to the publisher has the events of the start-up too
        self.outbox = None
        if config.plant is not None:
            from cell.plant.outbox import PlantOutbox
            self.outbox = PlantOutbox(config.log.path, config.plant.outbox_settings(config.name),
                                      publisher=self.publisher)
        r = config.recipes
        self.recipes = RecipeStore(r.directory, commit=self._commit_recipe_changes,
                                   max_bytes=r.max_bytes, settle_s=r.settle_s,
                                   clock=file_clock or MonotonicClock(), allow_examples=r.allow_examples)
        # ^ wall time, not the cell's: editors write files in wall time. On a simulated clock
        # that runs ahead (run --sim), settle_s of *simulated* time passed in milliseconds and a
        # file left half-written for a moment was taken as complete
        self.with_jobs = jobs
        self.controller: CellController | None = None
        self.jobs: CellJobs | None = None
        #: the read-only OPC UA server (``opcua`` section), started by :meth:`start`
        self.opcua = None
        self._insecure_opcua = devices == "sim"      # no security, anonymous: simulated cells only
        self.measuring_camera: MeasuringCamera | None = None

    def start(self) -> int:
        """Start devices, controller and jobs; returns the PLC link's TCP port."""
        if self.config.opcua is not None:
            self._start_opcua()
        with self.clock.attach():
            self.devices.start()
            v = self.config.vision
            camera = MeasuringCamera(self.camera, self.devices.calibration(), v.tool_radius_mm,
                                     v.radius_tolerance, v.grab_timeout_s, clock=self.clock,
                                     window_mm=v.window_mm)
            self.measuring_camera = camera
            self.calibrator.measuring_camera = camera
            # recipes are checked against these stations: SYNC support, and the segment time
            # against each station's delay (longest frames on the wire + measured latency)
            # and against the robot: every position a cycle goes to must be reachable
            motion, _ = motion_check_from_config(self.motion.cfg, self.motion.latency_s)
            self.recipes.check = all_checks(motion, reach_check(self.robot, self.config.robot.elbow))
            c = self.config.cycle
            runner = self.runner = CycleRunner(self.robot, self.motion, camera, self.cyclelog,
                                 CycleSettings(c.move_timeout_s, c.reach_tol_deg, c.tool_phi_deg,
                                               self.config.robot.elbow),
                                 OffsetMemory.from_log(self.cyclelog, self.robot),
                                 clock=self.clock)
            settings = ControllerSettings(self.config.controller.scan_s, self.config.plc.heartbeat_timeout_s,
                                          self.config.controller.recipe_refresh_s)
            self.controller = CellController(self.plc, self.motion, runner, self.cyclelog, self.recipes,
                                             settings, clock=self.clock, calibrator=self.calibrator,
                                             publisher=self.publisher)
            self.controller.start()
            port = self.plc.start(self.config.plc.host, self.plc_port)
            if self.outbox is not None:
                # a thread of its own on wall time, reading the log read-only: never the scan's time
                self.outbox.start()
                self.controller.plant_backlog = lambda: self.outbox.backlog
            if self.with_jobs:
                self.jobs = CellJobs(self.controller, self.config.scheduler, self.config.log.retention_days,
                                     clock=self.clock, outbox=self.outbox)
                self.jobs.start()
        log.info("cell_started", name=self.config.name, devices=type(self.devices).__name__, plc_port=port,
                 calibration=getattr(self.robot, "calibration", "") or "nominal")
        return port

    def _start_opcua(self) -> None:
        """The OPC UA server first: a port taken or an unusable ``opcua.pki`` refuses the start
        before any device moves. It subscribes to the publisher here, so it sees the
        controller's first status; it runs on wall time in its own thread, never on the scan."""
        from cell.opcua.server import OpcuaServer
        robot = self.config.robot.preset or "geometry"
        self.opcua = OpcuaServer(self.config.opcua, self.publisher, self.config.name,
                                 f"SCARA {robot} ({getattr(self.robot, 'calibration', '') or 'nominal'})",
                                 insecure=self._insecure_opcua)
        self.opcua.start()

    def _use_calibration(self, robot, doc: dict) -> None:
        """A kinematic calibration was written: plan the next cycles with it, learn afresh
        (the offsets learned so far referred to the old model). Runs in the calibration
        task, while no cycle can run."""
        self.robot = robot
        if self.runner is not None:
            self.runner.robot = self.runner.mover.robot = robot
            self.runner.memory = OffsetMemory(n=self.runner.memory.n)
        # the tamper-evident trail: which calibration the cell moves with from now on
        self.cyclelog.audit("plc", "calibration_write", str(self.calibrator.path),
                            str(doc.get("sha256", "")), f"applied {robot.calibration}")
        log.info("robot_calibration_applied", calibration=robot.calibration)
        self.publisher.event(self.clock.now(), "calibration_applied", {
            "calibration": str(robot.calibration), "path": str(self.calibrator.path),
            "sha256": str(doc.get("sha256", ""))})

    def _commit_recipe_changes(self, changes) -> None:
        """The recipe store's commit: the log's audit first (it raises: nothing applied, nothing
        said), then one ``recipe_changed`` event per change for the plant."""
        self.cyclelog.record_recipe_changes(changes)
        now = self.clock.now()
        for who, action, target, hash_, result, _version in changes:
            # the audit's action is recipe_<what the store did>
            self.publisher.event(now, "recipe_changed", {"action": str(action).removeprefix("recipe_"),
                                                         "target": str(target),
                                                         "hash": str(hash_ or ""), "result": str(result or ""),
                                                         "who": str(who or "")})

    def stop(self) -> None:
        with self.clock.attach():
            if self.controller is not None:
                self.controller.detach_plc()            # before the link goes: rows stay unsettled
            for step in (lambda: self.opcua and self.opcua.stop(),
                         lambda: self.jobs and self.jobs.stop(), lambda: self.outbox and self.outbox.stop(),
                         self.plc.stop,
                         lambda: self.controller and self.controller.stop(),
                         lambda: self.measuring_camera and self.measuring_camera.close(), self.devices.stop):
                try:
                    step()
                except Exception as exc:               # noqa: BLE001 -- keep going down
                    log.error("stop_step_failed", error=repr(exc))
        self.cyclelog.close()
        self._close_own_clock()

    def _close_own_clock(self) -> None:
        """Close the devices' clock if this cell made it (a clock handed in stays open)."""
        close = getattr(self.clock, "close", None)
        if close is not None and self._own_clock:
            close()
