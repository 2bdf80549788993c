"""Which candidates the data can support at all (checked before any fit). Pure numerics.

Every effect of :data:`cell.effects.EFFECTS` is tried, per joint where it acts on joints.
An effect whose signature needs a variable the campaign does not vary is not identifiable
and is not fitted (it is listed in the report with the reason). What each effect needs is
part of its definition (``Effect.needs``, requirements of :mod:`cell.effects.base`); this
module only measures what the fit rows vary (:func:`layout`) and asks them. Today:

* thermal_drift: a temp_c column whose spread (standard deviation over the fit rows) is at
  least 0.2 K; at a constant temperature thermal growth is a fixed link-length error and
  cannot be told from link_length.
* backlash on a joint: that joint must have been measured after motions in both
  directions (points' j*_dir, or moves running both ways).
* gear_ratio / cyclic_error on a joint: the joint's commanded angle must span at least
  20° (a scale or periodic error over a tiny span is an offset).
* camera_scale / camera_rotation: model.yaml must give the camera centre.
* comm_delay: paths.csv must hold moves in which the commands change.
"""
from __future__ import annotations

import numpy as np

from cell import effects as fx
from cell.diagnosis.fit import Candidate
from cell.diagnosis.places import stations
from cell.diagnosis.replay import DiagData
from cell.effects.gear_ratio import MIN_ANGLE_SPAN_DEG  # noqa: F401  (re-exported)
from cell.effects.thermal_drift import MIN_TEMP_SPREAD_C  # noqa: F401  (re-exported)
from cell.numerics.stats import distinct


def layout(d: DiagData) -> fx.Layout:
    """What the fit rows of ``d`` vary, for the effects' requirements."""
    p = d.points
    fit = None if p is None else p.fit
    fit_moves = [m for m in d.moves if m.fit]
    angles = [p.cmd[fit] if p is not None else np.zeros((0, 2))] + [m.cmd for m in fit_moves]
    angles = np.concatenate(angles)
    dirs_seen = [set(), set()]
    if p is not None:
        for j in range(2):
            dirs_seen[j] |= set(distinct(p.dirs[fit, j]).tolist()) - {0.0}
    for m in fit_moves:
        for j in range(2):
            dirs_seen[j] |= set(distinct(fx.path_directions(m.cmd, m.dirs0)[:, j]).tolist()) - {0.0}
    temp = None if p is None or p.temp is None else np.asarray(p.temp[fit], float)
    groups = [stations(p.cmd[fit]) if p is not None and np.any(fit) else np.zeros(0, int)]
    k = int(groups[0].max()) + 1 if len(groups[0]) else 0
    for i, m in enumerate(fit_moves):
        groups.append(np.full(len(m.cmd), k + i))
    return fx.Layout(angles, (frozenset(dirs_seen[0]), frozenset(dirs_seen[1])), temp,
                     d.center is not None,
                     any(np.ptp(m.cmd, axis=0).max() > 0 for m in fit_moves),
                     np.concatenate(groups))


def single_candidates(d: DiagData) -> tuple[list[Candidate], dict[str, str]]:
    """(candidates to fit, {label: reason} of those the data cannot identify)."""
    out: list[Candidate] = []
    skipped: dict[str, str] = {}
    lay = layout(d)
    for name, eff in fx.EFFECTS.items():
        for joints in ([(j,) for j in eff.joints] if eff.per_joint else [()]):
            lab = f"{name}[{','.join(joints)}]" if joints else name
            why = eff.unidentifiable(lay, joints)
            if why:
                skipped[lab] = why
            else:
                out.append(((name, joints),))
    return out, skipped


def merge(a: Candidate, b: Candidate) -> Candidate | None:
    """The two-effect candidate a+b (same effect on both joints becomes one component);
    None if they overlap."""
    (ea, ja), = a
    (eb, jb), = b
    if ea == eb:
        if not ja or set(ja) & set(jb):
            return None
        joints = tuple(j for j in fx.PLANAR_JOINTS if j in ja + jb)
        return ((ea, joints),)
    return tuple(sorted((a[0], b[0]), key=lambda c: list(fx.EFFECTS).index(c[0])))
