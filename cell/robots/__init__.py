"""Robots are data files (as in the Robotics Toolbox): one YAML file per robot in this
folder, read and checked here.

* ``kinematics: scara`` — the cell's SCARAs (seed 000, seed 002): link lengths, z/tool
  offsets, command units and joint limits, checked as a :class:`Geometry`;
  :data:`PRESETS` holds them by ``name``, :class:`cell.kinematics.Scara` turns one into
  kinematics.
* ``kinematics: dh`` (or ``urdf``) — any serial arm in the chain model format of
  ``cell/measurements.md`` (Extension v1.1): the seed 001 cobot and a UR5.
  :func:`chain_model_file` gives the file, which ``cellctl diagnose CAMPAIGN --model FILE``
  and :func:`cell.measurements.chain.load_spec` read like any campaign's model.yaml.

Adding a robot is adding a file; a bad file is refused when the package loads, naming the
file and the field (the cell cannot start on an unknown robot).
"""
from __future__ import annotations

import math
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cell.errors import ConfigError

FOLDER = Path(__file__).resolve().parent
JOINT_NAMES = ("j1", "j2", "j3", "j4")


class Geometry(BaseModel):
    """A SCARA's geometry and joint set-up as data (robot models are data).

    ``unit`` holds one command unit per joint (deg, deg, mm, deg); ``limits`` one
    ``[low, high]`` per joint in the same units.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = "custom"
    source: str = ""
    l1_mm: float = Field(gt=0, le=5000)
    l2_mm: float = Field(gt=0, le=5000)
    base_z_mm: float = 0.0
    tool_z_mm: float = 0.0
    unit: tuple[float, float, float, float] = (0.01, 0.01, 0.01, 0.01)
    limits: tuple[tuple[float, float], ...] = ((-170, 170), (-150, 150), (-200, 0), (-360, 360))
    singular_margin_deg: float = Field(default=0.5, ge=0, le=10)

    @model_validator(mode="after")
    def _check(self) -> "Geometry":
        if len(self.limits) != 4:
            raise ValueError(f"limits must hold 4 [low, high] pairs, got {len(self.limits)}")
        for name, (lo, hi) in zip(JOINT_NAMES, self.limits):
            if not lo < hi:
                raise ValueError(f"limits for {name}: low {lo} must be below high {hi}")
        for name, u in zip(JOINT_NAMES, self.unit):
            if not (u > 0 and math.isfinite(u)):
                raise ValueError(f"command unit for {name} must be > 0, got {u}")
        return self


def _read(path: Path):
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read the robot file: {exc}") from None


def _scara(raw, path: Path) -> Geometry:
    if not isinstance(raw, dict) or raw.get("kinematics") != "scara":
        raise ConfigError(f"{path}: not a SCARA robot file (kinematics: scara)")
    data = {k: v for k, v in raw.items() if k != "kinematics"}
    try:
        return Geometry.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"]) or "file"
        raise ConfigError(f"{path}: {where}: {err['msg']}") from None


def load_scara(path: Path | str) -> Geometry:
    """The SCARA of robot file ``path`` (``kinematics: scara``). Raises ConfigError naming
    the file and what is wrong."""
    path = Path(path)
    return _scara(_read(path), path)


def _scan() -> tuple[dict[str, Geometry], dict[str, Path]]:
    """Every robot file of the folder, each read once: SCARAs checked, chains by name."""
    scaras, chains = {}, {}
    for path in sorted(FOLDER.glob("*.yaml")):
        raw = _read(path)
        if isinstance(raw, dict) and raw.get("kinematics") == "scara":
            g = _scara(raw, path)
            scaras[g.name] = g
        else:
            chains[path.stem] = path
    return scaras, chains


#: the cell's SCARAs by name, from the robot files
PRESETS, CHAIN_MODELS = _scan()


def chain_model_file(name: str) -> Path:
    """The chain model file of robot ``name`` (e.g. ``ur5``, ``seed001_cobot``); unknown
    names raise KeyError listing the known ones."""
    try:
        return CHAIN_MODELS[name]
    except KeyError:
        raise KeyError(f"unknown chain robot {name!r}; known: {sorted(CHAIN_MODELS)}") from None
