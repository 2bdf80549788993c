"""What every compensation method shares: the robot-and-measurer it drives, and the trace it returns.

A compensation method never talks to hardware directly. It drives an :class:`Arm`: move to
a joint command (θ1, θ2 in whole command units) and return the measured tool centre
(x_mm, y_mm). The cell passes an arm made of the CAN stations plus the camera; tests and
benchmarks pass :class:`~cell.compensation.arms.NominalArm` or a perturbed simulated arm.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


class Arm(Protocol):
    """A robot plus a measurer of its tool centre in the robot base frame."""

    def move_and_measure(self, command_units: np.ndarray, via_units=None) -> np.ndarray:
        """Move θ1, θ2 to ``command_units`` (ints, one command unit each) and return the
        measured (x_mm, y_mm). With ``via_units``, pass through that command first, without
        stopping to measure: how an arrival takes up backlash from a chosen side.
        Raises :class:`~cell.errors.MeasurementError` if no measurement could be taken,
        :class:`~cell.errors.KinematicsError` if a command is outside the joint limits."""
        ...


@dataclass(frozen=True)
class Step:
    """One decision of a compensation run: the command it chose and what was measured there.

    ``moved`` is False when the method chose to stay where it was (the measured point is
    then the previous one and no motion happened). ``spacing_units`` is the grid spacing k
    the decision was made with (0 for the first arrival and for methods without a grid).
    ``via_units`` is the command the arrival passed through first to take up backlash from
    the approach side (None: straight there).
    """

    command_units: tuple[int, int]
    joints_deg: tuple[float, float]
    point_mm: tuple[float, float]
    error_mm: float
    moved: bool
    spacing_units: int = 0
    note: str = ""
    via_units: tuple[int, int] | None = None

    @classmethod
    def at(cls, command, unit_deg, point, target, *, moved: bool = True, spacing: int = 0,
           note: str = "", via=None) -> "Step":
        """The step at whole-unit ``command`` (units of ``unit_deg`` per joint) whose
        measurement ``point`` lies ``error_mm`` from ``target``."""
        joints = np.asarray(command, dtype=np.int64) * np.asarray(unit_deg, dtype=float)
        return cls(command_units=(int(command[0]), int(command[1])),
                   joints_deg=(round(float(joints[0]), 9), round(float(joints[1]), 9)),
                   point_mm=(float(point[0]), float(point[1])),
                   error_mm=float(np.hypot(*(np.asarray(point) - np.asarray(target)))),
                   moved=moved, spacing_units=spacing, note=note,
                   via_units=None if via is None else (int(via[0]), int(via[1])))

    def as_dict(self) -> dict:
        out = {"joints_deg": list(self.joints_deg), "point_mm": list(self.point_mm),
               "error_mm": self.error_mm, "moved": self.moved,
               "spacing_units": self.spacing_units, "note": self.note}
        if self.via_units is not None:
            out["via_units"] = list(self.via_units)
        return out


@dataclass
class CompensationResult:
    """Full trace of one compensation run.

    ``moves`` counts arrivals (each one measured) including the first; a via point an arrival
    passes through on its way is part of that arrival. ``final_error_mm`` is the
    measured distance between the last point and the target (what the camera saw, which on
    a real cell includes measurement noise).
    """

    method: str
    target_mm: tuple[float, float]
    steps: list[Step] = field(default_factory=list)

    @property
    def moves(self) -> int:
        return sum(1 for s in self.steps if s.moved)

    @property
    def final(self) -> Step:
        return self.steps[-1]

    @property
    def final_error_mm(self) -> float:
        return self.steps[-1].error_mm

    @property
    def initial_error_mm(self) -> float:
        return self.steps[0].error_mm

    def as_dict(self) -> dict:
        """The JSON form printed by ``cellctl compensate --json``."""
        return {"method": self.method, "target_mm": list(self.target_mm),
                "steps": [s.as_dict() for s in self.steps],
                "final_error_mm": self.final_error_mm, "moves": self.moves}


class Recorder:
    """Builds a :class:`CompensationResult` while a method drives the arm (shared bookkeeping)."""

    def __init__(self, method: str, arm: Arm, target: np.ndarray, unit_deg: np.ndarray):
        self.arm = arm
        self.target = np.asarray(target, dtype=float)
        self.unit_deg = np.asarray(unit_deg, dtype=float)
        self.result = CompensationResult(method, (float(target[0]), float(target[1])))
        self.command: np.ndarray | None = None
        self.point: np.ndarray | None = None

    def move(self, command_units, spacing: int = 0, note: str = "", via=None) -> np.ndarray:
        """Move to ``command_units`` (through ``via`` first, if given), measure, record the
        step; return the measured point."""
        cmd = np.asarray(command_units, dtype=np.int64)
        via = None if via is None else np.asarray(via, dtype=np.int64)
        self.point = np.asarray(self.arm.move_and_measure(cmd, via_units=via), dtype=float)
        self.command = cmd
        self._record(True, spacing, note, via)
        return self.point

    def stay(self, spacing: int = 0, note: str = "") -> None:
        """Record a decision to stay at the current command (no motion)."""
        self._record(False, spacing, note)

    def _record(self, moved: bool, spacing: int, note: str, via=None) -> None:
        assert self.command is not None and self.point is not None
        self.result.steps.append(Step.at(self.command, self.unit_deg, self.point, self.target,
                                         moved=moved, spacing=spacing, note=note, via=via))
