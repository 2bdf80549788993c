"""The README's commands as a new user runs them, from another folder (issue 13: every
README command works from a fresh clone and another directory).

Each test here reproduces a defect the audit of the README's commands found.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.system.conftest import REPO
from tests.waiting import wait_for


def cellctl(cwd, *args, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "cell.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_serve_without_the_can_interface_says_why_and_exits_2(tmp_path):
    """``cellctl serve --config deploy/cell.yaml`` on a PC whose CAN interface is missing
    (not plugged in, not brought up, no SocketCAN in the kernel) printed python-can's
    traceback and exited 1; the README promises a message and exit 2 before the start."""
    cfg = yaml.safe_load((REPO / "deploy/cell.yaml").read_text())
    cfg["plc"].update(host="127.0.0.1", allow=[], port=0)
    cfg["plc"]["tls"]["enabled"] = False
    cfg["stations"]["channel"] = "cellnocan9"           # no such interface on any machine
    cfg["log"]["path"] = "cell.sqlite"                   # beside the config, not /var/lib
    cfg["recipes"]["directory"] = str(REPO / "recipes")
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cfg))
    out = cellctl(tmp_path, "serve", "--config", "cell.yaml", "--seconds", "1", timeout=120)
    assert "Traceback" not in out.stderr, out.stderr[-3000:]
    assert out.returncode == 2, out.stderr[-3000:]
    assert "cellnocan9" in out.stderr and "stations.channel" in out.stderr, out.stderr


def test_dev_py_passes_a_stop_signal_to_the_command_it_runs(tmp_path):
    """``python3 dev.py cellctl serve --sim`` (or ``hmi``) stopped by SIGTERM (``timeout``,
    a service manager, ``kill``) ended dev.py alone: the cell kept serving, orphaned, and
    never said why it stopped. dev.py now becomes the command, so the signal reaches it."""
    out, err = tmp_path / "out.txt", tmp_path / "err.txt"
    with open(out, "w") as fo, open(err, "w") as fe:
        p = subprocess.Popen([sys.executable, str(REPO / "dev.py"), "cellctl", "serve", "--sim",
                              "--port", "0", "--db", "x.sqlite", "--seconds", "40"],
                             cwd=tmp_path, stdout=fo, stderr=fe)
    try:
        for _ in range(600):
            if "serving" in out.read_text() or p.poll() is not None:
                break
            time.sleep(0.1)
        assert "serving" in out.read_text(), err.read_text()[-2000:]
        p.send_signal(signal.SIGTERM)
        assert p.wait(timeout=60) == 0, err.read_text()[-2000:]
    finally:
        if p.poll() is None:
            p.kill()
    assert "stopped: SIGTERM received" in err.read_text(), err.read_text()[-2000:]


def _umask_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@pytest.mark.slow
def test_calibration_outputs_get_the_umask_mode_not_0600(tmp_path):
    """``cellctl calibrate-camera … --out cal.json`` and ``calibrate joint --png`` wrote their
    files 0600 (``tempfile.mkstemp``'s mode): run as root as deploy/INSTALL.md step 3 does,
    the calibration the service user ``cell`` must read at start-up was unreadable to it.
    The project's other outputs (reports, exports) take the umask's mode; so do these now."""
    import cv2

    from drivers.camera.sim import SimCamera
    from cell.vision.calibration import CircleGridBoard
    from cell.vision.camera_model import CameraModel
    board = CircleGridBoard(cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0, origin_mm=(234.0, 920.0))
    cam = SimCamera(CameraModel.nadir(640, 512, 0.08, centre_mm=(250.0, 930.0)), lambda: [board], seed=3)
    cam.open()
    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "board1.png"), cam.grab().image)
    cam.close()
    (tmp_path / "board.yaml").write_text(yaml.safe_dump(dict(
        kind="circles", cols=9, rows=6, pitch_mm=4.0, radius_mm=1.0, origin_mm=[234.0, 920.0], angle_deg=0.0)))
    out = cellctl(tmp_path, "calibrate-camera", "--board", "board.yaml", "--images", "imgs",
                  "--out", "cal.json")
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "cal.json").stat().st_mode & 0o777 == _umask_mode()

    out = cellctl(tmp_path, "calibrate", "joint", "j4", "--sim", "--runs", "1", "--png", "j4.png",
                  "--out", "robot.json")
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "j4.png").stat().st_mode & 0o777 == _umask_mode()
    assert (tmp_path / "robot.json").stat().st_mode & 0o777 == _umask_mode()


def _catches(pid: int, sig: int) -> bool:
    """Process ``pid`` has a handler for ``sig`` (its SigCgt mask in /proc)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = next(int(line.split()[1], 16) for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(mask >> (sig - 1) & 1)


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc for the child")
def test_dev_py_bench_stopped_by_sigterm_stops_its_benchmark(tmp_path):
    """``python3 dev.py bench`` stopped by SIGTERM ended dev.py alone: the benchmark it was
    running went on, orphaned (and ``dev.py test``'s pytest likewise)."""
    p = subprocess.Popen([sys.executable, str(REPO / "dev.py"), "bench"], cwd=tmp_path,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kids: list[int] = []
    try:
        for _ in range(600):
            kids = _children(p.pid)
            if kids or p.poll() is not None:
                break
            time.sleep(0.05)
        assert kids, "dev.py bench started no benchmark"
        # dev.py passes SIGTERM on once its handler is in place (just after it starts the
        # child): wait for that state, as /proc shows it, not for a guessed time
        wait_for(lambda: _catches(p.pid, signal.SIGTERM) or p.poll() is not None, 60,
                 "dev.py catching SIGTERM")
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)
        for _ in range(300):
            if not any(Path(f"/proc/{k}").exists() for k in kids):
                break
            time.sleep(0.1)
        left = [k for k in kids if Path(f"/proc/{k}").exists()]
        assert not left, f"benchmark process(es) {left} still running after dev.py was stopped"
    finally:
        if p.poll() is None:
            p.kill()
        for k in kids:
            try:
                os.kill(k, signal.SIGKILL)
            except ProcessLookupError:
                pass
