"""Registration and error-parameter fits for chain campaigns. Pure numerics; no I/O.

Measurement model (one measured point ``y`` of marker m on pose p)::

    y = R_s · ((1 + g_p) · T_tip(q_p; e) · m_m) + t_s,    measured: c + M(e) · (y − c)

``R_s, t_s`` (the sensor frame, when ``measurement_frame: sensor``) and ``m_m`` (marker
positions in the tip frame, when ``markers: unknown``) are **registration**: nuisance
fitted first and with every candidate. ``e`` are the error parameters of the chain
vocabulary (:func:`vocabulary`); ``g_p`` the growth of the whole arm on pose p that its
parameters give (thermal: α·(T_p − 20 °C); 0 without one); ``M(e)`` the product of the
sensor's own maps about its centre ``c`` (``sensor_center_mm``: a camera's scale and
rotation; I without one). Fits are damped Gauss–Newton
with exact Jacobians (:mod:`cell.kinematics.evaluate`); the sensor rotation is updated
multiplicatively.

**Honest uncertainty.** The markers of one pose share its joint readings and often one
tracked rigid body, so their errors are correlated: the covariance is the
cluster-robust (sandwich) estimate with poses as clusters and Student t intervals on
(poses − 1) degrees of freedom, and model selection uses leave-one-*pose*-out
prediction error (:attr:`Fit.cv_rms`), never per-point counts alone.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from cell import effects as fx
from cell.diagnosis import leaveout
from cell.diagnosis.leaveout import scaled
from cell.diagnosis.places import folds as place_folds, places as linked_places, stations
import cell.kinematics as kin
from cell.kinematics import identifiable
from cell.kinematics.chain import Chain
from cell.kinematics.identifiable import STRUCTURAL_TOL
from cell.measurements import CampaignFormatError
from cell.numerics.stats import t_quantile
from cell.numerics.sums import squares_last

MAX_VIF = 100.0           # beyond: registration and the parameter are hard to tell apart
TERM_EPS = 1e-9           # a joint term below this on every pose (deg, m, K, 1) is zero: the
                          # gravity lever of a joint whose axis runs through the tool point
NO_EFFECT = "has no effect on the measured points"   # not_identifiable: a parameter without a column
KEPT_REGISTRATIONS = 2    # Data.zero_blocks keeps the Jacobian blocks of this many
NUISANCE_BASIS = "nuisance basis"   # Data.zero_blocks' key of the registration columns' basis
# the chain vocabulary: the effects of cell.effects that apply to chains (Effect.chain)
EFFECTS = tuple(fx.CHAIN_EFFECTS)
SUBSYSTEM = {n: e.subsystem for n, e in fx.CHAIN_EFFECTS.items()}
DEPENDS_ON = {n: e.depends_on for n, e in fx.CHAIN_EFFECTS.items()}


@dataclass(frozen=True)
class Param:
    """One error parameter: ``effect`` of the chain vocabulary, 0-based ``joint``, the op it
    adds to and its unit (deg, mm, 1, deg/m, 1/K); ``joint`` and ``op`` are −1 for a
    parameter on no joint: of the whole arm (:attr:`arm`) or of the sensor
    (:attr:`sensor`); ``part`` which of its effect's terms on the joint it carries
    (:meth:`cell.effects.OnChain.terms`)."""

    name: str
    effect: str
    joint: int
    op: int
    unit: str
    part: int = 0

    @property
    def term(self):
        """Its effect's term on the joint (:attr:`cell.effects.OnChain.term`; None for a
        geometric parameter or the sensor's)."""
        return fx.CHAIN_EFFECTS[self.effect].chain.terms()[self.part][1]

    @property
    def nuisance(self) -> bool:
        """One of its effect's nuisance parameters (:attr:`cell.effects.OnChain.nuisance`),
        never a cause on its own."""
        return self.part >= fx.CHAIN_EFFECTS[self.effect].chain.n_own

    @property
    def on_joint(self) -> bool:
        return self.joint >= 0

    @property
    def sensor(self) -> bool:
        """A parameter of the sensor's map about its centre (a camera's scale, rotation)."""
        return fx.CHAIN_EFFECTS[self.effect].chain.joints == "sensor"

    @property
    def bus(self) -> bool:
        """A parameter of the drives' bus, acting on every joint (the comm delay)."""
        return fx.CHAIN_EFFECTS[self.effect].chain.joints == "bus"

    @property
    def arm(self) -> bool:
        """A parameter of the whole arm (thermal growth)."""
        return self.joint < 0 and not self.sensor and not self.bus

    def joint_terms(self, poses: fx.ChainPoses) -> np.ndarray:
        """(P, J) how each joint's value changes per unit of the parameter at 0 (zero but
        on its joint; a bus parameter's on every joint)."""
        out = np.zeros_like(poses.q)
        if self.bus:
            for k in range(out.shape[1]):
                out[:, k] = self.term(poses, k)
        elif self.on_joint:
            out[:, self.joint] = self.term(poses, self.joint)
        return out

    def joint_shift(self, poses: fx.ChainPoses, value: float) -> tuple[np.ndarray, np.ndarray]:
        """((P, J) the joints' change at ``value``, (P, J) its derivative): the effect's
        exact ``shift`` where it gives one (:attr:`cell.effects.OnChain.shift`), else
        ``value`` times :meth:`joint_terms`."""
        shift = fx.CHAIN_EFFECTS[self.effect].chain.shift
        if shift is None:
            t = self.joint_terms(poses)
            return value * t, t
        out, dv = np.zeros_like(poses.q), np.zeros_like(poses.q)
        for k in (range(out.shape[1]) if self.bus else [self.joint]):
            out[:, k], dv[:, k] = shift(poses, k, value)
        return out, dv


def vocabulary(chain: Chain) -> list[Param]:
    """All error parameters the chain defines, offsets first (the identifiability priority):
    per effect of :data:`EFFECTS`, in its order, the parameters its definition's
    :class:`cell.effects.OnChain` names (per joint, per revolute joint, the chain's
    geometric parameters, or one for the whole arm or the sensor)."""
    out = []
    for name, e in fx.CHAIN_EFFECTS.items():
        use = e.chain
        if use.joints in ("arm", "sensor") or use.joints == "bus" and any(
                j.bus_position is not None for j in chain.joints):
            out.append(Param(use.stem, name, -1, -1, use.unit))
            out += [Param(stem, name, -1, -1, unit, use.n_own + i)
                    for i, (stem, unit, _) in enumerate(use.nuisance)]
            continue
        if use.joints == "bus":
            continue
        if use.joints == "geometric":
            for pn, op in chain.geometric.items():
                out.append(Param(pn, name, int(pn.split("_")[0][1:]) - 1, op, pn.rsplit("_", 1)[1]))
            continue
        for k, j in enumerate(chain.joints):
            if use.joints in ("revolute", "geared") and j.type != "revolute" \
                    or use.joints == "geared" and j.motor_ratio is None:
                continue
            units = [use.unit] * use.n_own + [u for _, u, _ in use.nuisance]
            for part, (stem, _) in enumerate(use.terms()):
                out.append(Param(f"{j.column}_{stem.format(unit=j.unit)}", name, k,
                                 chain.joint_op[k], units[part].format(unit=j.unit), part))
    return out


def _levers(chain: Chain, frames: tuple[np.ndarray, dict[int, np.ndarray]]) -> np.ndarray:
    tips, starts = frames
    load = tips[:, :3, :3] @ chain.tool_mm + tips[:, :3, 3]
    return kin.gravity_levers(chain, starts, load)


def _take(frames, rows: np.ndarray):
    """``frames`` (tips, starts) of the poses ``rows`` (indices), or None."""
    if frames is None:
        return None
    tips, starts = frames
    return tips[rows], {i: F[rows] for i, F in starts.items()}


@dataclass
class Data:
    """Poses and measured points of (part of) a campaign; ``levers`` (P, J) m, the gravity
    lever of each joint at the nominal pose (None until :func:`_poses` first needs them); ``dirs`` (P, J) the sign of each joint's last
    motion (0: unknown); ``temp_c`` (P,) each pose's temperature (the mean ``temp_c`` of
    its rows; None: no column); ``axes`` the axes of the measurement frame the sensor sees
    (0, 1, 2 = x, y, z; ``sensor_axes``), ``xyz`` (M, len(axes)) holds those components
    only; ``centre`` (3,) mm the sensor's centre in the measurement frame
    (``sensor_center_mm``; None: not given); ``move`` (P,) the measured move each pose is a
    sample of (−1: static), ``move_t`` (P,) s its time in the move and ``rate`` (P, J) the
    commanded joint speed there, deg/s
    (:class:`~cell.measurements.chain.ChainCampaign`; None: static poses only); ``frames``
    the nominal forward kinematics of the poses (:meth:`nominal_frames`), None until asked."""

    chain: Chain
    readings: np.ndarray
    obs_pose: np.ndarray
    obs_marker: np.ndarray
    xyz: np.ndarray
    n_markers: int
    sensor: bool
    known_markers: np.ndarray | None
    levers: np.ndarray | None
    dirs: np.ndarray | None = None
    place: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    axes: tuple[int, ...] = (0, 1, 2)
    centre: np.ndarray | None = None
    move: np.ndarray | None = None
    rate: np.ndarray | None = None
    move_t: np.ndarray | None = None
    frames: tuple[np.ndarray, dict[int, np.ndarray]] | None = field(default=None, repr=False,
                                                                     compare=False)
    _blocks: list | None = field(default=None, init=False, repr=False, compare=False)
    _poses: fx.ChainPoses | None = field(default=None, init=False, repr=False, compare=False)
    _rows_are_poses: bool | None = field(default=None, init=False, repr=False, compare=False)
    _stations: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    _linked: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    _terms: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.dirs is None:
            self.dirs = np.zeros_like(self.readings)

    def zero_blocks(self, reg: "Registration") -> dict:
        """The Jacobian blocks :func:`model` has computed at zero parameters for
        registration ``reg`` (None: the registration's; a :class:`Param`: its column; and
        :data:`NUISANCE_BASIS`, :func:`identifiability`'s basis of the registration's
        columns), kept for the :data:`KEPT_REGISTRATIONS` registrations asked about last (a
        fit's start between two screenings must not drop the registration-only fit's)."""
        kept = self._blocks if self._blocks is not None else []
        for i, (r, blocks) in enumerate(kept):
            if r is reg:
                kept.append(kept.pop(i))
                return blocks
        self._blocks = (kept + [(reg, {})])[-KEPT_REGISTRATIONS:]
        return self._blocks[-1][1]

    def nominal_frames(self) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """(tips, starts) of :func:`cell.kinematics.forward` at the readings with every
        error parameter zero (``keep``): the registration-only model and every Jacobian
        taken at zero parameters use them. Computed once, shared with subsets."""
        if self.frames is None:
            self.frames = kin.forward(self.chain, self.readings, keep=True)
        return self.frames

    @classmethod
    def of(cls, cc, pose_mask: np.ndarray | None = None) -> "Data":
        """From a :class:`~cell.measurements.chain.ChainCampaign`, keeping the poses of ``pose_mask``."""
        frames = kin.forward(cc.chain, cc.readings, keep=True)
        axes = cc.axes
        d = cls(cc.chain, cc.readings, cc.obs_pose, cc.obs_marker,
                cc.xyz if len(axes) == 3 else cc.xyz[:, list(axes)], len(cc.markers),
                cc.spec.measurement_frame == "sensor", cc.known_markers,
                _levers(cc.chain, frames), cc.dirs, temp_c=cc.pose_temps(), axes=axes,
                centre=None if cc.spec.sensor_center_mm is None
                else np.asarray(cc.spec.sensor_center_mm, float), move=cc.move, rate=cc.rate,
                move_t=cc.move_t,
                frames=frames)
        return d if pose_mask is None else d.subset(pose_mask)

    def at(self, readings: np.ndarray, dirs: np.ndarray | None = None) -> "Data":
        """The same arm, markers and frame at other joint ``readings`` (P, J) approached
        from ``dirs`` (P, J; None: unknown), at the campaign's mean temperature, every
        marker on every pose, nothing measured (``xyz`` zero): for predicting, not fitting.
        Its nominal frames and gravity levers are computed when first asked for (a
        prediction of fitted parameters needs neither unless it holds a compliance)."""
        P, m = len(readings), max(self.n_markers, 1)
        temp = None if self.temp_c is None else np.full(P, float(np.nanmean(self.temp_c)))
        return Data(self.chain, readings, np.repeat(np.arange(P), m), np.tile(np.arange(m), P),
                    np.zeros((P * m, self.dims)), self.n_markers, self.sensor, self.known_markers,
                    None, dirs, np.arange(P), temp, self.axes, self.centre)

    def subset(self, pose_mask: np.ndarray) -> "Data":
        keep = np.flatnonzero(pose_mask)
        new = -np.ones(len(pose_mask), dtype=np.int64)
        new[keep] = np.arange(len(keep))
        rows = pose_mask[self.obs_pose]
        return Data(self.chain, self.readings[keep], new[self.obs_pose[rows]], self.obs_marker[rows],
                    self.xyz[rows], self.n_markers, self.sensor, self.known_markers,
                    self.levers[keep], self.dirs[keep],
                    temp_c=None if self.temp_c is None else self.temp_c[keep], axes=self.axes,
                    centre=self.centre, move=None if self.move is None else self.move[keep],
                    rate=None if self.rate is None else self.rate[keep],
                    move_t=None if self.move_t is None else self.move_t[keep],
                    frames=_take(self.frames, keep))

    def keep_points(self, keep: np.ndarray) -> "Data":
        """The measured points ``keep`` (M,) marks; poses left with none are dropped."""
        if keep.all():
            return self
        poses = np.bincount(self.obs_pose[keep], minlength=self.n_poses) > 0
        new = -np.ones(self.n_poses, dtype=np.int64)
        new[poses] = np.arange(int(poses.sum()))
        return Data(self.chain, self.readings[poses], new[self.obs_pose[keep]], self.obs_marker[keep],
                    self.xyz[keep], self.n_markers, self.sensor, self.known_markers,
                    self.levers[poses], self.dirs[poses],
                    temp_c=None if self.temp_c is None else self.temp_c[poses], axes=self.axes,
                    centre=self.centre, move=None if self.move is None else self.move[poses],
                    rate=None if self.rate is None else self.rate[poses],
                    move_t=None if self.move_t is None else self.move_t[poses],
                    frames=_take(self.frames, np.flatnonzero(poses)))

    @property
    def n_poses(self) -> int:
        return len(self.readings)

    def point_poses(self) -> np.ndarray | None:
        """``obs_pose``, or None when it is 0, 1, …, P − 1 (one point per pose, in pose
        order: a per-pose array is already per point)."""
        if self._rows_are_poses is None:
            self._rows_are_poses = len(self.obs_pose) == self.n_poses and bool(
                np.array_equal(self.obs_pose, np.arange(self.n_poses)))
        return None if self._rows_are_poses else self.obs_pose

    def per_point(self, a: np.ndarray) -> np.ndarray:
        """Per-pose ``a`` (P, …) for every measured point (M, …): ``a[obs_pose]``, or ``a``
        itself when the points are the poses (:meth:`point_poses`)."""
        rows = self.point_poses()
        return a if rows is None else a[rows]

    @property
    def dims(self) -> int:
        """Components per measured point: the axes the sensor sees."""
        return len(self.axes)

    def folds(self) -> tuple[np.ndarray, int]:
        """(fold of every measured point, number of folds) for leave-out prediction: the
        poses' places when they sit at stations (a station revisited: leaving out one
        visit would leave its twins in), else every pose on its own
        (:func:`cell.diagnosis.places.folds`); each measured move is a fold of its own."""
        if self.place is None:          # found when first asked: most Data never are; the
            self.place = _moves_apart(  # static poses' places, then each move one fold
                self.readings, self.move, lambda q: place_folds(q, linked=_linked(self))[0])
        n = int(self.place.max()) + 1 if len(self.place) else 0
        return self.place[self.obs_pose], n


@dataclass
class Registration:
    """Sensor frame (``R``, ``t``: base → sensor) and marker positions (K, 3) in the tip frame."""

    R: np.ndarray
    t: np.ndarray
    markers: np.ndarray

    def as_dict(self, sensor: bool, free: bool, marker_ids) -> dict:
        out: dict = {}
        if sensor:
            rx, ry, rz = _rpy_deg(self.R)
            out["sensor_frame"] = {"meaning": "pose of the base frame in the sensor frame: "
                                              "y_sensor = R · x_base + t",
                                   "t_mm": [round(float(v), 4) for v in self.t],
                                   "rpy_deg": [round(v, 5) for v in (rx, ry, rz)]}
        if free:
            out["markers_mm"] = {str(m): [round(float(v), 4) for v in p]
                                 for m, p in zip(marker_ids, self.markers)}
        return out


def _rpy_deg(R: np.ndarray) -> tuple[float, float, float]:
    pitch = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    return (math.degrees(math.atan2(R[2, 1], R[2, 2])), math.degrees(pitch),
            math.degrees(math.atan2(R[1, 0], R[0, 0])))


def _skew_rows(y: np.ndarray) -> np.ndarray:
    """(M, 3, 3): d(ω × y)/dω = −[y]× for each row of y."""
    z = np.zeros(len(y))
    return -np.stack([np.stack([z, -y[:, 2], y[:, 1]], -1), np.stack([y[:, 2], z, -y[:, 0]], -1),
                      np.stack([-y[:, 1], y[:, 0], z], -1)], 1)


def _exp(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R a + t − b| (rows are points)."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


class _LaterLevers:
    """The gravity levers of a :class:`Data` that has none yet (:meth:`Data.at`), computed
    on first indexing: most predictions hold no compliance and never read them."""

    def __init__(self, d: Data):
        self.d = d

    def __getitem__(self, key):
        if self.d.levers is None:
            self.d.levers = _levers(self.d.chain, self.d.nominal_frames())
        return self.d.levers[key]


def _stations(d: Data) -> np.ndarray:
    """The group of every pose for a requirement within each place: the static poses'
    (:func:`cell.diagnosis.places.stations`), then each measured move one group; found
    once per :class:`Data`."""
    if d._stations is None:
        d._stations = _moves_apart(d.readings, d.move, lambda q: stations(q, _linked(d)))
    return d._stations


def _linked(d: Data) -> np.ndarray:
    """:func:`cell.diagnosis.places.places` of ``d``'s static poses, found once for its folds
    and its stations."""
    if d._linked is None:
        static = d.readings if d.move is None or not np.any(d.move >= 0) else d.readings[d.move < 0]
        d._linked = linked_places(static)
    return d._linked


def _moves_apart(readings: np.ndarray, move: np.ndarray | None, group) -> np.ndarray:
    """``group(readings)`` (an int label per pose) for the static poses, and after its
    labels one label per measured move (``move`` ≥ 0; None: static poses only)."""
    if move is None or not np.any(move >= 0):
        return group(readings)
    static = move < 0
    out = np.empty(len(readings), np.int64)
    out[static] = group(readings[static]) if static.any() else []
    first = int(out[static].max()) + 1 if static.any() else 0
    out[~static] = first + np.unique(move[~static], return_inverse=True)[1]
    return out


def _poses(d: Data) -> fx.ChainPoses:
    """What the effects' joint terms read of ``d``'s poses, built once per :class:`Data`."""
    if d._poses is None:
        levers = _LaterLevers(d) if d.levers is None else d.levers
        d._poses = fx.ChainPoses(d.chain.model_values(d.readings), levers, d.dirs, d.temp_c,
                                 tuple(j.motor_ratio for j in d.chain.joints), d.rate,
                                 tuple(j.bus_position for j in d.chain.joints), d.move, d.move_t)
    return d._poses


def _term(d: Data, p: Param, k: int) -> np.ndarray:
    """``p.term`` on ``d``'s poses at joint ``k`` (−1: of the whole arm), computed once per
    :class:`Data` (callers do not change it)."""
    key = (p.effect, p.part, k)
    v = d._terms.get(key)
    if v is None:
        v = d._terms[key] = p.term(_poses(d), k)
    return v


def _joint_term(d: Data, p: Param) -> np.ndarray:
    """``p``'s term on ``d``'s poses as :func:`identifiability` judges it: on its joint
    (:func:`_term`), or a bus parameter's on every joint (:meth:`Param.joint_terms`)."""
    return p.joint_terms(_poses(d)) if p.bus else _term(d, p, p.joint)


def _term_size(d: Data, p: Param) -> tuple[bool, float]:
    """(whether :func:`_joint_term` is nonzero on some pose, its largest magnitude there;
    0.0 when it is zero everywhere), found once per :class:`Data`: every pool holding the
    parameter asks."""
    key = ("size", p.effect, p.part, p.joint)
    got = d._terms.get(key)
    if got is None:
        v = _joint_term(d, p)
        nonzero = bool(np.any(v))
        got = d._terms[key] = (nonzero, float(np.max(np.abs(v))) if nonzero else 0.0)
    return got


def joint_deltas(d: Data, params: list[Param], values: np.ndarray, shifts: dict | None = None
                 ) -> tuple[dict[int, float], np.ndarray, np.ndarray | None]:
    """The geometric op offsets, the (P, J) joint-value additions and the (P,) relative
    growth of the whole arm (None: none) of ``values``: each parameter's effect definition
    says which (:attr:`cell.effects.OnChain.term`). ``shifts`` (if given) receives, by the
    parameter's position, the exact shifts and derivatives of :meth:`Param.joint_shift`."""
    geo: dict[int, float] = {}
    dq = np.zeros_like(d.readings)
    grow = None
    poses = _poses(d)
    for i, (p, v) in enumerate(zip(params, values)):
        term = p.term
        if p.sensor:
            continue
        if term is None:
            geo[p.op] = geo.get(p.op, 0.0) + v
        elif p.arm:
            grow = (0.0 if grow is None else grow) + v * _term(d, p, -1)
        elif p.bus:
            shift = p.joint_shift(poses, v)
            if shifts is not None:
                shifts[i] = shift
            dq += shift[0]
        else:
            dq[:, p.joint] += v * _term(d, p, p.joint)
    return geo, dq, grow


def model(d: Data, reg: Registration, params: list[Param], values: np.ndarray, jac: bool = False
          ) -> tuple[np.ndarray, np.ndarray | None]:
    """Predicted points (M, dims) in the measurement frame, the axes the sensor sees (the
    arm grown by the growth of :func:`joint_deltas`, about the base frame's origin, and
    read through the sensor's maps about its centre, :func:`sensor_maps`); with ``jac``
    also the (dims·M, n) Jacobian, columns: sensor rotation (3) and translation (3) if
    ``d.sensor``, marker positions (3 each) if free, then ``params``. At zero ``values``
    the frames are the Data's nominal ones and the Jacobian's blocks are kept per
    registration and parameter (:meth:`Data.zero_blocks`): screening, identifiability and
    the registration-only fit ask for the same columns many times."""
    zero = not np.any(values)
    grow = None
    shifts: dict[int, tuple] = {}
    if zero:
        tips, starts = d.nominal_frames()
    else:
        geo, dq, grow = joint_deltas(d, params, values, shifts)
        tips, starts = kin.forward(d.chain, d.readings, geo, dq, keep=jac)
    local = reg.markers[d.obs_marker]
    rows = d.point_poses()
    xb = kin.points(tips, rows, local)
    scale = None if grow is None else d.per_point(1.0 + grow)[:, None]     # (M, 1)
    y = (xb if scale is None else xb * scale) @ reg.R.T + reg.t
    M, dM = sensor_maps(params, values)
    if zero or d.centre is None:            # the identity, or nothing to map about
        M = None
    read = y if M is None else d.centre + (y - d.centre) @ M.T
    if not jac:
        return _seen(d, read), None
    kept = d.zero_blocks(reg) if zero else {}
    blocks = kept.get(None)
    if blocks is None:
        cols = []
        if d.sensor:
            cols += [_skew_rows(y - reg.t), np.broadcast_to(np.eye(3), (len(y), 3, 3))]
        if d.known_markers is None:
            Rt = reg.R @ tips[d.obs_pose, :3, :3]                    # (M, 3, 3)
            if scale is not None:
                Rt = Rt * scale[:, :, None]
            for m in range(d.n_markers):
                cols.append(Rt * (d.obs_marker == m)[:, None, None])
        full = [c.reshape(len(y), 3, -1) for c in cols]
        if M is not None:                      # the sensor reads them through its maps
            full = [np.einsum("ij,mjk->mik", M, b) for b in full]
        blocks = kept[None] = [_seen_rows(d, b) for b in full]
    blocks = list(blocks)
    twists: dict[int, np.ndarray] = {}        # one op's twist serves all its parameters
    poses = None
    for i, (p, value) in enumerate(zip(params, values)):
        g = kept.get(p)
        if g is None:
            term = p.term
            if poses is None and term is not None:
                poses = _poses(d)
            if p.sensor:                       # ∂(c + M·(y − c))/∂v = (∂M/∂v)·(y − c)
                g = np.zeros_like(y) if d.centre is None else (y - d.centre) @ dM[p.name].T
            else:
                if p.arm:                      # ∂(s·x)/∂v = term · x
                    g = (xb * d.per_point(_term(d, p, -1))[:, None]) @ reg.R.T
                elif p.bus:                    # every joint's twist times its term
                    tj = d.per_point((shifts[i] if i in shifts else p.joint_shift(poses, value))[1]
                                     if value else p.joint_terms(poses))
                    g = np.zeros_like(xb)
                    for k in range(d.chain.n_joints):
                        op = d.chain.joint_op[k]
                        if np.any(tj[:, k]):
                            if op not in twists:
                                twists[op] = kin.twist(d.chain, starts, op, xb, rows) @ reg.R.T
                            g = g + twists[op] * tj[:, k][:, None]
                    if scale is not None:
                        g = g * scale
                else:
                    g = twists.get(p.op)
                    if g is None:
                        g = twists[p.op] = kin.twist(d.chain, starts, p.op, xb, rows) @ reg.R.T
                    if term is not None:
                        g = g * d.per_point(_term(d, p, p.joint))[:, None]
                    if scale is not None:      # the grown arm moves (1 + growth) as far
                        g = g * scale
                if M is not None:              # and the sensor reads it through its maps
                    g = g @ M.T
            g = kept[p] = _seen(d, g)[:, :, None]
        blocks.append(g)
    J = np.concatenate(blocks, axis=2) if blocks else np.zeros((len(y), d.dims, 0))
    return _seen(d, read), J.reshape(d.dims * len(y), -1)


def sensor_maps(params: list[Param], values: np.ndarray
                ) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
    """The sensor's whole map about its centre at ``values``, M = M₁·M₂·… over its
    parameters in ``params`` order (None without any), and per parameter name ∂M/∂value
    (the others' maps on either side of its own derivative)."""
    own = [(p.name, *fx.CHAIN_EFFECTS[p.effect].chain.sensor_map(float(v)))
           for p, v in zip(params, values) if p.sensor]
    if not own:
        return None, {}
    ms = [m for _, m, _ in own]
    return _product(ms), {name: _product([*ms[:i], dm, *ms[i + 1:]])
                          for i, (name, _, dm) in enumerate(own)}


def _product(mats: list[np.ndarray]) -> np.ndarray:
    """M₁·M₂·… of 3 × 3 matrices (I for none)."""
    return functools.reduce(np.matmul, mats, np.eye(3))


def _seen(d: Data, y: np.ndarray) -> np.ndarray:
    """The components of (M, 3) points the sensor sees."""
    return y if d.dims == 3 else y[:, list(d.axes)]


def _seen_rows(d: Data, b: np.ndarray) -> np.ndarray:
    """The rows of (M, 3, k) Jacobian blocks the sensor sees: :func:`model` keeps its
    blocks so, and joins them into its Jacobian as they are."""
    return b if d.dims == 3 else b[:, list(d.axes), :]


def joint_columns(d: Data, f: "Fit") -> np.ndarray:
    """(dims·M, J) each joint's column at fit ``f``: how the measured points move per unit
    (deg / mm) added to the joint's value, the column its offset would have. The rivals
    outside the vocabulary that act through a joint (a ripple, a drifting zero) are built
    on them."""
    offsets = [Param(f"j{k + 1}_column", "joint_offset", k, d.chain.joint_op[k], "")
               for k in range(d.chain.n_joints)]
    _, J = model(d, f.reg, list(f.params) + offsets, np.r_[f.values, np.zeros(len(offsets))],
                 jac=True)
    return J[:, J.shape[1] - len(offsets):]


def n_registration(d: Data) -> int:
    return (6 if d.sensor else 0) + (3 * d.n_markers if d.known_markers is None else 0)


def initial_registration(d: Data) -> Registration:
    """Closed-form start: Kabsch for the sensor frame alternated with the per-marker mean
    for free markers (markers start at the nominal tool point)."""
    chain = d.chain
    tips = d.nominal_frames()[0]
    markers = (np.tile(chain.tool_mm, (d.n_markers, 1)) if d.known_markers is None
               else d.known_markers.copy())
    R, t = np.eye(3), np.zeros(3)
    for _ in range(6 if d.known_markers is None else 1):
        xb = kin.points(tips, d.obs_pose, markers[d.obs_marker])
        if d.sensor:
            R, t = _kabsch(xb, d.xyz)
        if d.known_markers is None:
            T = tips[d.obs_pose]
            yb = (d.xyz - t) @ R                                   # back in the base frame
            loc = np.einsum("mji,mj->mi", T[:, :3, :3], yb - T[:, :3, 3])
            markers = np.array([loc[d.obs_marker == m].mean(0) for m in range(d.n_markers)])
    return Registration(R, t, markers)


def check_registrable(d: Data, file: str) -> None:
    """Refuse a sensor frame the fit poses cannot fix: too few non-collinear points."""
    if not d.sensor:
        return
    x = d.xyz - d.xyz.mean(0)
    s = np.linalg.svd(x, compute_uv=False) if len(x) >= 2 else np.zeros(1)
    if len(x) < 3 or s[0] == 0 or (len(s) > 1 and s[1] < 1e-6 * s[0]):
        raise CampaignFormatError(file, f"measurement_frame sensor: the {d.n_poses} fit pose(s) give "
                                        f"{len(x)} point(s) that are {'collinear' if len(x) >= 3 else 'too few'}; "
                                        "registering the sensor frame needs at least 3 non-collinear points",
                                  column="x_mm")


@dataclass
class Fit:
    """One fitted model on a :class:`Data`: ``params`` and ``values``, the registration,
    residuals ``resid`` (M, 3) = measured − predicted, the Jacobian ``J`` at the solution,
    the parameters' cluster-robust standard errors and 95 % intervals, and the
    leave-out prediction error ``cv_rms`` (mm, rms of the 3-D point error) with its
    per-fold mean squares ``cv_fold`` (folds are places when the poses sit at stations,
    :meth:`Data.folds`) and per-pose ones ``cv_pose`` (each pose left out alone)."""

    params: list[Param]
    values: np.ndarray
    reg: Registration
    resid: np.ndarray
    J: np.ndarray
    se: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ci95: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    cv_rms: float = math.nan
    cv_pose: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cv_fold: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def rms(self) -> float:
        return rms3(self.resid)

    def named(self) -> dict[str, float]:
        return {p.name: float(v) for p, v in zip(self.params, self.values)}

    def conditioning(self) -> tuple[int, int, float]:
        """(numerical rank, columns, condition number) of the column-scaled Jacobian at
        the solution, registration and parameters together: rank < columns means some
        combination of them is not identifiable from these poses; a large condition
        number means some are told apart only weakly."""
        return conditioning(self.J)


def conditioning(J: np.ndarray) -> tuple[int, int, float]:
    """(rank to :data:`STRUCTURAL_TOL`, columns, largest / smallest singular value) of
    ``J`` with unit-norm columns (so units and lever lengths do not count)."""
    if J.size == 0:
        return 0, J.shape[1] if J.ndim == 2 else 0, 1.0
    sv = np.linalg.svd(scaled(J)[0], compute_uv=False)
    rank = int(np.sum(sv > sv[0] * STRUCTURAL_TOL))
    return rank, J.shape[1], float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf


def rms3(r: np.ndarray) -> float:
    """RMS of the 3-D point error (sqrt of the mean squared norm), mm."""
    return float(math.sqrt(np.mean(squares_last(r)))) if len(r) else math.nan


def fit(d: Data, params: list[Param], reg0: Registration | None = None, values0=None,
        max_iter: int = 50, tol: float = 1e-10) -> Fit:
    """Fit registration and ``params`` on ``d`` by damped Gauss–Newton; adds the robust
    errors and the leave-one-pose-out error. It stops when a step changes the cost by at
    most ``tol`` of it, down or up (up only by rounding: the minimum is reached), or after
    ``max_iter`` steps."""
    start = reg0 or initial_registration(d)
    reg = Registration(start.R.copy(), start.t.copy(), start.markers.copy())
    v = np.zeros(len(params)) if values0 is None else np.asarray(values0, float).copy()
    y, J = model(d, start, params, v, jac=True)   # the start itself: its zero blocks are kept
    r = (d.xyz - y).ravel()
    cost, lam = float(r @ r), 1e-9
    for _ in range(max_iter):
        Js, scale = scaled(J)
        A = Js.T @ Js
        step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), Js.T @ r) / scale
        new_reg, new_v = _apply(d, reg, v, step)
        y2, J2 = model(d, new_reg, params, new_v, jac=True)   # most steps are taken
        r2 = (d.xyz - y2).ravel()
        c2 = float(r2 @ r2)
        if c2 <= cost:
            reg, v, done = new_reg, new_v, cost - c2 <= tol * max(cost, 1e-30)
            lam = max(lam / 10, 1e-12)
            y, J, r, cost = y2, J2, r2, c2
            if done:
                break
        elif c2 - cost <= tol * max(cost, 1e-30):
            break                         # a change within rounding: at the minimum already
        else:
            lam *= 10
            if lam > 1e8:
                break
    f = Fit(params, v, reg, r.reshape(-1, d.dims), J)
    _uncertainty(d, f)
    return f


def _apply(d: Data, reg: Registration, v: np.ndarray, step: np.ndarray) -> tuple[Registration, np.ndarray]:
    i = 0
    R, t, m = reg.R, reg.t, reg.markers
    if d.sensor:
        R, t = _exp(step[0:3]) @ reg.R, reg.t + step[3:6]
        i = 6
    if d.known_markers is None:
        m = reg.markers + step[i:i + 3 * d.n_markers].reshape(-1, 3)
        i += 3 * d.n_markers
    return Registration(R, t, m), v + step[i:]


def loo_with(d: Data, f: Fit, extra: np.ndarray) -> tuple[float, np.ndarray]:
    """Leave-out error (total rms, per-fold mean square; folds of :meth:`Data.folds`) of
    fit ``f`` with ``extra`` (3M, k) columns added to its Jacobian, linearised at ``f``: a
    rival hypothesis outside the vocabulary (an instrument scale, a drifting frame) judged
    as the candidates are."""
    J2 = np.column_stack([f.J, extra])
    r = f.resid.ravel()
    Js, _ = scaled(J2)
    beta, *_ = np.linalg.lstsq(Js, r, rcond=None)
    total, per, *_ = leaveout.at_solution(J2, r - Js @ beta, *d.folds(), dims=d.dims)
    return total, per


def _uncertainty(d: Data, f: Fit) -> None:
    """Cluster-robust covariance and leave-one-pose-out errors (linearised)."""
    r = f.resid.ravel()
    f.cv_rms, f.cv_fold, Ainv, scale = leaveout.at_solution(f.J, r, *d.folds(), dims=d.dims)
    f.cv_pose = f.cv_fold
    if d.folds()[1] < d.n_poses:
        _, f.cv_pose, *_ = leaveout.at_solution(f.J, r, d.obs_pose, d.n_poses, dims=d.dims,
                                                known=(Ainv, scale))
    Jg, rg, _ = leaveout.blocks(f.J / scale, r, d.obs_pose, d.n_poses, d.dims)
    S = (Jg.transpose(0, 2, 1) @ rg[..., None])[..., 0]
    G = d.n_poses
    corr = G / (G - 1) if G > 1 else 1.0
    cov = corr * Ainv @ (S.T @ S) @ Ainv / np.outer(scale, scale)
    n = len(f.params)
    se = np.sqrt(np.maximum(np.diag(cov)[len(cov) - n:], 0.0)) if n else np.zeros(0)
    tq = _t975(max(G - 1, 1))
    f.se = se
    f.ci95 = np.column_stack([f.values - tq * se, f.values + tq * se]) if n else np.zeros((0, 2))


def _t975(dof: int) -> float:
    return t_quantile(0.975, dof)


def predict_rms(d: Data, f: Fit, keep: np.ndarray | None = None) -> tuple[float, float]:
    """(rms, max) of the 3-D error of fit ``f`` on other poses ``d`` (registration kept),
    over the points ``keep`` marks (default all)."""
    y, _ = model(d, f.reg, f.params, f.values)
    e = d.xyz - y
    if keep is not None:
        e = e[keep]
    n = np.sqrt(squares_last(e))
    return rms3(e), float(n.max()) if len(n) else math.nan


@dataclass
class Identifiability:
    """Which of a parameter pool the data can see beside registration: ``kept`` in
    priority order; ``dropped`` name → reason; ``warnings`` name → warning for the kept
    parameters that registration (or the others) almost absorb; ``lacking`` the dropped
    names the campaign could show were it measured otherwise: its effect's column missing
    (:attr:`cell.effects.OnChain.unseen`) or hardly varying (``still``), or its poses not
    covering what the effect needs (``coverage``)."""

    kept: list[Param]
    dropped: dict[str, str]
    warnings: dict[str, str]
    lacking: frozenset = frozenset()


def identifiability(d: Data, pool: list[Param], reg: Registration, keep_first: list[Param] = ()
                    ) -> Identifiability:
    """The rule of :mod:`cell.kinematics.identifiable` in priority order (registration,
    ``keep_first``, then ``pool``) at :data:`STRUCTURAL_TOL`: a parameter whose scaled
    column lies in the span of those before it is dropped, naming what absorbs it; one
    kept with a variance inflation above :data:`MAX_VIF` is warned about. A parameter whose
    term varies over the static poses by less than its effect's ``min_spread`` is dropped first
    (:attr:`cell.effects.OnChain.still`: a temperature that hardly changes); one whose term
    stays below :data:`TERM_EPS` on every pose has no effect (its column is rounding noise,
    which scaled to unit length would look like a direction of its own); one whose effect's
    ``coverage`` fails on the poses (grouped by :func:`cell.diagnosis.places.stations`) is
    dropped with its reason (:attr:`cell.effects.OnChain.coverage`). An effect's nuisance
    parameters (:attr:`cell.effects.OnChain.nuisance`) are kept only beside one of its own,
    and never reported."""
    allp = list(keep_first) + [p for p in pool if p not in keep_first]
    dropped: dict[str, str] = {}
    poses = _poses(d)
    rounding = set()                       # terms that are zero but for rounding
    lacking = set()
    where = None
    for p in list(allp):
        use = fx.CHAIN_EFFECTS[p.effect].chain
        if p.term is None:
            continue
        if use.coverage is not None:
            where = _stations(d) if where is None else where
            why = use.coverage(poses, p.joint, where)
            if why:
                dropped[p.name] = why
                lacking.add(p.name)
                allp.remove(p)
                continue
        nonzero, peak = _term_size(d, p)
        if nonzero and peak < TERM_EPS:
            rounding.add(p.name)
        elif use.min_spread > 0 and not p.nuisance and nonzero and float(np.ptp(
                _joint_term(d, p)[slice(None) if d.move is None else d.move < 0])) < use.min_spread:
            dropped[p.name] = use.still
            lacking.add(p.name)
            allp.remove(p)
    _, J = model(d, reg, allp, np.zeros(len(allp)), jac=True)
    nr = n_registration(d)
    for i, p in enumerate(allp):
        if p.name in rounding:
            J[:, nr + i] = 0.0
    kept = d.zero_blocks(reg)              # the registration's columns are the same for every
    if NUISANCE_BASIS not in kept:         # pool: their basis is found once per registration
        kept[NUISANCE_BASIS] = identifiable.nuisance_basis(J[:, :nr], STRUCTURAL_TOL)
        kept[NUISANCE_BASIS].flags.writeable = False
    span = identifiable.greedy(J[:, nr:], range(len(allp)), STRUCTURAL_TOL, kept[NUISANCE_BASIS])
    unit = {i: v for i, v in span.unit.items() if np.isfinite(span.left[i])}
    warnings: dict[str, str] = {}
    for i, p in enumerate(allp):
        left = span.left[i]
        if p.nuisance:                     # not the effect's: neither reported nor warned of
            continue
        if i not in unit:
            unseen = fx.CHAIN_EFFECTS[p.effect].chain.unseen
            dropped[p.name] = unseen or NO_EFFECT
            if unseen:
                lacking.add(p.name)
        elif i not in span.kept:
            if span.outside(unit[i], span.Q0) < STRUCTURAL_TOL:
                dropped[p.name] = "absorbed by the registration (sensor frame / marker positions)"
            else:
                before = [k for k in span.kept if k < i]
                dropped[p.name] = "seen only as a sum with " + ", ".join(
                    _partners(unit[i], [allp[k] for k in before], [unit[k] for k in before]))
        elif 1.0 / left ** 2 > MAX_VIF:
            warnings[p.name] = (f"{p.name}: {100 * (1 - left ** 2):.1f} % of its effect looks like "
                                "the registration or other parameters; they are hard to tell apart")
    own = {allp[i].effect for i in span.kept if not allp[i].nuisance}
    kept = [allp[i] for i in span.kept if not allp[i].nuisance or allp[i].effect in own]
    return Identifiability(kept, dropped, warnings, frozenset(lacking))


def _partners(v: np.ndarray, kept: list[Param], cols: list[np.ndarray]) -> list[str]:
    if not cols:
        return ["the registration"]
    A = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(A, v, rcond=None)
    names = [kept[i].name for i in np.argsort(-np.abs(coef)) if abs(coef[i]) > 0.05]
    return names[:4] or ["the registration"]
