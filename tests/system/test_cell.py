"""Whole-cell scenarios: the simulated PLC drives the real server, stations, camera and log,
all on one simulated clock; every time asserted here is simulated time."""
from __future__ import annotations

import numpy as np

from cell.cycle.statemachine import State
from cell.cyclelog import CycleLog
from cell.faults import Fault, station_fault
from drivers.plc.register_map import PLC_MAP
from tests.waiting import unchanged_over


def drive_positions(h) -> np.ndarray:
    """Where the drives really are now (the simulated axes, not what they last reported)."""
    return np.array(h.cell.devices.sim_stations.positions())


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
    # seed 002 in every move: corrected velocities for the delays measured on the bus, which
    # grow with the station's place on the bus (σ·i plus the frames before it on the wire)
    for c in cycles:
        m = c.motion
        assert m["mode"] == "corrected" and m["moves"] >= 3 and m["segments"] >= m["moves"]
        assert np.all(np.diff(m["delays_ms"]) > 0.4), m


def test_heartbeat_loss_is_seen_after_the_timeout_and_within_one_scan(harness):
    h = harness
    h.cycle()
    part = h.present("slow-a")
    h.plc.select_recipe(8)
    h.plc.set_part_id(part)
    h.plc.set_command(execute=True)
    h.wait(lambda: h.controller.sm.state is State.FINAL_MOVE, what="FINAL_MOVE")
    h.plc.pause_heartbeat()
    h.plc.wait_scans(1)                               # a scan since: the heartbeat stands still
    last_beat = h.cell.plc.last_heartbeat_change
    h.wait(lambda: h.controller.sm.state is State.FAULT, what="FAULT")
    assert h.cell.plc.last_heartbeat_change == last_beat          # the last change was before
    timeout, scan = h.config.plc.heartbeat_timeout_s, h.config.controller.scan_s
    seen = h.controller.core.fault_at - last_beat
    assert timeout < seen <= timeout + scan + 1e-9, seen
    assert h.controller.fault_code == Fault.PLC_HEARTBEAT_LOST
    drives = h.cell.motion.drive_states()
    assert {s.name for s in drives.values()} == {"QUICK_STOP_ACTIVE"}
    h.wait(lambda: unchanged_over(lambda: drive_positions(h), h.sleep, 0.01),
           what="the quick-stop ramp (a category 2 stop) over")
    q = drive_positions(h)
    h.sleep(0.5)
    np.testing.assert_array_equal(drive_positions(h), q)          # nothing moves
    last = h.cell.cyclelog.cycles()[-1]
    assert last.status == "aborted" and last.fault_code == Fault.PLC_HEARTBEAT_LOST
    # the PLC comes back with execute still high: no cycle starts, reset recovers
    h.plc.resume_heartbeat()
    h.wait(lambda: h.status()["plc_link_ok"], what="link ok")
    assert h.status()["error"] and h.plc.inputs()["fault_code"] == Fault.PLC_HEARTBEAT_LOST
    h.sleep(1.0)
    np.testing.assert_array_equal(drive_positions(h), q)
    h.plc.set_command(execute=False)
    h.plc.reset()
    h.plc.select_recipe(7)
    assert h.controller.sm.state is State.IDLE and h.status()["ready"]
    assert h.cycle()["done"] == 1


def test_station_silent_faults_within_its_watchdog_time_and_reset_needs_it_back(harness):
    h = harness
    h.cycle()
    watchdog = h.cell.motion.watchdog
    h.cell.devices.sim_stations.by_joint("j2").unplug()
    h.wait(lambda: h.controller.sm.state is State.FAULT, what="FAULT")
    h.wait(lambda: h.plc.inputs()["fault_code"] == station_fault(1),
           what="fault code 201 (station heartbeat lost) at the PLC")
    seen = h.controller.core.fault_at - watchdog._last[2]
    assert watchdog.timeout_s < seen <= watchdog.timeout_s + watchdog.period_s + h.config.controller.scan_s
    resets = lambda: [a for a in h.cell.cyclelog.audit_rows() if a["action"] == "reset"]  # noqa: E731
    h.plc.set_command(reset=True)
    h.wait(lambda: resets() and h.controller.sm.state is State.FAULT, what="the reset tried")
    h.plc.set_command(reset=False)
    h.plc.wait_until(lambda i: not PLC_MAP.bits("command_word", i["command_word"])["reset"], 1.0,
                     "reset written low")                # so that the next pulse is an edge
    assert resets()[-1]["result"] == "accepted" and h.controller.sm.state is State.FAULT   # cause persists
    h.cell.devices.sim_stations.by_joint("j2").power_cycle()    # cable back in, drive rebooted
    h.wait(lambda: not watchdog.silent(), what="j2's heartbeat heard again")
    h.plc.reset(timeout_s=10)
    assert h.cycle()["done"] == 1


def test_camera_finds_no_target_faults_without_motion(harness):
    h = harness
    h.cycle()
    h.cell.devices.feeder.remove()                    # no part on the conveyor
    h.plc.select_recipe(7)
    h.plc.set_part_id(999)
    h.wait(lambda: h.status()["ready"], what="ready")
    h.plc.set_command(execute=True)
    seen = []
    h.wait(lambda: seen.append((h.controller.sm.state, drive_positions(h))) or h.status()["error"],
           timeout_s=20, what="error", step_s=0.005)
    h.sleep(0.3)                                      # keep looking while the fault stands
    seen.append((h.controller.sm.state, drive_positions(h)))
    h.plc.set_command(execute=False)
    assert h.plc.inputs()["fault_code"] == Fault.NO_TARGET
    # from the capture on, nothing moved: locate failed before any compensation move
    after_capture = [q for s, q in seen if s in (State.LOCATE, State.STOPPING, State.FAULT)]
    assert len(after_capture) >= 2 and np.ptp(np.array(after_capture), axis=0).max() == 0.0
    rec = h.cell.cyclelog.cycles()[-1]
    assert rec.status == "aborted" and rec.fault_code == Fault.NO_TARGET and rec.moves is None


def test_abort_mid_cycle_and_retrigger_refused(harness):
    h = harness
    part = h.present("slow-a")
    h.plc.select_recipe(8)
    h.plc.set_part_id(part)
    h.wait(lambda: h.status()["ready"], what="ready")
    h.plc.set_command(execute=True)
    h.wait(lambda: h.controller.sm.state.busy, what="busy")
    h.plc.set_command(execute=False)
    h.plc.wait_until(lambda i: not i["command_word"] & 1, 1.0, "execute written low")
    h.plc.set_command(execute=True)                   # retrigger while busy: refused visibly
    h.wait(lambda: h.status()["execute_refused"], what="execute_refused")
    h.plc.set_command(execute=False, abort=True)
    h.wait(lambda: h.status()["aborted"], what="aborted")
    h.plc.set_command(abort=False)
    rec = h.cell.cyclelog.cycles()[-1]
    assert rec.status == "aborted" and rec.fault_code == 0 and rec.fault_text == "abort by PLC"
    h.plc.set_command(acknowledge=True)
    h.wait(lambda: h.controller.sm.state is State.IDLE, what="IDLE")
    h.plc.set_command(acknowledge=False)
    assert h.cycle()["done"] == 1


def test_sync_mode_recipe_runs_every_move_on_sync(harness):
    h = harness
    path = h.tmp_path / "recipes" / "fast-a.yaml"
    path.write_text(path.read_text().replace("  sync: corrected\n", "  sync: sync\n"))
    h.wait(lambda: "sync" == h.cell.recipes.active["fast-a"].recipe.motion.sync, what="sync recipe active")
    res = [h.cycle() for _ in range(3)]
    assert all(r["done"] == 1 for r in res)
    assert {c.motion["mode"] for c in h.cell.cyclelog.cycles()[-3:]} == {"sync"}


def test_recipe_the_stations_cannot_run_is_refused_naming_the_field(harness):
    h = harness
    path = h.tmp_path / "recipes" / "fast-a.yaml"
    good = h.cell.recipes.active["fast-a"].hash
    path.write_text(path.read_text().replace("  segment_ms: 10\n", "  segment_ms: 1\n"))
    h.wait(lambda: h.plc.inputs()["recipe_status"] == 2, what="recipe_status 2")
    rejected = [a for a in h.cell.cyclelog.audit_rows() if a["action"] == "recipe_reject"][-1]
    assert "motion.segment_ms" in rejected["result"] and "fast-a.yaml:" in rejected["result"]
    assert h.cell.recipes.active["fast-a"].hash == good
    assert h.cycle()["done"] == 1                     # the last good version runs on


def test_bad_recipe_edit_during_a_run_is_rejected_and_the_run_goes_on(harness):
    h = harness
    path = h.tmp_path / "recipes" / "fast-a.yaml"
    good_hash = h.cell.recipes.active["fast-a"].hash
    assert h.cycle()["done"] == 1
    path.write_text(path.read_text().replace("tolerance_mm: 0.08", "tolerance_mm: -1"))
    h.wait(lambda: h.plc.inputs()["recipe_status"] == 2, what="recipe_status 2")
    results = [h.cycle() for _ in range(2)]
    assert all(r["done"] == 1 for r in results)
    cycles = h.cell.cyclelog.cycles()
    assert {c.recipe_hash for c in cycles} == {good_hash}
    audit = h.cell.cyclelog.audit_rows()
    rejected = [a for a in audit if a["action"] == "recipe_reject"]
    assert rejected and "fast-a.yaml:" in rejected[-1]["result"] and "tolerance_mm" in rejected[-1]["result"]
    assert h.cell.cyclelog.verify_audit() is None


def test_restart_comes_up_safe_with_execute_held_high(harness):
    h = harness
    assert h.cycle()["done"] == 1
    h.cell.stop()                                     # the controller goes down (crash, update)...
    h.plc.select_recipe(7)
    h.plc.set_command(execute=True)                   # ... while the PLC raises and holds execute
    errors = h.plc.link_errors
    h.wait(lambda: h.plc.link_errors > errors, what="the PLC finding the link down")
    h.cell = h.new_cell(port=h.port)
    h.cell.start()                                    # the PLC reconnects and rewrites its outputs
    h.wait(lambda: h.status()["plc_link_ok"], what="link ok after restart")
    h.wait(lambda: h.cell.plc.read("command_word") & 1, what="execute rewritten by the PLC")
    h.sleep(0.5)
    assert h.controller.sm.state is State.IDLE and not h.status()["busy"]
    assert not h.status()["ready"]                    # execute must be seen low first
    assert CycleLog(h.config.log.path, readonly=True).count() == 1
    h.plc.set_command(execute=False)                  # a fresh edge starts a cycle
    assert h.cycle()["done"] == 1


def test_kill_9_during_a_run_leaves_a_clean_log(tmp_path):
    """Killed inside a cycle (the log's open-cycle row says one is running) after 3 whole
    ones: the log is sound, holds only whole cycles, and names the one cut short."""
    import os
    import signal
    import sqlite3
    import subprocess
    import sys

    import yaml

    from tests.system.conftest import REPO, make_config
    from tests.waiting import wait_for
    cfg = make_config(tmp_path)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
    db = cfg.log.path
    proc = subprocess.Popen([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                             "--recipe", "fast-a", "--cycles", "500"], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def running_after_three():
        """The part of the cycle running now, once 3 are logged (another process's
        simulation: its log is all we can watch)."""
        if not os.path.exists(db):
            return None
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            if con.execute("SELECT COUNT(*) FROM cycles").fetchone()[0] < 3:
                return None
            row = con.execute("SELECT part_id FROM open_cycle WHERE stage = 'running'").fetchone()
            return row and row[0]
        except sqlite3.OperationalError:                # file created, schema not yet
            return None
        finally:
            con.close()
    try:
        running = wait_for(running_after_three, 300, "a cycle running after 3 logged", every=0.002)
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
    cut = log.recover_interrupted()                     # the kill landed inside a cycle ...
    assert cut is not None and cut.part_id >= running   # ... the one seen running (or the next)
    log.close()


def test_health_job_sees_drives_and_camera(harness):
    from cell.jobs import CellJobs
    h = harness
    jobs = CellJobs(h.controller, h.config.scheduler, h.config.log.retention_days, clock=h.clock)
    assert h.cycle()["done"] == 1
    report = jobs.health()
    assert set(report["drives"].values()) == {"OPERATION_ENABLED"}
    assert report["camera_open"] and report["camera_error"] is None and report["station_fault"] is None
    h.cell.camera.close()                             # the camera goes away
    res = h.cycle()
    assert res["error"] == 1 and res["fault_code"] == Fault.CAMERA_FAILED
    report = jobs.health()
    assert not report["camera_open"] and report["camera_error"] and report["station_fault"]


def test_a_half_written_recipe_is_not_taken_however_fast_simulated_time_runs(tmp_path):
    """Probe: while cycles ran, 4 truncated recipe files (an editor saving in place) became
    the active version. The settle time ran on the simulated clock, which races ahead of
    the wall clock, so a file left half-written for a moment looked stable. Edits settle on
    the file clock (wall time in the product; held still here) now."""
    from cell.clock import ManualClock
    from tests.system.conftest import Harness
    files = ManualClock(0.0)
    h = Harness(tmp_path, settle_s=1.0, file_clock=files)
    try:
        path = h.tmp_path / "recipes" / "fast-a.yaml"
        before = h.cell.recipes.active["fast-a"].hash
        full = path.read_text()
        path.write_text(full[:full.index("verify:")])      # valid on its own: verify has defaults
        h.sleep(5.0)                                        # 100 refreshes of simulated time ...
        assert h.cell.recipes.active["fast-a"].hash == before   # ... but no wall time: not taken
        path.write_text(full.replace("tolerance_mm: 0.08", "tolerance_mm: 0.07"))   # the rest
        h.sleep(0.2)
        files.advance(1.5)                                  # now the whole file has settled
        h.wait(lambda: h.cell.recipes.active["fast-a"].hash != before, what="the whole edit")
        assert h.cell.recipes.active["fast-a"].recipe.verify.tolerance_mm == 0.07
        assert h.cycle()["done"] == 1
    finally:
        h.close()


def test_an_edit_the_robot_cannot_reach_is_refused_before_it_runs(harness):
    """Probe: a nominal position out of reach was activated and faulted 401 at run time."""
    h = harness
    path = h.tmp_path / "recipes" / "fast-a.yaml"
    good = h.cell.recipes.active["fast-a"].hash
    text = path.read_text()
    x, y = h.cell.recipes.active["fast-a"].recipe.part.nominal_xy_mm
    path.write_text(text.replace(f"[{x}, {y}]", f"[{x + 700.0}, {y}]"))
    h.wait(lambda: h.plc.inputs()["recipe_status"] == 2, what="recipe_status 2")
    rejected = [a for a in h.cell.cyclelog.audit_rows() if a["action"] == "recipe_reject"
                and a["target"] == str(path)][-1]
    assert "part.nominal_xy_mm" in rejected["result"] and "out of reach" in rejected["result"]
    assert h.cell.recipes.active["fast-a"].hash == good and h.cycle()["done"] == 1


def test_on_the_simulated_clock_the_scan_and_the_watchdog_are_clock_callbacks(harness):
    """No thread of their own (each wake-up of one cost a hand-off of the clock's baton);
    the scan still runs every scan_s of clock time, serves the PLC and stops with the cell."""
    import threading
    names = {t.name for t in threading.enumerate()}
    assert "cell-scan" not in names and "stations-watchdog" not in names
    c = harness.controller
    period = c.settings.scan_s
    n0 = c.scans
    harness.sleep(50 * period)
    assert c.scans - n0 in (49, 50, 51)               # the sleep's ends may fall on a scan
    assert harness.cycle()["done"] == 1
    harness.cell.stop()
    n1 = c.scans
    harness.sleep(10 * period)
    assert c.scans == n1                              # stopped: no scan comes any more
