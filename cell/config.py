"""The cell config (``deploy/cell.yaml``): one section per subsystem, validated at load.

Each section is a pydantic model with ``extra="forbid"``: an unknown key or
a value out of range is a :class:`~cell.errors.ConfigError` naming file, line and field.
Driver sections reuse the drivers' own models (``plc`` → ``drivers.plc.PlcConfig``,
``stations`` → ``drivers.stations.StationsConfig``); ``camera`` is handed to the camera
registry (``drivers.camera.from_config``), which rejects unknown backends and options.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from cell.kinematics import PRESETS, Geometry, Scara
from cell.yamlio import load_model
from drivers.plc import PlcConfig
from drivers.stations import StationsConfig

FORMAT = "cell-config/1"


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RobotSection(_Section):
    preset: str | None = "seed000"
    geometry: Geometry | None = None
    elbow: Literal["right", "left"] = "right"

    @model_validator(mode="after")
    def _one(self) -> "RobotSection":
        if (self.preset is None) == (self.geometry is None):
            raise ValueError("give exactly one of robot.preset and robot.geometry")
        if self.preset is not None and self.preset not in PRESETS:
            raise ValueError(f"unknown robot preset {self.preset!r}; known: {sorted(PRESETS)}")
        return self

    def scara(self) -> Scara:
        return Scara(self.geometry) if self.geometry else Scara.preset(self.preset)


class VisionSection(_Section):
    calibration: str = "var/calibration.json"      #: PlaneCalibration JSON (cell-vision-calibration/1)
    tool_radius_mm: float = Field(default=3.0, gt=0.2, le=20)
    radius_tolerance: float = Field(default=0.3, gt=0, lt=1)
    grab_timeout_s: float = Field(default=2.0, gt=0, le=60)   #: a grab that takes longer is fault 301


class RecipesSection(_Section):
    directory: str = "recipes"
    max_bytes: int = Field(default=64 * 1024, ge=1024, le=16 * 1024 * 1024)   #: larger files are refused unread
    settle_s: float = Field(default=1.0, ge=0, le=60)   #: a changed file must stay unchanged this long


class LogSection(_Section):
    path: str = "var/cell.sqlite"
    retention_days: int = Field(default=365, ge=1, le=36500)
    format: Literal["json", "console"] = "json"
    level: str = "INFO"


class ControllerSection(_Section):
    scan_s: float = Field(default=0.01, gt=0, le=1)
    recipe_refresh_s: float = Field(default=1.0, gt=0, le=3600)


class CycleSection(_Section):
    move_timeout_s: float = Field(default=10.0, gt=0, le=600)
    reach_tol_deg: float = Field(default=0.001, gt=0, le=1)
    tool_phi_deg: float = Field(default=0.0, ge=-360, le=360)


class SchedulerSection(_Section):
    health_interval_s: float = Field(default=10.0, gt=0, le=3600)
    drift_interval_s: float = Field(default=30.0, gt=0, le=86400)
    drift_window: int = Field(default=20, ge=2, le=10000)
    drift_threshold_mm: float = Field(default=0.5, gt=0, le=100)
    retention_interval_s: float = Field(default=3600.0, gt=0, le=7 * 86400)


class SimSection(_Section):
    """Only for ``--sim``: the plant that stands in for the real robot and camera."""
    plant: str = "deploy/plants/default.yaml"
    part_jitter_mm: float = Field(default=1.0, ge=0, le=20)
    station_sigma_s: float = Field(default=0.0005, ge=0, le=0.1)   #: seed 002 λ = σ·i
    camera_px: tuple[int, int] = (640, 512)                          #: rendered image size
    camera_mm_per_px: float = Field(default=0.08, gt=0.001, le=1)    #: 51 × 41 mm field
    seed: int = 0


class CellConfig(_Section):
    format: Literal["cell-config/1"] = FORMAT
    name: str = "cell-1"
    robot: RobotSection = RobotSection()
    plc: PlcConfig = PlcConfig()
    stations: StationsConfig = StationsConfig()
    camera: dict[str, Any] = Field(default_factory=lambda: {"backend": "opencv", "source": 0})
    vision: VisionSection = VisionSection()
    recipes: RecipesSection = RecipesSection()
    log: LogSection = LogSection()
    controller: ControllerSection = ControllerSection()
    cycle: CycleSection = CycleSection()
    scheduler: SchedulerSection = SchedulerSection()
    sim: SimSection | None = None

    @classmethod
    def load(cls, path: Path | str) -> "CellConfig":
        """Load and validate ``path``; raises ConfigError naming file, line and field."""
        return load_model(path, cls, "cell config")
