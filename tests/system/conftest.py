"""Whole-cell fixtures: the simulated cell (real Modbus server on loopback, CANopen stations on
the virtual wire, rendered camera, plant) driven by the simulated PLC (a real Modbus client),
all on one simulated clock.

The cell here is the product's own ``cell.app.Cell``; only its recipe is shrunk for speed (a
short z stroke and fast joints), and the PLC heartbeat timeout is 0.4 s. The test thread
keeps the simulated time too (``Harness`` attaches it): every wait below is in simulated
seconds, so host load changes how long a test takes, never what it sees.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from cell.app import Cell
from cell.config import CellConfig, SimSection
from cell.sim.clock import VirtualClock
from cell.sim.plc import SimPlc
from drivers.plc.register_map import PLC_MAP

REPO = Path(__file__).resolve().parents[2]

FAST_RECIPE = """\
name: fast-a
number: 7
description: bracket-a with a short z stroke, for system tests
part:
  nominal_xy_mm: [250.0, 930.0]
  fiducial_radius_mm: 1.5
  search_radius_mm: 3.0
approach:
  offset_mm: [-12.0, 0.0]
  z_mm: -20.0
  joint_speed_deg_s: 240.0
place:
  z_mm: -22.0
compensation:
  method: lattice
  max_moves: 4
motion:
  sync: corrected
  segment_ms: 10
  time_law: smooth
verify:
  tolerance_mm: 0.08
"""


SLOW_RECIPE = FAST_RECIPE.replace("name: fast-a", "name: slow-a").replace("number: 7", "number: 8") \
    .replace("z_mm: -22.0", "z_mm: -60.0").replace("joint_speed_deg_s: 240.0", "joint_speed_deg_s: 20.0")


def make_config(tmp_path: Path, settle_s: float = 0.0, **plc) -> CellConfig:
    rdir = tmp_path / "recipes"
    shutil.copytree(REPO / "recipes", rdir)
    (rdir / "fast-a.yaml").write_text(FAST_RECIPE)
    (rdir / "slow-a.yaml").write_text(SLOW_RECIPE)      # a 2 s final move, to fail mid-motion
    cfg = CellConfig(sim=SimSection(plant=str(REPO / "deploy/plants/default.yaml")))
    return cfg.model_copy(update={
        "plc": cfg.plc.model_copy(update={"host": "127.0.0.1", "heartbeat_timeout_s": 0.4, **plc}),
        "log": cfg.log.model_copy(update={"path": str(tmp_path / "cell.sqlite")}),
        # the test's own calibration file: never the project's var/, whatever it holds
        "calibration": cfg.calibration.model_copy(update={"file": str(tmp_path / "robot-calibration.json")}),
        # edits settle on wall time; these tests write each file in one go and wait on the
        # simulated clock, so they take an edit at the next refresh
        "recipes": cfg.recipes.model_copy(update={"directory": str(rdir), "settle_s": settle_s}),
        "controller": cfg.controller.model_copy(update={"recipe_refresh_s": 0.05}),
    })


class Harness:
    """A started cell plus a connected simulated PLC, on one simulated clock that the test
    thread keeps too (until :meth:`close`)."""

    def __init__(self, tmp_path: Path, settle_s: float = 0.0, file_clock=None, **plc):
        self.tmp_path = tmp_path
        self.file_clock = file_clock
        self.config = make_config(tmp_path, settle_s, **plc)
        self.clock = VirtualClock()
        self._attached = self.clock.attach("test")
        self._attached.__enter__()
        self.cell = self.new_cell()
        self.port = self.cell.start()
        self.plc = SimPlc("127.0.0.1", self.port, scan_s=0.01, clock=self.clock)
        self.plc.start()
        self.next_part = 1

    def new_cell(self, port: int = 0) -> Cell:
        """A cell on this harness's clock (a restart builds a second one on the same port)."""
        return Cell(self.config, devices="sim", plc_port=port, jobs=False, clock=self.clock,
                    file_clock=self.file_clock)

    @property
    def controller(self):
        return self.cell.controller

    @property
    def now(self) -> float:
        return self.clock.now()

    def status(self) -> dict[str, bool]:
        return PLC_MAP.bits("status_word", self.plc.inputs()["status_word"])

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of simulated time pass."""
        self.clock.sleep(seconds)

    def wait(self, pred, timeout_s: float = 10.0, what: str = "condition", step_s: float = 0.001):
        """Poll ``pred`` every ``step_s`` simulated seconds; returns its first true value."""
        deadline = self.clock.now() + timeout_s
        while self.clock.now() <= deadline:
            value = pred()
            if value:
                return value
            self.clock.sleep(step_s)
        raise AssertionError(f"timed out after {timeout_s} simulated s waiting for {what}; state "
                             f"{self.controller.sm.state.name}, fault {self.controller.fault_code}")

    def present(self, recipe: str = "fast-a") -> int:
        part_id = self.next_part
        self.next_part += 1
        self.cell.devices.feeder.present(part_id, self.cell.recipes.active[recipe].recipe)
        return part_id

    def cycle(self, recipe: str = "fast-a", timeout_s: float = 20.0) -> dict:
        part_id = self.present(recipe)
        return self.plc.run_cycle(self.cell.recipes.active[recipe].recipe.number, part_id, timeout_s)

    def joints(self) -> np.ndarray:
        return self.cell.motion.actual_positions()

    def close(self) -> None:
        try:
            self.plc.stop()
            self.cell.stop()
        finally:
            self._attached.__exit__(None, None, None)
            self.clock.close()


@pytest.fixture
def harness(tmp_path):
    h = Harness(tmp_path)
    yield h
    h.close()
