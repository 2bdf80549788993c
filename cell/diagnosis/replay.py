"""Campaign -> diagnosis arrays, and the model replay every other step builds on. Pure numerics.

:func:`prepare` turns a validated :class:`~cell.measurements.Campaign` into
:class:`DiagData`: static poses (points) and moves (paths) as numpy arrays with their
fit/holdout masks. :func:`predict` replays them through :mod:`cell.effects` with a list of
effect instances (``[]`` = the nominal simulation); ``measured − predict(...)`` is the
residual. Units: mm, deg, s, °C, kg.

Conventions the format leaves open (documented here, used everywhere):

* ``split`` missing from a table: a seeded 70/30 split is drawn (rows for points, whole
  moves for paths; ``DiagData.split_source`` says ``"generated"``).
* Direction columns missing: directions are unknown (0, the centre of any backlash band).
* paths.csv holds no directions: each joint is taken to have approached a move's start in
  the direction of its own first commanded motion (unidirectional approach, the usual
  practice before a measured move), so ``dirs0`` is the sign of its first non-zero step.
* paths.csv holds no temperature: moves are replayed at the reference temperature unless
  the model carries a path temperature (``path_temp_c``).
* Camera effects need ``camera.center_mm`` in model.yaml; without it there is no camera
  centre to rotate or scale about, and camera candidates are not tried.

Semantic problems the reader cannot see (a move whose times do not increase, a move split
across fit and holdout, no fit or no holdout rows) raise
:class:`~cell.measurements.CampaignFormatError` naming file, line and column.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from cell import effects as fx
from cell.kinematics import PlanarArm
from cell.measurements import Campaign, CampaignFormatError
from cell.measurements.campaign import SplitRng, drawn_fit, first_step
from cell.numerics.stats import median



@dataclass
class PointsData:
    """Static poses: ``cmd`` (N,2) deg, ``dirs`` (N,2) ±1/0, ``time`` (N,) s, ``temp``
    (N,) °C or None, ``payload`` (N,) kg or None, ``xy`` (N,2) mm measured, ``fit`` (N,)
    bool (False = holdout), ``sample`` (N,) ids."""

    cmd: np.ndarray
    dirs: np.ndarray
    time: np.ndarray
    temp: np.ndarray | None
    payload: np.ndarray | None
    xy: np.ndarray
    fit: np.ndarray
    sample: np.ndarray
    has_dirs: bool = True


@dataclass
class Move:
    """One measured move: ``t`` (M,) s strictly increasing, ``cmd`` (M,2) deg commanded,
    ``xy`` (M,2) mm measured, ``dirs0`` (2,) assumed approach directions, ``fit`` bool."""

    move: int
    t: np.ndarray
    cmd: np.ndarray
    xy: np.ndarray
    dirs0: np.ndarray
    fit: bool


@dataclass
class DiagData:
    """Everything the diagnosis needs from one campaign (see module docstring)."""

    geometry: PlanarArm
    center: np.ndarray | None
    stations: list[str]
    order: np.ndarray
    points: PointsData | None
    moves: list[Move] = field(default_factory=list)
    split_source: dict = field(default_factory=dict)
    source: str = ""
    cache: dict = field(default_factory=dict, repr=False)   # derived arrays, never inputs

    @property
    def n_points(self) -> int:
        return 0 if self.points is None else len(self.points.xy)

    @property
    def n_path(self) -> int:
        return sum(len(m.t) for m in self.moves)

    def path_cat(self, name: str, which: str = "all") -> np.ndarray:
        """Attribute ``name`` of the moves concatenated (``which`` = all / fit / holdout)."""
        ms = [m for m in self.moves if which == "all" or m.fit == (which == "fit")]
        if not ms:
            return np.zeros((0, 2)) if name in ("cmd", "xy") else np.zeros(0)
        return np.concatenate([getattr(m, name) for m in ms])

    def path_fit_mask(self) -> np.ndarray:
        """(n_path,) bool: True for samples of fit moves."""
        return np.concatenate([np.full(len(m.t), m.fit) for m in self.moves]) if self.moves \
            else np.zeros(0, bool)

    def path_move_index(self) -> np.ndarray:
        """(n_path,) int: index of each sample's move in :attr:`moves`."""
        return np.concatenate([np.full(len(m.t), i) for i, m in enumerate(self.moves)]) \
            if self.moves else np.zeros(0, int)


def _geometry(c: Campaign) -> PlanarArm:
    """The campaign's nominal arm: its link lengths, and its joint limits where model.yaml
    gives them (θ1, θ2; else the cell's defaults)."""
    m = c.model
    limits = tuple((float(lo), float(hi)) for lo, hi in (m.joint_limits_deg or [])[:2])
    return PlanarArm(float(m.l1_mm), float(m.l2_mm), limits) if len(limits) == 2 \
        else PlanarArm(float(m.l1_mm), float(m.l2_mm))


def _split(table: dict, n_units: int, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    if "split" in table:
        return None, "file"
    return drawn_fit(n_units, rng), "generated"


def first_step_dirs(cmd: np.ndarray) -> np.ndarray:
    """(2,) sign of each joint's first non-zero commanded step (0 if it never moves):
    :func:`cell.measurements.campaign.first_step`."""
    return first_step(cmd)


def prepare(c: Campaign, lines: dict[str, Sequence[int]] | None = None) -> DiagData:
    """Arrays for the diagnosis from a validated campaign.

    ``lines`` maps ``"points"`` / ``"paths"`` to the 1-based file line of every data row
    (for error messages; row index + 2 when not given). Raises CampaignFormatError for the
    semantic problems listed in the module docstring.
    """
    lines = lines or {}
    src = Path(c.source or ".")
    rng = SplitRng()
    geom = _geometry(c)
    center = np.array(c.model.camera.center_mm, float) if c.model.camera else None
    try:
        order = fx.station_order(c.station_order)
    except Exception as exc:  # ConfigError from the vocabulary
        raise CampaignFormatError(src / "model.yaml", str(exc), column="stations") from None
    split_source = {}
    pts = None
    if c.points is not None:
        p = c.points
        n = len(p["sample"])
        fit, split_source["points"] = _split(p, n, rng)
        if fit is None:
            fit = p["split"] == "fit"
        has_dirs = "j1_dir" in p and "j2_dir" in p
        dirs = np.column_stack([p.get("j1_dir", np.zeros(n)), p.get("j2_dir", np.zeros(n))])
        pts = PointsData(cmd=np.column_stack([p["j1_deg"], p["j2_deg"]]).astype(float),
                         dirs=dirs.astype(float), time=p["time_s"].astype(float),
                         temp=p.get("temp_c"), payload=p.get("payload_kg"),
                         xy=np.column_stack([p["x_mm"], p["y_mm"]]).astype(float),
                         fit=np.asarray(fit, bool), sample=p["sample"], has_dirs=has_dirs)
    moves: list[Move] = []
    if c.paths is not None:
        moves = _moves(c.paths, src / "paths.csv", lines.get("paths"), rng, split_source)
    d = DiagData(geometry=geom, center=center, stations=list(c.station_order), order=order,
                 points=pts, moves=moves, split_source=split_source, source=c.source)
    n_fit = (int(pts.fit.sum()) if pts else 0) + sum(len(m.t) for m in moves if m.fit)
    n_hold = (int((~pts.fit).sum()) if pts else 0) + sum(len(m.t) for m in moves if not m.fit)
    if (n_fit < 4 or n_hold < 1) and src.is_file():        # a cycle log: no CSV to name
        raise CampaignFormatError(src, f"its done cycles give {n_fit} fit and {n_hold} holdout "
                                  "measurements; the diagnosis needs at least 4 fit and 1 holdout: "
                                  "log more cycles")
    if n_fit < 4 or n_hold < 1:
        bad = "points.csv" if pts is not None else "paths.csv"
        raise CampaignFormatError(src / bad, f"the split leaves {n_fit} fit and {n_hold} holdout "
                                  "rows; the diagnosis needs at least 4 fit rows and 1 holdout row",
                                  column="split")
    return d


def _moves(t: dict, path: Path, lines, rng, split_source) -> list[Move]:
    ids = t["move"]
    line_of = (lambda i: int(lines[i])) if lines is not None else (lambda i: i + 2)
    order: list[int] = []
    rows: dict[int, list[int]] = {}
    for i, m in enumerate(ids.tolist()):
        if m not in rows:
            rows[m] = []
            order.append(m)
        rows[m].append(i)
    fit_mv, split_source["paths"] = _split(t, len(order), rng)
    moves = []
    for k, m in enumerate(order):
        idx = np.array(rows[m])
        tt = t["time_s"][idx].astype(float)
        bad = np.flatnonzero(np.diff(tt) <= 0)
        if bad.size:
            i = idx[bad[0] + 1]
            raise CampaignFormatError(path, f"move {m}: time_s {tt[bad[0] + 1]!r} does not "
                                      f"increase (previous sample {tt[bad[0]]!r})",
                                      line=line_of(i), column="time_s")
        if fit_mv is None:
            sp = t["split"][idx]
            diff = np.flatnonzero(sp != sp[0])
            if diff.size:
                raise CampaignFormatError(path, f"move {m} is split across fit and holdout; "
                                          "split whole moves", line=line_of(idx[diff[0]]),
                                          column="split")
            is_fit = sp[0] == "fit"
        else:
            is_fit = bool(fit_mv[k])
        cmd = np.column_stack([t["j1_cmd_deg"][idx], t["j2_cmd_deg"][idx]]).astype(float)
        moves.append(Move(move=int(m), t=tt, cmd=cmd,
                          xy=np.column_stack([t["x_mm"][idx], t["y_mm"][idx]]).astype(float),
                          dirs0=first_step_dirs(cmd), fit=is_fit))
    return moves


# ------------------------------------------------------------------ replay
def delayed_commands(d: DiagData, effects: Sequence[fx.EffectInstance]) -> list[np.ndarray]:
    """Per move, the commands the joints actually had after the comms stage (stage 1)."""
    comms = [e for e in effects if e.spec.stage == fx.Stage.COMMS]
    out = []
    for m in d.moves:
        a = m.cmd
        for e in comms:
            a = e.spec.fn(e.full_vector(), d.order, m.t, a)
        out.append(a)
    return out


def path_inputs(d: DiagData, effects: Sequence[fx.EffectInstance]) -> tuple[np.ndarray, np.ndarray]:
    """(actual joints (n_path,2), directions (n_path,2)) of all path samples under ``effects``;
    directions follow the (delayed) motion from each move's ``dirs0`` as in
    :func:`cell.effects.simulate_path`."""
    if not any(e.spec.stage == fx.Stage.COMMS for e in effects):
        cached = d.cache.get("path_inputs")     # no comms stage: the same for every call
        if cached is None:
            cached = d.cache["path_inputs"] = _path_inputs(d, [])
        return cached
    return _path_inputs(d, effects)


def _path_inputs(d: DiagData, effects) -> tuple[np.ndarray, np.ndarray]:
    acts = delayed_commands(d, effects)
    if not acts:
        return np.zeros((0, 2)), np.zeros((0, 2))
    dirs = [fx.path_directions(a, m.dirs0) for a, m in zip(acts, d.moves)]
    return np.concatenate(acts), np.concatenate(dirs)


def predict(d: DiagData, effects: Sequence[fx.EffectInstance], path_temp_c: float | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Simulated measurements (points (N,2), path samples (n_path,2)) in mm under ``effects``.

    One :func:`cell.effects.simulate_points` call over points and path samples together
    (a path sample is a static pose at the joints the comms stage left it at, with the
    directions of its motion: the same as :func:`cell.effects.simulate_path`).
    ``path_temp_c`` is the temperature the moves are replayed at (default: the reference
    temperature of a thermal_drift effect among ``effects``, i.e. no thermal growth).
    """
    effects = list(effects)
    t_ref = fx.reference_temp_c(effects)
    cmd, dirs, temp = [], [], []
    if d.points is not None:
        cmd.append(d.points.cmd)
        dirs.append(d.points.dirs)
        temp.append(d.points.temp if d.points.temp is not None else np.full(d.n_points, t_ref))
    if d.moves:
        a, dd = path_inputs(d, effects)
        cmd.append(a)
        dirs.append(dd)
        temp.append(np.full(len(a), t_ref if path_temp_c is None else path_temp_c))
    xy = fx.simulate_points(d.geometry, [e for e in effects if e.spec.stage != fx.Stage.COMMS],
                            np.concatenate(cmd), np.concatenate(dirs), None,
                            np.concatenate(temp), d.center if d.center is not None else (0.0, 0.0))
    return xy[:d.n_points], xy[d.n_points:]


def measured(d: DiagData) -> tuple[np.ndarray, np.ndarray]:
    """Measured (points (N,2), path samples (n_path,2)) in mm."""
    if "measured" not in d.cache:
        pts = d.points.xy if d.points is not None else np.zeros((0, 2))
        d.cache["measured"] = (pts, d.path_cat("xy"))
    return d.cache["measured"]


def residuals(d: DiagData, effects: Sequence[fx.EffectInstance] = (), path_temp_c=None
              ) -> tuple[np.ndarray, np.ndarray]:
    """measured − simulated for (points, path samples), mm; ``effects=()`` is the nominal gap."""
    mp, mq = measured(d)
    sp, sq = predict(d, effects, path_temp_c)
    return mp - sp, mq - sq


def path_noise_mm(d: DiagData) -> float | None:
    """Model-free noise σ per axis (mm) of the path samples: robust (MAD) spread of second
    differences of the nominal residual along each move, /√6 (smooth gaps cancel at ms
    sampling; white noise of σ gives second differences of σ·√6). None without moves of
    ≥ 3 samples."""
    _, rq = residuals(d)
    parts, k = [], 0
    for m in d.moves:
        r = rq[k:k + len(m.t)]
        k += len(m.t)
        if len(r) >= 3:
            parts.append(np.diff(r, n=2, axis=0).ravel())
    if not parts:
        return None
    dd = np.concatenate(parts)
    return float(1.4826 * median(np.abs(dd - median(dd))) / np.sqrt(6.0))
