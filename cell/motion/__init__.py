"""Motion: every move of the cell, planned and streamed.

* :mod:`.mover`: a move as seed 002 makes it, cut into segments and streamed to the joint
  stations in the recipe's mode; the cell's interface to the stations (``JointMotion``).
* :mod:`.line`: seed 002's straight lines with CAN delay correction. Pure numerics.
* :mod:`.timelaw`: seed 003's time laws through joint way-points. Pure numerics.
* :mod:`.names`: the time laws' names, for recipes and the command line.

The names below load their module on first use (PEP 562), so importing one submodule (or
the law names of :mod:`.names`) does not import the others: :mod:`.timelaw` brings in
``scipy.interpolate``, which a command's start-up should not pay for.
"""
from __future__ import annotations

import importlib

_WHERE = {
    **{n: "cell.motion.line" for n in (
        "LinePlan", "Segment", "SimulatedPath", "delay_corrected_velocities", "joint_delays",
        "joint_positions_at", "line_joints", "max_line_deviation", "plan_line", "simulate_line", "station_delays",
        "tool_positions")},
    **{n: "cell.motion.timelaw" for n in (
        "JointTrajectory", "Peaks", "continuity_jumps", "knot_times", "plan_timelaw")},
    "LAWS": "cell.motion.names", "TIMINGS": "cell.motion.names",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    try:
        module = _WHERE[name]
    except KeyError:
        raise AttributeError(f"module 'cell.motion' has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)
