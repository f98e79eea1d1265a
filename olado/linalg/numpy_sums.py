"""numpy's pairwise summation, compiled (numba): the sums of the solvers' compiled passes
(olado.solvers.ipm.kernels, olado.solvers.sqp.kernels) with the rounding of ``a.sum()`` and
``np.abs(a).sum()``, so that a pass moved into a kernel keeps the iterates bit for bit.

numpy's ``add.reduce`` of a contiguous float64 array sums blocks of at most 128 terms with eight
partial sums and splits a longer range into two halves, the first a multiple of 8. Here the
recursion runs on an explicit stack (numba's cache does not take recursive functions).

numba caches a kernel keyed on its own source file: a kernel of another module that calls these
keeps its compiled copy of them after this file changes. The algorithm is numpy's and fixed; a
change here must come with a change of the calling modules (or their caches cleared).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_JIT = {"cache": True, "error_model": "numpy"}

#: the one signature of the pairwise-sum helpers: compiled once (when this module is loaded, from
#: numba's cache after the first time) instead of once per literal argument at every call site
_SUM_SIG = "float64(float64[::1], int64, int64, boolean)"


@nb.njit(_SUM_SIG, **_JIT)
def _block(a, lo, n, absolute):
    """numpy's pairwise_sum below its block size (n <= 128): a plain loop below 8 terms, else
    eight accumulators combined pairwise and the rest added in order."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += abs(a[i]) if absolute else a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    if absolute:
        r0, r1, r2, r3, r4, r5, r6, r7 = abs(r0), abs(r1), abs(r2), abs(r3), abs(r4), abs(r5), abs(r6), abs(r7)
    i = lo + 8
    end = lo + n - (n % 8)
    while i < end:
        if absolute:
            r0 += abs(a[i]); r1 += abs(a[i + 1]); r2 += abs(a[i + 2]); r3 += abs(a[i + 3])
            r4 += abs(a[i + 4]); r5 += abs(a[i + 5]); r6 += abs(a[i + 6]); r7 += abs(a[i + 7])
        else:
            r0 += a[i]; r1 += a[i + 1]; r2 += a[i + 2]; r3 += a[i + 3]
            r4 += a[i + 4]; r5 += a[i + 5]; r6 += a[i + 6]; r7 += a[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < lo + n:
        res += abs(a[i]) if absolute else a[i]
        i += 1
    return res


@nb.njit(_SUM_SIG, **_JIT)
def pairwise_sum(a, lo, n, absolute):
    """numpy's pairwise summation of a[lo:lo+n] (np.add.reduce of a contiguous float64 array:
    blocks of at most 128 terms (_block), halves at multiples of 8 above, left + right), of |a|
    when ``absolute``: the same rounding as ``np.abs(a).sum()`` or ``a.sum()``. The recursion
    runs on an explicit stack (frames: start, length, stage, left half's sum)."""
    if n <= 128:
        return _block(a, lo, n, absolute)
    f_lo = np.empty(64, dtype=np.int64)
    f_n = np.empty(64, dtype=np.int64)
    f_stage = np.zeros(64, dtype=np.int64)
    f_left = np.empty(64)
    f_lo[0], f_n[0], f_stage[0] = lo, n, 0
    sp, ret = 1, 0.0
    while sp > 0:
        t = sp - 1
        n_t = f_n[t]
        if n_t <= 128:
            ret = _block(a, f_lo[t], n_t, absolute)
            sp -= 1
            continue
        n2 = n_t // 2
        n2 -= n2 % 8
        if f_stage[t] == 0:
            f_stage[t] = 1
            f_lo[sp], f_n[sp], f_stage[sp] = f_lo[t], n2, 0
            sp += 1
        elif f_stage[t] == 1:
            f_left[t] = ret
            f_stage[t] = 2
            f_lo[sp], f_n[sp], f_stage[sp] = f_lo[t] + n2, n_t - n2, 0
            sp += 1
        else:
            ret = f_left[t] + ret
            sp -= 1
    return ret


@nb.njit(**_JIT)
def abs_sum(a):
    """float(np.abs(a).sum()) of an array (C-contiguous: numpy's pairwise sum over the flattened array)."""
    return pairwise_sum(np.ascontiguousarray(a).ravel(), 0, a.size, True)


__all__ = ["pairwise_sum", "abs_sum"]
