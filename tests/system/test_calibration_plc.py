"""Calibration started from the PLC (issue 10): the calibrate bit and calibration_select, the
CALIBRATING state under the heartbeat watchdog, residuals and the calibration version in
registers, the new model used by the next cycles (and recorded in their rows)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from cell.cycle.statemachine import State
from cell.cyclelog import CycleLog
from cell.faults import Fault
from tests.waiting import unchanged_over


def small(h, poses=10, holdout=6):
    h.cell.calibrator.config = h.cell.calibrator.config.model_copy(update={
        "calibration": h.cell.calibrator.config.calibration.model_copy(
            update={"poses": poses, "holdout": holdout, "runs": 1})})


@pytest.mark.slow
def test_kinematic_calibration_from_the_plc_is_written_applied_and_recorded(harness):
    h = harness
    small(h)
    h.cell.calibrator.path = str(h.tmp_path / "robot-calibration.json")
    assert h.cycle()["done"] == 1
    assert h.plc.inputs()["calibration_version"] == 0
    res = h.plc.run_calibration(0)
    assert res["done"] == 1 and res["fault_code"] == 0
    # held-out residual: what is left is the arm's repeatability, σ per axis on each arrival
    # (the hand camera's own centre error is ~0.5 µm), so a 2-D rms of √2·σ = 14 µm here
    # (this run: 13). Over 6 held-out poses an rms scatters by ~1/√12 ≈ 30 %: a window of 2×
    # either side.
    noise_um = 1000 * math.sqrt(2) * h.cell.devices.plant.config.repeatability_mm
    assert res["calibration_version"] == 1
    assert 0.5 * noise_um < res["calibration_residual_um"] < 2 * noise_um
    assert h.cell.runner.robot.calibration.startswith("v1-")
    assert h.cycle()["done"] == 1
    log = CycleLog(h.config.log.path, readonly=True)
    try:
        rows = log.cycles()
        audit = [r for r in log.audit_rows() if r["action"] == "calibration_write"]
        assert log.verify_audit() is None
    finally:
        log.close()
    assert [r.calibration for r in rows] == ["", h.cell.runner.robot.calibration]
    # the write is in the hash-chained audit trail, with the file and the document's hash
    assert len(audit) == 1 and audit[0]["target"] == h.cell.calibrator.path
    assert audit[0]["result"] == f"applied {h.cell.runner.robot.calibration}"
    assert h.cell.runner.robot.calibration.split("-")[1] == audit[0]["hash"][:8]


def test_joint_calibration_from_the_plc_reports_its_residual(harness):
    h = harness
    small(h)
    res = h.plc.run_calibration(2)
    assert res["done"] == 1 and res["calibration_residual_um"] == 0
    # The model's residual is the noise of one image's angle. The hand camera sits on the
    # tool and the target stays put, so j2 swings the camera on a circle of radius l2 about
    # the target; each arrival puts the tool off by the plant's repeatability σ per axis
    # (one draw per arrival), whose tangential part turns the seen angle by σ / l2 rad. The
    # camera's own centre error (~0.005 px of 0.1 mm) is negligible. Hand calculation:
    # 0.01 mm / 500 mm = 2e-5 rad = 1146 µdeg (this run: 1211). The rms of the residuals is
    # a little below σ (parameters fitted) and scatters by ~1/√(2·dof): a window of 2×.
    plant, robot = h.cell.devices.plant, h.cell.devices.robot
    predicted_udeg = 1e6 * math.degrees(plant.config.repeatability_mm / robot.g.l2_mm)
    assert 0.7 * predicted_udeg < res["calibration_residual_udeg"] < 1.4 * predicted_udeg
    # the joint's terms are recorded (a new version of the file) and applied: the backlash,
    # and no gear-ratio or cyclic term, as the default plant has none
    assert res["calibration_version"] == 1
    doc = json.loads(Path(h.cell.calibrator.path).read_text())
    assert doc["joints"]["j2"]["applied"] == [] and doc["parameters"] == {}
    assert h.cell.runner.robot.backlash_deg[1] > 0.015 and h.cell.runner.robot.joint_effects == ()


def test_heartbeat_loss_mid_calibration_stops_the_joints_and_faults_101(harness):
    h = harness
    small(h)
    h.plc._set_output("calibration_select", 1)
    h.wait(lambda: h.status()["ready"] and h.plc.inputs()["calibration_select"] == 1, what="ready")
    h.plc.set_command(calibrate=True)
    h.wait(lambda: h.controller.sm.state is State.CALIBRATING, what="calibrating")
    start = h.joints()
    h.wait(lambda: abs(h.joints() - start).max() > 0.1, what="the calibration moving a joint")
    h.plc.pause_heartbeat()
    h.wait(lambda: h.status()["error"], what="error")
    assert h.plc.inputs()["fault_code"] == Fault.PLC_HEARTBEAT_LOST
    h.wait(lambda: h.controller.sm.state is State.FAULT, what="fault")
    h.wait(lambda: unchanged_over(h.joints, h.sleep, 0.05), what="the quick-stop ramp over")
    still = h.joints()
    h.sleep(1.0)
    assert abs(h.joints() - still).max() < 1e-9                   # nothing moves until reset


def test_j3_is_refused_with_fault_601(harness):
    h = harness
    res = h.plc.run_calibration(3, timeout_s=10)
    assert res["error"] == 1 and res["fault_code"] == Fault.CALIBRATION_REFUSED
