"""``serve --config`` wiring (no ``--sim``): the cell built from a hardware-style config by the
``hardware`` device backend — the real JointStations driver on the CAN bus the config names
(here the virtual wire, with simulated drives plugged in by the test as real drives would
be), a camera from the registry (here a folder of images) and a calibration file on disk —
starts, serves the PLC, moves, and faults cleanly when the camera shows no part. The test
hands the cell a simulated clock (the virtual wire needs one); a real cell runs on wall time.

It also checks that the hardware path loads no simulation module."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np

from cell.app import Cell
from cell.config import CellConfig
from cell.cycle.statemachine import State
from cell.faults import Fault
from cell.sim.assembly import stations_config
from cell.sim.clock import VirtualClock
from cell.sim.plc import SimPlc
from cell.vision.calibration import CircleGridBoard, calibrate
from cell.vision.camera_model import CameraModel
from drivers.camera.sim import SimCamera
from drivers.plc.register_map import PLC_MAP
from drivers.stations.sim import SimStationSet
from tests.system.conftest import REPO, make_config


def test_hardware_config_path_starts_moves_and_faults_on_no_target(tmp_path):
    sim_cfg = make_config(tmp_path)
    robot = sim_cfg.robot.scara()
    stations = stations_config(robot, f"hw-path-{os.getpid()}")
    model = CameraModel.nadir(640, 512, 0.08, centre_mm=(250.0, 930.0))
    board = CircleGridBoard(cols=11, rows=7, pitch_mm=4.0, radius_mm=1.0, origin_mm=(230.0, 918.0))
    cam = SimCamera(model, lambda: [board], seed=1)
    cam.open()
    cal = calibrate([(cam.grab().image, board)], distortion=False)
    cam.close()
    (tmp_path / "cal.json").write_text(json.dumps(cal.as_dict()))
    (tmp_path / "frames").mkdir()
    cv2.imwrite(str(tmp_path / "frames" / "0001.png"), np.full((512, 640), 50, np.uint8))
    cfg = CellConfig.model_validate({
        **sim_cfg.model_dump(mode="json", exclude={"sim", "stations", "camera", "vision"}),
        "stations": stations.model_dump(mode="json"),
        "camera": {"backend": "folder", "path": str(tmp_path / "frames"), "loop": True},
        "vision": {"calibration": str(tmp_path / "cal.json"), "tool_radius_mm": 3.0},
    })
    clock = VirtualClock()
    drives = SimStationSet(stations, initial_positions=[60.0, 30.0, -20.0, -90.0], clock=clock).start()
    cell = Cell(cfg, devices="hardware", plc_port=0, jobs=False, clock=clock)
    with clock.attach():
        try:
            port = cell.start()
            plc = SimPlc("127.0.0.1", port, scan_s=0.01, clock=clock)
            plc.start()
            try:
                before = cell.motion.actual_positions()
                res = plc.run_cycle(7, 1, timeout_s=20)
                assert res["error"] == 1 and res["fault_code"] == Fault.NO_TARGET
                assert not np.allclose(cell.motion.actual_positions(), before, atol=1e-3)   # it did approach
                assert cell.controller.sm.state is State.FAULT
                assert PLC_MAP.bits("status_word", plc.inputs()["status_word"])["error"]
                plc.reset()
                assert cell.controller.sm.state is State.IDLE
            finally:
                plc.stop()
        finally:
            cell.stop()
            drives.stop()
    clock.close()


def test_the_hardware_path_imports_no_simulation_module():
    """Everything ``cellctl serve --config`` needs, imported in a fresh interpreter: no module
    of the simulated cell may come along."""
    code = ("import sys, cell.cli, cell.app, cell.devices, cell.controller, cell.cycle.runner, cell.motion.mover, "
            "cell.jobs, drivers.stations, drivers.plc.server, drivers.camera, drivers.camera.folder, "
            "drivers.camera.opencv_capture, cell.commands.run, cell.commands.report, cell.commands.recipe\n"
            "from cell.devices import HardwareDevices\n"
            "cell.cli.build_parser()\n"
            "from drivers.registry import is_simulation\n"
            "print('\\n'.join(sorted(m for m in sys.modules if is_simulation(m))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "", f"the hardware path imported simulation modules: {out.stdout.split()}"
