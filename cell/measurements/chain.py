"""Chain campaigns (``cell/measurements.md``, Extension v1.1): read, validate, write.

:func:`read_chain_campaign` reads ``model.yaml`` (``kinematics: dh`` or ``urdf``) and
``points.csv`` and checks everything before returning. Bad input raises
:class:`~cell.measurements.CampaignFormatError` naming the file, line, column or joint:

* a URDF that does not parse or has no path from ``base_link`` to ``tip_link``;
* joint columns that do not match ``joints`` (missing ``jK``, or a column past the last);
* a reading outside its joint's limits (a prismatic value typed in degrees or metres);
* rows of one ``sample`` that disagree on the joints or the split, a repeated marker;
* with ``markers: unknown``, a marker seen in too few fit poses to place it;
* a number in ``model.yaml`` (or the URDF) that is not finite, and a campaign whose poses
  all share one set of joint readings (:func:`cell.measurements.check_places`, which says
  why that is refused while a joint that never moves is not).

Poses are the unit of everything downstream: markers of one pose share its joints and its
split. :func:`write_chain_campaign` writes the same layout atomically.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from cell.kinematics.chain import Chain, dh_chain, urdf_chain
from cell.measurements.campaign import (FORMAT, SPLIT_SEED, CampaignFormatError, SplitRng,
                                        _read_table, _yaml_line, check_places, drawn_fit,
                                        first_step, yaml_loc)
from cell.measurements.chain_spec import ChainSpec, DHRow, _plain_spec, pydantic_models
from cell.measurements import plainyaml
from cell.measurements.checked import plain
from cell.measurements.folder import staged_dir

MIN_MARKER_POSES = 3     # 3 unknowns per marker: at least one pose more than that needs
LIMIT_SLACK = 0.05       # readings may pass a limit by 5 % of the range (overshoot, encoder)
EXTRA_COLUMNS = ("time_s", "temp_c", "payload_kg")   # optional per-point columns kept as read


@dataclass
class ChainCampaign:
    """A validated chain campaign, pose-major.

    ``readings`` (P, J) joint readings (deg / mm) per pose; ``pose_ids`` their ``sample``;
    ``split`` (P,) "fit"/"holdout" or None; ``obs_pose`` / ``obs_marker`` (M,) index of the
    pose and marker of each measured point, ``xyz`` (M, 3) in ``measurement_frame``;
    ``markers`` the marker ids (sorted); ``lines`` the points.csv line of each point (a
    move's sample: its paths.csv line);
    ``dirs`` (P, J) the sign of each joint's last motion before the pose (``jK_dir``, 0 where
    the campaign has no column for the joint), None without any ``jK_dir`` column;
    ``extra`` the optional per-point columns ``time_s``, ``temp_c``, ``payload_kg`` (M,)
    the campaign has (NaN on the poses of a measured move); ``move`` (P,) the index of the
    measured move each pose is a sample of (−1: a static pose), ``move_t`` (P,) s its time
    since the move's first command frame (NaN static), ``rate`` (P, J) deg/s (mm/s) the
    commanded joint speed there (0 static), all three None for a campaign of static poses
    only; ``split_source`` where ``split`` came from when the reader set it ('': the
    campaign's column); ``planar`` the v1 campaign and its rows when the campaign is a
    planar one read as a chain (:func:`planar_as_chain`; None otherwise)."""

    spec: ChainSpec
    chain: Chain
    readings: np.ndarray
    pose_ids: np.ndarray
    split: np.ndarray | None
    obs_pose: np.ndarray
    obs_marker: np.ndarray
    xyz: np.ndarray
    markers: list[int]
    lines: list[int]
    source: str = ""
    directory: Path | None = None
    extra: dict = field(default_factory=dict)
    dirs: np.ndarray | None = None
    move: np.ndarray | None = None
    rate: np.ndarray | None = None
    split_source: str = ""
    move_t: np.ndarray | None = None
    planar: "PlanarRows | None" = None

    @property
    def n_poses(self) -> int:
        return len(self.pose_ids)

    @property
    def axes(self) -> tuple[int, ...]:
        """The axes of the measurement frame the sensor sees (0, 1, 2 = x, y, z;
        ``sensor_axes``); ``xyz`` is 0 on the others."""
        return tuple("xyz".index(a) for a in self.spec.sensor_axes)

    def pose_temps(self) -> np.ndarray | None:
        """(P,) each pose's temperature, the mean ``temp_c`` of its rows (its markers are
        measured within moments of each other); None without the column."""
        t = self.extra.get("temp_c")
        if t is None:
            return None
        n = np.bincount(self.obs_pose, minlength=self.n_poses)
        return np.bincount(self.obs_pose, weights=t, minlength=self.n_poses) / np.maximum(n, 1)

    @property
    def known_markers(self) -> np.ndarray | None:
        """(K, 3) marker positions in the tip frame when the model gives them, else None."""
        if self.spec.markers == "unknown":
            return None
        return np.array([self.spec.markers[m] for m in self.markers], float)


def load_spec(path: Path) -> ChainSpec:
    try:
        raw = plainyaml.safe_load(path.read_text(encoding="utf-8"))
    except plainyaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise CampaignFormatError(path, f"not valid YAML: {getattr(exc, 'problem', exc)}",
                                  line=mark.line + 1 if mark else None) from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise CampaignFormatError(path, f"unknown format {raw.get('format') if isinstance(raw, dict) else raw!r}; "
                                        f"expected {FORMAT!r}", column="format")
    fields = plain(_plain_spec, raw)
    spec = ChainSpec(**fields) if fields is not None else _validated(path, raw)
    if spec.kinematics == "dh" and not all(isinstance(j, DHRow) for j in spec.joints):
        raise CampaignFormatError(path, "kinematics dh: every joint needs name, type, a_mm, "
                                        "alpha_deg, d_mm, theta_deg", column="joints")
    if spec.kinematics == "urdf":
        if not all(isinstance(j, str) for j in spec.joints):
            raise CampaignFormatError(path, "kinematics urdf: joints is a list of URDF joint names",
                                      column="joints")
        for key in ("urdf", "base_link", "tip_link"):
            if not getattr(spec, key):
                raise CampaignFormatError(path, f"kinematics urdf needs {key}", column=key)
    names = [j.name if isinstance(j, DHRow) else j for j in spec.joints]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise CampaignFormatError(path, f"joint name(s) {dupes} given twice", column="joints")
    if not np.all(np.isfinite(unit(spec.gravity))):
        raise CampaignFormatError(path, "gravity must be a non-zero direction", column="gravity")
    return spec


def _validated(path: Path, raw: dict) -> ChainSpec:
    """``raw`` that is not plainly valid, judged by pydantic (:mod:`cell.measurements.chain_spec`): the
    spec it converts to, or a CampaignFormatError naming the key and line of its error."""
    from pydantic import ValidationError
    from cell.yamlio import error_text
    try:
        return ChainSpec.model_validate(raw)
    except ValidationError as exc:
        # of a union's errors the deepest names the field best (markers.1.0, not markers)
        err = max(exc.errors(), key=lambda e: len(yaml_loc(e["loc"])))
        loc = yaml_loc(err["loc"])
        msg = error_text(err, pydantic_models()[0])
        if len(loc) > 2 and loc[0] == "joints" and isinstance(loc[1], int):
            msg = f"joint {loc[1] + 1} (column j{loc[1] + 1}): {msg}"
        raise CampaignFormatError(path, msg, line=_yaml_line(path, loc),
                                  column=".".join(str(p) for p in loc)) from None


def build_chain(spec: ChainSpec, model_path: Path) -> Chain:
    """The :class:`Chain` of ``spec``; an error about a key of ``model_path`` gets its line."""
    try:
        return _build_chain(spec, model_path)
    except CampaignFormatError as exc:
        if exc.file == str(model_path) and exc.column and not exc.line:
            line = _yaml_line(model_path, exc.column.split("."))
            if line:
                raise CampaignFormatError(model_path, exc.message, line=line,
                                          column=exc.column) from None
        raise


def unit(v) -> np.ndarray:
    """``v`` scaled to length 1, scaled by its largest component first so that a vector of
    huge (or tiny) finite components keeps its direction; NaN for a zero vector."""
    a = np.asarray(v, dtype=float)
    top = float(np.max(np.abs(a))) if a.size else 0.0
    if not top > 0:
        return np.full(a.shape, np.nan)
    a = a / top
    return a / np.linalg.norm(a)


def _build_chain(spec: ChainSpec, model_path: Path) -> Chain:
    chain = _chain_of(spec, model_path)
    ratios = spec.motor_gear_ratio or {}
    names = [j.name for j in chain.joints]
    for name, n in ratios.items():
        if name not in names:
            raise CampaignFormatError(model_path, f"motor_gear_ratio names {name!r}, which is not "
                                      f"one of the joints ({', '.join(names)})",
                                      column=f"motor_gear_ratio.{name}")
        if chain.joints[names.index(name)].type != "revolute":
            raise CampaignFormatError(model_path, f"motor_gear_ratio: {name} is prismatic; a "
                                      "motor gear ratio is stated for revolute joints",
                                      column=f"motor_gear_ratio.{name}")
    chain.joints = [replace(j, motor_ratio=ratios.get(j.name)) for j in chain.joints]
    return chain


def _chain_of(spec: ChainSpec, model_path: Path) -> Chain:
    g = unit(spec.gravity)
    coupling = [{"joint": c.joint, "from": c.from_, "factor": c.factor} for c in spec.coupling]
    if spec.kinematics == "dh":
        return dh_chain(model_path, [j.model_dump() for j in spec.joints], spec.dh_convention,
                        coupling, spec.tool_mm, g)
    if coupling:
        raise CampaignFormatError(model_path, "coupling is for dh models; a URDF states its own",
                                  column="coupling")
    return urdf_chain(model_path, model_path.parent / spec.urdf, spec.base_link, spec.tip_link,
                      list(spec.joints), spec.tool_mm, g)


def _columns(n_joints: int, axes=("x", "y", "z")) -> dict[str, tuple[str, bool]]:
    cols = {"sample": ("int", True), "time_s": ("float", False)}
    cols |= {f"j{k}": ("float", True) for k in range(1, n_joints + 1)}
    cols |= {"marker": ("int", False)}
    cols |= {f"{a}_mm": ("float", True) for a in axes}          # what the sensor does not see
    cols |= {"split": ("split", False), "temp_c": ("temp", False),  # is not read
             "payload_kg": ("float", False)}
    cols |= {f"j{k}_dir": ("dir", False) for k in range(1, n_joints + 1)}
    return cols


def _check_joint_columns(path: Path, chain: Chain) -> None:
    import csv
    with path.open(encoding="utf-8-sig") as f:
        header = [h.strip() for h in next(csv.reader(f), [])]
    n = chain.n_joints
    for h in header:
        if len(h) > 1 and h[0] == "j" and h[1:].isdigit() and int(h[1:]) > n:
            raise CampaignFormatError(path, f"column {h!r} but the model has {n} joints "
                                            f"({', '.join(j.name for j in chain.joints)})", line=1, column=h)
        if h.endswith("_deg") and h[:-4] in {j.column for j in chain.joints}:
            raise CampaignFormatError(path, f"column {h!r}: chain joint columns are j1 … j{n} "
                                            "(unit by joint type), not the SCARA's jK_deg", line=1, column=h)


def _check_axes(model_path: Path, spec: ChainSpec) -> None:
    """A sensor that sees fewer than three axes measures in the base frame a point known on
    the hand: its missing axis leaves a sensor frame and a marker's place undetermined."""
    if len(spec.sensor_axes) == 3:
        return
    if spec.measurement_frame != "base" or spec.markers == "unknown":
        raise CampaignFormatError(model_path, f"sensor_axes {list(spec.sensor_axes)}: a sensor that "
                                  "does not see every axis needs measurement_frame: base and the "
                                  "markers' positions given (markers: {id: [x, y, z]})",
                                  column="sensor_axes", line=_yaml_line(model_path, ("sensor_axes",)))


def _check_limits(path: Path, chain: Chain, readings: np.ndarray, lines: list[int]) -> None:
    for k, j in enumerate(chain.joints):
        if j.lower is None or j.upper is None:
            continue
        slack = LIMIT_SLACK * (j.upper - j.lower)
        bad = np.flatnonzero((readings[:, k] < j.lower - slack) | (readings[:, k] > j.upper + slack))
        if bad.size:
            i = int(bad[0])
            hint = (" (prismatic readings are in mm: a value in degrees or metres?)"
                    if j.type == "prismatic" else " (revolute readings are in degrees: radians?)")
            raise CampaignFormatError(path, f"joint {j.column} ({j.name}, {j.type}): {readings[i, k]:g} "
                                            f"{j.unit} is outside its limits {j.lower:g} … {j.upper:g} "
                                            f"{j.unit}{hint}; {bad.size} row(s) like this",
                                      line=lines[i], column=j.column)


def _rows_agree(pose: np.ndarray, marker: np.ndarray, q: np.ndarray, readings: np.ndarray,
                shared: list[np.ndarray], first_row: np.ndarray) -> bool:
    """Whether every row passes the checks :func:`read_chain_campaign` makes row by row (no
    marker twice on a pose; each row with its pose's joint readings and the ``shared``
    columns of its pose's first row ``first_row``), all at once: the row-by-row loop then
    runs only to name the first row that fails."""
    if len(pose) == 0:
        return True
    m = marker - marker.min()
    key = np.sort(pose * (int(m.max()) + 1) + m)          # (pose, marker), one number each
    if np.any(key[1:] == key[:-1]):
        return False
    return bool(np.all(q == readings[pose])) and all(
        bool(np.all(c == c[first_row])) for c in shared)


def read_chain_campaign(directory: Path | str, model_path: Path | str | None = None) -> ChainCampaign:
    """Read and validate a chain campaign. ``model_path`` replaces ``directory/model.yaml``
    (a calibrated model as the new nominal for the same points)."""
    d = Path(directory)
    mp = Path(model_path) if model_path else d / "model.yaml"
    if not mp.is_file():
        raise CampaignFormatError(mp, "missing: every campaign needs model.yaml")
    spec = load_spec(mp)
    chain = build_chain(spec, mp)
    pp = d / "points.csv"
    if not pp.is_file():
        raise CampaignFormatError(pp, "missing: a chain campaign needs points.csv")
    _check_joint_columns(pp, chain)
    _check_axes(mp, spec)
    t, lines = _read_table(pp, _columns(chain.n_joints, spec.sensor_axes))
    q = np.column_stack([t[f"j{k}"] for k in range(1, chain.n_joints + 1)])
    marker = t.get("marker", np.zeros(len(lines), dtype=np.int64))
    split = t.get("split")
    ids, first, inv = np.unique(t["sample"], return_index=True, return_inverse=True)
    order = np.argsort(first)             # poses in file order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    pose = rank[inv]
    readings = q[first[order]]
    dir_cols = {k: t[f"j{k + 1}_dir"] for k in range(chain.n_joints) if f"j{k + 1}_dir" in t}
    seen: set[tuple[int, int]] = set()
    shared = [c for c in (split, *dir_cols.values()) if c is not None]
    agree = _rows_agree(pose, marker, q, readings, shared, first[order[pose]])
    for i, (p, m) in enumerate([] if agree else zip(pose.tolist(), marker.tolist())):
        if (p, m) in seen:
            raise CampaignFormatError(pp, f"sample {int(ids[order[p]])} has marker {m} twice",
                                      line=lines[i], column="marker")
        seen.add((p, m))
        if not np.array_equal(q[i], readings[p]):
            raise CampaignFormatError(pp, f"rows of sample {int(ids[order[p]])} disagree on the joints "
                                          "(the markers of one pose share its joint readings)",
                                      line=lines[i], column="sample")
        if split is not None and split[i] != split[first[order[p]]]:
            raise CampaignFormatError(pp, f"rows of sample {int(ids[order[p]])} disagree on the split",
                                      line=lines[i], column="split")
        for k, col in dir_cols.items():
            if col[i] != col[first[order[p]]]:
                raise CampaignFormatError(pp, f"rows of sample {int(ids[order[p]])} disagree on "
                                              f"j{k + 1}_dir (the markers of one pose share its "
                                              "approach)", line=lines[i], column=f"j{k + 1}_dir")
    _check_limits(pp, chain, q, lines)
    check_places(pp, readings, ids[order].tolist(), [lines[int(first[o])] for o in order],
                 [j.column for j in chain.joints])
    pose_split = None if split is None else np.array([split[first[o]] for o in order], dtype=object)
    markers = sorted(set(marker.tolist()))
    if spec.markers != "unknown":
        unknown = [m for m in markers if m not in spec.markers]
        if unknown:
            i = int(np.flatnonzero(marker == unknown[0])[0])
            raise CampaignFormatError(pp, f"marker {unknown[0]} is not in model.yaml markers "
                                          f"{sorted(spec.markers)}", line=lines[i], column="marker")
    else:
        fit_pose = np.ones(len(order), bool) if pose_split is None else (pose_split == "fit")
        for m in markers:
            rows = np.flatnonzero(marker == m)
            n = len(set(pose[rows][fit_pose[pose[rows]]].tolist()))
            if n < MIN_MARKER_POSES:
                raise CampaignFormatError(pp, f"marker {m} is seen in {n} fit pose(s); placing an unknown "
                                              f"marker needs at least {MIN_MARKER_POSES}",
                                          line=lines[int(rows[0])], column="marker")
    mi = np.searchsorted(markers, marker)
    xyz = np.column_stack([t.get(f"{a}_mm", np.zeros(len(lines))) for a in "xyz"])
    extra = {k: t[k] for k in EXTRA_COLUMNS if k in t}
    dirs = None
    if dir_cols:
        dirs = np.zeros_like(readings)
        for k, col in dir_cols.items():
            dirs[:, k] = col[first[order]]
    return ChainCampaign(spec, chain, readings, ids[order], pose_split, pose, mi, xyz, markers,
                         lines, spec.source or str(d), d, extra, dirs)


def write_chain_campaign(c: ChainCampaign, directory: Path | str, spec: ChainSpec | None = None,
                         files: dict[str, str] | None = None, force: bool = False) -> Path:
    """Write ``c`` (with ``spec`` as its model, and extra ``files`` name → text such as a
    URDF) to ``directory`` (:func:`cell.measurements.folder.staged_dir`: a folder holding files it
    did not write is refused unless ``force``)."""
    import yaml
    d = Path(directory)
    with staged_dir(d, force) as tmp:
        model = (spec or c.spec).model_dump(mode="json", by_alias=True, exclude_defaults=False)
        if tuple(model.get("sensor_axes", ())) == ("x", "y", "z"):
            del model["sensor_axes"]             # the defaults: files written before them
        if model.get("sensor_center_mm", 0) is None:   # stay alike
            del model["sensor_center_mm"]
        (tmp / "model.yaml").write_text(yaml.safe_dump(model, sort_keys=False), encoding="utf-8")
        for name, text in (files or {}).items():
            (tmp / name).write_text(text, encoding="utf-8")
        nj = c.chain.n_joints
        head = ["sample"] + [f"j{k}" for k in range(1, nj + 1)] + ["marker", "x_mm", "y_mm", "z_mm"]
        head += ["split"] if c.split is not None else []
        dir_cols = [] if c.dirs is None else [k for k in range(nj) if np.any(c.dirs[:, k])]
        head += [f"j{k + 1}_dir" for k in dir_cols]
        extra = [k for k in EXTRA_COLUMNS if k in c.extra]
        head += extra
        out = [",".join(head)]
        for i in range(len(c.xyz)):
            p = c.obs_pose[i]
            row = [str(int(c.pose_ids[p]))] + [repr(float(v)) for v in c.readings[p]]
            row += [str(c.markers[c.obs_marker[i]])] + [repr(float(v)) for v in c.xyz[i]]
            row += [c.split[p]] if c.split is not None else []
            row += [str(int(c.dirs[p, k])) for k in dir_cols]
            row += [repr(float(c.extra[k][i])) for k in extra]
            out.append(",".join(row))
        (tmp / "points.csv").write_text("\n".join(out) + "\n", encoding="utf-8")
    return d


@dataclass(frozen=True)
class PlanarRows:
    """Which pose of a planar campaign read as a chain (:func:`planar_as_chain`) is which
    row of it: pose ``i < n_points`` is row ``i`` of points.csv; pose ``n_points + k`` is the
    ``k``-th path sample with the moves in the order of their first row in paths.csv and
    each move's samples in file order, which is the order of the planar arrays'
    ``DiagData.path_cat`` (:func:`cell.diagnosis.replay.prepare`). Each pose has one
    measured point (the tool centre), so point and pose indices are the same. ``campaign``
    is the v1 campaign itself (:class:`~cell.measurements.Campaign`); ``arrays`` its checked
    planar arrays (:func:`cell.diagnosis.replay.prepare`) once the diagnosis has made them."""

    campaign: object
    n_points: int
    arrays: object = None

    def points(self, a: np.ndarray) -> np.ndarray:
        """The rows of per-pose array ``a`` that are static points."""
        return a[:self.n_points]

    def paths(self, a: np.ndarray) -> np.ndarray:
        """The rows of per-pose array ``a`` that are path samples."""
        return a[self.n_points:]


def planar_as_chain(c, directory: Path | str = ".") -> ChainCampaign:
    """A v1 (SCARA) campaign ``c`` (:class:`~cell.measurements.Campaign`) as the chain
    campaign it is: two revolute joints in standard DH (a = ``l1_mm``, ``l2_mm``; α, d, θ
    zero; ``joint_limits_deg`` as limits; the v1 motor gear ratio, 50 as the format has it
    unless stated; each joint's bus position from ``stations``), the tool centre a known
    marker at the flange, measured in the base frame by a sensor that sees x and y
    (``sensor_axes: [x, y]``) whose centre is the camera's (``sensor_center_mm``).

    Its static points are poses with their ``jK_dir``, ``temp_c`` and ``time_s``. Each
    sample of a measured move (``paths.csv``) is a pose too, at the commanded angles, with
    ``move`` its move's index, ``move_t`` its time_s, ``rate`` the commanded joint speed
    there and the directions
    of the format's approach convention; its temperature is unknown (NaN in ``temp_c``:
    paths.csv records none). Without a ``split`` column the split is the v1 diagnosis's
    (:func:`drawn_fit`: 30 % of the points, then of the whole moves), so the holdout
    is the rows v1 held out. ``planar`` records which pose is which row (:class:`PlanarRows`).
    A campaign of measured moves only has no static poses. ``directory`` is where ``c``
    was read from (messages name its files)."""
    from cell.effects import path_directions, station_order
    from cell.effects.motor_cyclic_error import MOTOR_GEAR_RATIO   # v1: "50 unless stated"
    m = c.model
    limits = m.joint_limits_deg or [None, None]
    rows = [DHRow(name=f"j{k + 1}", type="revolute", a_mm=float(a), alpha_deg=0.0, d_mm=0.0,
                  theta_deg=0.0, limits=None if lim is None else tuple(lim))
            for k, (a, lim) in enumerate(zip((m.l1_mm, m.l2_mm), limits))]
    centre = None if m.camera is None else (*map(float, m.camera.center_mm), 0.0)
    spec = ChainSpec(format=FORMAT, kinematics="dh", joints=rows, measurement_frame="base",
                     markers={0: (0.0, 0.0, 0.0)}, sensor_axes=("x", "y"),
                     sensor_center_mm=centre, source=c.source or "planar campaign",
                     motor_gear_ratio={r.name: MOTOR_GEAR_RATIO for r in rows})
    chain = build_chain(spec, Path(directory) / "model.yaml")
    bus = station_order(c.station_order)
    chain.joints = [replace(j, bus_position=int(k)) for j, k in zip(chain.joints, bus)]
    p = c.points if c.points is not None else {
        "sample": np.zeros(0, np.int64), "split": np.zeros(0, "<U7"),
        **{k: np.zeros(0) for k in ("j1_deg", "j2_deg", "x_mm", "y_mm")}}
    n = len(p["sample"])
    rng = SplitRng()
    fit = p["split"] == "fit" if "split" in p else drawn_fit(n, rng)
    readings = [np.column_stack([p["j1_deg"], p["j2_deg"]]).astype(float)]
    xy = [np.column_stack([p["x_mm"], p["y_mm"]]).astype(float)]
    dirs = [np.column_stack([p.get(f"j{k}_dir", np.zeros(n)) for k in (1, 2)]).astype(float)]
    fits, moves, rates, times = [fit], [np.full(n, -1)], [np.zeros((n, 2))], [np.full(n, np.nan)]
    extra = {k: [np.asarray(p[k], float)] for k in EXTRA_COLUMNS if k in p}
    lines = list(range(2, n + 2))
    if c.paths is not None:
        t = c.paths
        ids = t["move"].tolist()
        order = list(dict.fromkeys(ids))
        move_fit = None if "split" in t else drawn_fit(len(order), rng)
        for i, mv in enumerate(order):
            idx = np.flatnonzero(t["move"] == mv)
            cmd = np.column_stack([t["j1_cmd_deg"][idx], t["j2_cmd_deg"][idx]]).astype(float)
            time = t["time_s"][idx].astype(float)
            readings.append(cmd)
            xy.append(np.column_stack([t["x_mm"][idx], t["y_mm"][idx]]).astype(float))
            dirs.append(path_directions(cmd, first_step(cmd)))
            fits.append(t["split"][idx] == "fit" if move_fit is None else np.full(len(idx), move_fit[i]))
            moves.append(np.full(len(idx), i))
            times.append(time)
            rates.append(np.column_stack([np.gradient(cmd[:, k], time) if len(idx) > 1
                                          else np.zeros(len(idx)) for k in range(2)]))
            for k in extra:
                extra[k].append(np.full(len(idx), np.nan))
            lines += (idx + 2).tolist()
    readings, xy = np.concatenate(readings), np.concatenate(xy)
    P = len(readings)
    has_dirs = "j1_dir" in p or "j2_dir" in p or c.paths is not None
    samples = np.concatenate([np.asarray(p["sample"]),
                              int(np.max(p["sample"], initial=0)) + 1 + np.arange(P - n)])
    split = np.where(np.concatenate(fits), "fit", "holdout")
    return ChainCampaign(spec, chain, readings, samples, split, np.arange(P),
                         np.zeros(P, dtype=np.int64), np.column_stack([xy, np.zeros(P)]), [0],
                         lines, spec.source, Path(directory),
                         {k: np.concatenate(v) for k, v in extra.items()},
                         np.concatenate(dirs) if has_dirs else None,
                         move=np.concatenate(moves), rate=np.concatenate(rates),
                         move_t=np.concatenate(times), planar=PlanarRows(c, n),
                         split_source="campaign" if (c.points is None or "split" in p)
                         and (c.paths is None or "split" in c.paths)
                         else f"generated as the v1 diagnosis's (seed {SPLIT_SEED})")
