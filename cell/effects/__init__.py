"""The effect vocabulary shared by the plant (which makes the truth), the sim-to-real
diagnosis (which fits it) and the calibrations. Pure, vectorised numerics; no I/O.

**One definition per effect**: each effect is one module of this package
(``cell/effects/<name>.py``) holding one :class:`Effect` that carries its parameters and
units, its forward function and analytic derivative, its subsystem and ``depends_on``,
what stands in for it when it cannot be tested (``mimics``), the recommended action
(``remedy``), and how it applies to a serial chain (``chain``: its term, the derivative the
diagnosis fits with, and what makes it identifiable); :mod:`cell.effects.base` documents
each field.
:mod:`cell.effects.vocabulary` lists them: :data:`REGISTRY` all, :data:`EFFECTS` the
planar vocabulary, :data:`CHAIN_EFFECTS` the chain's. ``docs/adding-an-effect.md`` is the
recipe for a new one.

Each planar effect is a pure function of an explicit parameter vector, so a fitter can
hand candidate vectors to :func:`simulate_points` / :func:`simulate_path` (e.g. inside
``scipy.optimize.least_squares``) exactly as the plant does with its true values. Names,
subsystems and ``depends_on`` follow the measurement format, ``cell/measurements.md``.

Composition order (one order, used everywhere)::

    1. comms   (paths only) comm_delay: joint i runs its command λ_i = σ·k_i late,
               k_i = its 1-based position in the CAN station order (seed 002)
    2. joint   θ_true = θ_cmd + Σ Δθ(θ_cmd, dir): joint_offset, gear_ratio, backlash,
               cyclic_error; every term is evaluated at the commanded (drive-side) angle,
               so the joint terms add and their order among themselves does not matter
    3. link    l_true = l_nominal + Σ Δl(T): link_length, thermal_drift
    4. FK      seed 000 eq. 4 with l_true, θ_true        -> true tool centre (x, y)
    5. vision  camera_scale, camera_rotation about the camera centre -> what the camera
               measures (a similarity about one centre: the two commute)

Units: angles in degrees, lengths in mm, time in s, temperature in °C, relative sizes
dimensionless. Per-joint parameters are named ``<joint>_<stem>`` (``j2_backlash_deg``);
``link_length`` on ``j1``/``j2`` means link 1/2. Bad input raises
:class:`~cell.errors.ConfigError` (effects and their parameters),
:class:`~cell.errors.KinematicsError` (joint and direction arrays) or
:class:`~cell.errors.TrajectoryError` (time arrays), naming the value.
"""
from __future__ import annotations

from cell.effects.base import (PLANAR_JOINTS, STAGES, SUBSYSTEMS, ChainPoses, Effect, OnChain,
                               ParamSpec, Remedy, Stage)
from cell.effects.vocabulary import CHAIN_EFFECTS, EFFECTS, REGISTRY
from cell.effects.instances import (EffectInstance, make_effect, reference_temp_c, split_vector,
                                   stack_vectors)
from cell.effects.compose import (DEFAULT_STATIONS, STATION_NAMES, camera_view, path_directions,
                                  planar_fk, simulate_path, simulate_points, station_order,
                                  true_joints, true_links)
from cell.effects.comm_delay import comm_delay  # noqa: E402  (the function, not the module)
from cell.errors import ConfigError  # noqa: F401  (kept: callers catch fx.ConfigError)

__all__ = ["PLANAR_JOINTS", "Stage", "STAGES", "SUBSYSTEMS", "STATION_NAMES", "DEFAULT_STATIONS",
           "ParamSpec", "Effect", "Remedy", "OnChain", "ChainPoses", "REGISTRY", "EFFECTS",
           "CHAIN_EFFECTS", "EffectInstance", "make_effect",
           "stack_vectors", "split_vector", "reference_temp_c", "true_joints", "true_links", "planar_fk",
           "camera_view", "simulate_points", "simulate_path", "station_order",
           "path_directions", "comm_delay"]
