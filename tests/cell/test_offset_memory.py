"""Seed 000 step (5) in the cell: learned start offsets, and their recovery from the log."""
import numpy as np

from cell.cycle import OffsetMemory
from cell.cyclelog import CycleLog, CycleRecord, utc_now
from cell.kinematics import Scara


def test_mean_of_recent_offsets_rounded():
    m = OffsetMemory(n=3)
    assert m.offset("a").tolist() == [0, 0]
    for off in ([10, -4], [12, -6], [11, -5], [2, 2]):
        m.learn("a", off)
    assert m.offset("a").tolist() == [8, -3]            # mean of the last 3: (25/3, -9/3)
    assert m.offset("b").tolist() == [0, 0]


def test_restart_recovers_offsets_from_the_log(tmp_path):
    robot = Scara.preset("seed000")
    log = CycleLog(tmp_path / "cell.sqlite")
    target = (250.0, 930.0)
    nominal = robot.to_units(robot.ik_planar(*target))
    for k in range(4):
        final = robot.from_units(nominal + np.array([7, -3 + k % 2]))
        log.add_cycle(CycleRecord(part_id=k, recipe="bracket-a", recipe_hash="h", started_at=utc_now(),
                                  finished_at=utc_now(), status="done", cycle_time_s=1.0, target_mm=target,
                                  trace=[{"joints_deg": list(final), "point_mm": list(target),
                                          "error_mm": 0.01, "moved": True}]))
    log.add_cycle(CycleRecord(part_id=9, recipe="bracket-a", recipe_hash="h", started_at=utc_now(),
                              finished_at=utc_now(), status="aborted", cycle_time_s=1.0))
    memory = OffsetMemory.from_log(log, robot)
    assert memory.offset("bracket-a").tolist() == [7, -2]     # mean of -3, -2, -3, -2 rounds to -2


def test_a_new_calibration_starts_learning_afresh(tmp_path):
    """Offsets learned against the nominal model (or an older calibration) refer to it: a
    robot with another calibration rebuilds its memory only from its own cycles."""
    from cell.calibration.calfile import CalibratedScara
    nominal = Scara.preset("seed000")
    calibrated = CalibratedScara(nominal, (0.04, -0.05), (0.3, -0.25), "v1-abcdef12")
    log = CycleLog(tmp_path / "cell.sqlite")
    target = (250.0, 930.0)
    for robot, off in ((nominal, [7, -3]), (calibrated, [1, 2])):
        cmd = robot.to_units(robot.ik_planar(*target)) + np.array(off)
        log.add_cycle(CycleRecord(part_id=1, recipe="bracket-a", recipe_hash="h", started_at=utc_now(),
                                  finished_at=utc_now(), status="done", cycle_time_s=1.0, target_mm=target,
                                  calibration=getattr(robot, "calibration", ""),
                                  trace=[{"joints_deg": list(robot.from_units(cmd)), "point_mm": list(target),
                                          "error_mm": 0.01, "moved": True}]))
    assert OffsetMemory.from_log(log, nominal).offset("bracket-a").tolist() == [7, -3]
    assert OffsetMemory.from_log(log, calibrated).offset("bracket-a").tolist() == [1, 2]
    other = CalibratedScara(nominal, (0.0, 0.0), (0.0, 0.0), "v2-00000000")
    assert OffsetMemory.from_log(log, other).offset("bracket-a").tolist() == [0, 0]
    assert [r.calibration for r in log.cycles()] == ["", "v1-abcdef12"]
