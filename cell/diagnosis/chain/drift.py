"""A sensor frame that moves during the campaign: a tracker bumped or settling, a camera
stand creeping. Pure numerics.

Every arm effect depends on the joint readings only; a drifting sensor frame depends on
*when* a pose was measured. Its model is the registration made linear in the sample
order: the sensor's rotation and translation each gain a rate, 6 parameters, with
``s`` = the pose's position in the campaign's sample order scaled to [−1, 1]. Nothing here
is fitted in full: like :func:`cell.diagnosis.chain.rank.instrument_scale`, a hypothesis is the
linearised least squares of a fit's residual on its own Jacobian plus the 6 drift columns,
judged by leave-out prediction over the folds of :meth:`cell.diagnosis.chain.fit.Data.folds`
(stations left out whole).

* **present** (:func:`check`): the named cause plus drift predicts left-out folds
  better than the named cause alone (one-sided Wilcoxon at ``alpha``): the frame moved,
  whatever else is wrong, and the gap is not explained by the arm.
* **a rival**: a smaller cause plus drift (the registration alone, or a candidate whose
  effects the named cause contains) predicts left-out folds as well as the named cause:
  when poses are walked in joint order, a drifting frame and a joint effect look alike,
  and the campaign cannot tell them apart.

With ``measurement_frame: base`` there is no sensor frame to drift, but a joint's zero
can move (a slipping encoder, a bumped coupling): the hypothesis is then every joint's
offset made linear in the sample order (one rate per joint: its twist at the fit times
``s``). At least :data:`MIN_POSES` fit poses.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cell.diagnosis import tie
from cell.diagnosis.chain import fit as F

MIN_POSES = 12
N_DRIFT = 6


@dataclass
class Drift:
    """``present``: the reason text when drift beside the named cause is supported, else
    ''; ``rivals``: labels of smaller causes that, with drift, predict as well."""

    present: str = ""
    rivals: list[str] = field(default_factory=list)


def _order(d: F.Data) -> np.ndarray:
    """Each measured point's pose position in sample order, scaled to [−1, 1]."""
    n = max(d.n_poses - 1, 1)
    return (2.0 * np.arange(d.n_poses) / n - 1.0)[d.obs_pose]


def with_drift(d: F.Data, f: F.Fit) -> tuple[float, np.ndarray]:
    """Leave-out error (total rms, per-fold mean square) of fit ``f`` plus a sensor frame
    (base frame: the joints' zeros) drifting linearly with sample order, linearised at ``f``."""
    s = np.repeat(_order(d), d.dims)
    return F.loo_with(d, f, _moving(d, f) * s[:, None])


def _moving(d: F.Data, f: F.Fit) -> np.ndarray:
    """(dims·M, k) what moves: the sensor frame's 6 registration columns of ``f``, or in
    the base frame each joint's column at ``f`` (:func:`cell.diagnosis.chain.fit.joint_columns`)."""
    return f.J[:, :N_DRIFT] if d.sensor else F.joint_columns(d, f)


def check(d: F.Data, named, smaller: list, alpha: float, ratio: float) -> Drift:
    """Drift against the named candidate ``named`` (a :class:`cell.diagnosis.chain.rank.Candidate`,
    the registration-only one when nothing is named; ``smaller`` the nominal and the
    candidates it contains), with the decision's ``alpha`` and rival ``ratio`` (module
    docstring)."""
    out = Drift()
    if d.n_poses < MIN_POSES:
        return out
    base = named.fit
    total, per = with_drift(d, base)
    p = tie.p_worse(base.cv_fold, per)
    if p < alpha:
        what, moves, plus = (("the sensor frame", "moves", "a frame") if d.sensor
                             else ("the joints' zeros", "move", "the joints' zeros"))
        out.present = (f"{what} {moves} with sample order: {named.label} plus {plus} drifting "
                       f"over the campaign predicts left-out places better than "
                       f"{named.label} alone (leave-out rms {base.cv_rms:.4f} -> {total:.4f} mm, "
                       f"p = {p:.2g})")
        return out
    if d.sensor:
        moving, tag, why = ("sensor frame", "sensor_drift",
                            "a sensor frame that moves is not an arm effect")
    else:
        moving, tag, why = ("joint zeros", "zero_drift",
                            "a joint zero that moves during the campaign is not a constant effect")
    for c in smaller:
        t, pc = with_drift(d, c.fit)
        if tie.p_worse(pc, base.cv_fold) >= alpha and t <= ratio * base.cv_rms:
            out.rivals.append({"label": f"{c.label} + {moving} drifting with sample order",
                               "effects": list(c.effects) + [tag], "joints": c.joints,
                               "cv_rms_mm": round(float(t), 6), "testable": False, "why": why})
    return out
