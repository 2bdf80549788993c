"""Motion planning: seed 002 straight lines with CAN delay correction (:mod:`.line`) and
seed 003 time laws through joint way-points (:mod:`.timelaw`). Pure numerics, no I/O.

The names below load their module on first use (PEP 562), so importing one submodule (or
the law names of :mod:`.names`) does not import the others: :mod:`.timelaw` brings in
``scipy.interpolate``, which a command's start-up should not pay for.
"""
from __future__ import annotations

import importlib

_WHERE = {
    **{n: "cell.trajectory.line" for n in (
        "LinePlan", "Segment", "SimulatedPath", "delay_corrected_velocities", "joint_delays",
        "joint_positions_at", "max_line_deviation", "plan_line", "simulate_line", "station_delays",
        "tool_positions")},
    **{n: "cell.trajectory.timelaw" for n in (
        "JointTrajectory", "Peaks", "continuity_jumps", "knot_times", "plan_timelaw")},
    "LAWS": "cell.trajectory.names", "TIMINGS": "cell.trajectory.names",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    try:
        module = _WHERE[name]
    except KeyError:
        raise AttributeError(f"module 'cell.trajectory' has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)
