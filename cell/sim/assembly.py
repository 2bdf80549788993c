"""The simulated cell: the plant behind simulated CANopen drives and a rendering camera, all
on one simulated clock.

Only the devices are simulated; the controller talks to them exactly as to real ones:

* clock: :class:`cell.sim.clock.VirtualClock` (pure for ``cellctl run --sim``, paced to
  wall time for ``cellctl serve --sim``); the controller gets the same clock;
* joint stations: four CANopen devices (:class:`drivers.stations.sim.SimStationSet`) on the
  virtual wire, driven by the real ``JointStations`` driver, which measures their
  latency on the bus at start-up; each axis reports its position to the plant;
* camera: :class:`drivers.camera.sim.SimCamera` renders the tool's and the part's fiducials
  at their TRUE positions (the plant's effects included) into 8-bit images, taking
  ``frame_time_s`` of clock time per frame;
* calibration: at start-up a circle-grid board is rendered through that camera and
  calibrated with the same code a real cell uses (``cell.vision.calibrate``);
* parts: :class:`PartFeeder` is the conveyor; the PLC (simulated or real) indexes it;
* hand camera: :class:`drivers.camera.sim_hand.SimHandRig`, the camera on the hand that robot
  calibration uses, and the fixture in front of it (``place_fixture``, what the operator
  does before a calibration).
"""
from __future__ import annotations

import itertools
import os
import threading
from dataclasses import dataclass

import numpy as np

from cell.config import CellConfig, SimSection
from cell.kinematics import JOINT_NAMES, Scara
from cell.recipes import Recipe
from cell.sim.clock import VirtualClock
from cell.sim.plant import Plant
from cell.vision.calibration import CircleGridBoard, PlaneCalibration, calibrate
from cell.vision.camera_model import CameraModel
from drivers.camera.sim import Fiducial, Optics, SimCamera
from drivers.camera.sim_hand import SimHandRig
from drivers.stations import JointStations, StationConfig, StationsConfig
from drivers.stations.sim import SimStationSet

_channels = itertools.count()
CAMERA_FRAME_S = 0.02        #: exposure + read-out of one simulated frame, clock seconds
#: the cell's renderer: 2×2 samples per pixel (the vision bench uses 4×4 for its Cramér–Rao
#: comparison; at 2×2 a fiducial's edge is still anti-aliased and its centre unbiased)
CAMERA_OPTICS = Optics(supersample=2)


@dataclass
class Part:
    part_id: int
    xy_mm: np.ndarray
    radius_mm: float


class PartFeeder:
    """The conveyor of the simulated cell: presents one part at a time, placed at its
    recipe's nominal position plus a seeded random offset of up to ``jitter_mm``."""

    def __init__(self, jitter_mm: float, seed: int = 0):
        self.jitter_mm, self.seed = jitter_mm, seed
        self._part: Part | None = None
        self._lock = threading.Lock()

    def present(self, part_id: int, recipe: Recipe) -> Part:
        rng = np.random.default_rng([self.seed, part_id])
        r = self.jitter_mm * np.sqrt(rng.uniform())
        a = rng.uniform(0, 2 * np.pi)
        part = Part(part_id, np.asarray(recipe.part.nominal_xy_mm) + r * np.array([np.cos(a), np.sin(a)]),
                    recipe.part.fiducial_radius_mm)
        with self._lock:
            self._part = part
        return part

    def remove(self) -> None:
        with self._lock:
            self._part = None

    @property
    def part(self) -> Part | None:
        with self._lock:
            return self._part


def stations_config(robot: Scara, channel: str) -> StationsConfig:
    """The four stations on ``channel`` with the robot's joint limits; their latency is
    measured on the bus at start-up (seed 002's λ, ``delays_s: measure``); positions come
    every 20 ms and with every applied set-point."""
    return StationsConfig(interface="virtual", channel=channel, delays_s="measure", tpdo_event_ms=20,
                          stations=tuple(
        StationConfig(joint=j, node_id=i + 1, limits=tuple(robot.g.limits[i]))
        for i, j in enumerate(JOINT_NAMES)))


class SimDevices:
    """Everything below the controller for ``--sim``: clock, plant, stations, camera,
    calibration, conveyor (see the module doc).

    :param clock: the simulated clock to use (default: a new one, paced if ``pace``).
    """

    def __init__(self, config: CellConfig, clock: VirtualClock | None = None, pace: bool = False):
        sim = config.sim or SimSection()
        self.clock = clock or VirtualClock(pace=pace)
        self.plant = Plant.from_yaml(sim.plant)
        self.robot = self.plant.robot
        self.feeder = PartFeeder(sim.part_jitter_mm, sim.seed)
        self.tool_radius_mm = config.vision.tool_radius_mm
        channel = f"cell-sim-{os.getpid()}-{next(_channels)}"
        self.stations_cfg = stations_config(self.robot, channel)
        start = self.plant.drive_positions()
        delays = [sim.station_sigma_s * (i + 1) for i in range(4)]
        self.sim_stations = SimStationSet(self.stations_cfg, delays, start, clock=self.clock,
                                          on_position=self.plant.update_drive)
        self.motion = JointStations.from_config(self.stations_cfg, clock=self.clock)
        centre = tuple(self.plant.config.camera_center_mm)
        self.camera_model = CameraModel.nadir(*sim.camera_px, sim.camera_mm_per_px, centre_mm=centre)
        self._board: CircleGridBoard | None = None
        self.camera = SimCamera(self.camera_model, self.scene, optics=CAMERA_OPTICS, seed=sim.seed,
                                clock=self.clock, frame_time_s=CAMERA_FRAME_S)
        self.hand = SimHandRig(self.plant, self.clock, seed=sim.seed, settle=self.sim_stations.positions,
                               frame_time_s=CAMERA_FRAME_S)
        self._hand_cal: PlaneCalibration | None = None

    def scene(self) -> list:
        """What lies on the work plane now: the part (under the tool if it is there) and the tool."""
        if self._board is not None:
            return [self._board]
        self.sim_stations.positions()              # bring the plant's drive state up to now
        tool = self.plant.true_tool_xy(self.clock.now())
        items = [Fiducial(*tool, self.tool_radius_mm, "tool")]
        part = self.feeder.part
        # the tool hides the part below it (the renderer adds overlapping marks, a camera
        # looking down sees only the top one)
        if part is not None and np.hypot(*(part.xy_mm - tool)) > part.radius_mm + self.tool_radius_mm:
            items.insert(0, Fiducial(*part.xy_mm, part.radius_mm, "part"))
        return items

    def start(self) -> None:
        """Power the drives, start the controller's side of the stations, open the camera
        (call from a thread that keeps the clock's time, e.g. inside ``clock.attach()``)."""
        self.sim_stations.start()
        self.motion.start()
        self.camera.open()

    def calibration(self) -> PlaneCalibration:
        """Render a circle-grid board on the work plane and calibrate from it (the same call a
        real cell makes with a real board)."""
        cx, cy = self.plant.config.camera_center_mm
        board = CircleGridBoard(cols=11, rows=7, pitch_mm=4.0, radius_mm=1.0,
                                origin_mm=(cx - 20.0, cy - 12.0), angle_deg=0.0)
        self._board = board
        try:
            views = [(self.camera.grab().image, board)]
        finally:
            self._board = None
        return calibrate(views, distortion=False, u_axis_deg=0.0)

    # ------------------------------------------------------------------ robot calibration
    @property
    def hand_camera(self) -> SimCamera:
        """The camera on the hand (opened on first use)."""
        from drivers.camera.base import CameraState
        if self.hand.camera.state is not CameraState.OPEN:
            self.hand.camera.open()
        return self.hand.camera

    def hand_calibration(self) -> PlaneCalibration:
        """The hand camera's plane calibration (hand frame), rendered and made once."""
        if self._hand_cal is None:
            self._hand_cal = self.hand.calibration()
        return self._hand_cal

    def place_fixture(self, kind: str, joint: str | None = None) -> None:
        """Lay the calibration fixture (``joint`` target for ``joint``, ``board``, ``none``);
        a calibration needs the work area clear, so the conveyor's part is taken away."""
        self.hand.place(kind, joint)
        if kind != "none":
            self.feeder.remove()

    def stop(self) -> None:
        for step in (self.camera.close, self.hand.camera.close, self.motion.shutdown, self.sim_stations.stop):
            try:
                step()
            except Exception:                      # noqa: BLE001 -- best effort on the way down
                pass
