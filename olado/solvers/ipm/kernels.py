"""Compiled passes over the flat iterate for :mod:`olado.solvers.ipm.barrier` (numba): the slacks,
Sigma (eq. (12)), the barrier gradient, the bound-multiplier step (13), the fraction-to-boundary
rule (15), the multiplier safeguard (16), the complementarity of eq. (5) and IPOPT's slack move
(Waechter and Biegler 2006).

Each is one loop over the vector instead of several numpy passes with a temporary each (at
N = 10^6 every temporary is 100 MB, and these passes were half of an iteration's time). The
arithmetic is the numpy expressions' own, operation by operation and in the same order (IEEE
operations are exactly rounded, and numba contracts no multiply-add without fastmath), and the
reductions keep numpy's NaN semantics (min and max propagate a NaN), so the results are bit for bit
those of the numpy forms, which tests/solvers/ipm/test_barrier_kernels.py keeps as the reference.
Imported on the first solve (barrier.py), so that importing olado does not load numba.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_JIT = {"cache": True, "error_model": "numpy"}   # x / 0 is inf or NaN, as in numpy


@nb.njit(**_JIT)
def slacks(v, lo, hi, has_lo, has_hi, sl, su):
    """sl = where(has_lo, v - lo, 1), su = where(has_hi, hi - v, 1)."""
    for i in range(v.size):
        sl[i] = v[i] - lo[i] if has_lo[i] else 1.0
        su[i] = hi[i] - v[i] if has_hi[i] else 1.0


@nb.njit(**_JIT)
def sigma(sl, su, zl, zu, out):
    """out = zl / sl + zu / su."""
    for i in range(sl.size):
        out[i] = zl[i] / sl[i] + zu[i] / su[i]


@nb.njit(**_JIT)
def barrier_gradient(sl, su, has_lo, has_hi, mu, kd_mu, out):
    """out = mu (hi_f / su - lo_f / sl) + kd_mu (one_lo_f - one_hi_f) with the masks as floats
    (lo_f = has_lo, one_lo_f = has_lo and not has_hi, ...), without storing them."""
    for i in range(sl.size):
        lo_f = 1.0 if has_lo[i] else 0.0
        hi_f = 1.0 if has_hi[i] else 0.0
        one_lo_f = 1.0 if has_lo[i] and not has_hi[i] else 0.0
        one_hi_f = 1.0 if has_hi[i] and not has_lo[i] else 0.0
        out[i] = mu * (hi_f / su[i] - lo_f / sl[i]) + kd_mu * (one_lo_f - one_hi_f)


@nb.njit(**_JIT)
def dual_step(sl, su, zl, zu, dv, has_lo, has_hi, mu, dzl, dzu):
    """dzl = where(has_lo, mu / sl - zl - zl / sl dv, 0), dzu = where(has_hi, mu / su - zu + zu / su dv, 0)."""
    for i in range(sl.size):
        dzl[i] = (mu / sl[i] - zl[i]) - zl[i] / sl[i] * dv[i] if has_lo[i] else 0.0
        dzu[i] = (mu / su[i] - zu[i]) + zu[i] / su[i] * dv[i] if has_hi[i] else 0.0


@nb.njit(inline="always")
def _min(r, a):
    """np.minimum's rule: a NaN propagates."""
    if r != r or a != a:
        return np.nan
    return a if a < r else r


@nb.njit(**_JIT)
def max_step(sl, su, dv, has_lo, has_hi, neg_tau, tau):
    """(min(where(has_lo & dv < 0, -tau sl / dv, 1), initial 1), min(where(has_hi & dv > 0, tau su / dv, 1), initial 1))."""
    a_lo, a_hi = 1.0, 1.0
    for i in range(sl.size):
        if has_lo[i] and dv[i] < 0:
            a_lo = _min(a_lo, neg_tau * sl[i] / dv[i])
        if has_hi[i] and dv[i] > 0:
            a_hi = _min(a_hi, tau * su[i] / dv[i])
    return a_lo, a_hi


@nb.njit(**_JIT)
def max_dual_step(z, dz, neg_tau):
    """min(where(dz < 0, -tau z / dz, 1), initial 1)."""
    r = 1.0
    for i in range(z.size):
        if dz[i] < 0:
            r = _min(r, neg_tau * z[i] / dz[i])
    return r


@nb.njit(inline="always")
def _clip(x, lo, hi):
    """np.clip of floats: max(x, lo) then min(., hi), a NaN x kept, a NaN bound taken."""
    if not x != x:
        x = x if x > lo else lo
    if not x != x:
        x = x if x < hi else hi
    return x


@nb.njit(**_JIT)
def safeguard(sl, su, zl, zu, has_lo, has_hi, mu, kappa_sigma, ks_mu, out_l, out_u):
    """out = where(has, clip(z, mu / (kappa_sigma s), (kappa_sigma mu) / s), 0) for both sides."""
    for i in range(sl.size):
        out_l[i] = _clip(zl[i], mu / (kappa_sigma * sl[i]), ks_mu / sl[i]) if has_lo[i] else 0.0
        out_u[i] = _clip(zu[i], mu / (kappa_sigma * su[i]), ks_mu / su[i]) if has_hi[i] else 0.0


@nb.njit(inline="always")
def _max(r, a):
    """np.maximum's rule: a NaN propagates."""
    if r != r or a != a:
        return np.nan
    return a if a > r else r


@nb.njit(**_JIT)
def complementarity(sl, su, zl, zu, has_lo, has_hi, mu):
    """(count, max) of |s_L z_L - mu| over has_lo and of |s_U z_U - mu| over has_hi (max -inf when
    the count is 0)."""
    n_lo, n_hi, m_lo, m_hi = 0, 0, -np.inf, -np.inf
    for i in range(sl.size):
        if has_lo[i]:
            m_lo = _max(m_lo, abs(sl[i] * zl[i] - mu))
            n_lo += 1
        if has_hi[i]:
            m_hi = _max(m_hi, abs(su[i] * zu[i] - mu))
            n_hi += 1
    return n_lo, m_lo, n_hi, m_hi


@nb.njit(inline="always")
def _floor1(a):
    """np.maximum(1, a) (a NaN propagates)."""
    return a if (a != a or a > 1.0) else 1.0


@nb.njit(**_JIT)
def move_tiny(v, lo, hi, has_lo, has_hi, eps, move):
    """IPOPT's slack move (barrier.Bounds.move_tiny) in place on lo, hi: a side with slack below
    eps max(1, |v|) is moved by ``move`` max(1, |bound|). Returns the number of sides moved."""
    moved = 0
    for i in range(v.size):
        tiny = eps * _floor1(abs(v[i]))
        if has_lo[i] and v[i] - lo[i] < tiny:
            lo[i] -= move * _floor1(abs(lo[i]))
            moved += 1
        if has_hi[i] and hi[i] - v[i] < tiny:
            hi[i] += move * _floor1(abs(hi[i]))
            moved += 1
    return moved
