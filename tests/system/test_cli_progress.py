"""Progress of long commands (issue 13, item 2): a bar on stderr when it is a terminal,
nothing when piped; ``run`` prints each part's line when the part finishes; ``serve`` says
what stopped it, why, and the state it ended in."""
from __future__ import annotations

import json
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time

import pytest

from tests.system.conftest import REPO

ANSI_OR_CR = re.compile(r"\x1b\[|\r")
VALIDATE = ["diagnose", "validate", "--chain", "--trials", "3", "--points", "20"]


def cellctl(*args):
    return [sys.executable, "-m", "cell.cli", *args]


def test_piped_output_has_no_progress_bar(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "CELL_PROGRESS"}
    out = subprocess.run(cellctl(*VALIDATE), cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "Chain diagnosis validation" in out.stdout
    assert not ANSI_OR_CR.search(out.stdout) and not ANSI_OR_CR.search(out.stderr), out.stderr
    assert "campaign" not in out.stderr


def test_a_terminal_sees_the_bar_and_stdout_stays_clean(tmp_path):
    """stderr on a pseudo-terminal (what a person at a shell has), stdout piped."""
    env = {k: v for k, v in os.environ.items() if k != "CELL_PROGRESS"}
    master, slave = pty.openpty()
    proc = subprocess.Popen(cellctl(*VALIDATE, "--json"), cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=slave, text=True)
    os.close(slave)
    seen = b""
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 4096)
            except OSError:                 # the child closed its end
                break
            if not chunk:
                break
            seen += chunk
        elif proc.poll() is not None:
            break
    stdout = proc.communicate(timeout=60)[0]
    os.close(master)
    assert proc.returncode == 0, seen[-2000:]
    text = seen.decode("utf-8", "replace")
    assert "validate --chain" in text and "/3" in text and "campaign" in text, text
    assert "\r" in text                      # the bar redraws in place
    assert not ANSI_OR_CR.search(stdout) and stdout.lstrip().startswith("{")


def test_run_prints_each_part_as_it_finishes(tmp_path):
    proc = subprocess.Popen(cellctl("run", "--sim", "--cycles", "5", "--db", "log.sqlite"),
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        header = proc.stdout.readline()
        first = proc.stdout.readline()
        still_running = proc.poll() is None
        rest = proc.communicate(timeout=300)[0]
    finally:
        proc.kill()
    assert header.split()[:2] == ["part", "recipe"]
    assert first.split()[:2] == ["1", "bracket-a"]
    assert still_running, "the first part's line came only when the run had ended"
    assert "5/5 cycles done" in rest
    assert not ANSI_OR_CR.search(header + first + rest)


def _serve(tmp_path, *extra):
    return subprocess.Popen(cellctl("serve", "--sim", "--port", "0", "--db", "serve.sqlite", *extra),
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_serve_says_why_it_stopped_and_in_what_state(tmp_path):
    proc = _serve(tmp_path, "--seconds", "1")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "stopped: --seconds 1 elapsed; final state IDLE, no fault, 0 cycle(s) this run; " \
           "log serve.sqlite" in err, err

    proc = _serve(tmp_path)
    try:
        assert "serving Modbus TCP" in proc.stdout.readline()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "stopped: SIGTERM received; final state " in err, err


# A recipe whose z stroke is long and slow: approach at z -5 mm, place at z -100 mm, every
# joint at most 11 units/s (mm/s for j3). The smooth time law peaks at 1.875 times the mean
# speed (cell/motion/line.py TIME_LAW_PEAK), so a 95 mm stroke takes at least
# 95 * 1.875 / 11 = 16.2 s of simulated time.
DEEP_RECIPE = """\
name: deep-z
number: 9
description: a slow 95 mm z stroke, so that a cycle outlasts the PLC's time-out
part:
  nominal_xy_mm: [250.0, 930.0]
  fiducial_radius_mm: 1.5
  search_radius_mm: 3.0
approach:
  offset_mm: [-12.0, 0.0]
  z_mm: -5.0
  joint_speed_deg_s: 11.0
place:
  z_mm: -100.0
compensation:
  method: lattice
  max_moves: 4
  min_gain_mm: 0.002
motion:
  sync: corrected
  segment_ms: 10
  time_law: smooth
verify:
  tolerance_mm: 0.08
"""
PLC_WAIT_S = 30.0           # what `cellctl run`'s simulated PLC waits for done (cell/commands/run.py)


def _deep_stroke_config(tmp_path):
    """A cell config for DEEP_RECIPE in which part 1 is done within the PLC's 30 s and part 2
    is not, on the built-in simulated cell:

    * part 1 starts where the drives power up, z = 0: 5 mm down to the approach height, then
      one 95 mm stroke down to place: one stroke, at least 16.2 s;
    * part 2 starts at the place height: 95 mm up to the approach height and 95 mm down again,
      at least 2 * 16.2 = 32.4 s, so the PLC's wait ends while its final move is under way;
    * ``cycle.tool_phi_deg`` is θ1 + θ2 at the approach point, so j4 stays near 0, where it
      powers up (with the default 0 the first approach would turn j4 by 92° at 11°/s: 16 s);
    * ``cycle.move_timeout_s`` 120: the controller itself waits for these slow moves.
    """
    import yaml

    from cell.kinematics import Scara
    t1, t2 = Scara.preset("seed000").ik_planar(250.0 - 12.0, 930.0, elbow="right")
    (tmp_path / "recipes").mkdir()
    (tmp_path / "recipes" / "deep-z.yaml").write_text(DEEP_RECIPE)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({
        "format": "cell-config/1", "plc": {"host": "127.0.0.1"}, "recipes": {"directory": "recipes"},
        "cycle": {"move_timeout_s": 120.0, "tool_phi_deg": round(float(t1 + t2), 3)}, "sim": {}}))
    return path


@pytest.mark.slow
def test_a_run_cut_short_by_a_plc_time_out_still_prints_the_parts_before(tmp_path, capsys):
    """A real time-out: the simulated PLC waits its 30 s of simulated time for done while
    part 2's cycle is still moving (see :func:`_deep_stroke_config`)."""
    from cell.cli import main
    from cell.cyclelog import CycleLog
    cfg = str(_deep_stroke_config(tmp_path))
    timed_out = f"PLC: SimPlc: timed out after {PLC_WAIT_S} s waiting for done, error or aborted"

    assert main(["run", "--sim", "--config", cfg, "--recipe", "deep-z", "--cycles", "3",
                 "--db", str(tmp_path / "log.sqlite")]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split()[:2] == ["1", "deep-z"] and lines[1].rstrip().endswith("-")
    assert lines[2].split()[:2] == ["2", "deep-z"] and timed_out in lines[2]
    assert lines[3].startswith("1/2 cycles done")

    assert main(["run", "--sim", "--config", cfg, "--recipe", "deep-z", "--cycles", "3", "--json",
                 "--db", str(tmp_path / "log2.sqlite")]) == 1
    first, second = json.loads(capsys.readouterr().out)["cycles"]
    assert (first["part_id"], first["fault"]) == (1, None)
    assert first["plc_round_trip_s"] < PLC_WAIT_S
    assert second["part_id"] == 2 and second["fault"].startswith(timed_out)
    assert second["plc_round_trip_s"] >= PLC_WAIT_S           # it waited its whole time-out
    log = CycleLog(tmp_path / "log2.sqlite", readonly=True)
    try:
        rows = {c.part_id: c for c in log.cycles()}
    finally:
        log.close()
    assert rows[1].status == "done"
    # the cycle the PLC gave up on was still running: the run's stop cut it short
    assert rows[2].status == "aborted" and rows[2].fault_code == 501, (rows[2].status, rows[2].fault_text)
