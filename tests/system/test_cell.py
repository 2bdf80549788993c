"""Whole-cell scenarios: the simulated PLC drives the real server, stations, camera and log."""
from __future__ import annotations

import threading
import time

import numpy as np

from cell.cyclelog import CycleLog
from cell.faults import Fault, station_fault
from cell.statemachine import State


def test_fifty_cycles_without_a_fault(harness):
    results = [harness.cycle() for _ in range(50)]
    assert all(r["done"] == 1 and r["error"] == 0 for r in results)
    finals = np.array([r["final_error_um"] for r in results]) / 1000.0
    assert finals.max() <= 0.08                       # the recipe's verify tolerance
    assert results[-1]["cycle_count"] == 50
    cycles = harness.cell.cyclelog.cycles()
    assert len(cycles) == 50 and {c.status for c in cycles} == {"done"}
    recipe = harness.cell.recipes.active["fast-a"]
    assert {(c.recipe, c.recipe_hash) for c in cycles} == {("fast-a", recipe.hash)}
    assert all(set(c.step_times) >= {"approach", "capture", "locate", "compensate", "final_move",
                                     "verify"} for c in cycles)
    # seed 000 step 5: the learned start offset makes later first arrivals closer
    initial = np.array([c.initial_error_mm for c in cycles])
    assert np.median(initial[-10:]) < np.median(initial[:3])


def test_heartbeat_loss_mid_cycle_stops_joints_and_faults(harness):
    harness.cycle()
    part = harness.present("slow-a")
    harness.plc.select_recipe(8)
    harness.plc.set_part_id(part)
    harness.plc.set_command(execute=True)
    harness.wait(lambda: harness.controller.sm.state is State.FINAL_MOVE, what="FINAL_MOVE")
    harness.plc.pause_heartbeat()
    harness.wait(lambda: harness.controller.sm.state is State.FAULT, what="FAULT")
    assert harness.controller.fault_code == Fault.PLC_HEARTBEAT_LOST
    drives = harness.cell.motion.drive_states()
    assert {s.name for s in drives.values()} == {"QUICK_STOP_ACTIVE"}
    time.sleep(0.1)                                   # the quick-stop ramp (a category 2 stop)
    q = harness.joints()
    time.sleep(0.3)
    np.testing.assert_allclose(harness.joints(), q, atol=1e-3)        # nothing moves
    last = harness.cell.cyclelog.cycles()[-1]
    assert last.status == "aborted" and last.fault_code == Fault.PLC_HEARTBEAT_LOST
    # the PLC comes back with execute still high: no cycle starts, reset recovers
    harness.plc.resume_heartbeat()
    harness.wait(lambda: harness.status()["plc_link_ok"], what="link ok")
    assert harness.status()["error"] and harness.plc.inputs()["fault_code"] == Fault.PLC_HEARTBEAT_LOST
    harness.plc.set_command(execute=False)
    harness.plc.reset()
    harness.plc.select_recipe(7)
    assert harness.controller.sm.state is State.IDLE and harness.status()["ready"]
    assert harness.cycle()["done"] == 1


def test_station_silent_faults_and_reset_needs_it_back(harness):
    harness.cycle()
    harness.cell.sim.sim_stations.by_joint("j2").unplug()
    harness.wait(lambda: harness.controller.sm.state is State.FAULT, what="FAULT")
    harness.wait(lambda: harness.plc.inputs()["fault_code"] == station_fault(1),
                 what="fault code 201 (station heartbeat lost) at the PLC")
    harness.plc.set_command(reset=True)
    time.sleep(0.3)
    harness.plc.set_command(reset=False)
    assert harness.controller.sm.state is State.FAULT                 # cause persists
    harness.cell.sim.sim_stations.by_joint("j2").power_cycle()      # cable back in, drive rebooted
    time.sleep(0.3)
    harness.plc.reset(timeout_s=10)
    assert harness.cycle()["done"] == 1


def test_camera_finds_no_target_faults_without_motion(harness):
    harness.cycle()
    harness.cell.sim.feeder.remove()                  # no part on the conveyor
    log = []
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            try:
                log.append((harness.controller.sm.state, harness.joints().copy()))
            except Exception:                         # noqa: BLE001 -- sampling only
                pass
            time.sleep(0.005)
    t = threading.Thread(target=sample)
    t.start()
    res = harness.plc.run_cycle(7, 999, timeout_s=20)
    time.sleep(0.2)                                   # keep sampling while the fault stands
    stop.set()
    t.join()
    assert res["error"] == 1 and res["fault_code"] == Fault.NO_TARGET
    # from the capture on, nothing moved: locate failed before any compensation move
    after_capture = [q for s, q in log if s in (State.LOCATE, State.STOPPING, State.FAULT)]
    assert len(after_capture) >= 2 and np.ptp(np.array(after_capture), axis=0).max() < 1e-3
    rec = harness.cell.cyclelog.cycles()[-1]
    assert rec.status == "aborted" and rec.fault_code == Fault.NO_TARGET and rec.moves is None


def test_abort_mid_cycle_and_retrigger_refused(harness):
    part = harness.present("slow-a")
    harness.plc.select_recipe(8)
    harness.plc.set_part_id(part)
    harness.wait(lambda: harness.status()["ready"], what="ready")
    harness.plc.set_command(execute=True)
    harness.wait(lambda: harness.controller.sm.state.busy, what="busy")
    harness.plc.set_command(execute=False)
    time.sleep(0.05)
    harness.plc.set_command(execute=True)             # retrigger while busy: refused visibly
    harness.wait(lambda: harness.status()["execute_refused"], what="execute_refused")
    harness.plc.set_command(execute=False, abort=True)
    harness.wait(lambda: harness.status()["aborted"], what="aborted")
    harness.plc.set_command(abort=False)
    assert harness.cell.cyclelog.cycles()[-1].status == "aborted"
    harness.plc.set_command(acknowledge=True)
    harness.wait(lambda: harness.controller.sm.state is State.IDLE, what="IDLE")
    harness.plc.set_command(acknowledge=False)
    assert harness.cycle()["done"] == 1


def test_bad_recipe_edit_during_a_run_is_rejected_and_the_run_goes_on(harness):
    path = harness.tmp_path / "recipes" / "fast-a.yaml"
    good_hash = harness.cell.recipes.active["fast-a"].hash
    assert harness.cycle()["done"] == 1
    path.write_text(path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: -1"))
    harness.wait(lambda: harness.plc.inputs()["recipe_status"] == 2, what="recipe_status 2")
    results = [harness.cycle() for _ in range(2)]
    assert all(r["done"] == 1 for r in results)
    cycles = harness.cell.cyclelog.cycles()
    assert {c.recipe_hash for c in cycles} == {good_hash}
    audit = harness.cell.cyclelog.audit_rows()
    rejected = [a for a in audit if a["action"] == "recipe_reject"]
    assert rejected and "fast-a.yaml:" in rejected[-1]["result"] and "tolerance_mm" in rejected[-1]["result"]
    assert harness.cell.cyclelog.verify_audit() is None


def test_restart_comes_up_safe_with_execute_held_high(tmp_path):
    from tests.system.conftest import Harness
    h = Harness(tmp_path)
    try:
        assert h.cycle()["done"] == 1
        h.cell.stop()                                 # the controller goes down (crash, update)...
        h.plc.select_recipe(7)
        h.plc.set_command(execute=True)               # ... while the PLC raises and holds execute
        h.cell = type(h.cell)(h.config, sim=True, plc_port=h.port, jobs=False)
        h.cell.start()                                # the PLC reconnects and rewrites its outputs
        h.wait(lambda: h.status()["plc_link_ok"], what="link ok after restart")
        h.wait(lambda: h.cell.plc.read("command_word") & 1, what="execute rewritten by the PLC")
        time.sleep(0.5)
        assert h.controller.sm.state is State.IDLE and not h.status()["busy"]
        assert not h.status()["ready"]                # execute must be seen low first
        assert CycleLog(h.config.log.path).count() == 1
        h.plc.set_command(execute=False)              # a fresh edge starts a cycle
        assert h.cycle()["done"] == 1
    finally:
        h.close()


def test_kill_9_during_a_run_leaves_a_clean_log(tmp_path):
    import os
    import signal
    import sqlite3
    import subprocess
    import sys

    import yaml

    from tests.system.conftest import REPO, make_config
    cfg = make_config(tmp_path)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
    db = cfg.log.path
    proc = subprocess.Popen([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                             "--recipe", "fast-a", "--cycles", "500"], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if os.path.exists(db):
                con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
                try:
                    if con.execute("SELECT COUNT(*) FROM cycles").fetchone()[0] >= 3:
                        break
                except sqlite3.OperationalError:        # file created, schema not yet
                    pass
                finally:
                    con.close()
            time.sleep(0.05)
        time.sleep(0.13)                                # land somewhere inside a cycle
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()
    log = CycleLog(db)                                  # what a restarted controller does
    cycles = log.cycles()
    assert len(cycles) >= 3
    for c in cycles:                                    # every row is a whole cycle
        assert c.status == "done" and c.finished_at and c.moves >= 1 and c.trace
        assert c.verify_error_mm is not None and "verify" in c.step_times
    assert [c.part_id for c in cycles] == list(range(1, len(cycles) + 1))


def test_health_job_sees_drives_and_camera(harness):
    from cell.jobs import CellJobs
    jobs = CellJobs(harness.controller, harness.config.scheduler, harness.config.log.retention_days)
    assert harness.cycle()["done"] == 1
    report = jobs.health()
    assert set(report["drives"].values()) == {"OPERATION_ENABLED"}
    assert report["camera_open"] and report["camera_error"] is None and report["station_fault"] is None
    harness.cell.camera.close()                       # the camera goes away
    res = harness.cycle()
    assert res["error"] == 1 and res["fault_code"] == Fault.CAMERA_FAILED
    report = jobs.health()
    assert not report["camera_open"] and report["camera_error"] and report["station_fault"]
