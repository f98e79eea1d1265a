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

from ...linalg.numpy_sums import pairwise_sum

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
def complementarity(sl, su, zl, zu, has_lo, has_hi, mu, mu1):
    """(count, max for mu, max for mu1) of |s_L z_L - mu| over has_lo, then the same of
    |s_U z_U - mu| over has_hi (a max is -inf when its count is 0): two barrier parameters in one
    pass (``complementarity_ranges`` without the ranges)."""
    n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, _, _, _, _ = complementarity_ranges(sl, su, zl, zu, has_lo, has_hi, mu, mu1)
    return n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1


@nb.njit(inline="always")
def _min_max(lo, hi, p):
    """(min, max) of a running range with ``p`` added, np.minimum's and np.maximum's rule (a NaN
    propagates to both)."""
    if lo != lo or p != p:
        return np.nan, np.nan
    return (p if p < lo else lo), (p if p > hi else hi)


@nb.njit(**_JIT)
def complementarity_ranges(sl, su, zl, zu, has_lo, has_hi, mu, mu1):
    """``complementarity``'s (n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1) -- the stopping test's mu = 0
    and the barrier update's -- and the ranges (lo_min, lo_max, hi_min, hi_max) of the products
    s_L z_L over has_lo and s_U z_U over has_hi (min inf, max -inf for an empty side; both NaN
    when a product is NaN), from which solver.products_complementarity has max |s z - mu| of any
    other mu (fl(p - mu) is monotone in p: the largest |fl(p - mu)| is at an end of the range)."""
    n_lo, n_hi, m_lo, m_hi, m_lo1, m_hi1 = 0, 0, -np.inf, -np.inf, -np.inf, -np.inf
    lo_min, lo_max, hi_min, hi_max = np.inf, -np.inf, np.inf, -np.inf
    for i in range(sl.size):
        if has_lo[i]:
            p = sl[i] * zl[i]
            m_lo = _max(m_lo, abs(p - mu))
            m_lo1 = _max(m_lo1, abs(p - mu1))
            lo_min, lo_max = _min_max(lo_min, lo_max, p)
            n_lo += 1
        if has_hi[i]:
            p = su[i] * zu[i]
            m_hi = _max(m_hi, abs(p - mu))
            m_hi1 = _max(m_hi1, abs(p - mu1))
            hi_min, hi_max = _min_max(hi_min, hi_max, p)
            n_hi += 1
    return n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, lo_min, lo_max, hi_min, hi_max


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


@nb.njit(inline="always")
def _abs_max_into(a, mx, seen):
    """One step of Python's max(..., default) over np.abs(a).max() of the non-empty arrays: a
    later value replaces only a smaller one (a NaN first stays, a NaN later is never greater)."""
    if a.size:
        m = abs(a[0])
        for i in range(1, a.size):
            m = _max(m, abs(a[i]))
        if not seen or m > mx:
            mx = m
        seen = True
    return mx, seen


@nb.njit("float64(float64[::1], float64[::1])", **_JIT)
def dot(a, b):
    """a.b in a fixed order, whatever the CPU: eight running partial sums over the entries i = j
    (mod 8), combined ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then the remaining
    entries in order (numpy's einsum sums in SIMD lanes whose number depends on the CPU; a compiled
    iteration computing the same product must get the same float)."""
    n = a.size
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i] * b[i]
        return res
    r0, r1, r2, r3 = a[0] * b[0], a[1] * b[1], a[2] * b[2], a[3] * b[3]
    r4, r5, r6, r7 = a[4] * b[4], a[5] * b[5], a[6] * b[6], a[7] * b[7]
    i = 8
    end = n - (n % 8)
    while i < end:
        r0 += a[i] * b[i]; r1 += a[i + 1] * b[i + 1]; r2 += a[i + 2] * b[i + 2]; r3 += a[i + 3] * b[i + 3]
        r4 += a[i + 4] * b[i + 4]; r5 += a[i + 5] * b[i + 5]; r6 += a[i + 6] * b[i + 6]; r7 += a[i + 7] * b[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[i] * b[i]
        i += 1
    return res


@nb.njit(**_JIT)
def residual_norms(h2, e2, eN, d2, dN):
    """(l1, max) of the residual arrays (flat views) as newton.Residuals.l1 and .max compute them:
    l1 = sum(np.abs(a).sum() for a) (Python's sum from 0, in this order), max = the largest
    np.abs(a).max() of the non-empty arrays (NaN propagating), 0 when all are empty."""
    h, e, d = h2.ravel(), e2.ravel(), d2.ravel()       # (N, .) arrays, C-contiguous or copied
    l1 = 0.0
    l1 += pairwise_sum(h, 0, h.size, True)
    l1 += pairwise_sum(e, 0, e.size, True)
    l1 += pairwise_sum(np.ascontiguousarray(eN), 0, eN.size, True)
    l1 += pairwise_sum(d, 0, d.size, True)
    l1 += pairwise_sum(np.ascontiguousarray(dN), 0, dN.size, True)
    mx, seen = 0.0, False
    mx, seen = _abs_max_into(h, mx, seen)
    mx, seen = _abs_max_into(e, mx, seen)
    mx, seen = _abs_max_into(eN, mx, seen)
    mx, seen = _abs_max_into(d, mx, seen)
    mx, seen = _abs_max_into(dN, mx, seen)
    return l1, mx





@nb.njit(**_JIT)
def barrier_logs(v, lo, hi, has_lo, has_hi, sl, su, logs):
    """The slacks into sl, su (as ``slacks``) and, inside the bounds, np.log(sl).sum() +
    np.log(su).sum() (``logs``: a work array of v's size); returns (inside, that sum)."""
    n = v.size
    for i in range(n):
        sl[i] = v[i] - lo[i] if has_lo[i] else 1.0
        su[i] = hi[i] - v[i] if has_hi[i] else 1.0
    if n:
        mn_l, mn_u = sl[0], su[0]
        for i in range(1, n):
            mn_l = _min(mn_l, sl[i])
            mn_u = _min(mn_u, su[i])
        # sl.min() <= 0 or su.min() <= 0 (a NaN minimum compares False: inside, as numpy)
        if mn_l <= 0 or mn_u <= 0:
            return False, 0.0
    for i in range(n):
        logs[i] = np.log(sl[i])
    s = pairwise_sum(logs, 0, n, False)
    for i in range(n):
        logs[i] = np.log(su[i])
    return True, s + pairwise_sum(logs, 0, n, False)


@nb.njit(**_JIT)
def dual_infeasibility(s_obj, lx, lu, lN, EA, EB, lam, ECx, ECu, CNL, has_r, has_rN, yd, ydN, zl, zu, nu, nuN):
    """|grad L - z_L + z_U|_inf over the flat vector (solver.error_terms), with grad L as
    olado.solvers.common.stage_gradient_terms (sigma = s_obj) and solver.lagrangian_gradient
    assemble it: rx[:-1] = s lx + EA, rx[1:-1] -= lam[:-1], rx[-1] = s lN - lam[-1],
    (rx[:-1] += ECx, has_r), ru = s lu + EB (ru += ECu), (rx[-1] += CNL, has_rN), then the
    slack rows -yd, -ydN; EA, EB, ECx, ECu are the einsum products A^T lam, B^T lam, Cx^T Lg,
    Cu^T Lg (computed by numpy, as there). The max is np.abs(.).max(initial=0) (NaN propagating);
    returns it with the multipliers' sums np.abs(zl).sum() + np.abs(zu).sum() and
    sum(np.abs(a).sum() for a in (lam[1:], nu, nuN, yd, ydN)) (lam: the rows lam[1:])."""
    N, n = EA.shape
    m = EB.shape[1]
    mx = 0.0
    j = 0
    for k in range(1, N + 1):
        for i in range(n):
            if k < N:
                g = s_obj * lx[k, i] + EA[k, i]
                g -= lam[k - 1, i]
                if has_r:
                    g += ECx[k, i]
            else:
                g = s_obj * lN[i] - lam[N - 1, i]
                if has_rN:
                    g += CNL[i]
            mx = _max(mx, abs((g - zl[j]) + zu[j]))
            j += 1
    for k in range(N):
        for i in range(m):
            g = s_obj * lu[k, i] + EB[k, i]
            if has_r:
                g += ECu[k, i]
            mx = _max(mx, abs((g - zl[j]) + zu[j]))
            j += 1
    yf = yd.ravel()
    for i in range(yf.size):
        mx = _max(mx, abs((-yf[i] - zl[j]) + zu[j]))
        j += 1
    for i in range(ydN.size):
        mx = _max(mx, abs((-ydN[i] - zl[j]) + zu[j]))
        j += 1
    zl, zu = np.ascontiguousarray(zl), np.ascontiguousarray(zu)
    zsum = pairwise_sum(zl, 0, zl.size, True) + pairwise_sum(zu, 0, zu.size, True)
    ysum = 0.0
    ysum += pairwise_sum(lam.ravel(), 0, lam.size, True)
    ysum += pairwise_sum(nu.ravel(), 0, nu.size, True)
    ysum += pairwise_sum(np.ascontiguousarray(nuN), 0, nuN.size, True)
    ysum += pairwise_sum(yf, 0, yf.size, True)
    ysum += pairwise_sum(np.ascontiguousarray(ydN), 0, ydN.size, True)
    return mx, zsum, ysum


@nb.njit(inline="always")
def _barrier_grad(sl_i, su_i, lo, hi, mu, kd_mu):
    """An entry of ``barrier_gradient`` from that entry's slacks and masks (scalars: an inlined
    helper that takes the arrays and an index ran ~6x slower than the plain loop)."""
    lo_f = 1.0 if lo else 0.0
    hi_f = 1.0 if hi else 0.0
    one_lo_f = 1.0 if lo and not hi else 0.0
    one_hi_f = 1.0 if hi and not lo else 0.0
    return mu * (hi_f / su_i - lo_f / sl_i) + kd_mu * (one_lo_f - one_hi_f)


@nb.njit(**_JIT)
def barrier_direction(s_obj, lx, lN, lu, sl, su, has_lo, has_hi, mu, kd_mu, q, r, gs, gsN, grad):
    """The Newton right-hand side of solver.barrier_gradient: with bg the barrier gradient
    (``barrier_gradient``) split over (x^1..x^N, u, s, s_N) (x^0's part 0),
    q[0] = s lx[0] + 0, q[k] = s lx[k] + bg_x^k (k < N), q[N] = s lN + bg_x^N, r = s lu + bg_u,
    gs, gsN the slack parts, and grad = (q[1:], r, gs, gsN) flat."""
    N, n = lx.shape
    m = lu.shape[1]
    for j in range(grad.size):      # the barrier gradient first (one inlined copy of its formula)
        grad[j] = _barrier_grad(sl[j], su[j], has_lo[j], has_hi[j], mu, kd_mu)
    for i in range(n):
        q[0, i] = s_obj * lx[0, i] + 0.0
    j = 0
    for k in range(1, N + 1):
        for i in range(n):
            q[k, i] = (s_obj * lx[k, i] if k < N else s_obj * lN[i]) + grad[j]
            grad[j] = q[k, i]
            j += 1
    for k in range(N):
        for i in range(m):
            r[k, i] = s_obj * lu[k, i] + grad[j]
            grad[j] = r[k, i]
            j += 1
    gf = gs.ravel()
    for i in range(gf.size):
        gf[i] = grad[j]
        j += 1
    for i in range(gsN.size):
        gsN[i] = grad[j]
        j += 1


@nb.njit(**_JIT)
def dual_step_lengths(sl, su, zl, zu, dv, has_lo, has_hi, mu, neg_tau, dzl, dzu):
    """``dual_step`` into dzl, dzu and the fraction-to-boundary minima of both sides
    (``max_dual_step`` of each: min(where(dz < 0, -tau z / dz, 1), initial 1))."""
    r_l, r_u = 1.0, 1.0
    for i in range(sl.size):
        dzl[i] = (mu / sl[i] - zl[i]) - zl[i] / sl[i] * dv[i] if has_lo[i] else 0.0
        dzu[i] = (mu / su[i] - zu[i]) + zu[i] / su[i] * dv[i] if has_hi[i] else 0.0
        if dzl[i] < 0:
            r_l = _min(r_l, neg_tau * zl[i] / dzl[i])
        if dzu[i] < 0:
            r_u = _min(r_u, neg_tau * zu[i] / dzu[i])
    return r_l, r_u


@nb.njit(**_JIT)
def safeguard_step(sl, su, zl, zu, dzl, dzu, alpha_z, has_lo, has_hi, mu, kappa_sigma, ks_mu, out_l, out_u):
    """``safeguard`` of the stepped multipliers zl + alpha_z dzl, zu + alpha_z dzu."""
    for i in range(sl.size):
        out_l[i] = _clip(zl[i] + alpha_z * dzl[i], mu / (kappa_sigma * sl[i]), ks_mu / sl[i]) if has_lo[i] else 0.0
        out_u[i] = _clip(zu[i] + alpha_z * dzu[i], mu / (kappa_sigma * su[i]), ks_mu / su[i]) if has_hi[i] else 0.0


@nb.njit(**_JIT)
def sigma_blocks(sl, su, zl, zu, Sx, Su, Ss, SsN):
    """``sigma`` split as Layout.split(sigma, 0) splits it: Sx (N+1, n) with row 0 zero, Su
    (N, m), Ss (N, ni), SsN (niN,)."""
    n = Sx.shape[1]
    for i in range(n):
        Sx[0, i] = 0.0
    j = 0
    for a in (Sx[1:].ravel(), Su.ravel(), Ss.ravel(), SsN):
        for i in range(a.size):
            a[i] = zl[j] / sl[j] + zu[j] / su[j]
            j += 1


@nb.njit(**_JIT)
def tiny_step(dv, v):
    """np.max(np.abs(dv) / (1 + np.abs(v)), initial=0) (NaN propagating)."""
    r = 0.0
    for i in range(v.size):
        r = _max(r, abs(dv[i]) / (1.0 + abs(v[i])))
    return r


# ---------------------------------------------------------------------------- the loop's fused passes
# (solver.py: one call each for the trial point, its measures, the step's line-search terms and the
# step taken; their callees are this file's kernels, so their caches stay in step with them)


@nb.njit(**_JIT)
def trial_point(v, dv, alpha, x0, v_t, X, U):
    """v_t = v + alpha dv, and (X, U) of barrier.Layout.states_controls(v_t): X[0] = x0, X[1:] and
    U the first N n and the next N m entries of v_t."""
    for i in range(v.size):
        v_t[i] = v[i] + alpha * dv[i]
    N1, n = X.shape
    m = U.shape[1]
    for i in range(n):
        X[0, i] = x0[i]
    j = 0
    for k in range(1, N1):
        for i in range(n):
            X[k, i] = v_t[j]
            j += 1
    for k in range(U.shape[0]):
        for i in range(m):
            U[k, i] = v_t[j]
            j += 1


@nb.njit(**_JIT)
def point_terms(v, lo, hi, has_lo, has_hi, sl, su, logs, h, e, eN, d, dN):
    """``residual_norms`` of the residual arrays (h, e, eN, d, dN) and ``barrier_logs`` at v in
    one call: (l1, max, inside, the sum of logs)."""
    l1, mx = residual_norms(h, e, eN, d, dN)
    inside, s = barrier_logs(v, lo, hi, has_lo, has_hi, sl, su, logs)
    return l1, mx, inside, s


@nb.njit(inline="always")
def _py_min(a, b):
    """Python's min(a, b) of floats: b only when b < a (a NaN b never replaces a, a NaN a stays)."""
    return b if b < a else a


@nb.njit(**_JIT)
def step_terms(dX, dU, ds, dsN, v, sl, su, has_lo, has_hi, neg_tau, tau, dv):
    """The step dv = barrier.Layout.pack(dX, dU, ds, dsN) (dX[0] left out), the fraction-to-boundary
    step min(1, a_lo, a_hi) of ``max_step`` (Python's min, as barrier.Bounds.max_step) and
    ``tiny_step`` (dv, v); returns (alpha_max, tiny)."""
    j = 0
    for k in range(1, dX.shape[0]):
        for i in range(dX.shape[1]):
            dv[j] = dX[k, i]
            j += 1
    for k in range(dU.shape[0]):
        for i in range(dU.shape[1]):
            dv[j] = dU[k, i]
            j += 1
    for k in range(ds.shape[0]):
        for i in range(ds.shape[1]):
            dv[j] = ds[k, i]
            j += 1
    for i in range(dsN.size):
        dv[j] = dsN[i]
        j += 1
    a_lo, a_hi = max_step(sl, su, dv, has_lo, has_hi, neg_tau, tau)
    return _py_min(_py_min(1.0, a_lo), a_hi), tiny_step(dv, v)


@nb.njit(**_JIT)
def step_bound_multipliers(sl, su, v_new, dv, lo, hi, has_lo, has_hi, zl, zu, mu, neg_tau, eps, move, kappa_sigma,
                           ks_mu, sl_new, su_new, zl_new, zu_new, lam, lam_step, alpha, lam_new):
    """The bound side of solver.take_step in one call: ``dual_step_lengths`` at the old slacks
    (sl, su; the steps dz held in zl_new, zu_new), alpha_z = min(min(1, r_l), min(1, r_u)) (Python's
    min, as barrier.Bounds.dual_step_length), ``move_tiny`` at v_new (lo, hi in place), the slacks
    at v_new (after the move) into sl_new, su_new and ``safeguard_step`` of z + alpha_z dz there
    into zl_new, zu_new; and the dynamics multipliers' step lam_new = lam + alpha (lam_step - lam)
    (the numpy expression's operations). Returns (alpha_z, the number of bound sides moved)."""
    lf, sf, nf = lam.ravel(), lam_step.ravel(), lam_new.ravel()
    for i in range(nf.size):
        nf[i] = lf[i] + alpha * (sf[i] - lf[i])
    r_l, r_u = dual_step_lengths(sl, su, zl, zu, dv, has_lo, has_hi, mu, neg_tau, zl_new, zu_new)
    alpha_z = _py_min(_py_min(1.0, r_l), _py_min(1.0, r_u))
    moved = move_tiny(v_new, lo, hi, has_lo, has_hi, eps, move)
    slacks(v_new, lo, hi, has_lo, has_hi, sl_new, su_new)
    safeguard_step(sl_new, su_new, zl, zu, zl_new, zu_new, alpha_z, has_lo, has_hi, mu, kappa_sigma, ks_mu,
                   zl_new, zu_new)
    return alpha_z, moved


@nb.njit(**_JIT)
def shifted_diagonals(Sx, Su, delta, Dx, Du):
    """The diagonals of newton.KKTMatrix with the shift delta: Dx = Sx + delta with Dx[0] = 0,
    Du = Su + delta (np.add's sums)."""
    for i in range(Dx.shape[1]):
        Dx[0, i] = 0.0
    for k in range(1, Dx.shape[0]):
        for i in range(Dx.shape[1]):
            Dx[k, i] = Sx[k, i] + delta
    for k in range(Du.shape[0]):
        for i in range(Du.shape[1]):
            Du[k, i] = Su[k, i] + delta


@nb.njit(**_JIT)
def stage_products(A, B, lam, EA, EB):
    """EA = A^T lam, EB = B^T lam per stage (np.einsum("kij,ki->kj", .)): every entry the sum over
    i in order from 0, one product added at a time -- the order of numpy's einsum for these
    operands (C-contiguous, an output row of 2 or more entries: its loop runs along the output
    row, adding A[k, i, :] lam[k, i] for i = 0, 1, ...; with one entry it sums in SIMD lanes
    instead, and solver.dual_terms keeps einsum then)."""
    N, n = lam.shape
    for k in range(N):
        for j in range(EA.shape[1]):
            EA[k, j] = 0.0
        for j in range(EB.shape[1]):
            EB[k, j] = 0.0
        for i in range(n):
            li = lam[k, i]
            for j in range(EA.shape[1]):
                EA[k, j] += A[k, i, j] * li
            for j in range(EB.shape[1]):
                EB[k, j] += B[k, i, j] * li


@nb.njit(**_JIT)
def error_pass(s_obj, lx, lu, lN, A, B, EA, EB, products, lam, ECx, ECu, CNL, has_r, has_rN, yd, ydN, zl, zu, nu, nuN,
               sl, su, has_lo, has_hi, mu0, mu1):
    """The optimality error's passes at an iterate in one call (solver.error_terms): with
    ``products``, ``stage_products`` (A, B, lam) into EA, EB first; then ``dual_infeasibility``
    and ``complementarity_ranges`` (sl, su, ..., mu0, mu1). Returns (max, z sum, y sum), the
    complementarity's (n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1) and the products' ranges (lo_min,
    lo_max, hi_min, hi_max)."""
    if products:
        stage_products(A, B, lam, EA, EB)
    mx, zsum, ysum = dual_infeasibility(s_obj, lx, lu, lN, EA, EB, lam, ECx, ECu, CNL, has_r, has_rN, yd, ydN, zl, zu,
                                        nu, nuN)
    n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, lo_min, lo_max, hi_min, hi_max = complementarity_ranges(
        sl, su, zl, zu, has_lo, has_hi, mu0, mu1)
    return mx, zsum, ysum, n_lo, m_lo, m_lo1, n_hi, m_hi, m_hi1, lo_min, lo_max, hi_min, hi_max


@nb.njit(**_JIT)
def newton_terms(s_obj, lx, lN, lu, sl, su, zl, zu, has_lo, has_hi, mu, kd_mu, Sx, Su, Ss, SsN, q, r, gs, gsN, grad):
    """``sigma_blocks`` and ``barrier_direction`` at an iterate in one call (solver.newton_system
    with the gradient: the Newton matrix's Sigma and the right-hand side)."""
    sigma_blocks(sl, su, zl, zu, Sx, Su, Ss, SsN)
    barrier_direction(s_obj, lx, lN, lu, sl, su, has_lo, has_hi, mu, kd_mu, q, r, gs, gsN, grad)
