"""The cell survives its own faults: a restart is a new start, a hung camera times out, an
abort gets through while a grab hangs, recipe files never block the scan, every row says
what the PLC was told. Whole cell, simulated PLC, one simulated clock; each test reproduces
a field-probe finding named in its doc."""
from __future__ import annotations

import numpy as np

from cell.cycle.statemachine import State
from cell.cyclelog import CycleLog
from cell.faults import Fault

SCAN_S = 0.01


def start_cycle(h, recipe="fast-a") -> int:
    """Present a part and raise execute the way SimPlc.run_cycle does, without waiting."""
    part_id = h.present(recipe)
    h.plc.select_recipe(h.cell.recipes.active[recipe].recipe.number)
    h.plc.set_part_id(part_id)
    h.wait(lambda: h.status()["ready"] and h.plc.inputs()["part_id"] == part_id, what="ready")
    h.plc.set_command(execute=True)
    return part_id


def test_a_hung_camera_faults_301_after_the_grab_time_out(harness):
    """Probe: a hung camera never timed out; the PLC saw busy for over 30 s, no fault."""
    h = harness
    assert h.cycle()["done"] == 1
    h.cell.camera.hang()
    start_cycle(h)
    h.wait(lambda: h.controller.sm.state is State.CAPTURE, what="capture")
    t_capture = h.now
    h.wait(lambda: h.status()["error"], timeout_s=5.0, what="error")
    timeout = h.config.vision.grab_timeout_s
    assert h.plc.inputs()["fault_code"] == Fault.CAMERA_FAILED
    # the grab starts up to a scan before the state machine shows CAPTURE
    assert timeout - SCAN_S <= h.controller.core.fault_at - t_capture <= timeout + 2 * SCAN_S
    assert "no frame within 2.0 s" in h.controller.fault_text
    joints = h.joints()
    h.sleep(1.0)
    assert np.allclose(h.joints(), joints)                     # stopped, and nothing moves
    # still hung: after reset the next grab waits once more, then is refused, never piles up
    h.plc.set_command(execute=False)
    h.plc.reset()
    start_cycle(h)
    h.wait(lambda: h.status()["error"], timeout_s=10.0, what="second error")
    assert "still hung" in h.controller.fault_text
    h.cell.camera.release()                                    # the camera comes back
    h.plc.set_command(execute=False)
    h.plc.reset()
    assert h.cycle()["done"] == 1


def test_an_abort_while_a_grab_hangs_reaches_the_plc_at_once(harness):
    """Probe: an abort during the camera hang reached the PLC 18 s late."""
    h = harness
    h.cell.camera.hang()
    start_cycle(h)
    h.wait(lambda: h.controller.sm.state is State.CAPTURE, what="capture")
    h.sleep(0.5)
    h.plc.set_command(abort=True)
    t_abort = h.now
    h.wait(lambda: h.status()["aborted"], timeout_s=1.0, what="aborted")
    # the PLC's write (next PLC scan), the controller's scan, the PLC's read: within 3 scans
    assert h.now - t_abort <= 3 * SCAN_S + 1e-9
    h.cell.camera.release()
    h.plc.set_command(abort=False, execute=False)
    h.plc.set_command(acknowledge=True)
    h.wait(lambda: not h.status()["aborted"], what="acknowledged")
    h.plc.set_command(acknowledge=False)
    assert h.cycle()["done"] == 1


def test_a_cycle_cut_by_a_restart_is_reported_once_and_nothing_moves_without_a_fresh_edge(harness):
    """Probe: after a kill during motion the controller came up IDLE with no fault; a PLC
    that rewrote its held execute 0.5 s later started a cycle (one joint moved 91.9°), and
    the PLC never learned that its cycle was lost."""
    h = harness
    assert h.cycle()["done"] == 1
    part = start_cycle(h, "slow-a")                            # a 2 s final move
    h.wait(lambda: h.controller.sm.state is State.FINAL_MOVE, what="final move")
    before = h.joints()
    h.wait(lambda: abs(h.joints() - before).max() > 0.1, what="the final move under way")
    h.cell.stop()                                              # the controller goes down mid-motion
    h.sleep(0.5)
    h.cell = h.new_cell(port=h.port)
    h.cell.start()
    # the PLC's image still holds the old controller's last answer until the link is back
    img = h.wait(lambda: h.plc.inputs()["controller_heartbeat"] < 50 and h.plc.inputs(),
                 what="the new controller's answer")
    assert img["fault_code"] == Fault.INTERRUPTED and img["part_id_echo"] == part
    assert h.status()["error"] and not h.status()["ready"] and h.controller.sm.state is State.FAULT
    reader = CycleLog(h.config.log.path, readonly=True)
    last = reader.cycles()[-1]
    reader.close()
    assert (last.part_id, last.status, last.fault_code) == (part, "aborted", Fault.INTERRUPTED)
    joints = h.joints()
    h.sleep(0.5)
    h.plc.set_command(execute=True)                            # held execute rewritten: nothing
    h.sleep(1.0)
    assert np.allclose(h.joints(), joints) and h.controller.sm.state is State.FAULT
    h.plc.reset()                                              # the PLC has seen it: reset clears it
    assert h.plc.inputs()["fault_code"] == 0
    h.sleep(0.5)
    assert h.controller.sm.state is State.IDLE and np.allclose(h.joints(), joints)
    assert h.cell.cyclelog.open_cycle() is None                # reported once: not at the next start
    h.plc.set_command(execute=False)                           # a fresh edge runs
    assert h.cycle()["done"] == 1


def test_every_row_is_settled_to_what_the_plc_was_told(harness):
    h = harness
    for _ in range(3):
        assert h.cycle()["done"] == 1
    h.wait(lambda: h.cell.cyclelog.open_cycle() is None, what="the last cycle settled")
    assert [c.status for c in h.cell.cyclelog.cycles()] == ["done"] * 3


def test_recipe_files_are_read_off_the_scan_task_and_a_huge_one_never(harness):
    """Probe: a valid 50 MB recipe froze the scan loop for 139 s; its text went to the log."""
    h = harness
    store = h.cell.recipes
    before, opened = store.refreshes.copy(), store.files_opened
    big = h.tmp_path / "recipes" / "huge.yaml"
    with open(big, "wb") as f:
        f.write(b"name: huge\nnumber: 50\npart: {nominal_xy_mm: [250, 930], fiducial_radius_mm: 1.5}\n")
        f.truncate(50_000_000)
    h.wait(lambda: any(a["target"] == str(big) for a in h.cell.cyclelog.audit_rows()), what="audit of huge.yaml")
    [row] = [a for a in h.cell.cyclelog.audit_rows() if a["target"] == str(big)]
    assert row["action"] == "recipe_reject" and "over the limit" in row["result"] and row["hash"] == ""
    since = store.refreshes - before                           # the refreshes that saw it
    assert since and set(since) == {"cell-log"}
    assert store.files_opened == opened                        # refused from its size, never opened
    assert h.cycle()["done"] == 1


def test_every_cycle_runs_on_one_long_lived_thread(harness):
    """Soak: a thread per cycle leaked OpenCV's thread-local state (~0.9 kB a thread, ~0.9 MB
    per 1000 cycles); cycles are jobs of one cell-cycle worker now."""
    h = harness
    rows, threads = len(h.cell.cyclelog.cycles()), []
    for _ in range(3):
        assert h.cycle()["done"] == 1
        threads.append(h.cell.runner.last_thread)
    assert len(h.cell.cyclelog.cycles()) == rows + 3           # three cycles ran, each its own row
    assert threads[0] is not None and threads[0].name == "cell-cycle" and threads[0].is_alive()
    assert all(t is threads[0] for t in threads)              # the same thread object, still running
