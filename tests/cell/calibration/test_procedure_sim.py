"""The calibration procedures on the simulated cell: the stations on the virtual CAN bus, the
hand camera rendering the plant's TRUE tool pose, OpenCV finding the target.

Truths come from deploy/plants/default.yaml (j1/j2 zeros +0.05°/−0.04°, links +0.3/−0.25 mm,
j2 backlash 0.02°) and drivers/camera/sim_hand.py (board placed off by BOARD_PLACEMENT); the
calibration is told none of them. Everything runs on the simulated clock."""
import json
from types import SimpleNamespace

import pytest

from cell.calibration import calfile
from cell.calibration.procedure import plan_joint
from cell.calibration.service import CellCalibrator
from cell.config import CellConfig, SimSection
from cell.cycle.runner import CancelToken
from cell.errors import CalibrationError
from cell.faults import Fault
from cell.kinematics import Scara
from cell.sim.assembly import SimDevices
from drivers.camera.sim_hand import BOARD_PLACEMENT

PLANT_J2_BACKLASH = 0.02         # deploy/plants/default.yaml


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal")
    cfg = CellConfig(sim=SimSection())
    cfg = cfg.model_copy(update={"calibration": cfg.calibration.model_copy(
        update={"file": str(out / "robot-calibration.json"), "poses": 10, "holdout": 6})})
    dev = SimDevices(cfg)
    with dev.clock.attach("test"):
        dev.start()
        try:
            yield cfg, dev, CellCalibrator(cfg, dev, dev.robot)
        finally:
            dev.stop()
    dev.clock.close()


def test_plan_keeps_the_target_in_view_and_refuses_what_cannot_be_done():
    robot = Scara.preset("seed000")
    j1 = plan_joint(robot, "j1", 20.6)
    assert 1.0 < j1.in_view_deg[1] < 1.3 and max(j1.nominal_deg) <= j1.in_view_deg[1]
    assert "R = 1000.0 mm" in j1.reason
    assert plan_joint(robot, "j4", 20.6).nominal_deg[0] > 100          # the target circles the axis
    with pytest.raises(CalibrationError, match="j3 is prismatic"):
        plan_joint(robot, "j3", 20.6)
    with pytest.raises(CalibrationError, match="choose a smaller --step-deg"):
        plan_joint(robot, "j1", 20.6, step_deg=1.0)
    with pytest.raises(CalibrationError, match="runs = 0"):
        plan_joint(robot, "j2", 20.6, runs=0)


def test_joint_calibration_finds_the_plants_j2_backlash(cell):
    _, dev, cal = cell
    plan, res = cal.joint("j2", runs=1)
    b = res.backlash_deg
    assert b.low <= PLANT_J2_BACKLASH <= b.high and b.high - b.low < 0.005
    assert res.gear_ratio_error.low <= 0.0 <= res.gear_ratio_error.high     # the plant has none
    assert res.n_images == 2 * len(plan.nominal_deg) + 1


def test_a_lost_target_names_the_image_and_nothing_is_kept(cell):
    _, dev, cal = cell
    dev.place_fixture("none")
    rig = cal.rig()
    with pytest.raises(CalibrationError, match=r"run 1 zero image: target not measured \(no_target\)") as info:
        from cell.calibration.procedure import sweep_joint
        sweep_joint(rig, plan_joint(cal.nominal, "j1", rig.view_radius_mm, runs=1))
    assert info.value.fault == "measurement"


def test_the_plc_hears_which_kind_of_failure_it_was(cell):
    """601 the cell cannot run it (no hand camera), 602 an image failed (the operator laid
    no target). The fault codes once followed words of the message, and "no hand camera"
    came out as 602."""
    cfg, dev, _ = cell
    no_camera = SimpleNamespace(hand_camera=None, place_fixture=dev.place_fixture, motion=dev.motion,
                                clock=dev.clock)
    out = CellCalibrator(cfg, no_camera, dev.robot).run_safely(1, CancelToken(dev.clock))
    assert (out.fault_code, out.fault_text) == (Fault.CALIBRATION_REFUSED, "no hand camera: set "
                                                "calibration.hand_camera in the cell config")
    no_target = SimpleNamespace(hand_camera=dev.hand_camera, hand_calibration=dev.hand_calibration,
                                place_fixture=lambda kind, joint=None: dev.place_fixture("none"),
                                motion=dev.motion, clock=dev.clock)
    out = CellCalibrator(cfg, no_target, dev.robot).run_safely(2, CancelToken(dev.clock))
    assert out.fault_code == Fault.CALIBRATION_MEASUREMENT and "target not measured (no_target)" in out.fault_text


@pytest.mark.slow
def test_kinematic_calibration_passes_its_held_out_check_and_is_written(cell):
    cfg, dev, cal = cell
    before = cal.version                 # a joint calibration of this module may have written one
    out = cal.kinematics()
    h = out.holdout
    assert h.passed and h.rms_xy_after_mm < 0.2 * h.rms_xy_before_mm
    p = out.parameters(cal.nominal)
    # the anchor poses (cell camera, base frame) tell the board's rotation from j1's zero
    assert abs(p["j1.theta"]["value"] - 0.05) < 0.003 and abs(p["base.rz"]["value"] + BOARD_PLACEMENT[2]) < 0.003
    assert abs(p["j1.a"]["value"] - 0.3) < 0.02 and abs(p["j2.a"]["value"] + 0.25) < 0.02
    # j2's backlash (approached from below: −b/2) acts as part of its zero
    assert abs(p["j2.theta"]["value"] - (-0.04 - PLANT_J2_BACKLASH / 2)) < 0.003
    d = calfile.load(cfg.calibration.file, cal.nominal, cfg.name)
    assert d["version"] == cal.version == before + 1 and len(d["data"]["holdout"]) == 6
    assert set(d["parameters"]) == set(out.identification.kept)


def test_without_anchors_the_boards_rotation_merges_into_j1s_zero(cell):
    cfg, dev, _ = cell
    board_only = CellCalibrator(cfg.model_copy(update={"calibration": cfg.calibration.model_copy(
        update={"anchors": 0})}), dev, dev.robot)
    out = board_only.kinematics(write=False)
    merged = {f["param"]: f["merged_into"] for f in out.identification.report.fixed if f["reason"] == "merged"}
    assert merged["base.rz"] == {"j1.theta": pytest.approx(1.0)}
    assert abs(out.identification.value("j1.theta") - (0.05 - BOARD_PLACEMENT[2])) < 0.003
    assert out.document is None


@pytest.mark.slow
def test_failed_held_out_check_writes_nothing_and_reports_fault_603(cell):
    cfg, dev, cal = cell
    strict = CellCalibrator(cfg.model_copy(update={"calibration": cfg.calibration.model_copy(
        update={"min_gain": 0.999, "file": cfg.calibration.file + ".strict"})}), dev, dev.robot)
    out = strict.run_safely(0, CancelToken(dev.clock))
    assert out.status == "fault" and out.fault_code == Fault.CALIBRATION_FIT
    assert "held-out check failed, nothing written" in out.fault_text
    assert not (__import__("pathlib").Path(cfg.calibration.file + ".strict")).exists()


def test_plc_entry_refuses_j3_and_a_board_out_of_reach(cell):
    cfg, dev, cal = cell
    out = cal.run_safely(3, CancelToken(dev.clock))
    assert out.fault_code == Fault.CALIBRATION_REFUSED and "j3 is prismatic" in out.fault_text
    far = CellCalibrator(cfg.model_copy(update={"calibration": cfg.calibration.model_copy(update={
        "board": {"kind": "circles", "cols": 3, "rows": 3, "pitch_mm": 100, "radius_mm": 3,
                  "origin_mm": [5000, 5000]}})}), dev, dev.robot)
    out = far.run_safely(0, CancelToken(dev.clock))
    assert out.fault_code == Fault.CALIBRATION_FIT and "board not found" in out.fault_text
    with pytest.raises(CalibrationError, match="cannot select 2 of"):
        cal.kinematics(poses=2, holdout=3, write=False)


def test_a_cancel_ends_the_calibration_as_aborted(cell):
    _, dev, cal = cell
    token = CancelToken(dev.clock)
    token.cancel(0, "abort by PLC")
    out = cal.run_safely(2, token)
    assert out.status == "aborted" and out.fault_text == "abort by PLC"
    json.dumps(out.calibration)          # None or plain
