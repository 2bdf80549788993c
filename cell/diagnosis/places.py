"""Which poses of a campaign are the same place, and the folds a cause is checked on. Pure
numerics, numpy only: planar and chain diagnoses both use it.

A station the arm revisits, with a few degrees of jitter, is one place for telling causes
apart: leaving out one visit would leave its twins in the fit, and any cause fits a
handful of places. :func:`places` joins poses closer than :data:`LINK_DEG` (single
linkage in joint space). :func:`folds` leaves out whole places when the poses sit at
stations (at least 3, none holding more than half the poses); when they are spread (the
linkage joins most of them into one) each pose is its own place. More groups than
``max_folds`` are gathered into that many regions (farthest-point centres)."""
from __future__ import annotations

import numpy as np

from cell.numerics.sums import pairwise_squares

LINK_DEG = 10.0       # poses closer than this (deg, or mm for a prismatic joint) are one place
MAX_SHARE = 0.5       # a place holding more of the poses means they are spread, not at stations


def places(q: np.ndarray, block: int = 512) -> np.ndarray:
    """Place index of every pose (rows of joint readings ``q``, deg or mm): connected
    components of poses closer than :data:`LINK_DEG` (the close pairs found block by block;
    each pose takes the least index it is linked to until none changes, with pointer
    jumping), numbered in the order of their first pose."""
    q = np.asarray(q, float)
    n = len(q)
    ii, jj = [], []
    for s0 in range(0, n, block):
        d2 = pairwise_squares(q[s0:s0 + block], q)
        i, j = np.nonzero(d2 < LINK_DEG ** 2)
        keep = i + s0 < j
        ii.append(i[keep] + s0)
        jj.append(j[keep])
    lab = np.arange(n)
    if n and sum(len(i) for i in ii):
        ii, jj = np.concatenate(ii), np.concatenate(jj)
        while True:
            new = lab.copy()
            np.minimum.at(new, ii, lab[jj])
            np.minimum.at(new, jj, lab[ii])
            new = new[new]
            if np.array_equal(new, lab):
                break
            lab = new
    return np.unique(lab, return_inverse=True)[1] if n else lab


def regions(centres: np.ndarray, k: int) -> np.ndarray:
    """Region (0..k-1) of every centre: ``k`` farthest-point seeds, each centre to its
    nearest seed."""
    chosen = [int(np.argmin(centres[:, 0]))]
    dist = np.linalg.norm(centres - centres[chosen[0]], axis=1)
    while len(chosen) < k:
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(centres - centres[chosen[-1]], axis=1))
    return np.argmin(np.stack([np.linalg.norm(centres - centres[c], axis=1) for c in chosen]),
                     axis=0)


def stations(q: np.ndarray, linked: np.ndarray | None = None) -> np.ndarray:
    """The group of every pose for a requirement that looks within each place (a short
    period sampled densely, :func:`cell.effects.phase_coverage`): its place
    (:func:`places`), except that the poses alone at their place form one group together.
    Those are spread, each with a phase of its own; as places of one they would leave
    nothing to vary within a place. ``linked``: :func:`places` of ``q`` when already found."""
    p = places(q) if linked is None else linked
    alone = np.bincount(p)[p] == 1
    return np.where(alone, -1, p)


def folds(q: np.ndarray, max_folds: int | None = None, linked: np.ndarray | None = None
          ) -> tuple[np.ndarray, int, bool]:
    """(fold of every pose, number of places, True when the poses sit at stations): see the
    module docstring. ``linked``: :func:`places` of ``q`` when already found."""
    q = np.asarray(q, float)
    if not len(q):
        return np.zeros(0, int), 0, False
    p = places(q) if linked is None else linked
    n_places = int(p.max()) + 1
    share = np.bincount(p).max() / len(q)
    stations = share <= MAX_SHARE and n_places >= 3 or n_places < 3 and len(q) > n_places
    group = p if stations else np.arange(len(q))
    n = int(group.max()) + 1
    if max_folds is not None and n > max_folds:
        cent = np.array([q[group == g].mean(axis=0) for g in range(n)])
        group = regions(cent, max_folds)[group]
    return group, n_places, bool(stations)


def spaced_best(q: np.ndarray, score: np.ndarray, n: int, spacing: float) -> list[int]:
    """Indices of up to ``n`` rows of ``q`` by falling ``score`` (only score > 0), each at
    least ``spacing`` (Euclidean, in ``q``'s units) from those already taken: the poses
    where rival causes differ most, not five neighbours of one."""
    picked: list[int] = []
    for i in np.argsort(-score):
        if score[i] <= 0 or len(picked) == n:
            break
        if all(np.linalg.norm(q[i] - q[j]) >= spacing for j in picked):
            picked.append(int(i))
    return picked


N_POSES = 5           # separating poses proposed


def separating(q: np.ndarray, diffs: np.ndarray, labels, noise_mm: float | None,
               spacing: float, where) -> list[dict]:
    """The separating poses of a named cause and its rivals (``labels``): of the
    configurations ``q`` (rows, in units where ``spacing`` is the least distance between two
    proposals), the up to :data:`N_POSES` where the smallest of the
    expected differences ``diffs`` (rows × rivals, mm) is largest (:func:`spaced_best`).
    Each entry is ``where(i)`` (the configuration, named as the campaign names joints), the
    difference per rival (``difference_mm``) and, with a noise σ per axis, that difference over it
    (``difference_over_noise``)."""
    out = []
    for i in spaced_best(q, diffs.min(axis=1), N_POSES, spacing):
        e = where(i) | {"difference_mm": {lab: round(float(v), 6)
                                          for lab, v in zip(labels, diffs[i])}}
        if noise_mm:
            e["difference_over_noise"] = {lab: round(float(v / noise_mm), 2)
                                          for lab, v in zip(labels, diffs[i])}
        out.append(e)
    return out
