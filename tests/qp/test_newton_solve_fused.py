"""The fused Newton solve of the interior-point QP (kernels._newton_solve_fixed: the right-hand
side, the two Riccati sweeps and the recovery of the eliminated slack and multiplier steps in one
kernel) against the three kernels it replaces (newton_rhs, RiccatiFactorization.solve_into,
recover_step), bit for bit, and against a dense solve of the unreduced Newton system (paper 001
(22))."""

import numpy as np
import pytest

from fixtures.qp_problems import random_qp
from olado.qp.interior_point import MehrotraQP
from olado.qp.interior_point.presolve import _Prepared
from olado.qp.interior_point.step import _StepContext

# (seed, N, n, m, nc, ncN): stage rows on every stage or none, final rows or none, horizons of one
# and of several stage blocks (kernels._BLOCK = 64), the zambezi block sizes n = 6, m = 7
CASES = [(0, 6, 3, 2, 2, 1), (1, 150, 3, 2, 0, 0), (2, 150, 3, 2, 2, 1), (3, 7, 3, 2, 0, 2), (4, 70, 6, 7, 1, 0),
         (5, 1, 2, 1, 0, 0), (6, 129, 6, 7, 0, 1)]


def _context(seed, N, n, m, nc, ncN):
    """A step context at a generic interior point of a random QP (bounds finite on both sides, on
    one side and on none, on x, u, the stage rows and the final rows), and random
    complementarity right-hand sides (0 on the infinite sides)."""
    qp = random_qp(seed, N=N, n=n, m=m, nc=nc, ncN=ncN)
    solver = MehrotraQP()
    P = _Prepared(qp)
    it = solver._initial_point(P)
    rng = np.random.default_rng(100 + seed)
    for a in (it.tl, it.tu, it.zl, it.zu):         # slacks and multipliers spread over 3 decades
        a *= 10.0 ** rng.uniform(-1.5, 1.5, a.shape)
    it.X[1:] += 0.1 * rng.standard_normal(it.X[1:].shape)
    it.U[...] += 0.1 * rng.standard_normal(it.U.shape)
    it.lam[...] += rng.standard_normal(it.lam.shape)
    res, *_ = solver._residuals(P, it)
    ctx = _StepContext(solver, P, it, res, 1.0)
    rho_l = np.where(P.fl, rng.standard_normal(P.nw), 0.0)
    rho_u = np.where(P.fu, rng.standard_normal(P.nw), 0.0)
    assert P.fl.any() and P.fu.any() and (~P.fl).any() and (~P.fu).any() and (P.fl & P.fu).any()
    return P, it, res, ctx, rho_l, rho_u


def _unfused(ctx, *args):
    fused, ctx._fused = ctx._fused, None
    try:
        return ctx._reduced_solve(*args)
    finally:
        ctx._fused = fused


@pytest.mark.parametrize("case", CASES, ids=str)
def test_fused_newton_solve_equals_the_three_kernels_bit_for_bit(case):
    P, it, res, ctx, rho_l, rho_u = _context(*case)
    assert ctx._fused is not None
    P.directions()
    for r in (res, ctx.zero_res):
        for out in (None, P.dir_aff):
            if out is not None:
                out.v[...] = np.nan           # a reused direction: every field is overwritten
            d = ctx._reduced_solve(r, rho_l, rho_u, out)
            v, split = d.v.copy(), d.max_split
            ref = _unfused(ctx, r, rho_l, rho_u)
            assert np.isfinite(v).all()
            assert v.tobytes() == ref.v.tobytes()
            assert split == ref.max_split and d.max_step == ref.max_step


def _newton_map(P, ctx, res, rho_l, rho_u):
    """The unreduced, unregularized Newton system (22) as a dense matrix M and right-hand side b
    (M d = b), probed column by column through the residual map (_StepContext._newton_residual,
    kkt_map: independent of the Riccati code), the rows and columns that are identically zero
    (the infinite sides) left out; returns (M, b, columns kept)."""
    def resid(v):
        e, el, eu, _ = ctx._newton_residual(P.point(v), res, rho_l, rho_u)
        return np.concatenate([e.buf, el, eu])
    size = P.point_layout.size
    b = resid(np.zeros(size))
    M = np.empty((b.size, size))
    for j in range(size):
        v = np.zeros(size)
        v[j] = 1.0
        M[:, j] = b - resid(v)
    # the slacks and multipliers of the infinite sides are not unknowns (0 in every direction)
    cols = np.ones(size, bool)
    nw = P.nw
    for j, f in enumerate((P.fl, P.fu, P.fl, P.fu)):
        cols[size - (4 - j) * nw:size - (3 - j) * nw] = f
    rows = np.abs(M[:, cols]).max(axis=1) > 0
    assert not b[~rows].any()
    return M[np.ix_(rows, cols)], b[rows], cols


@pytest.mark.parametrize("case", CASES[:1] + CASES[3:4] + CASES[5:6], ids=str)
def test_fused_newton_solve_solves_the_dense_newton_system(case):
    P, it, res, ctx, rho_l, rho_u = _context(*case)
    d = ctx._reduced_solve(res, rho_l, rho_u)
    v = d.v.copy()
    M, b, cols = _newton_map(P, ctx, res, rho_l, rho_u)
    assert M.shape[0] == M.shape[1]
    ref = np.linalg.solve(M, b)
    assert not v[~cols].any()                  # the infinite sides' slacks and multipliers stay 0
    scale = np.abs(ref).max()
    assert np.abs(v[cols] - ref).max() <= 1e-7 * scale   # the regularization 1e-10 and rounding


def test_non_finite_newton_step_is_reported_by_both_paths():
    P, it, res, ctx, rho_l, rho_u = _context(*CASES[0])
    rho_l[np.flatnonzero(P.fl)[3]] = np.nan
    with pytest.raises(FloatingPointError, match="non-finite Newton step"):
        ctx._reduced_solve(res, rho_l, rho_u)
    with pytest.raises(FloatingPointError, match="non-finite Newton step"):
        _unfused(ctx, res, rho_l, rho_u)


def _ratio(t, dt):
    """min(-t / dt) over dt < 0, plainly in numpy (1e30 when no step is negative)."""
    neg = dt < 0
    return min(1e30, float((-t[neg] / dt[neg]).min())) if neg.any() else 1e30


@pytest.mark.parametrize("case", CASES, ids=str)
@pytest.mark.parametrize("fused", [True, False])
def test_step_lengths_are_the_plain_ratio_tests(case, fused):
    """The recovery's step lengths (kernels._slack_steps skips the divisions that cannot lower
    the minimum) are the plain ratio tests over the direction's slacks and multipliers, bit for
    bit, on both paths; also with steps made tiny so that most divisions count."""
    P, it, res, ctx, rho_l, rho_u = _context(*case)
    for scale in (1.0, 1e-12):
        d = ctx._reduced_solve(res, scale * rho_l, scale * rho_u) if fused else \
            _unfused(ctx, res, scale * rho_l, scale * rho_u)
        ap = min(_ratio(it.tl, d.tl), _ratio(it.tu, d.tu))
        ad = min(_ratio(it.zl, d.zl), _ratio(it.zu, d.zu))
        assert d.max_split == (ap, ad)
