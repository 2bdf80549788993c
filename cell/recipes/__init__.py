"""Recipes: one YAML file per part type in ``recipes/``, edited by maintenance.

A recipe is validated by :class:`Recipe` (units in names, ranges, unknown keys rejected);
:func:`parse_recipe` names file, line and field of what is wrong. The cell checks recipes
against its stations with :func:`motion_check`. The active set and how edits reach it are
in :mod:`cell.recipes.store`.
"""
from __future__ import annotations

import enum
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cell.errors import ConfigError
from cell.yamlio import node_line, parse_yaml, validation_message



class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PartSpec(_Strict):
    """Where parts of this type arrive and what their fiducial looks like."""
    nominal_xy_mm: tuple[float, float] = Field(description="nominal part position, robot base frame")
    fiducial_radius_mm: float = Field(gt=0.2, le=20)
    search_radius_mm: float = Field(gt=0, le=50, description="how far from nominal a part may lie")


class ApproachSpec(_Strict):
    offset_mm: tuple[float, float] = Field(description="approach point relative to the nominal part "
                                                       "position; keep the tool clear of the part so "
                                                       "the camera sees both")
    z_mm: float = Field(ge=-500, le=500)
    joint_speed_deg_s: float = Field(gt=0, le=720)


class PlaceSpec(_Strict):
    z_mm: float = Field(ge=-500, le=500, description="height of the final move")


class CompensationSpec(_Strict):
    method: Literal["lattice", "paper"]
    max_moves: int = Field(default=4, ge=1, le=20, description="lattice: move budget incl. first arrival")
    min_gain_mm: float = Field(default=0.002, ge=0, le=1)
    backlash_margin_units: int = Field(default=5, ge=0, le=1000,
                                       description="lattice: every arrival takes up the backlash from "
                                                   "the calibrated side, through a via point this many "
                                                   "command units short of it when a joint would "
                                                   "arrive the other way (0 = off); keep it above "
                                                   "the backlash")
    extra_moves: int = Field(default=2, ge=0, le=5,
                             description="moves allowed after a verified error above tolerance: "
                                         "lift, move to the whole-unit command predicted nearest, "
                                         "place and verify again (0: fault at once)")
    k: int = Field(default=16, ge=1, le=256, description="paper: first grid spacing, command units")
    repeatability_mm: float = Field(default=0.02, ge=0, le=1)


class MotionSpec(_Strict):
    """How every move of the cycle is streamed to the joint stations (seed 002)."""
    sync: Literal["corrected", "sync", "none"] = Field(
        description="corrected: each station applies on reception, velocities Δθ/(T − λ) with λ "
                    "measured on the bus (seed 002); sync: all stations apply on one SYNC frame "
                    "(needs drives with SYNC support); none: Δθ/T on reception (for comparison)")
    segment_ms: float = Field(ge=1, le=1000,
                              description="interpolation segment time T; must exceed every station's delay")
    time_law: Literal["smooth", "linear"] = Field(
        description="smooth: smooth start and stop (seed 002 Fig. 8c); linear: equal steps")


class VerifySpec(_Strict):
    tolerance_mm: float = Field(gt=0, le=5, description="the cycle faults if the verified error exceeds this")


class Recipe(_Strict):
    """One part type's recipe (``recipes/<name>.yaml``).

    Every section, and every field in it that sets a safety or quality limit (where the
    tool goes and how fast, how moves are streamed, the tolerance), must be written out:
    a file cut short, or a section left out, is refused rather than filled in from
    defaults. Only tuning fields of the compensation method have defaults.

    ``production: false`` marks a recipe shipped as an example (to compare methods, say):
    listed and validated like any other, but the controller activates it only where the
    cell config allows examples (``recipes.allow_examples``, ``run --allow-examples``).
    """
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9_-]{0,39}$")
    number: int = Field(ge=1, le=999, description="what the PLC writes to recipe_select")
    description: str = ""
    production: bool = Field(default=True, description="false: an example, not for production; "
                                                       "activated only where the cell allows examples")
    part: PartSpec
    approach: ApproachSpec
    place: PlaceSpec
    compensation: CompensationSpec
    motion: MotionSpec
    verify: VerifySpec

    @model_validator(mode="after")
    def _check(self) -> "Recipe":
        if self.verify.tolerance_mm < self.compensation.min_gain_mm:
            raise ValueError("verify.tolerance_mm must not be below compensation.min_gain_mm")
        return self


#: the tolerance a recipe version got when it left ``verify`` out, before every limit had to
#: be written out (schema of 2026-11): what the controller enforced for such a version
UNSTATED_TOLERANCE_MM = 0.08


def recorded_tolerance(text: str) -> float | None:
    """``verify.tolerance_mm`` a logged recipe version ran with: read from its text as it
    was activated (an older version may lack sections the schema now requires, and then ran
    with :data:`UNSTATED_TOLERANCE_MM`); None if the text is not a recipe at all."""
    from cell.yamlio import bounded
    try:
        bounded(text, "<log>")
        doc = yaml.safe_load(text)
    except (yaml.YAMLError, ConfigError):
        return None
    if not isinstance(doc, dict) or "name" not in doc:
        return None
    verify = doc.get("verify")
    if verify is None:
        return UNSTATED_TOLERANCE_MM
    tol = verify.get("tolerance_mm", UNSTATED_TOLERANCE_MM) if isinstance(verify, dict) else None
    return float(tol) if isinstance(tol, (int, float)) and not isinstance(tol, bool) and tol > 0 else None


def content_hash(text: str) -> str:
    """SHA-256 of a recipe file's bytes (hex); what every cycle record carries."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def recipe_schema() -> dict:
    """JSON schema of a recipe file, for editors (exported to recipes/recipe.schema.json)."""
    return Recipe.model_json_schema()


@dataclass(frozen=True)
class ActiveRecipe:
    recipe: Recipe
    hash: str
    text: str
    path: str


class RecipeAction(enum.StrEnum):
    """What the recipe store did with a recipe file (the audit log's ``action``)."""

    ACTIVATE = "activate"
    REJECT = "reject"
    REMOVE = "remove"


@dataclass(frozen=True)
class AuditEntry:
    who: str
    action: RecipeAction
    target: str          # file path
    hash: str
    result: str          # "ok" or the error message
    recipe: str = ""
    #: a valid example recipe (``production: false``) the cell does not allow: refused by
    #: design, so not an edit the PLC must hear of as rejected (recipe_status 2)
    example: bool = False


def parse_recipe(text: str, source: str) -> Recipe:
    """Validate recipe text; raise ConfigError naming source, line and field."""
    data, root = parse_yaml(text, source, "recipe")
    try:
        recipe = Recipe.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(validation_message(source, exc, root, Recipe)) from None
    stem = Path(source).stem
    if stem != recipe.name and not source.startswith("<"):
        raise ConfigError(f"{source}:{node_line(root, ('name',))}: name: recipe name {recipe.name!r} "
                          f"must match the file name {stem!r}")
    return recipe


def example_refusal(recipe: Recipe, text: str, source: str) -> str:
    """Why a cell that does not allow examples refuses recipe ``recipe`` (``production: false``)."""
    return (f"{source}:{line_of(text, 'production')}: production: {recipe.name} is an example, not for production: not activated (allow it with recipes.allow_examples: true in the cell "
            "config, or cellctl run --allow-examples)")


def line_of(text: str, key: str) -> int | None:
    """Line of top-level ``key`` in YAML ``text`` (None if the text does not parse)."""
    try:
        return node_line(yaml.compose(text, Loader=yaml.SafeLoader), (key,))
    except yaml.YAMLError:
        return None


#: a check of a parsed recipe against the cell it runs on: (recipe, text, source) → raises
#: ConfigError naming source, line and field
CellCheck = Callable[[Recipe, str, str], None]


def motion_check(supports_sync: bool, delays_s) -> CellCheck:
    """The cell's motion check: ``motion.sync: sync`` needs SYNC support on every station;
    ``corrected`` and ``sync`` need ``motion.segment_ms`` above every station's delay λ
    (``delays_s`` (4,) per joint, s: wire time of a burst plus the measured latency)."""
    from cell.motion.mover import check_mode

    def check(recipe: Recipe, text: str, source: str) -> None:
        m = recipe.motion
        why = check_mode(m.sync, m.segment_ms / 1000.0, supports_sync, delays_s)
        if why is None:
            return
        field = "sync" if "SYNC" in why else "segment_ms"
        try:
            line = node_line(yaml.compose(text, Loader=yaml.SafeLoader), ("motion", field))
        except yaml.YAMLError:
            line = None
        raise ConfigError(f"{source}:{line}: motion.{field}: {why} (motion.sync: {m.sync})")
    return check


#: bits of the longest 8-byte standard CAN data frame (worst-case stuffing, inter-frame space)
_MAX_SETPOINT_FRAME_BITS = 135


def motion_check_from_config(stations, latency_s=None) -> tuple[CellCheck, bool]:
    """:func:`motion_check` for the stations a cell config names (``StationsConfig``): each
    station's λ is bounded by the wire time of the longest frames up to and including its
    own, plus its latency — ``latency_s`` (4,) per joint as measured by the running cell, or
    the configured one. Returns (check, complete): with ``delays_s: measure`` and nothing
    measured yet, the latency is unknown (``complete`` False; the controller checks again
    with what it measures)."""
    measured = stations.delays_s == "measure" and latency_s is None
    lam = [0.0] * 4
    for p, s in enumerate(stations.stations):
        if latency_s is not None:
            latency = float(latency_s[s.joint_index])
        else:
            latency = 0.0 if measured else stations.delays_s[p]
        lam[s.joint_index] = (p + 1) * _MAX_SETPOINT_FRAME_BITS / stations.bitrate + latency
    return motion_check(all(s.supports_sync for s in stations.stations), lam), not measured


def reach_check(robot, elbow: str = "right") -> CellCheck:
    """The cell's reach check: the part's nominal position, every point of its search
    window's rim (8 directions) and the approach position must be reachable with the
    robot's elbow and joint limits (what a cycle needs; else it faults 401 at run time).
    ``robot``: a :class:`cell.kinematics.Scara`."""
    import math

    from cell.errors import KinematicsError

    def check(recipe: Recipe, text: str, source: str) -> None:
        x, y = recipe.part.nominal_xy_mm
        r = recipe.part.search_radius_mm
        ox, oy = recipe.approach.offset_mm
        points = [("part.nominal_xy_mm", "the nominal part position", x, y)]
        points += [("part.search_radius_mm", f"the search window's rim at {a}°",
                    x + r * math.cos(math.radians(a)), y + r * math.sin(math.radians(a)))
                   for a in range(0, 360, 45)]
        points.append(("approach.offset_mm", "the approach position", x + ox, y + oy))
        for field, what, px, py in points:
            try:
                robot.ik_planar(px, py, elbow)
            except KinematicsError as exc:
                key = field.split(".")
                line = node_line(yaml.compose(text, Loader=yaml.SafeLoader), tuple(key))
                raise ConfigError(f"{source}:{line}: {field}: {what} ({px:.1f}, {py:.1f}) mm cannot "
                                  f"be reached with the {elbow} elbow: {exc}") from None
    return check


def all_checks(*checks: CellCheck | None) -> CellCheck:
    """One check that runs ``checks`` in order (None ones skipped)."""
    def check(recipe: Recipe, text: str, source: str) -> None:
        for c in checks:
            if c is not None:
                c(recipe, text, source)
    return check


def export_schema(path: Path | str) -> None:
    Path(path).write_text(json.dumps(recipe_schema(), indent=2) + "\n", encoding="utf-8")
