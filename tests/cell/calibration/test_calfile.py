"""The robot calibration file: versioned writes, refusals at load, the calibrated robot.

Golden values: the constructed documents of this file; the nominal robots are the presets
of cell/kinematics/scara.py (seed 000: l1 = l2 = 500 mm; seed 002: 200 mm)."""
import json

import numpy as np
import pytest

from cell.calibration import calfile
from cell.calibration.service import load_active
from cell.config import CellConfig, SimSection
from cell.errors import CalibrationError
from cell.kinematics import Scara

SEED000 = Scara.preset("seed000")
PARAMS = {"j1.theta": {"value": 0.04, "se": 0.0002, "low": 0.0396, "high": 0.0404, "unit": "deg"},
          "j2.theta": {"value": -0.05, "se": 0.0002, "low": -0.0504, "high": -0.0496, "unit": "deg"},
          "j1.a": {"value": 0.3, "se": 0.002, "low": 0.296, "high": 0.304, "unit": "mm"},
          "j2.a": {"value": -0.25, "se": 0.002, "low": -0.254, "high": -0.246, "unit": "mm"},
          "base.x": {"value": -1.1, "se": 0.002, "low": -1.104, "high": -1.096, "unit": "mm"}}


def doc(robot=SEED000, cell="cell-1"):
    return calfile.new_document(robot, cell, PARAMS, {"holdout": {"passed": True}},
                                {"fit": [{"q": [10, 20, 0, 0], "measured_mm": [1, 2]}]}, "2026-11-23T00:00:00+00:00")


def test_write_versions_and_keeps_the_one_it_replaces(tmp_path):
    path = tmp_path / "cal" / "robot.json"
    first = calfile.write(path, doc())
    second = calfile.write(path, doc())
    assert (first["version"], second["version"]) == (1, 2)
    assert json.loads((tmp_path / "cal" / "robot.v1.json").read_text())["sha256"] == first["sha256"]
    loaded = calfile.load(path, SEED000, "cell-1")
    assert loaded["version"] == 2 and calfile.calibration_id(loaded) == f"v2-{second['sha256'][:8]}"
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]      # no temp file left


@pytest.mark.parametrize("damage, message", [
    (lambda t: t[: len(t) // 2], "corrupt robot calibration, not valid JSON"),
    (lambda t: t.replace('"value": 0.3', '"value": 0.4'), "checksum does not match"),
    (lambda t: t.replace(calfile.FORMAT, "cell-robot-calibration/9"), "not a robot calibration"),
    (lambda t: "[1, 2]", "not a robot calibration"),
])
def test_a_damaged_file_is_refused_naming_file_and_cause(tmp_path, damage, message):
    path = tmp_path / "robot.json"
    calfile.write(path, doc())
    path.write_text(damage(path.read_text()))
    with pytest.raises(CalibrationError, match=message) as info:
        calfile.load(path, SEED000, "cell-1")
    assert str(path) in str(info.value)


def test_another_robots_or_another_cells_calibration_is_refused(tmp_path):
    path = tmp_path / "robot.json"
    calfile.write(path, doc(robot=Scara.preset("seed002")))
    with pytest.raises(CalibrationError, match="belongs to another robot .*'seed002'.*'seed000'"):
        calfile.load(path, SEED000, "cell-1")
    calfile.write(path, doc(cell="cell-7"))
    with pytest.raises(CalibrationError, match="belongs to cell 'cell-7', not to this cell 'cell-1'"):
        calfile.load(path, SEED000, "cell-1")


def test_the_cell_runs_nominal_without_a_file_and_refuses_a_bad_one(tmp_path):
    cfg = CellConfig(sim=SimSection())
    cfg = cfg.model_copy(update={"calibration": cfg.calibration.model_copy(update={"file": str(tmp_path / "c.json")})})
    robot, d = load_active(cfg, SEED000)
    assert robot is SEED000 and d is None
    calfile.write(tmp_path / "c.json", doc())
    robot, d = load_active(cfg, SEED000)
    assert robot.calibration == calfile.calibration_id(d)
    (tmp_path / "c.json").write_text("{")
    with pytest.raises(CalibrationError, match="not valid JSON"):
        load_active(cfg, SEED000)


def test_the_file_records_the_side_its_poses_took_up_backlash_from(tmp_path):
    """The procedure approaches every pose from below; the calibrated robot carries that side
    so the cell's arrivals come the same way. A file from before the key was written was
    measured the same way."""
    path = tmp_path / "robot.json"
    written = calfile.write(path, doc())
    assert written["approach_dirs"] == [1, 1] == list(Scara.approach_dirs)
    assert calfile.calibrated_robot(SEED000, calfile.load(path, SEED000, "cell-1")).approach_dirs == (1, 1)
    old = {k: v for k, v in doc().items() if k != "approach_dirs"}
    assert calfile.calibrated_robot(SEED000, calfile.write(path, old)).approach_dirs == (1, 1)


@pytest.mark.parametrize("dirs", [[1, 0], [1], "up", [1, -1, 1], [True, 1], [2, 1]])
def test_a_file_with_a_bad_approach_side_is_refused(tmp_path, dirs):
    path = tmp_path / "robot.json"
    calfile.write(path, {**doc(), "approach_dirs": dirs})       # checksummed: a writer's bug
    with pytest.raises(CalibrationError, match=r"approach_dirs = .*must be two of \+1 / -1") as info:
        calfile.load(path, SEED000, "cell-1")
    assert str(path) in str(info.value)


def test_calibrated_robot_is_the_nominal_one_with_its_zeros_and_links():
    robot = calfile.calibrated_robot(SEED000, {**doc(), "version": 1, "sha256": "0" * 64})
    q = np.array([30.0, 45.0])
    true = Scara(SEED000.g.model_copy(update={"l1_mm": 500.3, "l2_mm": 499.75}))
    assert np.allclose(robot.fk_planar(*q), true.fk_planar(30.04, 44.95), atol=1e-12)
    back = robot.ik_planar(*robot.fk_planar(*q))
    assert np.allclose(back, q, atol=1e-9)
    assert robot.g == SEED000.g and robot.calibration == "v1-00000000"     # limits and units nominal
    j = robot.jacobian(*q)
    eps = 1e-6
    num = np.column_stack([(robot.fk_planar(q[0] + eps, q[1]) - robot.fk_planar(q[0] - eps, q[1])) / (2 * eps),
                           (robot.fk_planar(q[0], q[1] + eps) - robot.fk_planar(q[0], q[1] - eps)) / (2 * eps)])
    assert np.allclose(j, num, atol=1e-6)


def test_compensation_predicts_with_the_calibrated_model():
    """A robot whose truth is exactly its calibration lands its first move on the target,
    and the lattice search predicts its candidates with the same model (it once mixed
    the nominal links into a calibrated prediction and walked away from the target)."""
    from cell.compensation.arms import PerturbedArm
    from cell.compensation.lattice import nearest_lattice, run_lattice
    robot = calfile.calibrated_robot(SEED000, {**doc(), "version": 1, "sha256": "0" * 64})
    truth = PerturbedArm(SEED000, dl_mm=(0.3, -0.25), offset_deg=(0.04, -0.05))
    target = np.array([250.0, 930.0])
    # within the rounding to whole 0.01° command units (~0.08 mm at ~960 mm reach)
    assert run_lattice(robot, truth, target).initial_error_mm < 0.1
    assert run_lattice(SEED000, truth, target).initial_error_mm > 0.15
    q = robot.to_units(robot.ik_planar(*target))
    point = truth.move_and_measure(q)
    best, predicted = nearest_lattice(robot, q, point, target + [0.05, -0.03])
    assert abs(np.hypot(*(truth.move_and_measure(best) - target - [0.05, -0.03])) - predicted) < 1e-3


def test_a_cell_refuses_to_start_on_a_corrupt_calibration_and_frees_its_log(tmp_path):
    from cell.app import Cell
    from cell.cyclelog import CycleLog
    cfg = CellConfig(sim=SimSection())
    bad = tmp_path / "robot.json"
    calfile.write(bad, doc(cell="cell-2"))
    cfg = cfg.model_copy(update={"log": cfg.log.model_copy(update={"path": str(tmp_path / "c.sqlite")}),
                                 "calibration": cfg.calibration.model_copy(update={"file": str(bad)})})
    with pytest.raises(CalibrationError, match="belongs to cell 'cell-2'"):
        Cell(cfg, devices="sim", plc_port=0, jobs=False)
    CycleLog(tmp_path / "c.sqlite").close()          # the writer's lock was released


def test_the_cell_loads_the_calibration_numerics_only_when_a_calibration_runs():
    import subprocess
    import sys
    code = ("import sys, cell.app; heavy = [m for m in ('scipy.stats', 'cell.calibration.joint', "
            "'cell.calibration.kinematic', 'matplotlib') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_an_unwritable_place_is_a_clear_error(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(CalibrationError, match="afile/robot.json: cannot write the robot calibration"):
        calfile.write(tmp_path / "afile" / "robot.json", doc())


def test_an_unreadable_active_file_is_kept_aside_and_replaced(tmp_path):
    path = tmp_path / "robot.json"
    path.write_bytes(b"\xff\xfe not json")
    assert calfile.write(path, doc())["version"] == 1
    assert (tmp_path / "robot.unreadable.json").read_bytes() == b"\xff\xfe not json"
    assert calfile.load(path, SEED000, "cell-1")["version"] == 1


def test_the_file_gets_the_umask_mode_not_0600(tmp_path):
    """The service user must read a calibration an engineer wrote (``cellctl calibrate
    kinematics`` as root): it was written 0600, ``tempfile.mkstemp``'s mode."""
    import os
    mask = os.umask(0)
    os.umask(mask)
    path = tmp_path / "robot.json"
    calfile.write(path, doc())
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask
