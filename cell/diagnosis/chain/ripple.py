"""A transmission ripple of more cycles per revolution than the chain vocabulary's
``cyclic_error`` holds (1–4: :data:`cell.effects.cyclic_error.ORDERS`): a joint whose error
varies periodically with its own angle at 5–8 cycles per revolution (a gear of several
teeth per turn, a worn tooth seen through a reduction). Pure numerics.

Over the spacing of a campaign's places such a ripple looks like a scatter of offsets, or
like a low-order ripple that happens to pass through the same places, so a vocabulary cause
may be named from a remainder barely above the noise. The check asks the remainder
directly. Its model is the named cause plus, on one revolute joint k,
Σₙ (aₙ·sin(n·θ_k) + bₙ·cos(n·θ_k)) added to the joint's angle for n in :data:`ORDERS`
(θ_k its model value): 2·len(ORDERS) columns, each the joint's twist at the named fit times
one harmonic. Nothing is fitted in full: like :mod:`cell.diagnosis.chain.drift`, the
hypothesis is the linearised least squares of the fit's residual on its own Jacobian plus
those columns, judged by leave-out prediction over the folds of
:meth:`cell.diagnosis.chain.fit.Data.folds`.

**present** (:func:`check`): for some joint, the named cause plus the ripple predicts
left-out folds better than the named cause alone (one-sided Wilcoxon at ``alpha`` divided
by the joints tried, Bonferroni): part of the gap varies with that joint's angle in a way
no effect of the vocabulary holds, and the gap is not explained. Only joints whose readings
span at least :data:`MIN_SPAN_DEG` and at least :data:`MIN_POSES` fit poses.
"""
from __future__ import annotations

import numpy as np

from cell.diagnosis import tie
from cell.diagnosis.chain import fit as F
from cell.effects.cyclic_error import ORDERS as VOCABULARY_ORDERS

ORDERS = tuple(range(max(VOCABULARY_ORDERS) + 1, 2 * max(VOCABULARY_ORDERS) + 1))   # 5 … 8
MIN_SPAN_DEG = 30.0
MIN_POSES = 12


def _harmonics(theta_deg: np.ndarray) -> np.ndarray:
    """(M, 2·len(ORDERS)) sin and cos of n·θ for n in :data:`ORDERS`."""
    t = np.radians(theta_deg)[:, None] * np.asarray(ORDERS, float)[None, :]
    return np.column_stack([np.sin(t), np.cos(t)])


def with_ripple(d: F.Data, f: F.Fit, k: int, column: np.ndarray) -> tuple[float, np.ndarray]:
    """Leave-out error (total rms, per-fold mean square) of fit ``f`` plus a ripple on
    joint ``k`` (module docstring), linearised at ``f``; ``column`` (dims·M,) the joint's
    column at ``f`` (:func:`cell.diagnosis.chain.fit.joint_columns`)."""
    theta = d.chain.model_values(d.readings)[d.obs_pose, k]
    extra = np.repeat(_harmonics(theta), d.dims, axis=0) * column[:, None]
    return F.loo_with(d, f, extra)


def check(d: F.Data, named, alpha: float) -> str:
    """The reason text when a ripple beside the named candidate ``named`` (a
    :class:`cell.diagnosis.chain.rank.Candidate`) is supported on some joint, else ''."""
    if d.n_poses < MIN_POSES:
        return ""
    q = d.chain.model_values(d.readings)
    joints = [k for k, j in enumerate(d.chain.joints)
              if j.type == "revolute" and float(np.ptp(q[:, k])) >= MIN_SPAN_DEG]
    if not joints:
        return ""
    base = named.fit
    columns = F.joint_columns(d, base)
    best = None
    for k in joints:
        total, per = with_ripple(d, base, k, columns[:, k])
        p = tie.p_worse(base.cv_fold, per)
        if best is None or p < best[0]:
            best = (p, k, total)
    p, k, total = best
    if p * len(joints) >= alpha:
        return ""
    j = d.chain.joints[k]
    who = j.column if j.name == j.column else f"{j.column} ({j.name})"
    return (f"the gap varies periodically with {who}'s angle: {named.label} plus "
            f"a ripple of {ORDERS[0]}–{ORDERS[-1]} cycles per revolution on it predicts left-out places "
            f"better than {named.label} alone (leave-out rms {base.cv_rms:.4f} -> {total:.4f} mm, "
            f"p = {p * len(joints):.2g} over {len(joints)} joints): a transmission ripple, which "
            "the vocabulary's cyclic_error (1–4 cycles) does not hold")
