"""``model.yaml`` of a chain campaign (``cell/measurements.md``, Extension v1.1) as data:
:class:`ChainSpec`, its :class:`DHRow` joints and :class:`Coupling` terms. No I/O.

The pydantic models of :func:`pydantic_models` define what is valid and every error
message, but importing pydantic and building them costs ~0.09 s CPU, more than the whole
diagnosis of a 100-pose campaign after its fits got fast. So, as
:class:`cell.measurements.ModelSpec` does for planar campaigns, the dataclasses here
accept **plainly valid** input themselves (:func:`_plain_spec`: known keys, the types the
model names with no conversion beyond int → float and list → tuple, finite numbers, the
listed literals, every required key present) and hand anything else to pydantic, which
converts what it accepts and raises its ``ValidationError`` for the rest. Whatever the
input, the result is the one pydantic gives: the plain path only takes what pydantic would
take unchanged (or convert int → float, list → tuple, as it does).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field, fields
from typing import Literal

from cell.measurements.campaign import _number
from cell.measurements.checked import PlainFirst

KINEMATICS = ("dh", "urdf")
CONVENTIONS = ("standard", "modified")
JOINT_TYPES = ("revolute", "prismatic")
FRAMES = ("base", "sensor")
AXES = ("x", "y", "z")
ROW_NUMBERS = ("a_mm", "alpha_deg", "d_mm", "theta_deg")


@functools.cache
def pydantic_models() -> tuple[type, type, type]:
    """The pydantic models (ChainSpec, DHRow, Coupling) of a chain ``model.yaml``, built on
    first use (module docstring). Every number must be finite; unknown keys are refused."""
    from pydantic import BaseModel, ConfigDict, Field, field_validator

    class DHRow(BaseModel):
        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
        name: str
        type: Literal["revolute", "prismatic"] = "revolute"
        a_mm: float
        alpha_deg: float
        d_mm: float
        theta_deg: float
        limits: tuple[float, float] | None = None

    class Coupling(BaseModel):
        model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)
        joint: str
        from_: str = Field(alias="from")
        factor: float

    class ChainSpec(BaseModel):
        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
        format: str
        kinematics: Literal["dh", "urdf"]
        dh_convention: Literal["standard", "modified"] = "standard"
        joints: list[DHRow] | list[str] = Field(min_length=1)
        coupling: list[Coupling] = []
        tool_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
        urdf: str | None = None
        base_link: str | None = None
        tip_link: str | None = None
        measurement_frame: Literal["base", "sensor"] = "base"
        markers: Literal["unknown"] | dict[int, tuple[float, float, float]] = "unknown"
        gravity: tuple[float, float, float] = (0.0, 0.0, -1.0)
        source: str = ""
        sensor_axes: tuple[Literal["x", "y", "z"], ...] = AXES
        sensor_center_mm: tuple[float, float, float] | None = None
        motor_gear_ratio: dict[str, float] | None = None

        @field_validator("motor_gear_ratio")
        @classmethod
        def _ratios(cls, v):
            bad = [f"{k}: {n:g}" for k, n in (v or {}).items() if not n > 0]
            if bad:
                raise ValueError(f"a motor gear ratio is a positive number of motor turns per "
                                 f"joint turn, not {', '.join(bad)}")
            return v

        @field_validator("sensor_axes")
        @classmethod
        def _axes(cls, v):
            if not _plain_axes(v):
                raise ValueError("sensor_axes must be two or three of x, y, z, each once, in "
                                 "that order (e.g. [x, y] for a camera looking down)")
            return v
    return ChainSpec, DHRow, Coupling


def _numbers(v, n: int) -> tuple[float, ...] | None:
    """``v`` as ``n`` floats if it is a list or tuple of ``n`` plain numbers, else None."""
    if not isinstance(v, (list, tuple)) or len(v) != n:
        return None
    out = tuple(_number(x) for x in v)
    return None if None in out else out


def _opt_str(v) -> bool:
    return v is None or isinstance(v, str)


def _plain_row(v) -> dict | None:
    """The fields of a :class:`DHRow` from ``v`` (a mapping or a DHRow) when plainly
    valid, else None."""
    if isinstance(v, DHRow):
        v = v.model_dump()
    if not isinstance(v, dict) or not set(v) <= _ROW_KEYS or not _ROW_REQUIRED <= set(v):
        return None
    out = {"name": v["name"], "type": v.get("type", "revolute")}
    out |= {k: _number(v[k]) for k in ROW_NUMBERS}
    limits = v.get("limits")
    out["limits"] = None if limits is None else _numbers(limits, 2)
    if not isinstance(out["name"], str) or out["type"] not in JOINT_TYPES \
            or any(out[k] is None for k in ROW_NUMBERS) or (limits is not None and out["limits"] is None):
        return None
    return out


def _plain_coupling(v) -> dict | None:
    """The fields of a :class:`Coupling` from ``v`` (a mapping as ``model.yaml`` holds it,
    ``from`` not ``from_``, or a Coupling) when plainly valid, else None."""
    if isinstance(v, Coupling):
        v = v.as_input()
    if not isinstance(v, dict) or set(v) != {"joint", "from", "factor"}:
        return None
    out = {"joint": v["joint"], "from_": v["from"], "factor": _number(v["factor"])}
    if not isinstance(out["joint"], str) or not isinstance(out["from_"], str) or out["factor"] is None:
        return None
    return out


def _plain_markers(v):
    if v == "unknown":
        return v
    if not isinstance(v, dict):
        return None
    out = {}
    for k, p in v.items():
        if type(k) is not int or (p := _numbers(p, 3)) is None:
            return None
        out[k] = p
    return out


def _plain_ratios(v):
    """``v`` as {joint name: motor turns per joint turn} when a mapping of names to positive
    numbers, else None."""
    if not isinstance(v, dict):
        return None
    out = {k: _number(n) for k, n in v.items()}
    return out if all(isinstance(k, str) and n is not None and n > 0 for k, n in out.items()) \
        else None


def _plain_axes(v) -> bool:
    """``v`` names two or three of x, y, z, each once, in that order."""
    return isinstance(v, (list, tuple)) and len(v) >= 2 and all(a in AXES for a in v) \
        and list(v) == sorted(set(v), key=AXES.index)


def _plain_spec(data) -> dict | None:
    """The fields of :class:`ChainSpec` from ``data`` (the mapping of ``model.yaml``, or
    its keyword arguments) when plainly valid (module docstring), else None."""
    if not isinstance(data, dict) or not set(data) <= set(_SPEC_DEFAULTS) \
            or not _SPEC_REQUIRED <= set(data):
        return None
    out = {k: data.get(k, default) for k, default in _SPEC_DEFAULTS.items()}
    if not isinstance(out["format"], str) or out["kinematics"] not in KINEMATICS \
            or out["dh_convention"] not in CONVENTIONS or out["measurement_frame"] not in FRAMES \
            or not all(_opt_str(out[k]) for k in ("urdf", "base_link", "tip_link")) \
            or not isinstance(out["source"], str):
        return None
    joints, coupling = out["joints"], data.get("coupling", [])
    if not isinstance(joints, list) or not joints or not isinstance(coupling, list):
        return None
    if all(isinstance(j, str) for j in joints):
        out["joints"] = list(joints)
    else:
        rows = [_plain_row(j) for j in joints]
        if None in rows:
            return None
        out["joints"] = [DHRow(**r) for r in rows]
    terms = [_plain_coupling(c) for c in coupling]
    if None in terms:
        return None
    out["coupling"] = [Coupling(**c) for c in terms]
    out["tool_mm"], out["gravity"] = _numbers(out["tool_mm"], 3), _numbers(out["gravity"], 3)
    out["markers"] = _plain_markers(out["markers"])
    if out["sensor_center_mm"] is not None:
        out["sensor_center_mm"] = _numbers(out["sensor_center_mm"], 3)
        if out["sensor_center_mm"] is None:
            return None
    if out["motor_gear_ratio"] is not None:
        out["motor_gear_ratio"] = _plain_ratios(out["motor_gear_ratio"])
        if out["motor_gear_ratio"] is None:
            return None
    if out["tool_mm"] is None or out["gravity"] is None or out["markers"] is None \
            or not _plain_axes(out["sensor_axes"]):
        return None
    out["sensor_axes"] = tuple(out["sensor_axes"])
    return out


@dataclass(kw_only=True)
class DHRow(PlainFirst, plain=_plain_row, pydantic=lambda: pydantic_models()[1]):
    """One joint of a ``kinematics: dh`` model: ``name``, ``type``, the DH numbers (mm,
    deg) and optional ``limits`` (lo, hi) in the joint's unit. Validated on construction
    (module docstring)."""

    name: str
    type: Literal["revolute", "prismatic"] = "revolute"
    a_mm: float
    alpha_deg: float
    d_mm: float
    theta_deg: float
    limits: tuple[float, float] | None = None

    def model_dump(self) -> dict:
        """The fields as a dict, in the order of the format."""
        return self.as_input()


@dataclass(kw_only=True)
class Coupling(PlainFirst, plain=_plain_coupling, pydantic=lambda: pydantic_models()[2]):
    """Model value of ``joint`` += ``factor`` × reading of ``from_`` (``from`` in the file).
    Validated on construction (module docstring)."""

    joint: str
    from_: str
    factor: float

    @classmethod
    def _from_pydantic(cls, m) -> dict:
        return {"joint": m.joint, "from_": m.from_, "factor": m.factor}

    def as_input(self) -> dict:
        """As ``model.yaml`` holds it."""
        return {"joint": self.joint, "from": self.from_, "factor": self.factor}


@dataclass(kw_only=True)
class ChainSpec(PlainFirst, plain=_plain_spec, pydantic=lambda: pydantic_models()[0]):
    """``model.yaml`` of a chain campaign. ``gravity`` (this project's addition) is the
    direction of gravity in the base frame, default −z; it only matters for the
    gravity-compliance effect. ``sensor_axes`` (this project's addition) the axes the
    sensor sees, two or three of x, y, z in that order (default all three).
    ``sensor_center_mm`` (this project's addition, optional) the point of the measurement
    frame a camera-like sensor's scale and rotation errors act about (its optical centre;
    the rotation is about the frame's z axis). ``motor_gear_ratio`` (this project's
    addition, optional) {joint name: motor turns per joint turn} of the joints whose drive
    states it: the period of a motor-side ripple at the joint. Every number must be finite. Validated on
    construction as the pydantic model of :func:`pydantic_models` (module docstring): bad input raises
    pydantic's ValidationError. :meth:`model_validate` and :meth:`model_dump` as
    pydantic's."""

    format: str
    kinematics: Literal["dh", "urdf"]
    dh_convention: Literal["standard", "modified"] = "standard"
    joints: list[DHRow] | list[str]
    coupling: list[Coupling] = field(default_factory=list)
    tool_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    urdf: str | None = None
    base_link: str | None = None
    tip_link: str | None = None
    measurement_frame: Literal["base", "sensor"] = "base"
    markers: Literal["unknown"] | dict[int, tuple[float, float, float]] = "unknown"
    gravity: tuple[float, float, float] = (0.0, 0.0, -1.0)
    source: str = ""
    sensor_axes: tuple[str, ...] = AXES
    sensor_center_mm: tuple[float, float, float] | None = None
    motor_gear_ratio: dict[str, float] | None = None

    def as_input(self) -> dict:
        """The fields as ``model.yaml`` holds them (rows and terms as mappings)."""
        out = super().as_input()
        out["joints"] = [j.model_dump() if isinstance(j, DHRow) else j for j in self.joints] \
            if isinstance(self.joints, list) else self.joints
        out["coupling"] = [c.as_input() if isinstance(c, Coupling) else c for c in self.coupling] \
            if isinstance(self.coupling, list) else self.coupling
        return out

    @classmethod
    def _from_pydantic(cls, m) -> dict:
        out = dict(m)
        out["joints"] = [j if isinstance(j, str) else DHRow(**j.model_dump()) for j in m.joints]
        out["coupling"] = [Coupling(joint=c.joint, from_=c.from_, factor=c.factor) for c in m.coupling]
        return out

    def model_dump(self, **kw) -> dict:
        """pydantic's ``model_dump`` (``mode``, ``by_alias``, … as there) of the same spec."""
        return pydantic_models()[0].model_validate(self.as_input()).model_dump(**kw)


_ROW_KEYS = frozenset(f.name for f in fields(DHRow))
_ROW_REQUIRED = frozenset(("name",) + ROW_NUMBERS)
_SPEC_DEFAULTS = {f.name: f.default for f in fields(ChainSpec)}   # coupling: see _plain_spec
_SPEC_REQUIRED = frozenset(("format", "kinematics", "joints"))
