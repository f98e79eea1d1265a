"""The compiled elementwise kernels of the interior-point QP (paper 001 sec. 4.2.2-4.2.3).

One pass each over the flat box vectors w = (x_1..x_N, u_0..u_{N-1}, C_k z_k, C_N x_N) (indexed as
in :mod:`.presolve`: x_k (k >= 1) at (k-1) n, u_k at N n + k m, row l of C_k z_k at
N (n+m) + k nc + l, then C_N x_N) or the flat point vectors:

* the scaling D = zl/tl + zu/tu of the eliminated slack and multiplier rows (:func:`_scaling`),
  the Newton right-hand side of the reduced system (25) (:func:`_newton_rhs`) and the recovery of
  the eliminated parts after the solve, delta lambda = W^{-1} Lambda (r_3 - C delta s) below (25)
  (:func:`_recover_step`), with the complementarity residual of (22) (:func:`_complementarity_residual`);
  for the plain Riccati recursion of small blocks the three steps of a Newton solve in one kernel,
  the right-hand side, the Riccati sweeps and the recovery (:func:`_newton_solve_fixed`);
* the step lengths of (23): ratio tests (:func:`_max_step`, :func:`_max_step_split`) and the
  neighbourhood test (:func:`_neighbourhood_step`); the right-hand sides of the correctors
  (:func:`_corrector_rhs`, :func:`_combined_rhs`, :func:`_centrality_rhs`);
* norms, axpys, and the numerics of the infeasibility certificates (:func:`_farkas_kappa`,
  :func:`_cone_violation`).

Reductions (sums, maxima) may be reassociated and multiply-adds contracted where the flags say
so (REASSOC; no NaN/inf assumptions, so non-finite values still propagate): results agree with
plain loops up to rounding. Points and directions are passed as their Slacks bundles
(``it``, ``d``: their complementarity pairs), residuals as Residuals bundles (``res``), the stage
data as the KKTData bundle (``data``): plain tuples with the fields of :mod:`.bundles`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ...linalg.backend import RHS, Solution
from ...linalg.codegen import REASSOC, as_bundle
from ...linalg.riccati_fixed import _solve_unconstrained_fixed
from .bundles import Residuals, Slacks


@nb.njit(cache=True)
def _complementarity_residual(rho_l, rho_u, it, d, el, eu):
    """el = rho_l - zl dtl - tl dzl, eu = rho_u - zu dtu - tu dzu; returns max |el, eu|."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    big = 0.0
    for i in range(tl.shape[0]):
        a = rho_l[i] - zl[i] * dtl[i] - tl[i] * dzl[i]
        b = rho_u[i] - zu[i] * dtu[i] - tu[i] * dzu[i]
        el[i] = a
        eu[i] = b
        big = max(big, abs(a), abs(b))
    return big


@nb.njit(cache=True)
def _scaling(it, fl, fu, inv_tl, inv_tu, D, reg, Dx, Du):
    """1/t on the finite sides (0 elsewhere) and D = zl/tl + zu/tu; then, in the same call, the
    diagonal terms of the Newton matrix with the regularization ``reg``: Dx (N+1, n) = (reg; D of
    x_1..x_N + reg), Du (N, m) = D of u + reg. (Written as one loop with an inlined helper for
    the three index ranges this ran 12x slower: keep the plain loops.)"""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    N, n = Dx.shape[0] - 1, Dx.shape[1]
    m = Du.shape[1]
    for i in range(n):
        Dx[0, i] = reg
    for i in range(tl.shape[0]):
        a = 1.0 / tl[i] if fl[i] else 0.0
        b = 1.0 / tu[i] if fu[i] else 0.0
        inv_tl[i] = a
        inv_tu[i] = b
        D[i] = zl[i] * a + zu[i] * b
    for k in range(N):
        for i in range(n):
            Dx[k + 1, i] = D[k * n + i] + reg
    o = N * n
    for k in range(N):
        for i in range(m):
            Du[k, i] = D[o + k * m + i] + reg


@nb.njit(cache=True)
def _newton_rhs(rx, ru, rl, rup, rho_l, rho_u, it, inv_tl, inv_tu, Ds, CN, q, r, ci):
    """Eliminate (dtl, dtu, dzl, dzu): g = (rho_u - zu rup)/tu - (rho_l - zl rl)/tl enters the
    gradient (q, r; C_N^T g for final rows) and the stage-row constants ci = g / D."""
    it = as_bundle(it, Slacks)
    _box_rhs(rx, ru, rl, rup, rho_l, rho_u, it.zl, it.zu, inv_tl, inv_tu, Ds, CN, q, r, ci)


@nb.njit(cache=True)
def _recover_step(dX, dU, Ct, CN, fl, fu, rl, rup, rho_l, rho_u, inv_tl, inv_tu, it, d, w):
    """After the KKT solve: dtl = dw + rl, dtu = -dw + rup, dzl = (rho_l - zl dtl)/tl,
    dzu = (rho_u - zu dtu)/tu.  Returns (ok, ap, ad): ok False if dX or dU is not finite; ap, ad
    the largest primal (slacks) and dual (multipliers) step lengths along the direction (as
    _max_step_split, in the same pass; min(ap, ad) is _max_step's common one); it, d: the
    Slacks of the iterate and of the direction."""
    return _recover_all(dX, dU, Ct, CN, fl, fu, rl, rup, rho_l, rho_u, inv_tl, inv_tu, as_bundle(it, Slacks),
                        as_bundle(d, Slacks), w)


@nb.njit(cache=True, fastmath=REASSOC)
def _max_step(it, d, c, omega):
    """Largest alpha (capped at 1e30) keeping tl, tu, zl, zu of the point ``it`` positive along
    d + omega c (omega = 0: along d; it, d, c PointArrays).  Infinite sides hold t = z = 0 and
    zero steps (by construction of the iterates and directions), so they never limit the step and
    need no test (the loop is branch-free and vectorizes)."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    c = as_bundle(c, Slacks)
    ctl, ctu, czl, czu = c.tl, c.tu, c.zl, c.zu
    a = 1e30
    inf = np.inf
    for i in range(tl.shape[0]):
        v = dtl[i] + omega * ctl[i]
        a = min(a, -tl[i] / v if v < 0.0 else inf)
        v = dzl[i] + omega * czl[i]
        a = min(a, -zl[i] / v if v < 0.0 else inf)
        v = dtu[i] + omega * ctu[i]
        a = min(a, -tu[i] / v if v < 0.0 else inf)
        v = dzu[i] + omega * czu[i]
        a = min(a, -zu[i] / v if v < 0.0 else inf)
    return a


@nb.njit(cache=True, fastmath=REASSOC)
def _max_step_split(it, d):
    """Largest primal (slacks) and dual (multipliers) step lengths (capped at 1e30) keeping
    tl, tu resp. zl, zu positive along d (infinite sides: see _max_step)."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    ap = 1e30
    ad = 1e30
    inf = np.inf
    for i in range(tl.shape[0]):
        v = dtl[i]
        ap = min(ap, -tl[i] / v if v < 0.0 else inf)
        v = dtu[i]
        ap = min(ap, -tu[i] / v if v < 0.0 else inf)
        v = dzl[i]
        ad = min(ad, -zl[i] / v if v < 0.0 else inf)
        v = dzu[i]
        ad = min(ad, -zu[i] / v if v < 0.0 else inf)
    return ap, ad


@nb.njit(cache=True)
def _axpy_split(x, ap, ad, y, dual):
    """x + a y in a new array with a = ad where ``dual`` else ap (one pass)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = x[i] + (ad if dual[i] else ap) * y[i]
    return out


@nb.njit(cache=True)
def _step_into(x, ap, ad, y, dual, out):
    """out = x + a y with a = ad where ``dual`` else ap (ad = ap: the common step; the same
    values as _axpy, _axpy_split) in one pass; returns whether every entry of out is finite
    (_all_finite of out, in the same pass). ``out`` may not be x or y."""
    ok = True
    if ap == ad:
        for i in range(x.shape[0]):
            v = x[i] + ap * y[i]
            out[i] = v
            ok = ok and np.isfinite(v)
    else:
        for i in range(x.shape[0]):
            v = x[i] + (ad if dual[i] else ap) * y[i]
            out[i] = v
            ok = ok and np.isfinite(v)
    return ok


@nb.njit(cache=True, fastmath=REASSOC)
def _neighbourhood_step(it, fl, fu, d, alpha, neighborhood, mu, alpha_dual=-1.0):
    """Shorten alpha by factors 0.9 (at most 60 times) until min t_i z_i >= gamma mean t_i z_i at
    it + alpha d, gamma = min(neighborhood, 1/2 min_i t_i z_i / mu) at the current iterate.
    With ``alpha_dual`` >= 0 the multipliers move by alpha_dual (shortened by the same factors) and
    the slacks by alpha; returns the (primal) alpha (the dual one is alpha_dual * alpha / alpha_in)."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    if alpha_dual < 0.0:
        alpha_dual = alpha
    ratio = alpha_dual / alpha if alpha > 0.0 else 1.0
    nw = tl.shape[0]
    cur = np.inf
    cnt = 0
    for i in range(nw):
        if fl[i]:
            cur = min(cur, tl[i] * zl[i])
            cnt += 1
        if fu[i]:
            cur = min(cur, tu[i] * zu[i])
            cnt += 1
    if cnt == 0:
        return alpha
    gamma = min(neighborhood, 0.5 * cur / max(mu, 1e-300))
    for _ in range(60):
        pmin = np.inf
        psum = 0.0
        ad = ratio * alpha
        for i in range(nw):
            if fl[i]:
                v = (tl[i] + alpha * dtl[i]) * (zl[i] + ad * dzl[i])
                pmin = min(pmin, v)
                psum += v
            if fu[i]:
                v = (tu[i] + alpha * dtu[i]) * (zu[i] + ad * dzu[i])
                pmin = min(pmin, v)
                psum += v
        if pmin >= gamma * (psum / cnt):
            break
        alpha *= 0.9
    return alpha


@nb.njit(cache=True)
def _predictor_rhs(it, rho_l, rho_u):
    """The affine-scaling (predictor) right-hand side rho = -z t (0 on infinite sides, where t = z
    = 0); returns max |rho_l, rho_u| (what _max_abs of both would give)."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    big = 0.0
    for i in range(tl.shape[0]):
        a = -zl[i] * tl[i]
        b = -zu[i] * tu[i]
        rho_l[i] = a
        rho_u[i] = b
        big = max(big, abs(a))
        big = max(big, abs(b))
    return big


@nb.njit(cache=True)
def _corrector_rhs(fl, fu, d, target, scale, rho_l, rho_u):
    """Mehrotra's corrector: rho = target - scale * dt_aff dz_aff on the finite sides; returns
    max |rho_l, rho_u|."""
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    big = 0.0
    for i in range(fl.shape[0]):
        a = target - scale * (dtl[i] * dzl[i]) if fl[i] else 0.0
        b = target - scale * (dtu[i] * dzu[i]) if fu[i] else 0.0
        rho_l[i] = a
        rho_u[i] = b
        big = max(big, abs(a))
        big = max(big, abs(b))
    return big


@nb.njit(cache=True, fastmath=REASSOC)
def _implied_newton_residual(new, old, ap, ad, n_dual):
    """Max-norm of the Newton residual of the linear KKT rows of the last direction, implied by
    the residuals before (old) and after (new) the step: each linear row r moves to
    (1 - a) r + a e (e its Newton residual) with a = ap on the primal rows (entries from n_dual
    on, functions of x, u and the slacks only) and, when ap == ad, on the stationarity rows
    (the first n_dual entries); with ap != ad those are skipped."""
    e = 0.0
    if ap == ad:
        for i in range(n_dual):
            e = max(e, abs(new[i] - (1.0 - ad) * old[i]))
    for i in range(n_dual, new.shape[0]):
        e = max(e, abs(new[i] - (1.0 - ap) * old[i]))
    return e / ap


@nb.njit(cache=True)
def _combined_rhs(it, fl, fu, d, target, scale, rho_l, rho_u):
    """Predictor plus Mehrotra corrector in one right-hand side: rho = -t z + target
    - scale * dt_aff dz_aff on the finite sides (the direction d_aff + d_c in one solve);
    returns max |rho_l, rho_u|."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    big = 0.0
    for i in range(fl.shape[0]):
        a = target - tl[i] * zl[i] - scale * (dtl[i] * dzl[i]) if fl[i] else 0.0
        b = target - tu[i] * zu[i] - scale * (dtu[i] * dzu[i]) if fu[i] else 0.0
        rho_l[i] = a
        rho_u[i] = b
        big = max(big, abs(a))
        big = max(big, abs(b))
    return big


@nb.njit(cache=True)
def _centrality_rhs(it, fl, fu, d, alpha, lo_t, hi_t, rho_l, rho_u):
    """Gondzio's corrector: products v at it + alpha d projected on [lo_t, hi_t], decrease capped
    at -hi_t: rho = max(clip(v) - v, -hi_t) on the finite sides."""
    it = as_bundle(it, Slacks)
    tl, tu, zl, zu = it.tl, it.tu, it.zl, it.zu
    d = as_bundle(d, Slacks)
    dtl, dtu, dzl, dzu = d.tl, d.tu, d.zl, d.zu
    for i in range(fl.shape[0]):
        if fl[i]:
            v = (tl[i] + alpha * dtl[i]) * (zl[i] + alpha * dzl[i])
            rho_l[i] = max(min(max(v, lo_t), hi_t) - v, -hi_t)
        else:
            rho_l[i] = 0.0
        if fu[i]:
            v = (tu[i] + alpha * dtu[i]) * (zu[i] + alpha * dzu[i])
            rho_u[i] = max(min(max(v, lo_t), hi_t) - v, -hi_t)
        else:
            rho_u[i] = 0.0


@nb.njit(cache=True)
def _axpy(x, alpha, y):
    """x + alpha y in a new array (one pass)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = x[i] + alpha * y[i]
    return out


@nb.njit(cache=True)
def _max_abs(a):
    big = 0.0
    for i in range(a.shape[0]):
        big = max(big, abs(a[i]))
    return big


@nb.njit(cache=True)
def _dot(a, b):
    """a.b by an elementwise loop (no threaded BLAS: it stalls on long vectors on a busy machine)."""
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@nb.njit(cache=True)
def _farkas_kappa(lam, c, x0, zl, lo, zu, hi, nu, be, eN):
    """kappa = lam_+.c + lam_0.x0 + zl.lo - zu.hi + nu.e + nu_N.eN of the primal certificate
    (be = e on the valid stage rows, 0 elsewhere)."""
    N = c.shape[0]
    s = 0.0
    for k in range(N):
        for i in range(c.shape[1]):
            s += lam[k + 1, i] * c[k, i]
        for l in range(be.shape[1]):
            s += nu[k, l] * be[k, l]
    for i in range(x0.shape[0]):
        s += lam[0, i] * x0[i]
    for i in range(zl.shape[0]):
        s += zl[i] * lo[i] - zu[i] * hi[i]
    for l in range(eN.shape[0]):
        s += nu[N, l] * eN[l]
    return s


@nb.njit(cache=True)
def _cone_violation(w, fl, fu):
    """max(0, max over finite lower sides of -w, max over finite upper sides of w)."""
    v = 0.0
    for i in range(w.shape[0]):
        if fl[i]:
            v = max(v, -w[i])
        if fu[i]:
            v = max(v, w[i])
    return v


@nb.njit(cache=True)
def _all_finite(a):
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return False
    return True



@nb.njit(cache=True)
def _symmetric_stage_hessians(Q, S, R, H):
    """H_k = the symmetric part of [Q_k S_k; S_k^T R_k] (k < N), in one pass."""
    N, n, m = S.shape
    for k in range(N):
        for i in range(n):
            for j in range(n):
                H[k, i, j] = 0.5 * (Q[k, i, j] + Q[k, j, i])
            for j in range(m):
                v = 0.5 * (S[k, i, j] + S[k, i, j])
                H[k, i, n + j] = v
                H[k, n + j, i] = v
        for i in range(m):
            for j in range(m):
                H[k, n + i, n + j] = 0.5 * (R[k, i, j] + R[k, j, i])
    return H


# ----------------------------------------------------------------------------- the fused Newton solve
# One Newton solve of the reduced system (25) for the plain Riccati recursion of small blocks
# (olado.linalg.riccati_fixed: no equality rows, n + m <= FIXED_SIZE_MAX): the right-hand side
# (_newton_rhs), the solve (_solve_unconstrained_fixed itself, the compiled function the KKT
# back-end calls: its code is not generated twice) and the recovery of the eliminated parts
# (_recover_step) in one call. Each value is computed by the same expression, in the same order
# of operations, as by the three kernels in turn (the helpers below are compiled without
# fast-math flags, like _newton_rhs and _recover_step -- explicitly: a callee without a fastmath
# option inherits its caller's flags), so the results are the same bit for bit
# (tests/qp/test_newton_solve_fused.py). Interleaving the three passes stage block by stage block
# (64 stages, the sweeps' intrinsics called per block) was slower than running them in turn at
# N = 2 400 and 12 000 -- the passes read disjoint arrays, a block shares no data between them --
# and compiled 2.7 s longer. numba's cache of _newton_solve_fixed does not see riccati_fixed.py:
# delete this module's cache files (__pycache__/kernels.*.nbi, *.nbc) after changing
# _solve_unconstrained_fixed (docs/architecture.md "Caches").

@nb.njit(cache=True, fastmath=False)
def _box_rhs(rx, ru, rl, rup, rho_l, rho_u, zl, zu, inv_tl, inv_tu, Ds, CN, q, r, ci):
    """The right-hand side of _newton_rhs (which calls it; the fused Newton solve too) with the
    iterate's zl, zu as arrays, in unsigned indices: numba tests a signed index for wraparound at
    every access, which made these loops 10-20 % slower."""
    N = ru.shape[0]
    n = rx.shape[1]
    m = ru.shape[1]
    nc = Ds.shape[1]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    for i in range(n):
        q[0, i] = rx[0, i]
    for kk in range(1, N + 1):
        k = np.uint64(kk)
        for i in range(n):
            idx = np.uint64((kk - 1) * n + i)
            g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
            q[k, i] = rx[k, i] + g
    for kk in range(N):
        k = np.uint64(kk)
        for i in range(m):
            idx = np.uint64(ou + kk * m + i)
            g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
            r[k, i] = ru[k, i] + g
        for l in range(nc):
            idx = np.uint64(os_ + kk * nc + l)
            g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
            d = Ds[k, l]
            ci[k, l] = g / d if d > 0 else 0.0
    for l in range(CN.shape[0]):
        idx = osN + l
        g = (rho_u[idx] - zu[idx] * rup[idx]) * inv_tu[idx] - (rho_l[idx] - zl[idx] * rl[idx]) * inv_tl[idx]
        for i in range(n):
            q[N, i] += CN[l, i] * g


_K = 1.0 + 2.0 ** -50   # p = fl(fl(ap y) _K) > ap y for fl(ap y) normal: see _slack_steps
_TINY = 1e-290


@nb.njit(cache=True, fastmath=False)
def _slack_steps(w, fl, fu, rl, rup, rho_l, rho_u, inv_tl, inv_tu, it, d):
    """The last loop of _recover_step: dtl, dtu, dzl, dzu and the step lengths; returns (True,
    ap, ad).

    The ratio tests skip the division -t/a (a < 0) when t >= p = fl(fl(ap (-a)) (1 + 2^-50)) and
    p is a normal number: then p > ap (-a) (the two roundings lose at most a factor (1 - 2^-53)^2),
    so t / (-a) > ap and its rounded value is >= ap (rounding is monotone, ap a double): the
    minimum is the same, bit for bit, with most divisions skipped once ap is small."""
    tl, tu, zl, zu = it
    dtl, dtu, dzl, dzu = d
    ap, ad = 1e30, 1e30
    for i in range(w.shape[0]):
        a = w[i] + rl[i] if fl[i] else 0.0
        b = -w[i] + rup[i] if fu[i] else 0.0
        c = (rho_l[i] - zl[i] * a) * inv_tl[i]
        e = (rho_u[i] - zu[i] * b) * inv_tu[i]
        dtl[i] = a
        dtu[i] = b
        dzl[i] = c
        dzu[i] = e
        if a < 0.0:
            t, p = tl[i], ap * -a * _K
            if not (t >= p and p >= _TINY):
                ap = min(ap, -t / a)
        if b < 0.0:
            t, p = tu[i], ap * -b * _K
            if not (t >= p and p >= _TINY):
                ap = min(ap, -t / b)
        if c < 0.0:
            t, p = zl[i], ad * -c * _K
            if not (t >= p and p >= _TINY):
                ad = min(ad, -t / c)
        if e < 0.0:
            t, p = zu[i], ad * -e * _K
            if not (t >= p and p >= _TINY):
                ad = min(ad, -t / e)
    return True, ap, ad


@nb.njit(cache=True, fastmath=False)
def _recover_all(X, U, Ct, CN, fl, fu, rl, rup, rho_l, rho_u, inv_tl, inv_tu, it, d, w):
    """The recovery of _recover_step (which calls it; the fused Newton solve too), X, U the
    solution's dX, dU: w = (dx_1..dx_N, du, C_k dz_k, C_N dx_N) checked for finiteness on the way,
    then _slack_steps (the step lengths' divisions partly skipped); returns (ok, ap, ad)."""
    N = U.shape[0]
    n = X.shape[1]
    m = U.shape[1]
    nc = Ct.shape[2]
    ou = N * n
    os_ = ou + N * m
    osN = os_ + N * nc
    # w = (x_1..x_N, u, C_k z_k, C_N x_N), X and U checked for finiteness on the way
    for i in range(n):
        if not np.isfinite(X[0, i]):
            return False, 1e30, 1e30
    for kk in range(N):
        k = np.uint64(kk)
        for i in range(n):
            t = X[k + np.uint64(1), i]
            if not np.isfinite(t):
                return False, 1e30, 1e30
            w[np.uint64(kk * n + i)] = t
        for i in range(m):
            t = U[k, i]
            if not np.isfinite(t):
                return False, 1e30, 1e30
            w[np.uint64(ou + kk * m + i)] = t
        o = os_ + kk * nc
        for l in range(nc):
            w[o + l] = 0.0
        for j in range(n):
            t = X[k, j]
            for l in range(nc):
                w[o + l] += Ct[k, j, l] * t
        for j in range(m):
            t = U[k, j]
            for l in range(nc):
                w[o + l] += Ct[k, n + j, l] * t
    for l in range(CN.shape[0]):
        s = 0.0
        for j in range(n):
            s += CN[l, j] * X[N, j]
        w[osN + l] = s
    return _slack_steps(w, fl, fu, rl, rup, rho_l, rho_u, inv_tl, inv_tu, it, d)


@nb.njit(cache=True, fastmath=False)
def _newton_solve_fixed(tags, dyn, ipt, fac, rhs, sol, res, rho_l, rho_u, it, inv_tl, inv_tu, Ds, Ct, CN, fl, fu, d,
                        w):
    """_newton_rhs, the solve of the plain Riccati recursion compiled for the sizes of tags
    (olado.linalg.riccati_fixed._solve_unconstrained_fixed, with the factors ``fac`` of
    _factor_unconstrained_fixed(_loops) and its bundles ``dyn``, ``ipt``) and _recover_step in
    one call (paper 001 (25) and the recovery below it): the gradient terms q, r and the stage-row
    constants ci go into the work arrays of ``rhs`` (the RHS bundle whose c, x0 are the
    residuals' dyn, x0r), the solution into ``sol`` (the direction's Solution bundle; nu is
    zeroed, as RiccatiFactorization.solve_into does), the slack and multiplier steps into ``d``
    (the direction's Slacks); ``res``: the Residuals bundle, ``it``: the iterate's Slacks, ``w``
    scratch (nw,). Returns (ok, ap, ad) as _recover_step (ok False: a non-finite solution; the
    direction is then partly written). The helpers are called once per pass, not per stage or
    entry: each call of a compiled function with array arguments costs reference counting per
    array (a helper called per box entry made the kernel 4x slower at N = 24)."""
    rhs_ = as_bundle(rhs, RHS)
    q, r, ci = rhs_.q, rhs_.r, rhs_.ci
    sol_ = as_bundle(sol, Solution)
    X, U, nu = sol_.X, sol_.U, sol_.nu
    res = as_bundle(res, Residuals)
    rx, ru, rl, rup = res.rx, res.ru, res.rl, res.rup
    zl, zu = it[2], it[3]
    for i in range(nu.shape[0]):
        for j in range(nu.shape[1]):
            nu[i, j] = 0.0
    _box_rhs(rx, ru, rl, rup, rho_l, rho_u, zl, zu, inv_tl, inv_tu, Ds, CN, q, r, ci)
    _solve_unconstrained_fixed(tags, dyn, ipt, fac, rhs, sol)
    return _recover_all(X, U, Ct, CN, fl, fu, rl, rup, rho_l, rho_u, inv_tl, inv_tu, it, d, w)
