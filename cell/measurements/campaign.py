"""Measurement exchange format v1 (``cell/measurements.md``): read and write campaigns
(the planar ones here; chains, Extension v1.1, in :mod:`cell.measurements.chain`).

A campaign directory holds ``model.yaml`` (required), ``points.csv`` and/or ``paths.csv``.
:func:`read_campaign` validates everything before returning: any bad input raises
:class:`CampaignFormatError` naming the file, the line (1-based, the header is line 1) and
the column, and nothing is returned half-read. :func:`write_campaign` writes the same layout
atomically (a temporary directory renamed into place), so a reader never sees a half-written
campaign. Export then import round-trips exactly (floats are written with ``repr``).

What the readers refuse as unusable, and why (the line between refusing and answering):

* a value that is not a finite number (NaN, inf), in a CSV cell or in ``model.yaml``: it
  is not a measurement, and one of it turns every fitted number into NaN;
* a ``temp_c`` outside :data:`TEMP_RANGE_C` (a typo, or kelvin): an arm is not measured
  there, and one such row would decide the thermal growth on its own;
* a campaign whose poses all have the same joint readings, one pose included
  (:func:`check_places`): nothing that depends on the joints can be learned from one
  configuration, however often it is measured, and no pose is left to check a fit on.
  Whatever a consumer asks, the answer would be made up, so it is refused.

A campaign at two or more places is a valid one even when it cannot tell causes apart
(poses at a few clustered places, a joint that never moves): it is read, and the
consumer answers with what it can and cannot tell (for a joint that never moves, its
angle-dependent effects are not identifiable). The readers judge the data, never a
diagnosis.
"""
from __future__ import annotations

import csv
import functools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cell.errors import CampaignFormatError
from cell.measurements.checked import PlainFirst, plain
from cell.measurements.folder import staged_dir
from cell.measurements import plainyaml

FORMAT = "cell-measurements/1"
INT64 = (-2 ** 63, 2 ** 63 - 1)   # the range of an int column (sample, move, marker)
TEMP_RANGE_C = (-40.0, 150.0)     # temp_c: where an arm is measured, in °C
CHAIN_KINEMATICS = ("dh", "urdf")

POINT_COLUMNS = {  # name: (kind, required)
    "sample": ("int", True), "time_s": ("float", True),
    "j1_deg": ("float", True), "j2_deg": ("float", True),
    "x_mm": ("float", True), "y_mm": ("float", True),
    "j1_dir": ("dir", False), "j2_dir": ("dir", False),
    "temp_c": ("temp", False), "payload_kg": ("float", False),
    "split": ("split", False),
}
PATH_COLUMNS = {
    "move": ("int", True), "time_s": ("float", True),
    "j1_cmd_deg": ("float", True), "j2_cmd_deg": ("float", True),
    "x_mm": ("float", True), "y_mm": ("float", True),
    "split": ("split", False),
}


@functools.cache
def pydantic_models() -> tuple[type, type]:
    """The pydantic models (ModelSpec, CameraSpec) of ``model.yaml``, built on first use:
    they define what is valid and every error message, but importing pydantic and building
    them costs ~0.08 s CPU, so :class:`ModelSpec` asks them only about input that is not
    plainly valid (:func:`_plain`)."""
    from pydantic import BaseModel, ConfigDict, Field

    class CameraSpec(BaseModel):
        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
        center_mm: tuple[float, float]

    class ModelSpec(BaseModel):
        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
        format: str
        kinematics: str = "scara"
        l1_mm: float = Field(gt=0)
        l2_mm: float = Field(gt=0)
        command_unit_deg: float | None = Field(default=None, gt=0)
        joint_limits_deg: list[tuple[float, float]] | None = None
        camera: CameraSpec | None = None
        stations: list[str] | None = None
    return ModelSpec, CameraSpec


def _number(v, positive: bool = False) -> float | None:
    """``v`` as a float if it is plainly a finite number (an int or float, not a bool; > 0
    with ``positive``), else None. An int too large for a float is not: the pydantic model
    refuses it ('must be a valid number') and the reader names its line and key."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    try:
        v = float(v)
    except OverflowError:
        return None
    return v if math.isfinite(v) and (v > 0 or not positive) else None


def _pair(v) -> tuple[float, float] | None:
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        return None
    a, b = _number(v[0]), _number(v[1])
    return None if a is None or b is None else (a, b)


def _plain(data: dict) -> dict | None:
    """The fields of :class:`ModelSpec` from ``data`` (its keyword arguments or the mapping
    of ``model.yaml``) when they are plainly valid: known keys, the types the model names
    with no conversion beyond int → float and list → tuple, finite numbers, positive where
    the model says so. None for anything else, which :func:`pydantic_models` then decide
    (converting what it accepts, raising its ValidationError for the rest)."""
    if not isinstance(data, dict) or not set(data) <= set(ModelSpec.__dataclass_fields__):
        return None
    out = {"format": data.get("format"), "kinematics": data.get("kinematics", "scara"),
           "l1_mm": _number(data.get("l1_mm"), True), "l2_mm": _number(data.get("l2_mm"), True)}
    if not isinstance(out["format"], str) or not isinstance(out["kinematics"], str) \
            or out["l1_mm"] is None or out["l2_mm"] is None:
        return None
    unit, limits = data.get("command_unit_deg"), data.get("joint_limits_deg")
    camera, stations = data.get("camera"), data.get("stations")
    if unit is not None and (unit := _number(unit, True)) is None:
        return None
    if limits is not None:
        if not isinstance(limits, list):
            return None
        limits = [_pair(p) for p in limits]
        if None in limits:
            return None
    if isinstance(camera, CameraSpec):
        camera = CameraSpec(camera.center_mm)
    elif camera is not None:
        if not isinstance(camera, dict) or set(camera) != {"center_mm"} \
                or _pair(camera["center_mm"]) is None:
            return None
        camera = CameraSpec(_pair(camera["center_mm"]))
    if stations is not None and not (isinstance(stations, list)
                                     and all(isinstance(x, str) for x in stations)):
        return None
    return {**out, "command_unit_deg": unit, "joint_limits_deg": limits, "camera": camera,
            "stations": None if stations is None else list(stations)}


def _plain_camera(data) -> dict | None:
    """The fields of :class:`CameraSpec` from ``data`` when plainly valid, else None."""
    pair = _pair(data.get("center_mm")) if isinstance(data, dict) and set(data) == {"center_mm"} \
        else None
    return None if pair is None else {"center_mm": pair}


@dataclass
class CameraSpec(PlainFirst, plain=_plain_camera, pydantic=lambda: pydantic_models()[1]):
    """``model.yaml`` ``camera``: ``center_mm`` (x, y) mm on the work plane."""

    center_mm: tuple[float, float]

    @classmethod
    def _from_pydantic(cls, m) -> dict:
        return {"center_mm": m.center_mm}


@dataclass
class ModelSpec(PlainFirst, plain=_plain, pydantic=lambda: pydantic_models()[0]):
    """``model.yaml``: the nominal model the simulation uses (every number finite).
    Validated on construction as the pydantic model :func:`pydantic_models` defines it
    (unknown keys refused, lengths and command unit > 0, numbers finite), plain input
    without pydantic (:class:`~cell.measurements.checked.PlainFirst`); bad input raises
    pydantic's ValidationError. :meth:`model_validate` and :meth:`model_dump` as pydantic's."""

    format: str
    l1_mm: float
    l2_mm: float
    kinematics: str = "scara"
    command_unit_deg: float | None = None
    joint_limits_deg: list[tuple[float, float]] | None = None
    camera: CameraSpec | None = None
    stations: list[str] | None = None

    def as_input(self) -> dict:
        out = super().as_input()
        if isinstance(out["camera"], CameraSpec):
            out["camera"] = {"center_mm": out["camera"].center_mm}
        return out

    @classmethod
    def _from_pydantic(cls, m) -> dict:
        d = dict(m)
        d["camera"] = None if m.camera is None else CameraSpec(m.camera.center_mm)
        return d

    def model_dump(self, exclude_none: bool = False, mode: str = "python") -> dict:
        """The fields as a dict in declaration order of the format (camera as a mapping;
        ``mode="json"``: tuples as lists)."""
        out = {}
        for k in ("format", "kinematics", "l1_mm", "l2_mm", "command_unit_deg",
                  "joint_limits_deg", "camera", "stations"):
            v = getattr(self, k)
            if k == "camera" and v is not None:
                v = {"center_mm": list(v.center_mm) if mode == "json" else v.center_mm}
            elif k == "joint_limits_deg" and v is not None:
                v = [list(p) if mode == "json" else p for p in v]
            elif k == "stations" and v is not None:
                v = list(v)
            if v is not None or not exclude_none:
                out[k] = v
        return out


@dataclass
class Campaign:
    """A validated campaign. ``points`` / ``paths`` map column name -> numpy array (``split``
    is an array of "fit"/"holdout" strings); a table absent from the campaign is None.
    ``lines`` (a campaign read from files) maps ``points`` / ``paths`` to the 1-based file
    line of each of its rows (None: the table is absent), what error messages cite."""

    model: ModelSpec
    points: dict[str, np.ndarray] | None = None
    paths: dict[str, np.ndarray] | None = None
    source: str = ""
    extra: dict = field(default_factory=dict)
    lines: dict[str, list[int] | None] = field(default_factory=dict, compare=False, repr=False)

    @property
    def station_order(self) -> list[str]:
        return self.model.stations or ["j1", "j2"]


def _parse_cell(kind: str, text: str, path: Path, line: int, column: str) -> object:
    def bad(msg: str) -> CampaignFormatError:
        return CampaignFormatError(path, msg, line=line, column=column)
    t = text.strip()
    if kind == "split":
        if t not in ("fit", "holdout"):
            raise bad(f"split must be 'fit' or 'holdout', got {text!r}")
        return t
    try:
        v = float(t)
    except ValueError:
        raise bad(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        big = math.isinf(v) and "inf" not in t.lower()
        raise bad(f"not a finite number: {text!r}" + (" (too large for a float)" if big else ""))
    if kind == "int":
        from decimal import Decimal       # only on the cell-by-cell path: ~1 ms to import
        d = Decimal(t)                    # exact: a float rounds ids past 2**53
        if d != d.to_integral_value():
            raise bad(f"not a whole number: {text!r}")
        if not INT64[0] <= (n := int(d)) <= INT64[1]:
            raise bad(f"whole number out of range (a 64-bit integer, {INT64[0]} to "
                      f"{INT64[1]}): {text!r}")
        return n
    if kind == "dir" and v not in (-1.0, 1.0):
        raise bad(f"direction must be +1 or -1, got {text!r}")
    if kind == "temp" and not TEMP_RANGE_C[0] <= v <= TEMP_RANGE_C[1]:
        raise bad(f"temperature {text.strip()} °C is outside {TEMP_RANGE_C[0]:g} … "
                  f"{TEMP_RANGE_C[1]:g} °C, where an arm is measured (a typo, or kelvin?)")
    return v


def _check_separator(path: Path, header: str) -> None:
    """A header with ';' or tabs and no ',' (a spreadsheet export in a locale whose decimal
    mark is ','): say so, instead of reporting the one long column as missing columns."""
    if "," in header:
        return
    for sep, name in ((";", "';'"), ("\t", "a tab")):
        if sep in header:
            raise CampaignFormatError(path, f"the separator is {name} where ',' is required (the "
                                            "format, cell/measurements.md, is comma-separated with "
                                            "'.' as decimal mark); save the file as CSV with ',' "
                                            "separators", line=1)


def _read_table(path: Path, columns: dict[str, tuple[str, bool]], at_once: bool = True
                ) -> tuple[dict[str, np.ndarray], list[int]]:
    """Parse one CSV table; returns the columns and the 1-based file line of every row.
    ``at_once`` converts whole columns first (falling back to the cell-by-cell reading,
    which names the bad line and column, at the first doubt); False reads cell by cell."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CampaignFormatError(path, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    lines = text.splitlines()
    _check_separator(path, lines[0] if lines else "")
    rows = list(csv.reader(lines))
    if not rows or not any(c.strip() for c in rows[0]):
        raise CampaignFormatError(path, "empty file: expected a header line", line=1)
    header = [h.strip() for h in rows[0]]
    dupes = {h for h in header if header.count(h) > 1}
    if dupes:
        raise CampaignFormatError(path, f"duplicate column(s) {sorted(dupes)}", line=1)
    for name, (_, required) in columns.items():
        if required and name not in header:
            raise CampaignFormatError(path, "missing required column", line=1, column=name)
    used = [(i, name, columns[name][0]) for i, name in enumerate(header) if name in columns]
    fast = _columns_at_once(rows, len(header), used) if at_once else None
    if fast is not None:
        return fast
    data: dict[str, list] = {name: [] for _, name, _ in used}
    lines: list[int] = []
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or not any(c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise CampaignFormatError(path, f"{len(row)} fields, header has {len(header)}", line=lineno)
        for i, name, kind in used:
            data[name].append(_parse_cell(kind, row[i], path, lineno, name))
        lines.append(lineno)
    if not lines:
        raise CampaignFormatError(path, "no data rows after the header", line=2)
    out = {}
    for _, name, kind in used:
        out[name] = (np.array(data[name], dtype=object if kind == "split" else
                              (np.int64 if kind == "int" else float)))
    return out, lines


def _columns_at_once(rows: list[list[str]], width: int, used: list[tuple[int, str, str]]
                     ) -> tuple[dict[str, np.ndarray], list[int]] | None:
    """What :func:`_read_table` returns, converted a column at a time (``float``, or ``int``
    for an int column, mapped over it, the checks of :func:`_parse_cell` on whole arrays)
    when every row and cell is valid;
    None at the first doubt, and the table is read again cell by cell, which names the
    first bad line and column."""
    body = [(n, row) for n, row in enumerate(rows[1:], start=2) if "".join(row).strip()]
    if not body or any(len(row) != width for _, row in body):
        return None
    cols = list(zip(*(row for _, row in body)))
    out = {}
    for i, name, kind in used:
        if kind == "split":
            v = [c.strip() for c in cols[i]]
            if not set(v) <= {"fit", "holdout"}:
                return None
            out[name] = np.array(v, dtype=object)
            continue
        if kind == "int":                 # int() of the text, exact; "2.0", "1e3" go cell by cell
            try:
                out[name] = np.array(list(map(int, cols[i])), dtype=np.int64)
            except (ValueError, OverflowError):
                return None
            continue
        try:
            x = np.array(list(map(float, cols[i])))
        except ValueError:
            return None
        if not np.all(np.isfinite(x)):
            return None
        if kind == "dir" and not np.all((x == 1.0) | (x == -1.0)):
            return None
        if kind == "temp" and not np.all((x >= TEMP_RANGE_C[0]) & (x <= TEMP_RANGE_C[1])):
            return None
        out[name] = x
    return out, [n for n, _ in body]


def _safe_load(path: Path):
    """``yaml.safe_load`` of ``path`` (a plainly written file without importing PyYAML,
    :func:`cell.measurements.plainyaml.safe_load`). A scalar YAML cannot make into a value,
    where PyYAML raises a bare ValueError (an integer of more digits than Python converts,
    ``sys.get_int_max_str_digits``; a date such as 2021-13-01; ``!!float abc``), raises
    CampaignFormatError naming its line and key. Raises yaml.YAMLError and
    UnicodeDecodeError as ``yaml.safe_load`` and ``read_text`` do."""
    text = path.read_text(encoding="utf-8")
    try:
        return plainyaml.safe_load(text)
    except ValueError as exc:
        import yaml
        why = str(exc).split(";")[0]      # without Python's advice to the programmer
        loc, node = _unmade_scalar(yaml.compose(text))
        raise CampaignFormatError(path, f"cannot be read: {why}",
                                  line=node.start_mark.line + 1 if node else None,
                                  column=".".join(map(str, loc)) or None) from None


def _unmade_scalar(node, loc=()) -> tuple[tuple, yaml.Node | None]:
    """(key path, node) of the first scalar under ``node`` (keys included) that PyYAML's
    safe constructor raises ValueError on, or ((), None)."""
    import yaml
    if isinstance(node, yaml.ScalarNode):
        make = yaml.constructor.SafeConstructor()
        try:
            make.yaml_constructors.get(node.tag, lambda *_: None)(make, node)
        except ValueError:
            return loc, node
        return (), None
    children = [(x, loc + (k.value,)) for k, v in node.value for x in (k, v)] \
        if isinstance(node, yaml.MappingNode) else \
        [(v, loc + (i,)) for i, v in enumerate(node.value)] if isinstance(node, yaml.SequenceNode) else []
    for child, at in children:
        if (found := _unmade_scalar(child, at))[1] is not None:
            return found
    return (), None


def _load_model(path: Path) -> ModelSpec:
    try:
        raw = _safe_load(path)
    except plainyaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise CampaignFormatError(path, f"not valid YAML: {getattr(exc, 'problem', exc)}",
                                  line=mark.line + 1 if mark else None) from None
    if not isinstance(raw, dict):
        raise CampaignFormatError(path, "expected a mapping of keys to values")
    if raw.get("format") != FORMAT:
        raise CampaignFormatError(path, f"unknown format {raw.get('format')!r}; expected {FORMAT!r}",
                                  column="format")
    fields = plain(_plain, raw)
    if fields is not None:
        model = ModelSpec(**fields)
    else:
        from pydantic import ValidationError
        from cell.yamlio import error_text
        try:
            model = ModelSpec.model_validate(raw)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(p) for p in err["loc"])
            raise CampaignFormatError(path, error_text(err, pydantic_models()[0]),
                                      line=_yaml_line(path, err["loc"]), column=loc) from None
    if model.kinematics != "scara":
        raise CampaignFormatError(path, f"unsupported kinematics {model.kinematics!r}; known: scara, "
                                        f"{', '.join(CHAIN_KINEMATICS)}", column="kinematics")
    return model


def yaml_loc(loc) -> tuple:
    """A pydantic error location without its union tags (``joints.list[DHRow].1.a_mm`` is
    ``joints.1.a_mm``): the path of keys and list indices in the YAML file."""
    return tuple(p for p in loc if not (isinstance(p, str) and "[" in p))


def _yaml_line(path: Path, loc) -> int | None:
    """1-based line of the deepest key or list item along ``loc`` in a YAML mapping, if found."""
    import yaml

    from cell.yamlio import node_line
    try:
        node = yaml.compose(path.read_text(encoding="utf-8"))
    except yaml.YAMLError:
        return None
    loc = yaml_loc(loc)
    if not isinstance(node, yaml.MappingNode) or not loc:
        return None
    if not any(k.value == str(loc[0]) for k, _ in node.value):
        return None
    return node_line(node, loc)


def check_places(path: Path, readings: np.ndarray, ids, lines: list[int], columns: list[str],
                 id_column: str = "sample") -> None:
    """Refuse a campaign whose poses all share one set of joint readings (one pose included).

    ``readings`` (N, J) per pose in file order, ``ids`` their ``id_column`` values,
    ``lines`` their file lines, ``columns`` the joint columns. Exact equality, no tolerance:
    poses a hair apart are a valid (if weak) campaign, and saying how weak is the
    consumer's job."""
    if len(readings) == 0 or np.ptp(readings, axis=0).any():
        return
    at = ", ".join(f"{c} {v:g}" for c, v in zip(columns, readings[0]))
    if len(readings) == 1:
        what = f"one pose ({id_column} {ids[0]}, {at})"
    else:
        what = f"all {len(readings)} poses at one place ({at} in every row)"
    raise CampaignFormatError(path, f"{what}: nothing that depends on the joints can be told "
                                    "from one configuration, however often it is measured; measure "
                                    "poses spread over the joints' ranges", line=lines[0],
                              column=columns[0])


def _chain_kind(path: Path) -> bool:
    """True if ``model.yaml`` describes a serial chain (Extension v1.1: dh or urdf)."""
    try:
        raw = _safe_load(path)
    except (plainyaml.YAMLError, UnicodeDecodeError):
        return False  # _load_model reports it with its line
    return isinstance(raw, dict) and raw.get("kinematics") in CHAIN_KINEMATICS


def read_campaign(directory: Path | str, model_path: Path | str | None = None):
    """Read and validate a campaign directory; raises CampaignFormatError on any bad input.

    Returns a :class:`Campaign` for ``kinematics: scara`` (v1) and a
    :class:`cell.measurements.chain.ChainCampaign` for ``dh`` / ``urdf`` chains (Extension
    v1.1). ``model_path`` (chains only) replaces ``directory/model.yaml``, e.g. a
    calibrated model as the new nominal for the same points."""
    d = Path(directory)
    if not d.is_dir():
        raise CampaignFormatError(d, "not a campaign directory")
    model_path = Path(model_path) if model_path else d / "model.yaml"
    if not model_path.is_file():
        raise CampaignFormatError(model_path, "missing: every campaign needs model.yaml")
    if _chain_kind(model_path):
        from cell.measurements.chain import read_chain_campaign  # lazy: only chains need it
        return read_chain_campaign(d, model_path)
    if model_path != d / "model.yaml":
        raise CampaignFormatError(model_path, "a replacement nominal model is for chain campaigns "
                                              "(kinematics dh or urdf)", column="kinematics")
    model = _load_model(model_path)
    points = paths = lines = path_lines = None
    if (d / "points.csv").is_file():
        points, lines = _read_table(d / "points.csv", POINT_COLUMNS)
        seen: set[int] = set()
        for sample, line in zip(points["sample"].tolist(), lines):
            if sample in seen:
                raise CampaignFormatError(d / "points.csv", f"sample id {sample} is not unique",
                                          line=line, column="sample")
            seen.add(sample)
    if (d / "paths.csv").is_file():
        paths, path_lines = _read_table(d / "paths.csv", PATH_COLUMNS)
    if points is None and paths is None:
        raise CampaignFormatError(d, "neither points.csv nor paths.csv is present")
    tables = [(d / "points.csv", points, lines, "sample", ["j1_deg", "j2_deg"]),
              (d / "paths.csv", paths, path_lines, "move", ["j1_cmd_deg", "j2_cmd_deg"])]
    tables = [(f, t, ln, ids, [t[c] for c in cols], cols) for f, t, ln, ids, cols in tables if t is not None]
    if not np.ptp(np.concatenate([np.column_stack(q) for *_, q, _ in tables]), axis=0).any():
        f, t, ln, ids, q, cols = tables[0]   # every table at the same one place: say so on the first
        check_places(f, np.column_stack(q), t[ids].tolist(), ln, cols, ids)
    return Campaign(model=model, points=points, paths=paths, source=str(d),
                    lines={"points": lines, "paths": path_lines})


def _write_table(path: Path, table: dict[str, np.ndarray], columns: dict) -> None:
    names = [c for c in columns if c in table]
    n = len(table[names[0]])
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(names)
        for i in range(n):
            row = []
            for c in names:
                v = table[c][i]
                kind = columns[c][0]
                row.append(v if kind == "split" else (str(int(v)) if kind in ("int", "dir") else repr(float(v))))
            w.writerow(row)


def write_campaign(campaign: Campaign, directory: Path | str, force: bool = False) -> Path:
    """Write ``campaign`` to ``directory`` (see :func:`staged_dir`: a new, empty or earlier
    written folder is replaced atomically; any other folder only with ``force``)."""
    import yaml
    d = Path(directory)
    with staged_dir(d, force) as tmp:
        model = campaign.model.model_dump(exclude_none=True, mode="json")
        (tmp / "model.yaml").write_text(yaml.safe_dump(model, sort_keys=False), encoding="utf-8")
        if campaign.points is not None:
            _write_table(tmp / "points.csv", campaign.points, POINT_COLUMNS)
        if campaign.paths is not None:
            _write_table(tmp / "paths.csv", campaign.paths, PATH_COLUMNS)
    return d


SPLIT_SEED = 20260501      # the v1 diagnosis's generated split (any fixed value: repeatable)
HOLDOUT_SHARE = 0.3


def first_step(cmd: np.ndarray) -> np.ndarray:
    """(J,) sign of each joint's first non-zero commanded step along a move (0 if it never
    moves): the direction it approached the move's start from (the format's approach
    convention)."""
    d = np.sign(np.diff(cmd, axis=0))
    out = np.zeros(cmd.shape[1])
    for j in range(cmd.shape[1]):
        nz = np.flatnonzero(d[:, j])
        out[j] = d[nz[0], j] if nz.size else 0.0
    return out


class SplitRng:
    """``numpy.random.default_rng(SPLIT_SEED)``, made on the first draw: a campaign whose
    tables carry a ``split`` column never draws, and never imports ``numpy.random``
    (about 6 ms of every start). Draws as the generator itself, in the same order."""

    def __init__(self):
        self._rng = None

    def __getattr__(self, name):
        if self._rng is None:
            self._rng = np.random.default_rng(SPLIT_SEED)
        return getattr(self._rng, name)


def drawn_fit(n_units: int, rng: np.random.Generator) -> np.ndarray:
    """(n_units,) True for fit: the v1 diagnosis's split of a table without a ``split``
    column, :data:`HOLDOUT_SHARE` of the units (points, or whole moves) held out at random
    from ``rng`` (seeded with :data:`SPLIT_SEED`, the points drawn before the moves)."""
    hold = np.zeros(n_units, bool)
    k = max(1, int(round(HOLDOUT_SHARE * n_units))) if n_units > 1 else 0
    hold[rng.permutation(n_units)[:k]] = True
    return ~hold
