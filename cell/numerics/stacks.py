"""Products of a stack of small matrices with one shared matrix, as one BLAS call. Pure
numerics.

``A @ B`` with ``A`` (..., m, n) a stack and ``B`` (n, p) one matrix makes numpy call BLAS
once per matrix of the stack: for thousands of 2 × k blocks that call's overhead (~0.1 µs
each) is the whole cost. Rows of the stack laid end to end make one (… · m, n) @ (n, p)
product whose rows are the same dot products: BLAS's matrix-matrix kernel accumulates
each entry over n in the same order whichever rows share the call, so the values are
the same bits (tested against the stacked product). With m = 1 numpy takes its
vector-matrix route per matrix instead, whose rounding differs: such stacks are left to
``@``.
"""
from __future__ import annotations

import numpy as np


def times_shared(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for a stack ``A`` (..., m, n) and one matrix ``B`` (n, p), the same values,
    as one matrix-matrix product when m ≥ 2 (module docstring)."""
    m, n = A.shape[-2:]
    if m < 2 or A.ndim < 3:
        return A @ B
    return (A.reshape(-1, n) @ B).reshape(A.shape[:-1] + (B.shape[-1],))
