"""Forward kinematics of a :class:`~cell.kinematics.chain.Chain` and its exact Jacobians. Pure,
vectorised numerics over poses; no I/O.

Every error parameter adds to the value of one op (:mod:`cell.kinematics.chain`), so the
derivative of a base-frame point ``x`` with respect to it is that op's twist, taken at
the frame ``F`` the op starts in::

    R op (deg):  ∂x/∂v = (w × (x − o)) · π/180        w = F_R · axis, o = F_t
    T op (mm):   ∂x/∂v = w

Joint effects add to a joint op's value a per-pose regressor times their parameter
(1 for an offset, the model value for a gear-ratio error, the gravity lever for
compliance), so their columns are the joint op's twist times that regressor.
"""
from __future__ import annotations

import numpy as np

from cell.kinematics.chain import D2R, Chain, rot, trans


def forward(chain: Chain, readings: np.ndarray, geo: dict[int, float] | None = None,
            dq: np.ndarray | None = None, keep: bool = False
            ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Tip frames (P, 4, 4) in the base frame for (P, J) ``readings``.

    ``geo`` maps op index → added value (geometric errors); ``dq`` (P, J) adds to the
    joints' model values (joint effects). With ``keep`` the second result maps each R/T op
    index to the (P, 4, 4) frame it starts in (for :func:`twist`).

    The product is taken op by op from the base, as ``T @ op`` with the same rounding: a
    fixed transform multiplies all poses' frames as one (4P × 4) matrix (:func:`_times`).
    """
    P = readings.shape[0]
    qm = chain.model_values(readings)
    if dq is not None:
        qm = qm + dq
    T = None                                   # the identity, until the first op
    starts: dict[int, np.ndarray] = {}
    for i, op in enumerate(chain.ops):
        if op.kind == "F":
            T = _times(T, op.matrix, P)
            continue
        if keep:
            starts[i] = T if T is not None else np.broadcast_to(np.eye(4), (P, 4, 4)).copy()
        g = geo.get(i) if geo else None
        if op.joint is None:                   # one transform for every pose
            T = _times(T, op.nominal_matrix if g is None else op.at(op.nominal + g), P)
            continue
        v = np.full(P, op.nominal + (g or 0.0)) + qm[:, op.joint]
        J = rot(op.axis, v) if op.kind == "R" else trans(op.axis, v)
        T = J + 0.0 if T is None else T @ J      # + 0.0: a −0 entry reads +0, as I · J gives it
    return (T if T is not None else np.broadcast_to(np.eye(4), (P, 4, 4)).copy()), starts


def _times(T: np.ndarray | None, M: np.ndarray, P: int) -> np.ndarray:
    """(P, 4, 4) frames ``T`` (None: the identity) times one 4 × 4 ``M``: the values of
    ``T @ M`` (one BLAS product of the same kernel instead of one per pose)."""
    if T is None:
        return np.broadcast_to(M + 0.0, (P, 4, 4)).copy()     # + 0.0: as I · M gives −0
    return (T.reshape(-1, 4) @ M).reshape(T.shape)


def points(tips: np.ndarray, obs_pose: np.ndarray | None, local: np.ndarray) -> np.ndarray:
    """(M, 3) base-frame points: ``local`` (M, 3) tip-frame points on the poses ``obs_pose``
    (None: one point on each pose, in order)."""
    T = tips if obs_pose is None else tips[obs_pose]
    return np.einsum("mij,mj->mi", T[:, :3, :3], local) + T[:, :3, 3]


def twist(chain: Chain, starts: dict[int, np.ndarray], op_index: int, x: np.ndarray,
          obs_pose: np.ndarray | None) -> np.ndarray:
    """(M, 3) derivative of the base-frame points ``x`` (M, 3) on poses ``obs_pose`` (None:
    one point on each pose, in order) with respect to a unit (1 deg / 1 mm) change of op
    ``op_index``'s value."""
    op = chain.ops[op_index]
    F = starts[op_index] if obs_pose is None else starts[op_index][obs_pose]
    w = _along(F, op.axis)
    if op.kind == "T":
        return w
    v = x - F[:, :3, 3]
    return np.stack([w[:, 1] * v[:, 2] - w[:, 2] * v[:, 1], w[:, 2] * v[:, 0] - w[:, 0] * v[:, 2],
                     w[:, 0] * v[:, 1] - w[:, 1] * v[:, 0]], axis=1) * D2R


def _along(F: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(M, 3) ``F[:, :3, :3] @ axis``, its values, as one matrix-vector product."""
    return (F[:, :3, :3].reshape(-1, 3) @ axis).reshape(len(F), 3)


def joint_axes(chain: Chain, starts: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, its axis (P, J, 3) and a point on it (P, J, 3) in the base frame."""
    ax, org = [], []
    for k in range(chain.n_joints):
        F = starts[chain.joint_op[k]]
        ax.append(F[:, :3, :3] @ chain.ops[chain.joint_op[k]].axis)
        org.append(F[:, :3, 3])
    return np.stack(ax, axis=1), np.stack(org, axis=1)


def gravity_levers(chain: Chain, starts: dict[int, np.ndarray], load_b: np.ndarray) -> np.ndarray:
    """(P, J) gravity lever of each revolute joint, m: the moment about the joint's axis of
    a unit force along ``chain.gravity`` applied at ``load_b`` (P, 3), base frame, mm.
    0 for prismatic joints and for axes along gravity."""
    ax, org = joint_axes(chain, starts)
    arm = load_b[:, None, :] - org
    lever = np.einsum("pjk,pjk->pj", ax, np.cross(arm, chain.gravity)) * 1e-3
    for k, j in enumerate(chain.joints):
        if j.type != "revolute":
            lever[:, k] = 0.0
    return lever
