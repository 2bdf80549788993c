"""Export logged cycles to the measurement exchange format, so the diagnosis can read what the
cell logged (``cell/measurements.md``).

Every physical move of a cycle's compensation trace is one static measurement: the joint
command it was reached with, the point the camera measured, the direction each joint last
moved in (from the previous command of the same cycle; the first arrival has no previous
command inside the cycle and takes +1 where unknown), the time since the first exported
cycle started, and the cycle's temperature if it was logged. The ``sample`` id is the
cycle id × 100 + the move index, so samples trace back to their cycle.
"""
from __future__ import annotations

from datetime import datetime

import numpy as np

from cell.cyclelog import CycleRecord
from cell.measurements import FORMAT, Campaign, CameraSpec, ModelSpec

MOVES_PER_CYCLE = 100


def cycles_to_campaign(cycles: list[CycleRecord], l1_mm: float, l2_mm: float,
                       command_unit_deg: float | None = None,
                       camera_center_mm: tuple[float, float] | None = None,
                       stations: list[str] | None = None,
                       joint_limits_deg: list[list[float]] | None = None) -> Campaign:
    """Build a campaign (points only) from logged cycles; cycles without a trace add nothing.
    ``joint_limits_deg`` ([[lo, hi], [lo, hi]] of j1, j2: the robot's) lets the diagnosis
    propose poses to measure next anywhere the arm can go, not only where the parts were.

    Raises ValueError if no cycle holds a measured move.
    """
    cols: dict[str, list] = {k: [] for k in ("sample", "time_s", "j1_deg", "j2_deg", "x_mm", "y_mm",
                                             "j1_dir", "j2_dir", "temp_c")}
    t0 = None
    for c in cycles:
        if c.id is None:
            raise ValueError("only logged cycles (with an id) can be exported")
        start = datetime.fromisoformat(c.started_at)
        t0 = t0 or start
        prev, dirs = None, np.ones(2)
        moves = [s for s in c.trace if s.get("moved")]
        for i, s in enumerate(moves[:MOVES_PER_CYCLE]):
            q = np.asarray(s["joints_deg"], dtype=float)
            if prev is not None:                   # a joint that did not move keeps its direction
                dirs = np.where(q > prev, 1.0, np.where(q < prev, -1.0, dirs))
            prev = q
            cols["sample"].append(c.id * MOVES_PER_CYCLE + i)
            cols["time_s"].append((start - t0).total_seconds() + float(s.get("t_s", 0.0)))
            cols["j1_deg"].append(q[0])
            cols["j2_deg"].append(q[1])
            cols["x_mm"].append(float(s["point_mm"][0]))
            cols["y_mm"].append(float(s["point_mm"][1]))
            cols["j1_dir"].append(dirs[0])
            cols["j2_dir"].append(dirs[1])
            cols["temp_c"].append(c.temp_c)
    if not cols["sample"]:
        raise ValueError("no logged cycle holds a measured move to export")
    if any(t is None for t in cols["temp_c"]):
        del cols["temp_c"]
    points = {k: np.array(v, dtype=np.int64 if k == "sample" else float) for k, v in cols.items()}
    model = ModelSpec(format=FORMAT, l1_mm=l1_mm, l2_mm=l2_mm, command_unit_deg=command_unit_deg,
                      camera=CameraSpec(center_mm=camera_center_mm) if camera_center_mm else None,
                      stations=stations, joint_limits_deg=joint_limits_deg)
    return Campaign(model=model, points=points, source="cycle log")
