"""Simulated arms for compensation runs: the nominal model, and one whose true geometry differs.

These are the "robot + measurer" stand-ins tests and benchmarks use. The whole cell uses
the plant (``cell.sim.plant``) behind the CAN stations and the camera instead.
"""
from __future__ import annotations

import numpy as np

from cell.kinematics import Scara


class NominalArm:
    """The nominal model itself: measured point = forward kinematics of the command (seed 000's
    simulation set-up). Optional Gaussian repeatability and measurement noise (σ in mm)."""

    def __init__(self, robot: Scara, repeat_sigma_mm: float = 0.0, meas_sigma_mm: float = 0.0,
                 rng: np.random.Generator | None = None):
        self.robot = robot
        self.repeat_sigma_mm = repeat_sigma_mm
        self.meas_sigma_mm = meas_sigma_mm
        self.rng = rng or np.random.default_rng(0)
        self.moves = 0
        self.true_point = np.zeros(2)

    def true_position(self, command_units: np.ndarray) -> np.ndarray:
        q = self.robot.from_units(command_units)
        return self.robot.fk_planar(q[0], q[1])

    def move_and_measure(self, command_units: np.ndarray, via_units=None) -> np.ndarray:
        """See :class:`~cell.compensation.base.Arm`; this arm has no backlash, so a via
        point changes nothing but is checked against the limits like the command."""
        if via_units is not None:
            self.robot.check_limits(self.robot.from_units(via_units), joints=(0, 1))
        q = self.robot.from_units(command_units)
        self.robot.check_limits(q, joints=(0, 1))
        self.moves += 1
        p = self.true_position(command_units)
        if self.repeat_sigma_mm:
            p = p + self.rng.normal(0.0, self.repeat_sigma_mm, 2)
        self.true_point = p
        if self.meas_sigma_mm:
            return p + self.rng.normal(0.0, self.meas_sigma_mm, 2)
        return p.copy()


class PerturbedArm(NominalArm):
    """An arm whose true link lengths and joint zeros differ from the nominal model.

    ``dl_mm`` = (Δl1, Δl2) added to the nominal link lengths; ``offset_deg`` = (Δθ1, Δθ2)
    added to every commanded angle. The commanded lattice stays the nominal one.
    """

    def __init__(self, robot: Scara, dl_mm=(0.0, 0.0), offset_deg=(0.0, 0.0), **noise):
        super().__init__(robot, **noise)
        self.true_robot = Scara(robot.g.model_copy(update={
            "l1_mm": robot.g.l1_mm + dl_mm[0], "l2_mm": robot.g.l2_mm + dl_mm[1]}))
        self.offset_deg = np.asarray(offset_deg, dtype=float)

    @classmethod
    def random(cls, robot: Scara, rng: np.random.Generator, dl_mm: float = 0.5,
               offset_deg: float = 0.05, **noise) -> "PerturbedArm":
        """Link lengths ±``dl_mm`` and joint zeros ±``offset_deg``, uniform."""
        return cls(robot, dl_mm=rng.uniform(-dl_mm, dl_mm, 2),
                   offset_deg=rng.uniform(-offset_deg, offset_deg, 2), rng=rng, **noise)

    def true_position(self, command_units: np.ndarray) -> np.ndarray:
        q = self.robot.from_units(command_units) + self.offset_deg
        return self.true_robot.fk_planar(q[0], q[1])
