"""Whole-cell fixtures: the simulated cell (real Modbus server on loopback, CANopen stations on
the virtual bus, rendered camera, plant) driven by the simulated PLC (a real Modbus client).

The cell here is the product's own ``cell.app.Cell``; only its sizes are shrunk for speed
(a 640x512 camera at 0.08 mm/px covers the same field as the default 1280x1024 at 0.04; a
recipe with a short z stroke and fast joints), and the PLC heartbeat timeout is 0.4 s.
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from cell.app import Cell
from cell.config import CellConfig, SimSection
from drivers.plc.register_map import PLC_MAP
from cell.sim.plc import SimPlc

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
verify:
  tolerance_mm: 0.08
"""


SLOW_RECIPE = FAST_RECIPE.replace("name: fast-a", "name: slow-a").replace("number: 7", "number: 8") \
    .replace("z_mm: -22.0", "z_mm: -60.0").replace("joint_speed_deg_s: 240.0", "joint_speed_deg_s: 20.0")


def make_config(tmp_path: Path, **plc) -> CellConfig:
    rdir = tmp_path / "recipes"
    shutil.copytree(REPO / "recipes", rdir)
    (rdir / "fast-a.yaml").write_text(FAST_RECIPE)
    (rdir / "slow-a.yaml").write_text(SLOW_RECIPE)      # a 2 s final move, to fail mid-motion
    cfg = CellConfig(sim=SimSection(plant=str(REPO / "deploy/plants/default.yaml"),
                                    camera_px=(640, 512), camera_mm_per_px=0.08))
    return cfg.model_copy(update={
        "plc": cfg.plc.model_copy(update={"host": "127.0.0.1", "heartbeat_timeout_s": 0.4, **plc}),
        "log": cfg.log.model_copy(update={"path": str(tmp_path / "cell.sqlite")}),
        "recipes": cfg.recipes.model_copy(update={"directory": str(rdir)}),
        "controller": cfg.controller.model_copy(update={"recipe_refresh_s": 0.05}),
    })


class Harness:
    """A started cell plus a connected simulated PLC."""

    def __init__(self, tmp_path: Path):
        self.tmp_path = tmp_path
        self.config = make_config(tmp_path)
        self.cell = Cell(self.config, sim=True, plc_port=0, jobs=False)
        self.port = self.cell.start()
        self.plc = SimPlc("127.0.0.1", self.port, scan_s=0.01)
        self.plc.start()
        self.next_part = 1

    @property
    def controller(self):
        return self.cell.controller

    def status(self) -> dict[str, bool]:
        return PLC_MAP.bits("status_word", self.plc.inputs()["status_word"])

    def wait(self, pred, timeout_s: float = 10.0, what: str = "condition"):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = pred()
            if value:
                return value
            time.sleep(0.01)
        raise AssertionError(f"timed out waiting for {what}; state {self.controller.sm.state.name}, "
                             f"fault {self.controller.fault_code}")

    def present(self, recipe: str = "fast-a") -> int:
        part_id = self.next_part
        self.next_part += 1
        self.cell.sim.feeder.present(part_id, self.cell.recipes.active[recipe].recipe)
        return part_id

    def cycle(self, recipe: str = "fast-a", timeout_s: float = 20.0) -> dict:
        part_id = self.present(recipe)
        return self.plc.run_cycle(self.cell.recipes.active[recipe].recipe.number, part_id, timeout_s)

    def joints(self) -> np.ndarray:
        return self.cell.motion.actual_positions()

    def close(self) -> None:
        self.plc.stop()
        self.cell.stop()


@pytest.fixture
def harness(tmp_path):
    h = Harness(tmp_path)
    yield h
    h.close()
