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
