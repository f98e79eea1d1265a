"""The compiled passes of olado.solvers.ipm.kernels behind barrier.Bounds give, bit for bit, what
the numpy expressions they replace give (kept here as the reference), on random data with zeros,
signed zeros, infinities and NaNs, infinite bound sides and tiny slacks; and Bounds' per-point
cache follows the point and the bound moves."""

import numpy as np
import pytest

from olado.solvers.ipm.barrier import KAPPA_D, Bounds

EPS = np.finfo(float).eps


# ---------------------------------------------------------------------------- numpy reference
def ref_slacks(b, v):
    return np.where(b.has_lo, v - b.lo, 1.0), np.where(b.has_hi, b.hi - v, 1.0)


def ref_barrier(b, v, mu):
    sl, su = ref_slacks(b, v)
    if sl.size and (sl.min() <= 0 or su.min() <= 0):
        return np.inf, None
    value = (-mu * (np.log(sl).sum() + np.log(su).sum())
             + KAPPA_D * mu * (b.one_lo_f @ sl + b.one_hi_f @ su))
    lo_f, hi_f = b.has_lo.astype(float), b.has_hi.astype(float)
    grad = mu * (hi_f / su - lo_f / sl) + KAPPA_D * mu * (b.one_lo_f - b.one_hi_f)
    return value, grad


def ref_dual_step(b, v, dv, zl, zu, mu):
    sl, su = ref_slacks(b, v)
    return (np.where(b.has_lo, mu / sl - zl - zl / sl * dv, 0.0),
            np.where(b.has_hi, mu / su - zu + zu / su * dv, 0.0))


def ref_max_step(b, v, dv, tau):
    sl, su = ref_slacks(b, v)
    a_lo = np.where(b.has_lo & (dv < 0), -tau * sl / dv, 1.0)
    a_hi = np.where(b.has_hi & (dv > 0), tau * su / dv, 1.0)
    return min(1.0, float(a_lo.min(initial=1.0)), float(a_hi.min(initial=1.0)))


def ref_max_dual_step(z, dz, tau):
    return min(1.0, float(np.where(dz < 0, -tau * z / dz, 1.0).min(initial=1.0)))


def ref_safeguard(b, v, zl, zu, mu, ks=1e10):
    sl, su = ref_slacks(b, v)
    return (np.where(b.has_lo, np.clip(zl, mu / (ks * sl), ks * mu / sl), 0.0),
            np.where(b.has_hi, np.clip(zu, mu / (ks * su), ks * mu / su), 0.0))


def ref_complementarity(b, v, zl, zu, mu):
    sl, su = ref_slacks(b, v)
    parts = [np.abs(sl * zl - mu)[b.has_lo], np.abs(su * zu - mu)[b.has_hi]]
    return max((float(p.max()) for p in parts if p.size), default=0.0)


def ref_move_tiny(b, v):
    lo, hi = b.lo.copy(), b.hi.copy()
    tiny = EPS * np.maximum(1.0, np.abs(v))
    lo_tiny = b.has_lo & (v - lo < tiny)
    hi_tiny = b.has_hi & (hi - v < tiny)
    lo[lo_tiny] -= EPS ** 0.75 * np.maximum(1.0, np.abs(lo[lo_tiny]))
    hi[hi_tiny] += EPS ** 0.75 * np.maximum(1.0, np.abs(hi[hi_tiny]))
    return lo, hi, int(lo_tiny.sum() + hi_tiny.sum())


# ---------------------------------------------------------------------------- data
def _bounds(rng, size):
    lo = rng.normal(size=size) - 2.0
    hi = lo + rng.uniform(0.0, 5.0, size=size)
    lo[rng.random(size) < 0.3] = -np.inf
    hi[rng.random(size) < 0.3] = np.inf
    return Bounds(lo, hi, np.isfinite(lo), np.isfinite(hi))


def _inside(rng, b):
    """A point strictly inside, a few entries within rounding of a bound."""
    size = b.lo.size
    base = np.where(b.has_lo, b.lo, np.where(b.has_hi, b.hi - 1.0, 0.0))
    width = np.where(b.has_lo & b.has_hi, b.hi - b.lo, 3.0)
    v = base + width * rng.uniform(0.05, 0.95, size=size)
    near = rng.random(size) < 0.05
    v[near & b.has_lo] = b.lo[near & b.has_lo] + EPS * 0.1
    return v


def _special(rng, x, share=0.05):
    """x with some entries replaced by 0, -0, +-inf, NaN."""
    x = x.copy()
    pick = rng.random(x.size) < share
    x[pick] = rng.choice([0.0, -0.0, np.inf, -np.inf, np.nan], size=int(pick.sum()))
    return x


@pytest.fixture(params=range(6))
def case(request):
    rng = np.random.default_rng(request.param)
    b = _bounds(rng, 4001)
    v = _inside(rng, b)
    zl, zu = rng.exponential(size=v.size), rng.exponential(size=v.size)
    dv = rng.normal(size=v.size) * 10.0 ** rng.integers(-12, 3, size=v.size)
    if request.param >= 3:       # special values in the multipliers and the step
        zl, zu, dv = _special(rng, zl), _special(rng, zu), _special(rng, dv)
    return rng, b, v, zl, zu, dv


def test_slacks_barrier_and_sigma_are_the_numpy_forms(case):
    _, b, v, zl, zu, _ = case
    for x, y in zip(b.slacks(v), ref_slacks(b, v)):
        assert np.array_equal(x, y)
    for mu in (0.1, 1e-9):
        value, grad = b.barrier(v, mu)
        rvalue, rgrad = ref_barrier(b, v, mu)
        assert value == rvalue and np.array_equal(grad, rgrad)
        assert b.barrier_value(v, mu) == rvalue


def test_outside_the_bounds_the_barrier_is_infinite(case):
    _, b, v, _, _, _ = case
    w = v.copy()
    i = int(np.flatnonzero(b.has_lo)[0])
    w[i] = b.lo[i] - 1.0
    assert b.barrier(w, 0.1) == (np.inf, None) and b.barrier_value(w, 0.1) == np.inf
    assert ref_barrier(b, w, 0.1) == (np.inf, None)


def test_steps_safeguard_and_complementarity_are_the_numpy_forms(case):
    _, b, v, zl, zu, dv = case
    with np.errstate(all="ignore"):
        assert np.array_equal(b.sigma(v, zl, zu), np.divide(zl, ref_slacks(b, v)[0]) + zu / ref_slacks(b, v)[1],
                              equal_nan=True)
        for mu in (0.1, 0.0, 1e-11):
            for x, y in zip(b.dual_step(v, dv, zl, zu, mu), ref_dual_step(b, v, dv, zl, zu, mu)):
                assert np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y))
            for x, y in zip(b.safeguard(v, zl, zu, mu), ref_safeguard(b, v, zl, zu, mu)):
                assert np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y))
            got, want = b.complementarity(v, zl, zu, mu), ref_complementarity(b, v, zl, zu, mu)
            assert got == want or (np.isnan(got) and np.isnan(want))
        for tau in (0.99, 1.0 - 1e-9):
            got, want = b.max_step(v, dv, tau), ref_max_step(b, v, dv, tau)
            assert got == want or (np.isnan(got) and np.isnan(want))
            for z, dz in ((zl, dv), (zu, -dv)):
                got, want = Bounds.max_dual_step(z, dz, tau), ref_max_dual_step(z, dz, tau)
                assert got == want or (np.isnan(got) and np.isnan(want))


def test_clip_keeps_numpys_rules_for_nan_and_crossed_bounds():
    b = Bounds(np.zeros(6), np.full(6, np.inf), np.ones(6, bool), np.zeros(6, bool))
    v = np.array([1.0, 1e-30, 1e30, 2.0, 3.0, 0.5])
    zl = np.array([np.nan, 1e40, 1e-40, np.inf, 0.0, -0.0])
    zu = np.zeros(6)
    for mu in (0.1, np.nan, 0.0):
        for x, y in zip(b.safeguard(v, zl, zu, mu), ref_safeguard(b, v, zl, zu, mu)):
            assert np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y))


def test_move_tiny_moves_the_bounds_as_numpy_does_and_drops_the_cache():
    rng = np.random.default_rng(7)
    b = _bounds(rng, 2001)
    v = _inside(rng, b)
    near_hi = b.has_hi & (rng.random(v.size) < 0.05)
    v[near_hi] = b.hi[near_hi] - EPS * 0.1 * np.maximum(1.0, np.abs(b.hi[near_hi]))
    sl_before = b.slacks(v)[0]
    lo, hi, count = ref_move_tiny(b, v)
    assert count > 0
    assert b.move_tiny(v) == count
    assert np.array_equal(b.lo, lo) and np.array_equal(b.hi, hi)
    sl_after = b.slacks(v)[0]
    assert sl_after is not sl_before and np.array_equal(sl_after, ref_slacks(b, v)[0])
    lo, hi, count = ref_move_tiny(b, v)          # moved again where the move stays below rounding
    assert b.move_tiny(v) == count and np.array_equal(b.lo, lo) and np.array_equal(b.hi, hi)


def test_the_cache_keeps_the_two_latest_points():
    rng = np.random.default_rng(3)
    b = _bounds(rng, 101)
    v1, v2, v3 = (_inside(rng, b) for _ in range(3))
    s1, s2 = b.slacks(v1), b.slacks(v2)
    assert b.slacks(v1) is s1 and b.slacks(v2) is s2
    b.slacks(v3)
    assert b.slacks(v2) is s2 and b.slacks(v1) is not s1       # v1 was the oldest
    assert np.array_equal(b.slacks(v1)[0], ref_slacks(b, v1)[0])
    # a copy is another point: equal values, its own entry
    w = v2.copy()
    assert b.slacks(w) is not s2 and np.array_equal(b.slacks(w)[1], s2[1])


# ---------------------------------------------------------------------------- the fused passes
def test_fused_dual_step_safeguard_and_sigma_are_the_numpy_forms(case):
    """Bounds.dual_step_length, safeguard_step and sigma_blocks (one pass each) against the
    numpy forms of the separate steps they fuse."""
    from olado.solvers.ipm.barrier import Layout

    _, b, v, zl, zu, dv = case
    with np.errstate(all="ignore"):
        for mu, tau in ((0.1, 0.99), (1e-11, 1.0 - 1e-9)):
            dzl, dzu, alpha_z = b.dual_step_length(v, dv, zl, zu, mu, tau)
            rl, ru = ref_dual_step(b, v, dv, zl, zu, mu)
            assert np.array_equal(dzl, rl, equal_nan=True) and np.array_equal(dzu, ru, equal_nan=True)
            want = min(ref_max_dual_step(zl, rl, tau), ref_max_dual_step(zu, ru, tau))
            assert alpha_z == want or (np.isnan(alpha_z) and np.isnan(want))
            for x, y in zip(b.safeguard_step(v, zl, zu, dzl, dzu, alpha_z, mu),
                            ref_safeguard(b, v, zl + alpha_z * rl, zu + alpha_z * ru, mu)):
                assert np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y))

    class P:            # a layout of 4001 = 40 (n + m + ni) + 1: N = 40, n = 50, m = 30, ni = 20, niN = 1
        N, n, m, x0 = 40, 50, 30, np.zeros(50)
        stage_equality_mask = np.array([False] * 20)
        final_equality_mask = np.array([False])

    L = Layout(P)
    assert L.size == v.size
    with np.errstate(all="ignore"):
        ref = L.split(np.divide(zl, ref_slacks(b, v)[0]) + zu / ref_slacks(b, v)[1], np.zeros(L.n))
    for x, y in zip(b.sigma_blocks(v, zl, zu, L), ref):
        assert np.array_equal(x, y, equal_nan=True)


@pytest.mark.parametrize("size", [0, 1, 7, 8, 9, 127, 128, 129, 255, 1000, 8192, 8193, 100_003])
def test_pairwise_sums_are_numpys(size):
    """numpy_sums.abs_sum / pairwise_sum and the residual norms sum as numpy does (pairwise), bit
    for bit."""
    from olado.linalg import numpy_sums
    from olado.solvers.ipm.newton import Residuals

    rng = np.random.default_rng(size)
    a = rng.normal(size=size) * 10.0 ** rng.uniform(-10, 10, size=size)
    assert numpy_sums.abs_sum(a) == np.abs(a).sum()
    assert numpy_sums.pairwise_sum(a, 0, a.size, False) == a.sum()
    if size % 7 == 0 and size:            # a C-contiguous 2-D array (the SQP's step sizes): the flat sum
        assert numpy_sums.abs_sum(a.reshape(7, -1)[1:]) == np.abs(a.reshape(7, -1)[1:]).sum()
    res = Residuals(a[: size // 2].reshape(-1, 1), rng.normal(size=(3, 2)), np.zeros(0), np.zeros((3, 0)),
                    -a[size // 2:])
    want_l1 = float(sum(np.abs(x).sum() for x in res))
    want_max = max((float(np.abs(x).max()) for x in res if x.size), default=0.0)
    assert res.norms() == (want_l1, want_max)


def test_residual_max_keeps_pythons_rule_for_nan():
    from olado.solvers.ipm.newton import Residuals

    for arrays in ((np.array([[np.nan, 1.0]]), np.array([[2.0]])), (np.array([[1.0]]), np.array([[np.nan, 5.0]]))):
        res = Residuals(arrays[0], arrays[1], np.zeros(0), np.zeros((1, 0)), np.zeros(0))
        want = max((float(np.abs(x).max()) for x in res if x.size), default=0.0)
        got = res.max()
        assert got == want or (np.isnan(got) and np.isnan(want))


def test_barrier_direction_and_dual_terms_are_the_numpy_forms():
    """The compiled Newton right-hand side and dual infeasibility against the numpy assembly they
    replace (solver.objective_gradient + Bounds.gradient split and packed; stage_gradient_terms)."""
    from olado.solvers.common import stage_gradient_terms
    from olado.solvers.ipm import kernels

    rng = np.random.default_rng(11)
    N, n, m, ni, niN = 7, 4, 3, 2, 1
    size = N * (n + m + ni) + niN
    b = _bounds(rng, size)
    v = _inside(rng, b)
    sl, su = b.slacks(v)
    lx, lu, lN = rng.normal(size=(N, n)), rng.normal(size=(N, m)), rng.normal(size=n)
    mu, s_obj = 0.01, 0.37
    q, r = np.empty((N + 1, n)), np.empty((N, m))
    gs, gsN, grad = np.empty((N, ni)), np.empty(niN), np.empty(size)
    kernels.barrier_direction(s_obj, lx, lN, lu, sl, su, b.has_lo, b.has_hi, mu, KAPPA_D * mu, q, r, gs, gsN, grad)
    lo_f, hi_f = b.has_lo.astype(float), b.has_hi.astype(float)
    with np.errstate(divide="ignore"):      # a slack at 0 (a point within rounding of its bound)
        bg = mu * (hi_f / su - lo_f / sl) + KAPPA_D * mu * (b.one_lo_f - b.one_hi_f)    # ref_barrier's gradient
    qo = np.concatenate([lx, lN[None]]) * s_obj
    bx = np.concatenate([np.zeros((1, n)), bg[:N * n].reshape(N, n)])
    assert np.array_equal(q, qo + bx)
    assert np.array_equal(r, s_obj * lu + bg[N * n:N * (n + m)].reshape(N, m))
    assert np.array_equal(gs.ravel(), bg[N * (n + m):N * (n + m + ni)]) and np.array_equal(gsN, bg[-niN:])
    assert np.array_equal(grad, np.concatenate([(qo + bx)[1:].ravel(), r.ravel(), gs.ravel(), gsN]))

    class Pt:
        pass

    pt = Pt()
    pt.lx, pt.lu, pt.lN = lx, lu, lN
    pt.A, pt.B = rng.normal(size=(N, n, n)), rng.normal(size=(N, n, m))
    pt.Cx, pt.Cu, pt.CN = rng.normal(size=(N, ni, n)), rng.normal(size=(N, ni, m)), rng.normal(size=(niN, n))

    class P:
        pass

    p = P()
    p.N, p.n, p.r, p.rN = N, n, ni, niN
    lam = rng.normal(size=(N, n))
    yd, ydN = -rng.exponential(size=(N, ni)), -rng.exponential(size=niN)
    zl, zu = rng.exponential(size=size), rng.exponential(size=size)
    rx, ru = stage_gradient_terms(p, pt, lam, yd, ydN, sigma=s_obj)
    dual = np.concatenate([rx[1:].ravel(), ru.ravel(), -yd.ravel(), -ydN]) - zl + zu
    EA, EB = np.einsum("kij,ki->kj", pt.A, lam), np.einsum("kij,ki->kj", pt.B, lam)
    ECx, ECu = np.einsum("kij,ki->kj", pt.Cx, yd), np.einsum("kij,ki->kj", pt.Cu, yd)
    nu, nuN = np.zeros((N, 0)), np.zeros(0)
    mx, zsum, ysum = kernels.dual_infeasibility(s_obj, lx, lu, lN, EA, EB, lam, ECx, ECu, pt.CN.T @ ydN, True, True,
                                                yd, ydN, zl, zu, nu, nuN)
    assert mx == np.abs(dual).max(initial=0.0)
    assert zsum == np.abs(zl).sum() + np.abs(zu).sum()
    assert ysum == sum(float(np.abs(a).sum()) for a in (lam, nu, nuN, yd, ydN))
