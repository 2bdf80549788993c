"""An independent forward model of a DH arm measured by an external sensor, for blind
checks of the chain diagnosis. Written plainly, per pose, from the DH definitions; it
shares no code with :mod:`cell.kinematics` / :mod:`cell.diagnosis.chain.fit`,
so a sign, unit or composition mistake there cannot cancel out here (the agreement test
in ``tests/cell/chain/test_chain_model.py`` compares the two on every vocabulary effect).

Effects it can put into a campaign (``effects`` maps a name to its size):

* vocabulary: ``offset`` {joint: deg}, ``a``/``d``/``alpha`` {joint: mm or deg} (DH
  parameter errors), ``ratio`` {joint: relative}, ``sag`` {joint: deg per m of the
  gravity lever of a unit load at the tool point, taken on the nominal arm},
  ``backlash`` {joint: total lost-motion width b, deg}: the joint trails its reading by
  b/2 against the direction of its last motion (``dirs`` per pose, the format's
  ``jK_dir``: θ = θ_reading − dir·b/2); ``grow`` α (1/K): every length of the arm (DH a
  and d, a prismatic joint's travel, the marker offsets on the hand) is (1 + α·(T − 20 °C))
  times its size at the pose's temperature T (``temp_c``; the format's thermal_drift, its
  reference temperature 20 °C); ``cyclic`` {joint: (amplitude deg, cycles per revolution,
  phase deg)} (a transmission ripple a·sin(n·reading + φ); the vocabulary's cyclic_error
  for 1–4 cycles, outside it for more); ``motor`` {joint: (amplitude deg, motor gear ratio
  N, phase deg)} (a ripple of the motor-side gear, a·sin(N·reading + φ): the vocabulary's
  motor_cyclic_error, N as model.yaml's ``motor_gear_ratio`` states it);
* outside it: ``lens`` (radial scale of the sensor about its origin, 1/m),
  ``reach_sag`` (tool drops by k·reach², mm/m²), ``bump`` {joint: deg} (an offset from
  the middle pose on), ``couple`` (joint 3 turns by factor × joint 2's reading),
  ``plane_bump`` (amplitude mm, centre (3,) mm, width mm, direction (3,)) (a smooth local
  displacement A·exp(−|p − p₀|²/(2w²)) of every measured point in the base frame).
"""
from __future__ import annotations

import math

import numpy as np

DEG = math.pi / 180.0
T_REF_C = 20.0      # the format's thermal_ref_temp_c: the nominal lengths hold at 20 °C


def dh_matrix(theta_deg: float, d: float, a: float, alpha_deg: float, modified: bool) -> np.ndarray:
    """One DH row as a 4×4 (standard: Rz·Tz·Tx·Rx; modified: Rx·Tx·Rz·Tz)."""
    ct, st = math.cos(theta_deg * DEG), math.sin(theta_deg * DEG)
    ca, sa = math.cos(alpha_deg * DEG), math.sin(alpha_deg * DEG)
    if not modified:
        return np.array([[ct, -st * ca, st * sa, a * ct],
                         [st, ct * ca, -ct * sa, a * st],
                         [0.0, sa, ca, d],
                         [0.0, 0.0, 0.0, 1.0]])
    return np.array([[ct, -st, 0.0, a],
                     [st * ca, ct * ca, -sa, -sa * d],
                     [st * sa, ct * sa, ca, ca * d],
                     [0.0, 0.0, 0.0, 1.0]])


def _chain(rows, q, modified, eff, pose_index, n_poses, dirs=None, size=1.0):
    """(list of 4×4 joint frames, tip 4×4) for one pose with the effects applied; ``dirs``
    the sign of each joint's last motion (None: unknown, the centre of a backlash band);
    ``size`` the factor every length of the arm has grown by."""
    T = np.eye(4)
    frames = []
    for k, r in enumerate(rows):
        name = r["name"]
        qk = q[k]
        if eff.get("couple") and k == 2:
            qk = qk + eff["couple"] * q[1]
        qk = qk * (1.0 + eff.get("ratio", {}).get(name, 0.0)) + eff.get("offset", {}).get(name, 0.0)
        if pose_index >= n_poses // 2:
            qk += eff.get("bump", {}).get(name, 0.0)
        qk += eff.get("_sag_dq", {}).get(name, 0.0)
        if dirs is not None:
            qk -= dirs[k] * eff.get("backlash", {}).get(name, 0.0) / 2.0
        if name in eff.get("cyclic", {}):
            amp, cycles, phase = eff["cyclic"][name]
            qk += amp * math.sin(cycles * q[k] * DEG + phase * DEG)
        if name in eff.get("motor", {}):
            amp, ratio, phase = eff["motor"][name]
            qk += amp * math.sin(ratio * q[k] * DEG + phase * DEG)
        th = r["theta_deg"] + (qk if r["type"] == "revolute" else 0.0)
        d = size * (r["d_mm"] + eff.get("d", {}).get(name, 0.0)
                     + (qk if r["type"] == "prismatic" else 0.0))
        a = size * (r["a_mm"] + eff.get("a", {}).get(name, 0.0))
        al = r["alpha_deg"] + eff.get("alpha", {}).get(name, 0.0)
        if modified:
            frames.append(T @ dh_matrix(0.0, 0.0, a, al, True))   # joint axis: z after Rx·Tx
            T = T @ dh_matrix(th, d, a, al, True)
        else:
            frames.append(T.copy())                                 # joint axis: z before the row
            T = T @ dh_matrix(th, d, a, al, False)
    return frames, T


def tool_points(rows, q, modified, tool_mm, markers, eff, pose_index, n_poses, gravity=(0, 0, -1),
                dirs=None, temp_c=None):
    """Base-frame positions (K, 3) of ``markers`` (K, 3, tip frame) on one pose approached
    from ``dirs`` (per joint ±1; None: unknown) at temperature ``temp_c`` (°C; None: not
    recorded, and the arm is at the reference temperature)."""
    eff = dict(eff)
    if eff.get("sag"):
        # the lever is taken on the nominal arm (the effect's definition; the deflected
        # pose would change it by a second-order amount)
        frames, T = _chain(rows, q, modified, {}, pose_index, n_poses)
        load = T[:3, :3] @ np.asarray(tool_mm, float) + T[:3, 3]
        g = np.asarray(gravity, float)
        dq = {}
        for k, r in enumerate(rows):
            if r["type"] != "revolute" or r["name"] not in eff["sag"]:
                continue
            z, o = frames[k][:3, 2], frames[k][:3, 3]
            lever_m = float(z @ np.cross(load - o, g)) / 1000.0
            dq[r["name"]] = eff["sag"][r["name"]] * lever_m
        eff["_sag_dq"] = dq
    size = 1.0
    if eff.get("grow") and temp_c is not None:
        size = 1.0 + eff["grow"] * (temp_c - T_REF_C)
    _, T = _chain(rows, q, modified, eff, pose_index, n_poses, dirs, size)
    out = np.array([T[:3, :3] @ (size * np.asarray(m, float)) + T[:3, 3] for m in markers])
    if eff.get("reach_sag"):
        reach_m = np.hypot(out[:, 0], out[:, 1]) / 1000.0
        out[:, 2] -= eff["reach_sag"] * reach_m ** 2
    if eff.get("plane_bump"):
        amp, at, width, direction = eff["plane_bump"]
        r2 = ((out - np.asarray(at, float)) ** 2).sum(axis=1, keepdims=True)
        u = np.asarray(direction, float)
        out = out + amp * np.exp(-r2 / (2.0 * width ** 2)) * (u / np.linalg.norm(u))
    return out


def sensor_view(points_b: np.ndarray, R: np.ndarray, t: np.ndarray, lens: float = 0.0) -> np.ndarray:
    """Points as the sensor reports them: ``R x + t``, then a radial scale (1 + lens·r)
    about the sensor origin (r in m) for the out-of-vocabulary lens effect."""
    y = points_b @ R.T + t
    if lens:
        r = np.linalg.norm(y, axis=1, keepdims=True) / 1000.0
        y = y * (1.0 + lens * r)
    return y


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def campaign_rows(rows, modified, readings, markers, eff, R, t, noise_mm, rng, tool_mm=(0, 0, 0),
                  lens: float = 0.0, dirs=None, temps=None) -> list[list]:
    """points.csv rows ``[sample, j1..jN, marker, x, y, z]`` for every pose and marker;
    ``dirs`` (P, J) each pose's approach directions, ``temps`` (P,) its temperature °C
    (None: unknown / not recorded)."""
    out = []
    P = len(readings)
    for p, q in enumerate(readings):
        pts = sensor_view(tool_points(rows, q, modified, tool_mm, markers, eff, p, P,
                                      dirs=None if dirs is None else dirs[p],
                                      temp_c=None if temps is None else float(temps[p])), R, t, lens)
        pts = pts + rng.normal(0.0, noise_mm, pts.shape)
        for m, x in enumerate(pts):
            out.append([p, *q, m + 1, *x])
    return out
