"""Seed 000 step (5) in the cell: what the arrivals measured against the model, the first
command it gives, and its recovery from the log."""
import itertools

import numpy as np
import pytest

from cell.cycle.runner import VERIFY_NOTE, OffsetMemory
from cell.cyclelog import CycleLog, CycleRecord, utc_now
from cell.kinematics import Scara

TARGET = (250.0, 930.0)


def _step(robot, units, residual_mm, note="first arrival"):
    q = robot.from_units(np.asarray(units))
    return {"joints_deg": list(q), "point_mm": list(robot.fk_planar(*q) + residual_mm),
            "error_mm": 0.01, "moved": True, "note": note}


def test_mean_of_the_last_n_residuals_in_mm():
    m = OffsetMemory(n=3)
    assert m.offset_mm("a").tolist() == [0.0, 0.0]
    for res in ([0.10, -0.04], [0.12, -0.06], [0.11, -0.05], [0.02, 0.02]):
        m.learn("a", res)
    assert m.offset_mm("a") == pytest.approx([0.25 / 3, -0.03])    # the last 3 only
    assert m.offset_mm("b").tolist() == [0.0, 0.0]
    m.learn("a", None)                                           # a trace with no arrival
    assert len(m.history["a"]) == 3


def test_scatter_is_the_arrivals_noise_without_the_drift():
    """Successive differences: a steady drift (a warming arm) is not noise."""
    m = OffsetMemory(n=10)
    m.learn("a", [0.1, 0.0])
    m.learn("a", [0.1, 0.02])
    assert m.scatter_mm("a") == 0.0                              # too few to tell
    assert m.scatter_mm("a", prior_mm=0.015) == 0.015            # ... so the calibration's
    m.learn("a", [0.1, 0.0])
    assert m.scatter_mm("a") == pytest.approx(0.02 / np.sqrt(2))   # √(mean |Δ|² / 2)
    assert m.scatter_mm("a", prior_mm=0.5) == pytest.approx(0.02 / np.sqrt(2))   # then measured
    drift = OffsetMemory(n=10)
    for k in range(10):
        drift.learn("a", [0.01 * k, 0.0])                        # 0.09 mm of warm-up
    assert drift.scatter_mm("a") == pytest.approx(0.01 / np.sqrt(2))


def _nearest_by_brute_force(robot, around, target, bias=(0.0, 0.0)):
    box = [np.asarray(around) + d for d in itertools.product(range(-4, 5), repeat=2)]
    return min(box, key=lambda c: np.hypot(*(robot.fk_planar(*robot.from_units(c)) + bias - target)))


def test_an_empty_memory_starts_from_the_lattice_point_the_model_predicts_nearest():
    """Not the model's inverse kinematics rounded joint by joint: at bracket-a's place the
    lattice is skewed, and at TARGET that rounding lands 0.061 mm off while one θ2 unit
    more lands 0.030 mm off (seed000, golden values)."""
    robot = Scara.preset("seed000")
    ik = robot.to_units(robot.ik_planar(*TARGET))
    start = OffsetMemory().start(robot, "a", TARGET)
    assert start.tolist() == _nearest_by_brute_force(robot, ik, TARGET).tolist() == (ik + [0, 1]).tolist()
    miss = [np.hypot(*(robot.fk_planar(*robot.from_units(c)) - TARGET)) for c in (ik, start)]
    assert miss == pytest.approx([0.0609, 0.0295], abs=1e-4)


def test_the_first_command_is_the_lattice_point_the_residual_predicts_nearest():
    """A residual of half a θ2 unit's displacement and more moves the first command."""
    robot = Scara.preset("seed000")
    m = OffsetMemory()
    ik = robot.to_units(robot.ik_planar(*TARGET))
    q = robot.from_units(ik)
    shift = robot.jacobian(*q) @ robot.from_units([3, -2])      # the arm lands 3, −2 units over
    m.learn("a", shift)
    start = m.start(robot, "a", TARGET)
    predicted = robot.fk_planar(*robot.from_units(start)) + shift
    assert np.hypot(*(predicted - TARGET)) < 0.05
    assert start.tolist() == _nearest_by_brute_force(robot, ik + [-3, 2], TARGET, shift).tolist()


def test_residual_counts_arrivals_only():
    robot = Scara.preset("seed000")
    ik = robot.to_units(robot.ik_planar(*TARGET))
    steps = [_step(robot, ik, [0.02, 0.0]), _step(robot, ik + 5, [0.5, 0.5], "backlash pre-move"),
             _step(robot, ik + 1, [0.04, 0.0], "predicted 0.01 mm"),
             _step(robot, ik + 2, [0.9, 0.9], f"{VERIFY_NOTE}, predicted 0.02 mm"),
             {**_step(robot, ik, [0.7, 0.7]), "moved": False}]
    assert OffsetMemory.residual(robot, steps) == pytest.approx([0.03, 0.0])
    assert OffsetMemory.residual(robot, steps[1:2]) is None


def _cycle(log, robot, residual, part_id=1, status="done"):
    ik = robot.to_units(robot.ik_planar(*TARGET))
    log.add_cycle(CycleRecord(part_id=part_id, recipe="bracket-a", recipe_hash="h", started_at=utc_now(),
                              finished_at=utc_now(), status=status, cycle_time_s=1.0, target_mm=TARGET,
                              calibration=getattr(robot, "calibration", ""),
                              trace=[_step(robot, ik, residual)]))


def test_restart_recovers_the_memory_from_the_log(tmp_path):
    robot = Scara.preset("seed000")
    log = CycleLog(tmp_path / "cell.sqlite")
    for k in range(4):
        _cycle(log, robot, [0.1, -0.02 * (k % 2)], part_id=k)
    _cycle(log, robot, [5.0, 5.0], part_id=9, status="aborted")
    memory = OffsetMemory.from_log(log, robot)
    assert memory.offset_mm("bracket-a") == pytest.approx([0.1, -0.01])


def test_a_new_calibration_starts_learning_afresh(tmp_path):
    """Residuals learned against the nominal model (or an older calibration) refer to it: a
    robot with another calibration rebuilds its memory only from its own cycles."""
    from cell.calibration.calfile import CalibratedScara
    nominal = Scara.preset("seed000")
    calibrated = CalibratedScara(nominal, (0.04, -0.05), (0.3, -0.25), "v1-abcdef12")
    log = CycleLog(tmp_path / "cell.sqlite")
    _cycle(log, nominal, [0.3, -0.2])
    _cycle(log, calibrated, [0.01, 0.02])
    assert OffsetMemory.from_log(log, nominal).offset_mm("bracket-a") == pytest.approx([0.3, -0.2])
    assert OffsetMemory.from_log(log, calibrated).offset_mm("bracket-a") == pytest.approx([0.01, 0.02])
    other = CalibratedScara(nominal, (0.0, 0.0), (0.0, 0.0), "v2-00000000")
    assert OffsetMemory.from_log(log, other).offset_mm("bracket-a").tolist() == [0.0, 0.0]
    assert [r.calibration for r in log.cycles()] == ["", "v1-abcdef12"]


def test_a_calibrated_robot_brings_the_scatter_its_check_measured(tmp_path):
    """Before three parts are remembered, a correction must gain more than the held-out rms
    of the robot's calibration: the scatter of arrivals about that model, measured."""
    from cell.calibration import calfile
    from cell.kinematics import Scara
    nominal = Scara.preset("seed000")
    doc = calfile.new_document(nominal, "cell-1", {}, {"holdout": {"rms_xy_after_mm": 0.0152}}, {},
                               "2026-11-26T00:00:00+00:00")
    robot = calfile.calibrated_robot(nominal, calfile.write(tmp_path / "c.json", doc))
    assert robot.arrival_scatter_mm == 0.0152 and nominal.arrival_scatter_mm == 0.0
    no_check = calfile.new_document(nominal, "cell-1", {}, {}, {}, "2026-11-26T00:00:00+00:00")
    assert calfile.calibrated_robot(nominal, calfile.write(tmp_path / "d.json", no_check)).arrival_scatter_mm == 0.0


def test_before_three_parts_a_correction_must_beat_the_calibrations_scatter():
    """The first part of a calibrated cell: its first arrival lands a little off and the
    lattice predicts a neighbour nearer. A robot whose calibration measured a held-out rms
    above that gain keeps the arrival (one move); a robot with no measured scatter moves.
    Golden values: the arm below (zeros −0.005° and 0.003° off, exact links, no noise: the
    first arrival 0.043 mm off, the neighbour 0.037 mm) and bracket-a's recipe."""
    from pathlib import Path

    from cell.compensation.arms import PerturbedArm
    from cell.cycle.runner import compensate
    from cell.kinematics import Scara
    from cell.recipes import parse_recipe
    text = (Path(__file__).resolve().parents[2] / "recipes" / "bracket-a.yaml").read_text()
    recipe = parse_recipe(text, "bracket-a.yaml")
    nominal = Scara.preset("seed000")
    target = np.array([250.004, 930.003])
    arm = PerturbedArm(nominal, offset_deg=(-0.005, 0.003))
    plain = compensate(nominal, arm, OffsetMemory(), recipe, target)
    assert len(plain.steps) == 2 and plain.final_error_mm < plain.initial_error_mm   # moved for a gain
    gain = plain.initial_error_mm - plain.final_error_mm
    measured = Scara(nominal.g)
    measured.arrival_scatter_mm = gain + 0.005                     # the calibration's held-out rms
    kept = compensate(measured, PerturbedArm(nominal, offset_deg=(-0.005, 0.003)), OffsetMemory(),
                      recipe, target)
    assert len(kept.steps) == 1 and kept.final_error_mm == plain.initial_error_mm
