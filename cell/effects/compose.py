"""Composition of the planar effects, in the one order used everywhere (see
:mod:`cell.effects`): the plant's and the replay's forward model. Pure, vectorised; no I/O."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from cell.effects.base import PLANAR_JOINTS, Stage
from cell.effects.instances import EffectInstance
from cell.errors import ConfigError, KinematicsError, TrajectoryError
from cell.kinematics import planar_xy

STATION_NAMES = ("j1", "j2", "j3", "j4")
DEFAULT_STATIONS = STATION_NAMES


def _joint_batch(name: str, a, n: int | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 2 or (n is not None and a.shape[0] != n):
        want = "(N, 2)" if n is None else f"({n}, 2)"
        raise KinematicsError(f"{name} must have shape {want} (j1, j2 per row), got {a.shape}")
    is_dir = name.startswith("dirs")
    ok = np.isin(a, (-1.0, 0.0, 1.0)) if is_dir else np.isfinite(a)
    if not ok.all():
        r, c = np.argwhere(~ok)[0]
        raise KinematicsError(f"{name}[{r}, {c}] = {float(a[r, c])!r} is not "
                              + ("-1, 0 or +1" if is_dir else "a finite number"))
    return a


def _series(name: str, a, n: int, effects=()) -> np.ndarray:
    if a is None:  # only temp_c may be left out, and only without an effect of temperature
        warm = [e.effect for e in effects if e.spec.depends_on == "temperature"]
        if name != "temp_c" or warm:
            raise ConfigError(f"{name} is required" + (f": {warm[0]} is among the effects"
                                                       if name == "temp_c" else ""))
        return np.zeros(n)
    a = np.asarray(a, dtype=float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,):
        raise TrajectoryError(f"{name} must have shape ({n},), got {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise TrajectoryError(f"{name}[{bad[0]}] = {float(a[bad[0]])!r} is not a finite number")
    return a


def _check_effects(effects) -> list[EffectInstance]:
    effects = list(effects)
    for i, e in enumerate(effects):
        if not isinstance(e, EffectInstance):
            raise ConfigError(f"effects[{i}] = {e!r} is not an EffectInstance (use make_effect)")
    return effects


def _links(geometry) -> np.ndarray:
    g = getattr(geometry, "g", geometry)  # a Scara or its Geometry
    return np.array([g.l1_mm, g.l2_mm], dtype=float)


def true_joints(effects: Sequence[EffectInstance], cmd_deg: np.ndarray, dirs: np.ndarray
                ) -> np.ndarray:
    """Stage 2: true joint angles (N,2) deg from commanded angles and last-motion directions."""
    q = np.array(cmd_deg, dtype=float)
    for e in effects:
        if e.spec.stage == Stage.JOINT:
            q += e.spec.fn(e.full_vector(), e.jidx, cmd_deg, dirs)
    return q


def true_links(geometry, effects: Sequence[EffectInstance], temp_c: np.ndarray) -> np.ndarray:
    """Stage 3: true link lengths (N,2) mm at temperatures ``temp_c`` (N,) °C."""
    nominal = _links(geometry)
    links = np.tile(nominal, (len(temp_c), 1))
    for e in effects:
        if e.spec.stage == Stage.LINK:
            links += e.spec.fn(e.full_vector(), e.jidx, nominal, temp_c)
    return links


def planar_fk(links_mm: np.ndarray, q_deg: np.ndarray) -> np.ndarray:
    """Stage 4: seed 000 eq. 4, vectorised: (x, y) mm (N,2) for links (N,2) mm, joints (N,2) deg."""
    return planar_xy(links_mm[:, 0], links_mm[:, 1], q_deg)


def camera_view(effects: Sequence[EffectInstance], xy_mm: np.ndarray, camera_center_mm
                ) -> np.ndarray:
    """Stage 5: what the camera measures (N,2) mm for true points ``xy_mm`` (N,2)."""
    c = np.asarray(camera_center_mm, dtype=float)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ConfigError(f"camera_center_mm = {camera_center_mm!r} must be 2 finite mm values")
    out = np.asarray(xy_mm, dtype=float)
    for e in effects:
        if e.spec.stage == Stage.VISION:
            out = e.spec.fn(e.full_vector(), out, c)
    return out


def simulate_points(nominal_geometry, effects: Sequence[EffectInstance], cmd_deg, dirs,
                    time_s=None, temp_c=None, camera_center_mm=(0.0, 0.0)) -> np.ndarray:
    """What the camera measures (x, y) mm (N,2) for static poses, through stages 2–5.

    ``nominal_geometry`` is a :class:`~cell.robots.Geometry`, a Scara or a :class:`~cell.kinematics.PlanarArm`;
    ``cmd_deg`` (N,2) commanded θ1, θ2 in deg; ``dirs`` (N,2) sign of each joint's last
    motion (−1, 0, +1); ``time_s`` (N,) s (checked, no static effect uses it yet);
    ``temp_c`` (N,) or scalar °C (required only with thermal_drift); ``camera_center_mm``
    where the camera's optical axis meets the work plane. comm_delay has no effect on
    static poses. Raises as the module docstring says; nothing is stored.
    """
    effects = _check_effects(effects)
    cmd = _joint_batch("cmd_deg", cmd_deg)
    n = len(cmd)
    d = _joint_batch("dirs", dirs, n)
    if time_s is not None:
        _series("time_s", time_s, n)
    temp = _series("temp_c", temp_c, n, effects)
    xy = planar_fk(true_links(nominal_geometry, effects, temp), true_joints(effects, cmd, d))
    return camera_view(effects, xy, camera_center_mm)


def station_order(stations: Sequence[str]) -> np.ndarray:
    """1-based bus positions (k_j1, k_j2) from a CAN station order such as ``[j2, j1, j3]``."""
    st = list(stations)
    if len(set(st)) != len(st) or any(s not in STATION_NAMES for s in st) \
            or not set(PLANAR_JOINTS) <= set(st):
        raise ConfigError(f"stations = {st!r}: list distinct names of {list(STATION_NAMES)} "
                          f"including j1 and j2")
    return np.array([st.index(j) + 1 for j in PLANAR_JOINTS], dtype=float)


def path_directions(q_deg: np.ndarray, dirs0) -> np.ndarray:
    """Sign of each joint's last motion along a sampled path (N,2); ``dirs0`` (2,) before it."""
    step = np.sign(np.diff(q_deg, axis=0))
    signs = np.vstack([np.asarray(dirs0, dtype=float)[None, :], step])
    # forward-fill zeros (joint at rest keeps its last direction)
    idx = np.where(signs != 0, np.arange(len(signs))[:, None], 0)
    idx = np.maximum.accumulate(idx, axis=0)
    return np.take_along_axis(signs, idx, axis=0)


def simulate_path(nominal_geometry, effects: Sequence[EffectInstance], cmd_deg, time_s,
                  temp_c=None, camera_center_mm=(0.0, 0.0), stations=DEFAULT_STATIONS,
                  dirs0=(0, 0)) -> np.ndarray:
    """What the camera measures (x, y) mm (N,2) along one move, through stages 1–5.

    ``cmd_deg`` (N,2) is where the controller meant θ1, θ2 to be at ``time_s`` (N,), s,
    strictly increasing (paths.csv's j*_cmd_deg, time_s). comm_delay gives each joint the
    command of t − λ_j (linear interpolation in the commanded samples); the directions for
    backlash follow the delayed command, starting from ``dirs0`` (−1/0/+1 per joint).
    ``stations`` is the CAN station order. Raises as the module docstring says.
    """
    effects = _check_effects(effects)
    cmd = _joint_batch("cmd_deg", cmd_deg)
    n = len(cmd)
    t = _series("time_s", time_s, n)
    if n > 1 and not np.all(np.diff(t) > 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise TrajectoryError(f"time_s must increase strictly: time_s[{k}] = {float(t[k])!r} "
                              f"after {float(t[k - 1])!r}")
    d0 = _joint_batch("dirs0", np.asarray(dirs0, dtype=float).reshape(1, -1), 1)[0]
    order = station_order(stations)
    if n == 0:
        return np.zeros((0, 2))
    actual = cmd
    for e in effects:
        if e.spec.stage == Stage.COMMS:
            actual = e.spec.fn(e.full_vector(), order, t, actual)
    dirs = path_directions(actual, d0)
    temp = _series("temp_c", temp_c, n, effects)
    xy = planar_fk(true_links(nominal_geometry, effects, temp), true_joints(effects, actual, dirs))
    return camera_view(effects, xy, camera_center_mm)
