"""``PlantArm``: the plant as a compensation :class:`~cell.compensation.base.Arm`, without
CAN or camera in between (benchmarks, fast tests)."""
from __future__ import annotations

import numpy as np

from cell.clock import Clock
from cell.errors import KinematicsError
from cell.kinematics import Scara
from cell.sim.plant.core import Plant


class PlantArm:
    """Moves the plant's θ1, θ2 and measures it, taking simulated time through ``clock``.

    ``robot`` is the nominal model that turns command units into degrees and checks the
    joint limits (default: the plant's nominal robot). Both joints start together and move
    at ``joint_speed_deg_s``; the move lasts max|Δθ| / speed seconds of ``clock`` time.
    """

    def __init__(self, plant: Plant, clock: Clock, robot: Scara | None = None):
        self.plant = plant
        self.clock = clock
        self.robot = robot if robot is not None else plant.robot
        self.moves = 0
        self.true_point = plant.true_tool_xy(clock.now())

    def move_and_measure(self, command_units: np.ndarray, via_units=None) -> np.ndarray:
        """Move θ1, θ2 to ``command_units`` (2 whole command units; through ``via_units``
        first if given), wait for the motion on the clock, update the plant's drive state
        and return the measured (x_mm, y_mm) (truth with a fresh repeatability draw,
        through the camera effects, plus measurement noise). Raises KinematicsError for a
        command that is not 2 whole numbers or is outside the joint limits; nothing moves
        then."""
        stops = [self._checked(via_units)] if via_units is not None else []
        stops.append(self._checked(command_units))
        for q in stops:
            start = self.plant.drive_positions()[:2]
            self.clock.sleep(float(np.max(np.abs(q - start))) / self.plant.config.joint_speed_deg_s)
            t = self.clock.now()
            for i in (0, 1):
                self.plant.update_drive(i, float(q[i]), t)
        self.moves += 1
        self.true_point = self.plant.true_tool_xy(t)
        return self.plant.measured_xy(t)

    def _checked(self, command_units) -> np.ndarray:
        """θ1, θ2 (deg) of a command, or KinematicsError if it is not 2 whole numbers inside
        the joint limits."""
        u = np.asarray(command_units)
        if u.shape != (2,) or not np.all(np.isfinite(u.astype(float))) \
                or not np.all(u.astype(float) == np.round(u.astype(float))):
            raise KinematicsError(f"command_units = {command_units!r} must be 2 whole numbers "
                                  "(θ1, θ2 command units)")
        q = self.robot.from_units(u.astype(np.int64))
        self.robot.check_limits(q, joints=(0, 1))
        return q
