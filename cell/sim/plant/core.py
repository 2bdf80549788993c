"""The plant: the simulated "real" robot behind the simulated CAN stations and camera.

It keeps the true state (each joint's drive position as its station reports it, and the
direction of its last motion) and turns it into the truth through the effects of
:mod:`cell.effects`, in their one composition order. Noise:

* repeatability (σ ``repeatability_mm`` per axis): one draw per arrival, i.e. per change of
  the θ1/θ2 drive state, held while the arm stands still; part of the truth.
* measurement (σ ``measurement_noise_mm`` per axis): a fresh draw per measurement.

Randomness comes from ``seed`` through three independent streams (arrivals, measurements,
campaigns), so the same seed and the same calls give the same run, and generating a
campaign does not change what the live path measures. Thread-safe: stations may call
:meth:`Plant.update_drive` from their own threads.
"""
from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from cell import effects as fx
from cell.errors import ConfigError, KinematicsError, TrajectoryError
from cell.kinematics import JOINT_NAMES, Scara
from cell.sim.plant.config import PlantConfig, config_from_mapping, load_plant_config


class Plant:
    """The true robot of one simulated cell, built from a validated :class:`PlantConfig`."""

    def __init__(self, config: PlantConfig):
        if not isinstance(config, PlantConfig):
            raise ConfigError(f"Plant needs a PlantConfig, got {type(config).__name__} "
                              "(use Plant.from_yaml or Plant.from_config)")
        self.config = config
        self.robot = Scara(config.nominal_geometry())  # the nominal model
        self.effects = config.effect_instances()
        self._static_effects = [e for e in self.effects if e.spec.stage != fx.Stage.VISION]
        self._center = np.array(config.camera_center_mm, dtype=float)
        arrive, meas, camp = np.random.SeedSequence(config.seed).spawn(3)
        self._rng_arrive = np.random.default_rng(arrive)
        self._rng_meas = np.random.default_rng(meas)
        self._rng_camp = np.random.default_rng(camp)
        self._lock = threading.Lock()
        self._drive = np.array([*config.start_deg, 0.0, 0.0])
        self._dirs = np.array([*config.start_dirs, 0, 0], dtype=float)
        self._t_last = 0.0
        self._arrivals = 0          # counts changes of the θ1/θ2 drive state
        self._offset_arrival = -1   # arrival the current repeatability offset belongs to
        self._offset = np.zeros(2)

    @classmethod
    def from_yaml(cls, path) -> "Plant":
        """Plant from a plant file; ConfigError names file, line and field (see config.py)."""
        return cls(load_plant_config(Path(path)))

    @classmethod
    def from_config(cls, data: Mapping[str, Any], source: str = "<plant config>") -> "Plant":
        """Plant from an already-parsed mapping; ConfigError names ``source`` and the field."""
        return cls(config_from_mapping(data, source))

    # ------------------------------------------------------------------ true state
    def update_drive(self, joint_index: int, drive_deg: float, t_s: float) -> None:
        """Record joint ``joint_index``'s drive position as its station reports it.

        ``joint_index`` is 0-based (0..3 = j1..j4); ``drive_deg`` is the drive (motor-side)
        position expressed in joint units (deg, mm for j3) through the *nominal* gear ratio,
        i.e. the commanded joint angle the drive has reached; ``t_s`` the plant-clock time
        (s). A change of position sets the joint's last-motion direction (backlash); an
        unchanged one keeps it. j3/j4 are stored but do not move the tool centre in x, y.
        Raises KinematicsError for a bad index or non-finite position, TrajectoryError for a
        non-finite time; the state is then unchanged.
        """
        if isinstance(joint_index, bool) or not isinstance(joint_index, (int, np.integer)) \
                or not 0 <= joint_index < 4:
            raise KinematicsError(f"joint_index = {joint_index!r}; use 0..3 for j1..j4")
        v = float(drive_deg)
        if not math.isfinite(v):
            raise KinematicsError(f"{JOINT_NAMES[joint_index]} drive position = {drive_deg!r} "
                                  "is not a finite number")
        t = float(t_s)
        if not math.isfinite(t):
            raise TrajectoryError(f"t_s = {t_s!r} is not a finite time")
        with self._lock:
            step = v - self._drive[joint_index]
            if step:
                self._dirs[joint_index] = math.copysign(1.0, step)
                self._drive[joint_index] = v
                if joint_index < 2:
                    self._arrivals += 1
            self._t_last = max(self._t_last, t)

    def drive_positions(self) -> np.ndarray:
        """Drive positions (4,) of j1..j4 in joint units (deg, deg, mm, deg), a copy."""
        with self._lock:
            return self._drive.copy()

    def directions(self) -> np.ndarray:
        """Last-motion direction (4,) of j1..j4: −1, 0 (not moved yet) or +1, a copy."""
        with self._lock:
            return self._dirs.copy()

    def temperature(self, t_s):
        """Temperature near the arm (°C) at time(s) ``t_s`` (s) from the warm-up model."""
        return self.config.temperature.at(t_s)

    def true_tool_xy(self, t_s: float) -> np.ndarray:
        """True tool centre (x, y) mm at ``t_s`` for the current drive state: joint and link
        effects, forward kinematics, plus this arrival's repeatability offset. What the
        simulated camera renders. Raises TrajectoryError for a non-finite time."""
        temp = self._temp_checked(t_s)
        with self._lock:
            q = self._drive[None, :2].copy()
            d = self._dirs[None, :2].copy()
            offset = self._arrival_offset()
        xy = fx.simulate_points(self.robot.g, self._static_effects, q, d, None, [temp])
        return xy[0] + offset

    def true_points(self, cmd_deg, dirs, t_s: float) -> np.ndarray:
        """True tool centres (N,2) mm, noise-free, for N commanded θ1, θ2 ``cmd_deg`` (N,2)
        arrived at with last-motion directions ``dirs`` (N,2) or (2,) at time ``t_s``: what
        each command would reach before the arrival's repeatability draw, without touching
        the drive state (how a benchmark finds the best command the plant allows).
        Raises TrajectoryError for a non-finite time, KinematicsError for bad commands."""
        temp = self._temp_checked(t_s)
        cmd = np.asarray(cmd_deg, dtype=float)
        d = np.broadcast_to(np.asarray(dirs, dtype=float), cmd.shape)
        return fx.simulate_points(self.robot.g, self._static_effects, cmd, d, None,
                                  np.full(len(cmd), temp))

    def true_tool_pose(self, t_s: float) -> np.ndarray:
        """True tool pose (x_mm, y_mm, phi_deg) at ``t_s``: the centre of
        :meth:`true_tool_xy` and the orientation θ1 + θ2 + θ4 of the TRUE joint angles (the
        joint effects act on θ1, θ2; θ4 is its drive position). What a camera on the hand
        sees the world from. Raises TrajectoryError for a non-finite time."""
        xy = self.true_tool_xy(t_s)
        with self._lock:
            q = self._drive[None, :2].copy()
            d = self._dirs[None, :2].copy()
            t4 = float(self._drive[3])
        q_true = fx.true_joints(self._static_effects, q, d)[0]
        return np.array([xy[0], xy[1], float(q_true[0] + q_true[1]) + t4])

    def measured_xy(self, t_s: float) -> np.ndarray:
        """What the camera measures (x, y) mm at ``t_s`` without rendering an image: the
        truth through the vision effects plus measurement noise."""
        truth = self.true_tool_xy(t_s)
        seen = fx.camera_view(self.effects, truth[None, :], self._center)[0]
        with self._lock:
            noise = self._rng_meas.normal(0.0, self.config.measurement_noise_mm, 2)
        return seen + noise

    def _arrival_offset(self) -> np.ndarray:
        # caller holds the lock; one draw per arrival (change of the θ1/θ2 drive state)
        if self._offset_arrival != self._arrivals:
            self._offset = self._rng_arrive.normal(0.0, self.config.repeatability_mm, 2)
            self._offset_arrival = self._arrivals
        return self._offset

    def _temp_checked(self, t_s) -> float:
        t = float(t_s)
        if not math.isfinite(t):
            raise TrajectoryError(f"t_s = {t_s!r} is not a finite time")
        return self.temperature(t)

    # ------------------------------------------------------------------ campaigns
    def campaign_points(self, cmd_deg, dirs, times) -> np.ndarray:
        """Measured (x, y) mm (N,2) for N static poses, vectorised, without touching the
        drive state: commanded θ1, θ2 ``cmd_deg`` (N,2) deg, last-motion directions
        ``dirs`` (N,2) ±1 (0 = unknown), measurement times ``times`` (N,) s (temperature
        from the warm-up model). Each row gets its own repeatability and measurement
        noise from the campaign stream. Raises KinematicsError / TrajectoryError (see
        :func:`cell.effects.simulate_points`)."""
        cmd = np.asarray(cmd_deg, dtype=float)
        t = _times("times", times)
        truth = fx.simulate_points(self.robot.g, self._static_effects, cmd, dirs, t,
                                   self.temperature(t))
        n = len(truth)
        truth = truth + self._rng_camp.normal(0.0, self.config.repeatability_mm, (n, 2))
        seen = fx.camera_view(self.effects, truth, self._center)
        return seen + self._rng_camp.normal(0.0, self.config.measurement_noise_mm, (n, 2))

    def campaign_path(self, cmd_deg, time_s, start_s: float = 0.0, dirs0=None) -> np.ndarray:
        """Measured (x, y) mm (N,2) along one move, vectorised: ``cmd_deg`` (N,2) where the
        controller meant θ1, θ2 to be at ``time_s`` (N,) s since the move's first command
        frame (strictly increasing); the move starts at plant time ``start_s`` (for the
        temperature); ``dirs0`` (2,) the directions before the move (default: the
        configured start directions). comm_delay applies with the configured station
        order; each sample gets measurement noise (repeatability is an arrival property
        and is left out along a path)."""
        t = _times("time_s", time_s)
        if not math.isfinite(float(start_s)):
            raise TrajectoryError(f"start_s = {start_s!r} is not a finite time")
        d0 = self.config.start_dirs if dirs0 is None else dirs0
        xy = fx.simulate_path(self.robot.g, self.effects, cmd_deg, t,
                              self.temperature(float(start_s) + t), self._center,
                              self.config.stations, d0)
        return xy + self._rng_camp.normal(0.0, self.config.measurement_noise_mm, xy.shape)


def _times(name: str, a) -> np.ndarray:
    t = np.asarray(a, dtype=float)
    if t.ndim != 1:
        raise TrajectoryError(f"{name} must have shape (N,), got {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise TrajectoryError(f"{name}[{bad[0]}] = {float(t[bad[0]])!r} is not a finite time")
    return t
