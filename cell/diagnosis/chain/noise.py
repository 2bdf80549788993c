"""How large the measurement noise of a chain campaign is, from the data alone. Pure numerics.

Two estimates of σ per axis (mm) of one measured point:

* **Rigid constellation** (:func:`rigid_noise_mm`): the markers of one pose sit at fixed
  places on the hand, so within a pose they must form the marker constellation (the
  registration's marker positions) moved rigidly. A rigid fit per pose (Kabsch) leaves
  3·n − 6 degrees of freedom of pure sensor noise for a pose with n ≥ 3 markers, whatever
  the arm does: no kinematic error, drift or bump can show here.
* **Revisited poses** (:func:`repeat_noise_mm`): poses measured again with identical joint
  readings (and approach directions and, within :data:`TEMP_BIN_C`, temperature, where the
  campaign records them). Their scatter holds the sensor noise *and* the arm's
  repeatability, the floor no kinematic model can go below, but also anything that changed
  between the visits.

Every effect of the chain vocabulary is a function of the joint readings, the directions
the joints last moved in and the temperature, so two visits that agree on all three
must agree. :func:`revisits_disagree` tests whether their scatter
exceeds the sensor noise by more than chance (one-sided F test of the two variances): then the
arm did not come back to where it was (poor repeatability, drift, a step during the
campaign), which the vocabulary cannot explain.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.diagnosis.noise import MAD_EFFICIENCY, MIN_POINTS, NEIGHBOURS, local_plane, mad, pooled, \
    revisits
from cell.effects.thermal_drift import MIN_TEMP_SPREAD_C
from cell.measurements.chain import ChainCampaign
from cell.numerics.stats import distinct

DRIFT_ALPHA = 1e-3      # revisits disagree beyond the sensor noise at this significance
TEMP_BIN_C = MIN_TEMP_SPREAD_C    # visits in one such temperature bin count as one pose


def repeat_noise_mm(cc: ChainCampaign, keep: np.ndarray | None = None
                    ) -> tuple[float | None, int, int]:
    """σ per axis from poses revisited with identical readings (and ``jK_dir``, and
    ``temp_c`` in one bin of :data:`TEMP_BIN_C`), each marker's points a
    group of their own (:func:`cell.diagnosis.noise.pooled`, as v1 pools a planar
    campaign's revisits); the number of revisited poses' groups and the degrees of freedom;
    (None, 0, 0) without repeats. ``keep`` (M,) marks the points to use (default all:
    outliers set aside are not)."""
    visits = cc.readings if cc.dirs is None else np.column_stack([cc.readings, cc.dirs])
    temps = cc.pose_temps()
    if temps is not None:
        visits = np.column_stack([visits, np.floor(temps / TEMP_BIN_C)])
    _, n_groups = revisits(visits)
    label, _ = revisits(np.column_stack([visits[cc.obs_pose], cc.obs_marker]))
    if keep is not None:
        label = np.where(keep, label, -1)
    sigma, dof = pooled(label, cc.xyz[:, list(cc.axes)])
    return (sigma, n_groups, dof) if sigma is not None else (None, 0, 0)


def rigid_noise_mm(xyz: np.ndarray, obs_pose: np.ndarray, obs_marker: np.ndarray,
                   markers_tip: np.ndarray, free_markers: bool) -> tuple[float | None, int]:
    """σ per axis from each pose's markers against the constellation ``markers_tip`` (K, 3)
    moved rigidly, and the degrees of freedom; (None, 0) without a pose of ≥ 3 markers.
    ``free_markers``: the constellation was fitted to these data (its 3K − 6 shape
    parameters are taken off the degrees of freedom)."""
    ss, dof = 0.0, 0
    order = np.argsort(obs_pose, kind="stable")
    bounds = np.flatnonzero(np.diff(obs_pose[order])) + 1
    poses = np.split(order, bounds)
    per = _rigid_squares(poses, xyz, obs_marker, markers_tip)
    for i, rows in enumerate(poses):
        if len(rows) >= 3:
            ss += float(per[i])
            dof += 3 * len(rows) - 6
    if free_markers:
        dof -= 3 * len(markers_tip) - 6
    return (math.sqrt(ss / dof), dof) if dof > 0 and ss > 0 else (None, 0)


def remainder_noise_mm(coords: np.ndarray, obs_pose: np.ndarray, obs_marker: np.ndarray,
                       r: np.ndarray) -> tuple[float | None, int, str]:
    """σ per axis from the remainder ``r`` (M, dims) of a fit, as v1 takes a point's noise
    when nothing better is at hand (:func:`cell.diagnosis.noise.residual`), per marker:
    each point against the leave-one-out plane through its :data:`NEIGHBOURS` nearest
    points in joint space (``coords`` (M, J), the joints' model values), scaled by
    √(1 + ΣW²); and the differences of consecutive poses in sample order, scaled by √2. A
    remainder smooth in the joints (an arm effect) mostly cancels in the first, one slow in
    time (a warm-up) in the second; the noise in neither. σ = 1.4826 × the MAD, the smaller
    of the two. Returns (σ, degrees of freedom, how); (None, 0, '') with fewer than
    :data:`cell.diagnosis.noise.MIN_POINTS` points of every marker."""
    planes, steps = [], []
    k = NEIGHBOURS
    for m in distinct(obs_marker):
        rows = np.flatnonzero(obs_marker == m)
        if len(rows) < MIN_POINTS:
            continue
        k = min(NEIGHBOURS, len(rows) - 1)
        nb, W = local_plane(coords[rows], k)
        e = r[rows] - np.einsum("nk,nkc->nc", W, r[rows][nb])
        planes.append(e / np.sqrt(1.0 + np.sum(W * W, axis=1))[:, None])
        o = rows[np.argsort(obs_pose[rows], kind="stable")]
        steps.append((r[o][1:] - r[o][:-1]) / np.sqrt(2.0))
    if not planes:
        return None, 0, ""
    found = [(mad(np.concatenate(planes)), f"local planes through {k} joint-space neighbours"),
             (mad(np.concatenate(steps)), "differences of consecutive poses in sample order")]
    s, how = min(found, key=lambda t: t[0])
    n = sum(len(z) for z in planes) * r.shape[1]
    return (s, int(MAD_EFFICIENCY * n), how) if s > 0 else (None, 0, "")


def revisits_disagree(repeat_sigma: float, repeat_dof: int, sensor_sigma: float,
                      sensor_dof: int) -> float:
    """One-sided p that revisits scatter by ``repeat_sigma`` (``repeat_dof`` degrees of
    freedom) or more if only the sensor noise estimated as ``sensor_sigma`` (``sensor_dof``)
    were at work: the F test of the two variances, with Paulson's normal approximation of
    the F distribution (good to a few per cent of p for these degrees of freedom). Small p:
    the arm did not come back."""
    if repeat_dof <= 0 or sensor_dof <= 0 or sensor_sigma <= 0:
        return 1.0
    f = (repeat_sigma / sensor_sigma) ** 2
    a, b = 2.0 / (9.0 * repeat_dof), 2.0 / (9.0 * sensor_dof)
    c = f ** (1.0 / 3.0)
    z = ((1.0 - b) * c - (1.0 - a)) / math.sqrt(a + c * c * b)
    return 0.5 * math.erfc(z / math.sqrt(2.0))


@dataclass(frozen=True)
class SensorNoise:
    """A chain campaign's measurement noise as the data give it: ``sigma`` per axis, mm
    (None: unknown), its degrees of freedom ``dof``, where it came from (``source``), and
    ``disagree``: why the revisited poses are not noise, when they scatter beyond the
    sensor noise (else None)."""

    sigma: float | None
    dof: int
    source: str
    disagree: str | None = None


def _rigid_squares(poses: list[np.ndarray], xyz: np.ndarray, obs_marker: np.ndarray,
                   markers_tip: np.ndarray) -> np.ndarray:
    """Per pose (its points' rows ``poses[i]``; fewer than 3 give 0) the sum of squares of
    its points about the constellation moved rigidly onto them (Kabsch), the poses of one
    marker count stacked: the same products, decompositions and sums, matrix by matrix, as
    one pose at a time."""
    out = np.zeros(len(poses))
    sizes = np.array([len(rows) for rows in poses])
    for k in sorted(set(sizes[sizes >= 3].tolist())):
        which = np.flatnonzero(sizes == k)
        rows = np.stack([poses[i] for i in which])                  # (G, k)
        a, b = markers_tip[obs_marker[rows]], xyz[rows]             # (G, k, 3)
        a0, b0 = a - a.mean(1, keepdims=True), b - b.mean(1, keepdims=True)
        u, _, vt = np.linalg.svd(a0.transpose(0, 2, 1) @ b0)
        s = np.zeros((len(which), 3, 3))
        s[:, 0, 0] = s[:, 1, 1] = 1.0
        s[:, 2, 2] = np.sign(np.linalg.det(u @ vt))
        fit = a0 @ (u @ s @ vt)                                     # b0 ≈ a0 · rot'
        out[which] = np.sum(((b0 - fit) ** 2).reshape(len(which), -1), axis=1)
    return out


def estimate(cc: ChainCampaign, xyz: np.ndarray, obs_pose: np.ndarray, obs_marker: np.ndarray,
             markers_tip: np.ndarray, free_markers: bool,
             keep: np.ndarray | None = None,
             remainder: tuple[np.ndarray, np.ndarray] | None = None) -> SensorNoise:
    """The noise the diagnosis and the calibration both judge with: the revisits' scatter
    when it agrees with the sensor noise of the rigid constellation (it then also holds the
    arm's repeatability); the rigid estimate when the revisits disagree (the disagreement
    is not noise: it is :attr:`SensorNoise.disagree`) or when there are none; unknown
    without either. The fit points (``xyz``, ``obs_pose``, ``obs_marker``) and the marker
    constellation are those of :func:`rigid_noise_mm`; ``keep`` (M,) marks the campaign's
    points that are not outliers (:func:`repeat_noise_mm`). Without revisits and without
    a rigid constellation (fewer than 3 markers per pose, or a sensor that does not see
    every axis), ``remainder`` (the fit points' joint values (M, J) and a fit's residual)
    gives the estimate of :func:`remainder_noise_mm`."""
    rep, groups, rep_dof = repeat_noise_mm(cc, keep)
    rig, rig_dof = rigid_noise_mm(xyz, obs_pose, obs_marker, markers_tip, free_markers) \
        if len(cc.axes) == 3 else (None, 0)     # a rigid fit needs every axis
    disagree = None
    if rep is not None and rig is not None:
        p = revisits_disagree(rep, rep_dof, rig, rig_dof)
        if p < DRIFT_ALPHA:
            disagree = (f"revisited poses disagree by {rep:.3f} mm per axis, {rep / rig:.1f}× the "
                        f"sensor noise ({rig:.3f} mm, from the markers' rigid constellation; "
                        f"p = {p:.2g}): the arm did not come back to where it was (poor "
                        "repeatability, drift or a step during the campaign), which no effect "
                        "of the chain vocabulary explains")
    if rep is not None and disagree is None:
        return SensorNoise(rep, rep_dof, f"repeats ({groups} revisited poses)")
    if rig is not None:
        return SensorNoise(rig, rig_dof, f"markers (rigid constellation within each pose, "
                                         f"{rig_dof} dof)", disagree)
    if rep is None and remainder is not None:
        s, dof, how = remainder_noise_mm(remainder[0], obs_pose, obs_marker, remainder[1])
        if s is not None:
            return SensorNoise(s, dof, f"residual ({how})")
    return SensorNoise(None, 0, "unknown")
