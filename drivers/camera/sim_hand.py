"""The simulated hand camera: a camera fixed on the robot's hand, looking down at the work
plane, and the calibration fixtures it looks at (seed 004's target, seed 001's board).

The camera's optical axis lies on the tool axis and its image axes turn with the tool, so
it sees the plane from the plant's TRUE tool pose (:meth:`Plant.true_tool_pose`): every
joint and link effect of the plant shows in its images, none is told to the calibration.
A fixture point at ``w`` (base frame, mm) lies at ``h = R(−φ)·(w − p)`` in the *hand
frame* (origin on the tool axis, x along the tool's x axis), with ``(p, φ)`` the true tool
pose; the camera renders the hand frame through a nadir :class:`CameraModel` centred on its
origin, with the same renderer as the cell camera (:mod:`drivers.camera.sim`).

Fixtures (what the operator would put on the plane; :meth:`SimHandRig.place`):

* ``joint`` — one target disc for seed 004, placed under the camera at the all-zero pose
  (a little off the axis, as a person places it; for j4, whose axis is the camera's own,
  ``J4_TARGET_OFFSET_MM`` off it so that it describes a circle);
* ``board`` — the known points of seed 001's board (a :class:`CircleGridBoard` as
  description, its dots rendered as discs), laid at its nominal place plus a placement
  error the calibration is not told (``BOARD_PLACEMENT``).

Only points near the field of view are handed to the renderer, so a board of hundreds of
points costs what one disc costs.
"""
from __future__ import annotations

import math
import numpy as np

from cell.clock import Clock
from cell.errors import ConfigError
from cell.sim.plant import Plant
from cell.vision.calibration import DEFAULT_BOARD, CircleGridBoard, PlaneCalibration, calibrate
from cell.vision.camera_model import CameraModel
from drivers.camera.base import CameraState
from drivers.camera.sim import Fiducial, Optics, SimCamera

HAND_CAMERA_PX = (640, 512)          #: rendered image size of the hand camera
HAND_MM_PER_PX = 0.1                 #: 64 × 51 mm field on the work plane
TARGET_RADIUS_MM = 3.0               #: seed 004's target disc and the board's dots
TARGET_PLACEMENT_MM = (0.8, -0.5)    #: how far off the camera axis a person lays the target
J4_TARGET_OFFSET_MM = (15.0, 0.0)    #: j4 turns the camera about its own axis: target off it
BOARD_PLACEMENT = (1.2, -0.8, 0.01)  #: true placement error (dx mm, dy mm, drz deg) of a board pinned to the base



def rot(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s], [s, c]])


def placed(board: CircleGridBoard, error=BOARD_PLACEMENT) -> np.ndarray:
    """The board's points (N, 2) mm where they truly lie: the nominal points turned by
    ``error[2]`` deg about the board origin and shifted by ``error[:2]`` mm."""
    o = np.asarray(board.origin_mm, dtype=float)
    return (board.points_mm() - o) @ rot(error[2]).T + o + np.asarray(error[:2], dtype=float)


class SimHandRig:
    """The hand camera of a simulated cell and the fixture in front of it.

    :param plant: the plant (true tool pose); ``clock`` the cell's clock;
    :param settle: called before each frame to bring the plant's drive state up to now
        (the stations' position reports), or None.
    """

    def __init__(self, plant: Plant, clock: Clock, *, seed: int = 0, settle=None,
                 board: CircleGridBoard = DEFAULT_BOARD, frame_time_s: float = 0.02):
        self.plant, self.clock, self.board = plant, clock, board
        self._settle = settle
        self.model = CameraModel.nadir(*HAND_CAMERA_PX, HAND_MM_PER_PX, centre_mm=(0.0, 0.0))
        self._points = np.zeros((0, 2))
        self.camera = SimCamera(self.model, self.scene, optics=Optics(supersample=2), seed=seed + 17,
                                clock=clock, frame_time_s=frame_time_s)
        w, h = HAND_CAMERA_PX
        #: radius of the hand frame the renderer needs to be told about (field + a disc)
        self._reach = math.hypot(w, h) * HAND_MM_PER_PX / 2 + 2 * TARGET_RADIUS_MM

    # ------------------------------------------------------------------ fixtures
    def place(self, kind: str, joint: str | None = None) -> None:
        """Lay fixture ``kind`` (``joint`` with its joint name, ``board``, or ``none``) on the
        plane, as the operator does before a calibration. Raises ConfigError for an unknown
        kind or joint."""
        if kind == "none":
            self._points = np.zeros((0, 2))
        elif kind == "board":
            self._points = placed(self.board)
        elif kind == "joint":
            if joint not in ("j1", "j2", "j3", "j4"):
                raise ConfigError(f"fixture for joint {joint!r}: use j1..j4")
            zero = self.plant.robot.fk([0.0, 0.0, 0.0, 0.0])
            off = J4_TARGET_OFFSET_MM if joint == "j4" else TARGET_PLACEMENT_MM
            self._points = (zero[:2] + rot(zero[3]) @ np.asarray(off, dtype=float))[None, :]
        else:
            raise ConfigError(f"unknown calibration fixture {kind!r}; use joint, board or none")

    def scene(self) -> list:
        """The fixture's discs near the field of view, in the hand frame."""
        if self._settle is not None:
            self._settle()
        if not len(self._points):
            return []
        x, y, phi = self.plant.true_tool_pose(self.clock.now())
        h = (self._points - np.array([x, y])) @ rot(phi)       # R(−φ)·(w − p), row-wise
        near = np.hypot(h[:, 0], h[:, 1]) < self._reach
        return [Fiducial(float(u), float(v), TARGET_RADIUS_MM, "target") for u, v in h[near]]

    # ------------------------------------------------------------------ calibration
    def calibration(self) -> PlaneCalibration:
        """The hand camera's plane calibration in the hand frame: a circle-grid board laid
        centred on the tool axis, rendered and calibrated with the cell's own code."""
        grid = CircleGridBoard(cols=11, rows=9, pitch_mm=4.0, radius_mm=1.0,
                               origin_mm=(-20.0, -16.0), angle_deg=0.0)
        saved, scene = self.camera.scene, (lambda: [grid])
        self.camera.scene = scene
        try:
            if self.camera.state is not CameraState.OPEN:
                self.camera.open()
            views = [(self.camera.grab().image, grid)]
        finally:
            self.camera.scene = saved
        return calibrate(views, distortion=False, u_axis_deg=0.0)

