"""Compiled helpers of the evaluation path (numba), imported on first use by docp and nlp so
that importing :mod:`olado.problems` does not load numba."""

from __future__ import annotations

import math

import numba as nb

@nb.njit(cache=True)
def gather_hessian_values(Hxx, Hxu, Huu, HN, out):
    """Lower triangles of the stage blocks [[Hxx, Hxu], [Hxu^T, Huu]] (row by row, stage by
    stage) followed by the lower triangle of HN: the order of ``np.tril_indices``."""
    N, n, m = Hxu.shape
    nz = n + m
    pos = 0
    for k in range(N):
        for a in range(nz):
            for b in range(a + 1):
                if a < n:
                    out[pos] = Hxx[k, a, b]
                elif b < n:
                    out[pos] = Hxu[k, b, a - n]
                else:
                    out[pos] = Huu[k, a - n, b - n]
                pos += 1
    for a in range(n):
        for b in range(a + 1):
            out[pos] = HN[a, b]
            pos += 1


@nb.njit(cache=True)
def all_finite_pair(a, b):
    """True when every entry of the float64 arrays ``a`` and ``b`` (any shape and layout) is
    finite: the check of a stage function's two returned arrays in one compiled call."""
    for v in a.flat:
        if not math.isfinite(v):
            return False
    for v in b.flat:
        if not math.isfinite(v):
            return False
    return True


@nb.njit(cache=True)
def all_finite(a):
    """True when every entry of the float64 array ``a`` (any shape of at least one axis, any
    layout) is finite: one compiled pass, no temporary, no BLAS call, exits at the first NaN/inf."""
    for v in a.flat:
        if not math.isfinite(v):
            return False
    return True
