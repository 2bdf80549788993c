"""The main commands end to end: ``cellctl run --sim`` prints its cycles; ``cellctl serve --sim``
is driven through a full cycle by pyModbusTCP, a Modbus client nobody here wrote."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import yaml
from pyModbusTCP.client import ModbusClient

from drivers.plc.register_map import PLC_MAP
from tests.system.conftest import REPO, make_config


def write_config(tmp_path):
    """The system config for a ``cellctl`` child on wall time. Its PLC is a thread of this
    test process, and a loaded machine can hold a thread for longer than the 0.4 s the
    in-process tests use: a stalled heartbeat would lose the link (and its ownership), which
    these tests are not about. The watchdog itself is tested on the simulated clock.
    (The CI failure this guards against may also have been the race fixed in ``regs``: a
    heartbeat sent before the server listened, a read just after, so no owner yet.)"""
    cfg = make_config(tmp_path, heartbeat_timeout_s=5.0)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json")))
    return cfg, path


def run_json(path, *extra) -> dict:
    out = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                          "--recipe", "fast-a", "--json", *extra], cwd=REPO,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


def without_wall_time(d):
    """``d`` without the fields that depend on the host (their names say so: ``wall_s``)."""
    if isinstance(d, dict):
        return {k: without_wall_time(v) for k, v in d.items() if k != "wall_s"}
    if isinstance(d, list):
        return [without_wall_time(v) for v in d]
    return d


def test_run_sim_prints_cycles_as_json(tmp_path):
    cfg, path = write_config(tmp_path)
    cycles = run_json(path, "--cycles", "3")["cycles"]
    assert [c["part_id"] for c in cycles] == [1, 2, 3]
    for c in cycles:
        assert set(c) >= {"part_id", "recipe", "initial_error_mm", "final_error_mm", "moves",
                          "cycle_time_s", "plc_round_trip_s", "motion", "fault", "wall_s"}
        assert c["fault"] is None and c["recipe"] == "fast-a" and 0 < c["final_error_mm"] <= 0.08
        assert c["motion"]["mode"] == "corrected" and len(c["motion"]["delays_ms"]) == 4


def test_run_sim_twice_with_one_seed_prints_the_same_cycles(tmp_path):
    """Deterministic: only the fields named wall_s may differ between two runs (and the
    second run starts from power-on too: the first run's log is kept aside, not learned from)."""
    cfg, path = write_config(tmp_path)
    first = run_json(path, "--cycles", "4", "--seed", "7")
    second = run_json(path, "--cycles", "4", "--seed", "7")
    assert without_wall_time(first) == without_wall_time(second)
    assert len(list(tmp_path.glob("cell.prev-*.sqlite"))) == 1
    other = run_json(path, "--cycles", "4", "--seed", "8")
    assert len(list(tmp_path.glob("cell.prev-*.sqlite"))) == 2        # kept, never overwritten
    assert without_wall_time(other)["cycles"] != without_wall_time(first)["cycles"]


def test_run_sim_bad_input(tmp_path):
    cfg, path = write_config(tmp_path)
    out = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--config", str(path),
                          "--recipe", "nope", "--cycles", "1"], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2 and "recipe 'nope' is not active" in out.stderr


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_sim_is_driven_by_an_independent_modbus_client(tmp_path):
    cfg, path = write_config(tmp_path)
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(path),
                             "--port", str(port), "--seconds", "60"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    c = ModbusClient(host="127.0.0.1", port=port, auto_open=True, timeout=2.0)
    hb = 0

    def regs():
        nonlocal hb
        hb = (hb + 1) & 0xFFFF
        if not c.write_single_register(PLC_MAP["plc_heartbeat"].address, hb):
            return None         # not landed (e.g. the server came up only for the read after it)
        r = c.read_holding_registers(0, PLC_MAP.size)
        return r and {reg.name: (r[reg.address] << 16 | r[reg.address + 1]) if reg.words == 2
                      else r[reg.address] for reg in PLC_MAP}

    def until(pred, what, timeout_s=30.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            img = regs()
            if img and pred(img):
                return img
            time.sleep(0.02)
        raise AssertionError(f"timed out waiting for {what}")

    def bits(img):
        return PLC_MAP.bits("status_word", img["status_word"])

    try:
        img = until(lambda i: i["map_version"] == PLC_MAP.version, "the server")
        assert c.write_single_register(PLC_MAP["recipe_select"].address, 7), c.last_except
        assert c.write_multiple_registers(PLC_MAP["part_id"].address, [0, 4242]), c.last_except
        cmd = PLC_MAP["command_word"].address
        assert not bits(regs())["ready"]                             # not armed yet after start
        assert c.write_single_register(cmd, 0)                       # execute written low: armed
        img = until(lambda i: i["recipe_ack"] == 7 and bits(i)["ready"], "recipe 7 and ready")
        assert c.write_single_register(cmd, 1)                       # execute
        img = until(lambda i: bits(i)["done"] or bits(i)["error"], "done")
        assert bits(img)["done"] and img["part_id_echo"] == 4242 and img["fault_code"] == 0
        assert 0 < img["final_error_um"] <= 80 and img["moves"] >= 1 and img["cycle_count"] == 1
        assert c.write_single_register(cmd, 8)                       # drop execute, acknowledge
        until(lambda i: not bits(i)["done"], "done cleared")
        # a write the map refuses: the client gets the exception, nothing changes
        assert not c.write_single_register(PLC_MAP["fault_code"].address, 5)
        assert c.last_except == 2 and regs()["fault_code"] == 0
    finally:
        c.close()
        proc.terminate()
        proc.wait(timeout=30)


def test_kill_9_during_motion_then_restart_reports_the_cycle_and_moves_nothing(tmp_path):
    """Field probe, as run: ``serve --sim`` killed with SIGKILL while a joint moves, started
    again on the same log; the PLC resumes its heartbeat first and rewrites its held execute
    later. Before: the controller came up IDLE with no fault and started a cycle (a joint
    moved 91.9°), and the lost cycle left no row. Wall time here: another process's cell."""
    import signal

    from cell.clock import MonotonicClock
    from cell.cyclelog import CycleLog
    from cell.sim.plc import SimPlc
    cfg, path = write_config(tmp_path)
    port = free_port()

    def serve():
        return subprocess.Popen([sys.executable, "-m", "cell.cli", "serve", "--sim", "--config", str(path),
                                 "--port", str(port), "--seconds", "120"], cwd=REPO,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)

    def plc_for(proc):
        assert "serving Modbus TCP" in proc.stdout.readline()
        plc = SimPlc("127.0.0.1", port, clock=MonotonicClock(), timeout_s=5.0)
        plc.start()
        return plc

    first = serve()
    try:
        plc = plc_for(first)
        plc.select_recipe(8)                                # slow-a: a 2 s final move
        plc.set_part_id(31337)
        plc.wait_until(lambda i: i["recipe_ack"] == 8 and PLC_MAP.bits("status_word", i["status_word"])["ready"],
                       60.0, "ready")
        plc.set_command(execute=True)
        plc.wait_until(lambda i: i["state_code"] == 14, 60.0, "final move")   # FINAL_MOVE: joints moving
        plc.wait_scans(3)                                   # a few PLC scans into the 2 s move ...
        assert plc.inputs()["state_code"] == 14, "the final move ended before the kill"   # ... still in it
        first.send_signal(signal.SIGKILL)
        first.wait()
        plc.stop()
    finally:
        if first.poll() is None:
            first.kill()
    second = serve()
    try:
        plc = plc_for(second)                               # heartbeat first, execute still held
        img = plc.wait_until(lambda i: i["fault_code"] != 0, 60.0, "the restart's fault")
        assert img["fault_code"] == 503 and img["part_id_echo"] == 31337
        assert img["state_code"] == 40                      # FAULT: nothing moves until reset
        plc.set_command(execute=False)
        plc.wait_scans(3)                                   # execute written low (and read back)
        img = plc.inputs()
        assert img["command_word"] == 0 and not PLC_MAP.bits("status_word", img["status_word"])["execute_refused"]
        plc.set_command(execute=True)                        # even a fresh edge is refused:
        img = plc.wait_until(lambda i: PLC_MAP.bits("status_word", i["status_word"])["execute_refused"],
                             30.0, "the fresh execute edge refused")   # set by this edge, not before
        assert img["command_word"] & 1 and img["state_code"] == 40 and img["fault_code"] == 503
        plc.stop()
    finally:
        second.terminate()
        second.wait(timeout=30)
    log = CycleLog(cfg.log.path, readonly=True)
    last = log.cycles()[-1]
    assert (last.part_id, last.status, last.fault_code) == (31337, "aborted", 503)
    assert log.open_cycle()["stage"] == "interrupted"       # until the PLC resets it
    log.close()


def test_run_prints_a_faulted_parts_own_logged_figures(tmp_path):
    """Probe: a faulted part printed the previous part's figures while the log held NULL and
    'aborted' for it. pin-b faults 402 on this plant (its file says why): its row must show
    what the log holds for that part, and the fault."""
    from cell.cyclelog import CycleLog
    db = tmp_path / "cell.sqlite"        # the built-in sim cell, seed 0: part 52 faults 402
    out = subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--db", str(db),
                          "--recipe", "pin-b", "--allow-examples", "--cycles", "5", "--first-part", "50",
                          "--json"],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 1, out.stderr[-2000:]
    rows = json.loads(out.stdout)["cycles"]
    log = CycleLog(db, readonly=True)
    logged = {c.part_id: c for c in log.cycles()}
    log.close()
    *good, bad = rows                                   # the run stops at the first fault
    assert good, "this seed should run some parts before the fault"
    assert bad["fault"] == 402 and all(r["fault"] is None for r in good)
    rec = logged[bad["part_id"]]
    assert (rec.status, rec.fault_code) == ("fault", 402)
    assert bad["final_error_mm"] == rec.verify_error_mm > 0.1 and bad["moves"] == rec.moves
    assert bad["initial_error_mm"] == rec.initial_error_mm
    for r in good:                                      # each row its own part's figures
        assert abs(r["final_error_mm"] - logged[r["part_id"]].final_error_mm) < 0.001
