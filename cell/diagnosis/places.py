"""Which poses of a campaign are the same place: a station the arm revisits, with a little
jitter, is one place for telling causes apart (leaving out one visit of it would leave its
twins in the fit). Pure numerics, numpy only: planar and chain diagnoses both use it."""
from __future__ import annotations

import numpy as np

LINK_DEG = 2.0        # poses closer than this (deg, or mm for a prismatic joint) are one place


def places(q: np.ndarray, block: int = 512) -> np.ndarray:
    """Place index of every pose (rows of joint readings ``q``, deg or mm): connected
    components of poses closer than :data:`LINK_DEG` (union-find over the close pairs,
    found block by block)."""
    q = np.asarray(q, float)
    n = len(q)
    parent = np.arange(n)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i
    for s0 in range(0, n, block):
        d2 = np.sum((q[s0:s0 + block, None, :] - q[None, :, :]) ** 2, axis=2)
        ii, jj = np.nonzero(d2 < LINK_DEG ** 2)
        for i, j in zip(ii + s0, jj):
            if i < j:
                ri, rj = find(int(i)), find(int(j))
                if ri != rj:
                    parent[max(ri, rj)] = min(ri, rj)
    roots = np.array([find(i) for i in range(n)], int)
    return np.unique(roots, return_inverse=True)[1] if n else roots
