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


def test_a_run_cut_short_by_a_plc_time_out_still_prints_the_parts_before(tmp_path, capsys, monkeypatch):
    from cell.cli import main
    from cell.sim.plc import SimPlc, SimPlcError
    real, calls = SimPlc.run_cycle, []

    def second_times_out(self, *a, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise SimPlcError("SimPlc: timed out after 30 s waiting for done, error or aborted")
        return real(self, *a, **kw)
    monkeypatch.setattr(SimPlc, "run_cycle", second_times_out)
    assert main(["run", "--sim", "--cycles", "3", "--db", str(tmp_path / "log.sqlite")]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split()[:2] == ["1", "bracket-a"] and lines[1].rstrip().endswith("-")
    assert lines[2].split()[:2] == ["2", "bracket-a"] and "PLC: SimPlc: timed out" in lines[2]
    assert lines[3].startswith("1/2 cycles done")

    calls.clear()
    assert main(["run", "--sim", "--cycles", "3", "--json", "--db", str(tmp_path / "log2.sqlite")]) == 1
    cycles = json.loads(capsys.readouterr().out)["cycles"]
    assert [c["part_id"] for c in cycles] == [1, 2]
    assert cycles[0]["fault"] is None and cycles[1]["fault"].startswith("PLC: SimPlc: timed out")
