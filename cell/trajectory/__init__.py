"""Motion planning: seed 002 straight lines with CAN delay correction (:mod:`.line`) and
seed 003 time laws through joint way-points (:mod:`.timelaw`). Pure numerics, no I/O."""
from __future__ import annotations

from cell.trajectory.line import (LinePlan, Segment, SimulatedPath, delay_corrected_velocities,
                                  joint_delays, joint_positions_at, max_line_deviation, plan_line,
                                  simulate_line, station_delays, tool_positions)
from cell.trajectory.timelaw import (LAWS, TIMINGS, JointTrajectory, Peaks, continuity_jumps,
                                     knot_times, plan_timelaw)

__all__ = [
    "LinePlan", "Segment", "SimulatedPath", "delay_corrected_velocities", "joint_delays",
    "joint_positions_at", "max_line_deviation", "plan_line", "simulate_line", "station_delays",
    "tool_positions",
    "LAWS", "TIMINGS", "JointTrajectory", "Peaks", "continuity_jumps", "knot_times",
    "plan_timelaw",
]
