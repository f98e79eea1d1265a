"""The compiled passes of olado.solvers.certificate_kernels against the numpy forms they replace,
bit for bit, on random stage data of many shapes with the awkward entries mixed in (NaN, inf,
-0.0, fixed variables, infinite bounds, equal entries): the stage Lagrangian gradient
(common.stage_gradient_terms), the Result's stationarity and violation (residuals.stage_kkt), the
certificate's KKT figures, its spot-check formulas and the largest violation (the reference
forms of tests/solvers/test_certificate_fastpath.py)."""

import types

import numpy as np
import pytest

from olado.solvers import certificate as C
from olado.solvers import certificate_kernels as K
from olado.solvers.common import stage_gradient_terms, stage_gradient_terms_reference
from olado.solvers.diagnosis import largest_violation, largest_violation_of, violation_arrays
from olado.solvers.sqp.residuals import stage_kkt, stage_kkt_reference
from olado.solvers.sqp.state import BoundMultipliers, Multipliers

from test_certificate_fastpath import _reference_figures

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")       # the numpy references on NaN and inf

SHAPES = [(1, 2, 2, 0, 0), (3, 2, 3, 1, 0), (5, 6, 7, 0, 0), (4, 3, 2, 2, 1), (6, 9, 8, 3, 2), (2, 12, 10, 1, 3),
          (7, 4, 5, 4, 1)]


def _same(a, b):
    """Equal arrays, NaN where NaN (of either sign), the signs of zeros alike."""
    nan = np.isnan(a)
    return (np.array_equal(a, b, equal_nan=True)
            and np.array_equal(np.signbit(a[~nan]), np.signbit(np.asarray(b)[~nan])))


def _awkward(rng, shape, share=0.1):
    """Random numbers with NaN, inf, -0.0, 0.0 and repeated entries mixed in."""
    a = rng.standard_normal(shape) * 10.0 ** rng.integers(-8, 4, shape)
    flat = a.reshape(-1)
    picks = rng.random(flat.size) < share
    flat[picks] = rng.choice([np.nan, np.inf, -np.inf, -0.0, 0.0, 1.0], picks.sum())
    return a


def _case(seed, N, n, m, r, rN, awkward=False):
    """A fake problem and point of these sizes: bounds with infinite sides and fixed variables."""
    rng = np.random.default_rng(seed)
    draw = (lambda *s: _awkward(rng, s)) if awkward else (lambda *s: rng.standard_normal(s))
    p = types.SimpleNamespace(N=N, n=n, m=m, r=r, rN=rN, x0=rng.standard_normal(n),
                              stage_equality_mask=rng.random(r) < 0.4, final_equality_mask=rng.random(rN) < 0.4)

    def bounds(shape):
        lo, hi = -rng.random(shape) * 2, rng.random(shape) * 2
        lo[rng.random(shape) < 0.3] = -np.inf
        hi[rng.random(shape) < 0.3] = np.inf
        fixed = rng.random(shape) < 0.15
        hi[fixed] = lo[fixed] = np.where(np.isfinite(lo[fixed]), lo[fixed], 0.5)
        return lo, hi

    p.x_lower, p.x_upper = bounds((N + 1, n))
    p.u_lower, p.u_upper = bounds((N, m))
    X = np.clip(draw(N + 1, n), p.x_lower - 0.1, p.x_upper + 0.1)
    U = np.clip(draw(N, m), p.u_lower - 0.1, p.u_upper + 0.1)
    X[rng.random(X.shape) < 0.2] = -0.0
    pt = types.SimpleNamespace(X=X, U=U, lx=draw(N, n), lu=draw(N, m), lN=draw(n), A=draw(N, n, n), B=draw(N, n, m),
                               Cx=draw(N, r, n), Cu=draw(N, r, m), CN=draw(rN, n), h=draw(N, n), g=draw(N, r),
                               gN=draw(rN), J=float(rng.standard_normal()))
    lam, Lg, LgN = draw(N, n), draw(N, r), draw(rN)
    return p, pt, lam, Lg, LgN, rng


@pytest.mark.parametrize("awkward", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_stage_gradient_terms_equal_numpy_s_einsum(shape, awkward):
    for seed in range(5):
        p, pt, lam, Lg, LgN, _ = _case(seed, *shape, awkward=awkward)
        for a, b in zip(stage_gradient_terms(p, pt, lam, Lg, LgN), stage_gradient_terms_reference(p, pt, lam, Lg, LgN)):
            assert _same(a, b)


@pytest.mark.parametrize("awkward", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_stage_kkt_equals_the_reference(shape, awkward):
    for seed in range(5):
        p, pt, lam, Lg, LgN, rng = _case(seed, *shape, awkward=awkward)
        mult = Multipliers(np.vstack([np.zeros(p.n), lam]), Lg, LgN)
        z = BoundMultipliers(*(np.abs(_awkward(rng, s.shape)) for s in (pt.X, pt.X, pt.U, pt.U)))
        a, b = stage_kkt(p, pt, mult, z), stage_kkt_reference(p, pt, mult, z)
        assert repr(a[:3]) == repr(b[:3])                   # NaN == NaN, -0.0 != 0.0
        for x, y in zip(a.bounds, b.bounds, strict=True):
            assert _same(x, y)


@pytest.mark.parametrize("awkward", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_figures_equal_the_reference(shape, awkward):
    for seed in range(5):
        p, pt, lam, Lg, LgN, _ = _case(seed, *shape, awkward=awkward)
        bounds = C.StageBounds.of(p)
        W = (np.maximum(1.0, np.abs(pt.X)), np.maximum(1.0, np.abs(pt.U)))
        S = max(1.0, abs(pt.J))
        try:
            ref = _reference_figures(p, pt, bounds, W, S, lam, Lg, LgN, "solver")
        except IndexError:          # every figure NaN and no controls: the reference fails alike
            with pytest.raises(IndexError):
                C._figures(p, pt, bounds, W, S, lam, Lg, LgN, "solver")
            continue
        assert repr(C._figures(p, pt, bounds, W, S, lam, Lg, LgN, "solver")) == repr(ref)


@pytest.mark.parametrize("awkward", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_largest_violation_equals_the_violation_arrays(shape, awkward):
    for seed in range(5):
        p, pt, *_ = _case(seed, *shape, awkward=awkward)
        assert repr(largest_violation_of(p, pt)) == repr(largest_violation(violation_arrays(p, pt)))


def _spot_reference(vals, an, size, h):
    """The spot check's formulas in numpy (the certificate's form before the compiled pass)."""
    v1, m1, v2, m2 = (vals[:, i] for i in range(4))
    d_h, d_2h = (v1 - m1) / (2 * h), (v2 - m2) / (4 * h)
    d5 = (4 * d_h - d_2h) / 3
    av = np.abs(vals)
    rounding = C._EPS * (av[:, 0] + av[:, 1] + av[:, 2] + av[:, 3]) / h
    scale = np.maximum(size, np.abs(d5))
    allowed = C.CHECK_RTOL * scale + 10 * (np.abs(d_h - d_2h) + rounding) + 1e-300
    err = np.abs(d5 - an)
    rel = err / np.maximum(scale, 1e-300)
    worst = max(0.0, float(np.where(err > 10 * rounding, rel, 0.0).max()))
    ratio = (err / allowed).ravel()
    j = int(np.argmax(ratio))
    return worst, j, float(ratio[j]), *(float(a.ravel()[j]) for a in (d5, an, rel))


@pytest.mark.parametrize("share", [0.0, 0.02, 0.3])
def test_spot_verdict_equals_the_numpy_formulas(share):
    rng = np.random.default_rng(11)
    for D, L in ((1, 1), (2, 7), (2, 300), (3, 41)):
        for _ in range(10):
            vals = 1.0 + 1e-3 * rng.standard_normal((D, 4, L))
            an = (vals[:, 0] - vals[:, 1]) / 2e-3 * (1 + 1e-6 * rng.standard_normal((D, L)))
            size = np.abs(an) * rng.random((D, L))
            for a in (vals, an, size):
                flat = a.reshape(-1)
                picks = rng.random(flat.size) < share
                flat[picks] = rng.choice([np.nan, np.inf, 0.0, -0.0], picks.sum())
            out = np.empty(6)
            K.spot_verdict(vals, an, size, C.CHECK_STEP, C._EPS, C.CHECK_RTOL, out)
            got = (float(out[0]), int(out[1]), *(float(x) for x in out[2:]))
            assert repr(got) == repr(_spot_reference(vals, an, size, C.CHECK_STEP))


@pytest.mark.parametrize("awkward", [False, True])
@pytest.mark.parametrize("shape", SHAPES + [(3, 1, 1, 1, 1), (2, 17, 33, 2, 0)])
def test_spot_points_equal_the_directions_and_the_numpy_points(shape, awkward):
    """The compiled directions and shifted points against the directions drawn one by one
    (certificate._direction) and the points built in numpy (_stacked_shifted_values without
    points)."""
    for seed in range(3):
        p, pt, *_ = _case(seed, *shape, awkward=awkward)
        bounds = C.StageBounds.of(p)
        W = (np.maximum(1.0, np.abs(pt.X)), np.maximum(1.0, np.abs(pt.U)))
        h = C.CHECK_STEP
        draw = C._uniform_draws(C.CHECK_SEED, C.CHECK_DIRECTIONS, pt.X.size + pt.U.size)
        Vx, Vu, (Xs, Us, ends) = C._spot_points(draw, pt, bounds, W, h)
        rng = np.random.default_rng(C.CHECK_SEED)
        one_by_one = [C._direction(rng, pt, bounds, W, h) for _ in range(C.CHECK_DIRECTIONS)]
        assert _same(Vx, np.array([v[0] for v in one_by_one])) and _same(Vu, np.array([v[1] for v in one_by_one]))
        steps = (C._STEPS * h)[None, :, None, None]
        Xp, Up = pt.X + steps * Vx[:, None], pt.U + steps * Vu[:, None]
        P = Vx.shape[0] * len(C._SHIFTS)
        assert _same(Xs, Xp[:, :, :-1].reshape(P * p.N, p.n)) and _same(Us, Up.reshape(P * p.N, p.m))
        assert _same(ends, Xp[:, :, -1].reshape(P, p.n))
