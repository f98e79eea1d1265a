"""Compiled helpers of the evaluation path (numba), imported on first use by docp and nlp so
that importing :mod:`olado.problems` does not load numba."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

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


#: one declared signature (flat float64 arrays: the callers pass ``a.ravel("K")``, a view of a
#: contiguous array of any layout): compiled once instead of once per rank and pair of ranks
_FLAT_RO = nb.types.Array(nb.float64, 1, "C", readonly=True)   # a writeable array converts to it


@nb.njit(nb.boolean(_FLAT_RO, _FLAT_RO), cache=True)
def all_finite_flat(a, b):
    """True when every entry of the 1-D float64 arrays ``a`` and ``b`` is finite: one compiled
    pass, no temporary, no BLAS call, exits at the first NaN/inf."""
    for i in range(a.size):
        if not math.isfinite(a[i]):
            return False
    for i in range(b.size):
        if not math.isfinite(b[i]):
            return False
    return True


_NONE = np.empty(0)


def _flat(a):
    """``a`` as a 1-D float64 array (a view where ``a`` is contiguous in any order)."""
    return np.ravel(np.asarray(a, dtype=np.float64), order="K")


def all_finite_pair(a, b):
    """True when every entry of the float64 arrays ``a`` and ``b`` (any shape and layout) is
    finite: the check of a stage function's two returned arrays in one compiled call."""
    return all_finite_flat(_flat(a), _flat(b))


def all_finite(a):
    """True when every entry of the float64 array ``a`` (any shape of at least one axis, any
    layout) is finite: one compiled pass, no temporary, no BLAS call, exits at the first NaN/inf."""
    return all_finite_flat(_flat(a), _NONE)
