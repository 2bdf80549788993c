"""The plant file (``deploy/plants/*.yaml``): its model, and loading it with file:line errors.

Every problem is a :class:`~cell.errors.ConfigError` whose message names the file, the
line (found in the YAML node tree from ``yaml.compose``) and the field, e.g.
``deploy/plants/x.yaml:14: effects[1].params.j2_backlash_deg: ... outside [0.0, 2.0]``.
The data itself is read with ``yaml.safe_load`` only.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Mapping

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from cell.effects import STATION_NAMES, EffectInstance, make_effect, station_order
from cell.errors import ConfigError
from cell.robots import PRESETS, Geometry
from cell.yamlio import parse_yaml, read_text, validation_message

FORMAT = "cell-plant/1"
_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


def _err(msg: str, *loc) -> ConfigError:
    exc = ConfigError(msg)
    exc.loc = tuple(loc)  # position below the validator's own location
    return exc


class EffectConfig(BaseModel):
    """One effect of the plant: ``{effect, joints, params}`` (see :mod:`cell.effects`)."""

    model_config = _STRICT

    effect: str
    joints: list[str] = []
    params: dict[str, float] = {}

    @model_validator(mode="after")
    def _valid(self) -> "EffectConfig":
        make_effect(self.effect, self.joints, self.params)  # raises ConfigError with .loc
        return self

    def instance(self) -> EffectInstance:
        return make_effect(self.effect, self.joints, self.params)


class TemperatureModel(BaseModel):
    """Warm-up from a cold start at t = 0: ``T(t) = ambient_c + rise_c·(1 − exp(−t/tau_s))``
    in °C; before t = 0 the arm is at ambient."""

    model_config = _STRICT

    ambient_c: float = Field(default=20.0, ge=-50, le=100)
    rise_c: float = Field(default=0.0, ge=-50, le=100)
    tau_s: float = Field(default=1800.0, gt=0, le=1e7)

    def at(self, t_s) -> np.ndarray | float:
        """Temperature (°C) at time(s) ``t_s`` (s); vectorised."""
        t = np.maximum(np.asarray(t_s, dtype=float), 0.0)
        out = self.ambient_c + self.rise_c * (1.0 - np.exp(-t / self.tau_s))
        return float(out) if out.ndim == 0 else out


class PlantConfig(BaseModel):
    """The simulated cell's true robot. Exactly one of ``robot`` (a preset name of
    :data:`cell.robots.PRESETS`) or ``geometry`` (a full Geometry) gives the nominal
    model; ``effects`` say how the truth differs from it.

    Units: mm, deg, s, °C. ``repeatability_mm`` / ``measurement_noise_mm`` are Gaussian σ
    per axis; ``camera_center_mm`` is where the camera's optical axis meets the work plane
    (base frame); ``stations`` the CAN station order (comm_delay); ``joint_speed_deg_s``
    the speed of θ1, θ2 for :class:`~cell.sim.plant.PlantArm`; ``start_deg`` / ``start_dirs``
    the drive positions and last-motion directions at t = 0 (default: seed 000's start
    pose (60°, 30°), approached from below); ``seed`` makes every run repeatable.
    """

    model_config = _STRICT

    format: Literal["cell-plant/1"] = FORMAT
    robot: str | None = None
    geometry: Geometry | None = None
    effects: list[EffectConfig] = []
    repeatability_mm: float = Field(default=0.0, ge=0, le=10)
    measurement_noise_mm: float = Field(default=0.0, ge=0, le=10)
    temperature: TemperatureModel = TemperatureModel()
    camera_center_mm: tuple[float, float] = (0.0, 0.0)
    stations: list[str] = list(STATION_NAMES)
    joint_speed_deg_s: float = Field(default=90.0, gt=0, le=3600)
    start_deg: tuple[float, float] = (60.0, 30.0)
    start_dirs: tuple[int, int] = (1, 1)
    seed: int = Field(default=0, ge=0)

    @field_validator("robot")
    @classmethod
    def _preset(cls, v: str | None) -> str | None:
        if v is not None and v not in PRESETS:
            raise ValueError(f"unknown robot preset {v!r}; known: {sorted(PRESETS)}")
        return v

    @field_validator("stations")
    @classmethod
    def _stations(cls, v: list[str]) -> list[str]:
        station_order(v)
        return v

    @field_validator("start_dirs")
    @classmethod
    def _dirs(cls, v: tuple[int, int]) -> tuple[int, int]:
        if any(d not in (-1, 0, 1) for d in v):
            raise ValueError(f"start_dirs = {list(v)}: each direction is -1, 0 or +1")
        return v

    @model_validator(mode="after")
    def _whole(self) -> "PlantConfig":
        if (self.robot is None) == (self.geometry is None):
            raise _err("give exactly one of robot (a preset name) or geometry", "robot")
        g = self.nominal_geometry()
        for i, v in enumerate(self.start_deg):
            lo, hi = g.limits[i]
            if not lo <= v <= hi:
                raise _err(f"start_deg j{i + 1} = {v} is outside its limits [{lo}, {hi}]",
                           "start_deg", i)
        seen: dict[tuple[str, str], int] = {}
        for i, e in enumerate(self.effects):
            for j in e.joints or [""]:
                if (e.effect, j) in seen:
                    raise _err(f"{e.effect} on {j or 'the cell'} is given twice "
                               f"(effects[{seen[e.effect, j]}] and effects[{i}])", "effects", i)
                seen[e.effect, j] = i
        return self

    def nominal_geometry(self) -> Geometry:
        return PRESETS[self.robot] if self.robot is not None else self.geometry

    def effect_instances(self) -> list[EffectInstance]:
        return [e.instance() for e in self.effects]


# ------------------------------------------------------------------ loading with file:line
def config_from_mapping(data: Any, source: str = "<plant config>",
                        root: yaml.Node | None = None) -> PlantConfig:
    """Validate a plant mapping; ConfigError names ``source``, line (if ``root`` is the
    YAML node tree) and field. Nothing is kept on failure."""
    if not isinstance(data, Mapping):
        line = f":{root.start_mark.line + 1}" if root is not None else ""
        raise ConfigError(f"{source}{line}: (top level): the plant must be a mapping of "
                          f"fields, got {type(data).__name__}")
    try:
        return PlantConfig.model_validate(dict(data))
    except ValidationError as exc:
        raise ConfigError(validation_message(source, exc, root, PlantConfig)) from None


def load_plant_config(path) -> PlantConfig:
    """Read and validate a plant YAML file (format ``cell-plant/1``, see deploy/plants/README.md).

    Raises ConfigError naming the file (and line and field where there is one) when the file
    is missing or unreadable, is not valid YAML, is empty, repeats a key, or fails validation.
    """
    p = Path(path)
    data, root = parse_yaml(read_text(p, "plant file"), str(p), "plant file")
    return config_from_mapping(data, str(p), root)
