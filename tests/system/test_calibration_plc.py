"""Calibration started from the PLC (issue 10): the calibrate bit and calibration_select, the
CALIBRATING state under the heartbeat watchdog, residuals and the calibration version in
registers, the new model used by the next cycles (and recorded in their rows)."""
from __future__ import annotations

from cell.cyclelog import CycleLog
from cell.faults import Fault
from cell.statemachine import State


def small(h, poses=10, holdout=6):
    h.cell.calibrator.config = h.cell.calibrator.config.model_copy(update={
        "calibration": h.cell.calibrator.config.calibration.model_copy(
            update={"poses": poses, "holdout": holdout, "runs": 1})})


def test_kinematic_calibration_from_the_plc_is_written_applied_and_recorded(harness):
    h = harness
    small(h)
    h.cell.calibrator.path = str(h.tmp_path / "robot-calibration.json")
    assert h.cycle()["done"] == 1
    assert h.plc.inputs()["calibration_version"] == 0
    res = h.plc.run_calibration(0)
    assert res["done"] == 1 and res["fault_code"] == 0
    assert res["calibration_version"] == 1 and 0 < res["calibration_residual_um"] < 100
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
    assert 100 < res["calibration_residual_udeg"] < 10_000        # ~1e-3 deg of repeatability
    assert res["calibration_version"] == 0                        # a joint calibration writes no model


def test_heartbeat_loss_mid_calibration_stops_the_joints_and_faults_101(harness):
    h = harness
    small(h)
    h.plc._set_output("calibration_select", 1)
    h.wait(lambda: h.status()["ready"] and h.plc.inputs()["calibration_select"] == 1, what="ready")
    h.plc.set_command(calibrate=True)
    h.wait(lambda: h.controller.sm.state is State.CALIBRATING, what="calibrating")
    h.sleep(0.3)
    h.plc.pause_heartbeat()
    h.wait(lambda: h.status()["error"], what="error")
    assert h.plc.inputs()["fault_code"] == Fault.PLC_HEARTBEAT_LOST
    h.wait(lambda: h.controller.sm.state is State.FAULT, what="fault")
    h.sleep(0.5)                                                  # the quick-stop ramp
    still = h.joints()
    h.sleep(1.0)
    assert abs(h.joints() - still).max() < 1e-9                   # nothing moves until reset


def test_j3_is_refused_with_fault_601(harness):
    h = harness
    res = h.plc.run_calibration(3, timeout_s=10)
    assert res["error"] == 1 and res["fault_code"] == Fault.CALIBRATION_REFUSED
