"""The SQP's compiled passes (olado.solvers.sqp.kernels) against the numpy forms they replace:
the same numbers bit for bit (numpy's arithmetic order: pairwise sums, sequential einsum
contractions), the same QP entry for entry, and the same iterates of whole solves with the numpy
forms patched back in."""

from pathlib import Path

import numpy as np
import pytest

from olado.config import load_config, make_solver
from olado.solvers.common import einsum_sequential
from olado.problems.suites import load_suite
from olado.problems.zambezi import zambezi_problem
from olado.solvers.sqp import kernels, merit as merit_mod, phases, residuals, step as step_mod
from olado.solvers.sqp.merit import Merit
from olado.solvers.sqp.state import BoundMultipliers, ConstraintMasks, Multipliers, Point

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _same(a, b):
    """Bit for bit (NaNs at the same places; +0.0 and -0.0 are not told apart)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("shape", [(0, 6), (5, 1), (24, 6), (31, 7), (121, 6), (1500, 6), (12000, 6)])
def test_weighted_sum_is_numpys_pairwise_sum(shape):
    rng = np.random.default_rng(sum(shape))
    w, v = rng.random(shape) * 1e3, rng.standard_normal(shape) * (rng.random(shape) < 0.6)
    assert kernels._weighted(w, v, np.empty(w.size)) == float((w * v).sum())


def _random_point(rng, N=20, n=4, m=3, r=2, rN=3):
    class P:
        pass
    pt = P()
    pt.X, pt.U = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))
    pt.h, pt.g, pt.gN = rng.standard_normal((N, n)), rng.standard_normal((N, r)), rng.standard_normal(rN)
    pt.g[0, 0] = 0.0
    prob = P()
    prob.N, prob.n, prob.m, prob.r, prob.rN = N, n, m, r, rN
    prob.x_lower, prob.x_upper = np.full((N + 1, n), -0.5), np.full((N + 1, n), 0.5)
    prob.x_lower[:, 0] = -np.inf
    prob.u_lower, prob.u_upper = np.full((N, m), -1.0), np.full((N, m), np.inf)
    masks = ConstraintMasks(np.array([True, False]), np.array([False, True]), np.array([True, False, True]),
                            np.array([False, True, False]))
    return prob, pt, masks


def test_violations_and_penalty_are_the_numpy_forms():
    rng = np.random.default_rng(3)
    prob, pt, masks = _random_point(rng)
    merit = Merit(prob, masks)
    compiled, worst, _ = merit._violations(pt)
    merit_mod_compiled = merit_mod._compiled
    try:
        merit_mod._compiled = lambda q: False
        reference, ref_worst, _ = Merit(prob, masks)._violations(pt)
        weights = tuple(rng.random(v.shape) for v in reference)
        ref_penalty = Merit(prob, masks).penalty(pt, weights)
    finally:
        merit_mod._compiled = merit_mod_compiled
    assert all(_same(a, b) for a, b in zip(compiled, reference))
    assert worst == ref_worst
    assert merit.penalty(pt, weights) == ref_penalty
    assert merit.penalty(pt, weights) == ref_penalty        # the kept value


def _multipliers(rng, p):
    mult = Multipliers(rng.standard_normal((p.N + 1, p.n)), rng.standard_normal((p.N, p.r)), rng.standard_normal(p.rN))
    bounds = BoundMultipliers(*(rng.random(s) for s in ((p.N + 1, p.n), (p.N + 1, p.n), (p.N, p.m), (p.N, p.m))))
    return mult, bounds


def _problems():
    """zambezi12 (no constraint rows) and two problems with stage and final constraint rows."""
    out = [zambezi_problem("zambezi12", N=24)]
    entries = {e.name: e for e in load_suite("robustness")}
    for name in ("free-flying-robot", "alp-rider"):
        out.append(entries[name].build()[0])
    return out


@pytest.fixture(scope="module")
def points():
    pts = []
    for p in _problems():
        U = np.clip(p.initial_guess(), p.u_lower, p.u_upper)
        pts.append((p, Point(p, p.simulate(U), U)))
    return pts


def test_kkt_residual_is_the_numpy_form(points):
    rng = np.random.default_rng(5)
    for p, pt in points:
        assert einsum_sequential(p.n, p.m)
        for _ in range(3):
            mult, bounds = _multipliers(rng, p)
            assert residuals.kkt_residual(p, pt, mult, bounds) == residuals.kkt_residual_reference(p, pt, mult, bounds)


def test_complementarity_is_the_numpy_form(points):
    rng = np.random.default_rng(19)
    for p, pt in points:
        for _ in range(3):
            mult, bounds = _multipliers(rng, p)
            bounds = BoundMultipliers(*(b - 0.3 for b in bounds))      # some negative parts too
            assert residuals.stage_complementarity(p, pt, mult, bounds) == \
                residuals.stage_complementarity_reference(p, pt, mult, bounds)
        bounds.zl_u[0, 0] = np.nan                                      # numpy's part is NaN: Python's max passes it
        assert residuals.stage_complementarity(p, pt, mult, bounds) == \
            residuals.stage_complementarity_reference(p, pt, mult, bounds)


def test_einsum_contraction_order():
    """The kernels' sequential contraction is numpy's einsum wherever einsum_sequential says so."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        N, ni, m = (int(v) for v in rng.integers((1, 0, 2), (40, 30, 16)))
        M, v = rng.standard_normal((N, ni, m)), rng.standard_normal((N + 1, ni))
        out = np.array([[kernels._contract.py_func(M, v, 1, k, j) for j in range(m)] for k in range(N)])
        assert _same(out.reshape(N, m), np.einsum("kij,ki->kj", M, v[1:]))


def _assert_same_qp(a, b):
    for name in ("Q", "R", "S", "q", "r", "A", "B", "c", "x0", "E", "F", "e", "EN", "eN", "C", "c_lower", "c_upper",
                 "CN", "cN_lower", "cN_upper", "x_lower", "x_upper", "u_lower", "u_upper"):
        assert _same(getattr(a, name), getattr(b, name)), name
    assert (a.N, a.n, a.m) == (b.N, b.n, b.m)


@pytest.mark.parametrize("shifted", [False, True])
def test_assembled_qp_is_build_qp_of_the_shifted_blocks(points, shifted):
    rng = np.random.default_rng(11)
    for p, pt in points:
        nz = p.n + p.m
        M = rng.standard_normal((p.N, nz, nz)); Bk = M + M.transpose(0, 2, 1)
        BN = np.eye(p.n) * 2.0
        masks = ConstraintMasks.of(p)
        if shifted:
            d = rng.random(p.N + 1)
            Bd = Bk + d[:-1][:, None, None] * np.eye(nz)
            BNd = BN + d[-1] * np.eye(p.n)
        else:
            d, Bd, BNd = None, Bk, BN
        _assert_same_qp(step_mod.assemble_qp(p, pt, Bk, BN, d, masks), step_mod.build_qp(p, pt, Bd, BNd, masks))


def _fixed_case(rng, N, n, m, clock_bounds, clock_offsets):
    """Random dynamics with a parameter stage (x_1 copies x0's first components), an Euler-like
    position fixed one stage, a clock (a state copied from stage to stage, no control) and a
    singleton final row."""
    A = rng.standard_normal((N, n, n)); B = rng.standard_normal((N, n, m))
    A[0] = 0.0; A[0, 0, 0] = A[0, 1, 1] = 1.0; B[0, :2] = 0.0
    A[:, -1] = 0.0; A[:, -1, -1] = 1.0; B[:, -1] = 0.0          # the clock
    c = 0.1 * rng.standard_normal((N, n)); c[0, :2] = 0.0; c[:, -1] = 0.5 if clock_offsets else 0.0
    x0 = rng.standard_normal(n)
    xl, xu = np.full((N + 1, n), -np.inf), np.full((N + 1, n), np.inf)
    xl[1, 0] = x0[0]; xu[1, 1] = x0[1] + 1e-14; xl[N, 0] = 5.0
    if clock_bounds:
        xu[:, -1] = 100.0
    xl[0], xu[0] = -np.inf, np.inf
    EN = np.zeros((2, n)); EN[0, 1] = 2.0; EN[1, :2] = 1.0
    eN = np.array([-0.4, 0.3])
    xl[N, 1] = 0.2
    X = rng.standard_normal((N + 1, n))
    return A, B, c, x0, xl, xu, EN, eN, X


@pytest.mark.parametrize("clock_bounds", [False, True])
@pytest.mark.parametrize("clock_offsets", [False, True])
def test_fixed_bound_rule_is_the_numpy_form(clock_bounds, clock_offsets):
    rng = np.random.default_rng(13)
    for N in (2, 6, 30):
        A, B, c, x0, xl, xu, EN, eN, X = _fixed_case(rng, N, 4, 2, clock_bounds, clock_offsets)
        ref_l, ref_u = xl.copy(), xu.copy()
        step_mod.drop_fixed_bounds(A, B, c, x0, ref_l, ref_u, EN, eN, slack=step_mod.FIXED_BOUND_RTOL * (1.0 + np.abs(X)))
        kl, ku = xl.copy(), xu.copy()
        kernels.drop_fixed_bounds(A, B, c, x0, kl, ku, EN, eN, X, step_mod.FIXED_BOUND_RTOL)
        assert _same(kl, ref_l) and _same(ku, ref_u)
        assert not _same(kl, xl)      # the rule dropped something


def test_hessian_scale_is_numpys_max():
    rng = np.random.default_rng(17)
    Bk, BN = rng.standard_normal((7, 5, 5)), rng.standard_normal((3, 3))
    ref = max(1e-300, float(np.max(np.abs(Bk), initial=0.0)), float(np.max(np.abs(BN), initial=0.0)))
    assert step_mod.hessian_scale(Bk, BN) == ref
    Bk[2, 1, 1] = np.nan
    assert step_mod.hessian_scale(Bk, BN) == max(1e-300, float("nan"), float(np.max(np.abs(BN))))


def _reference_paths(monkeypatch):
    """Patch the numpy forms back in for every compiled pass."""
    monkeypatch.setattr(merit_mod, "_compiled", lambda q: False)
    monkeypatch.setattr(phases, "kkt_residual", residuals.kkt_residual_reference)
    monkeypatch.setattr(phases, "stage_complementarity", residuals.stage_complementarity_reference)
    monkeypatch.setattr(residuals, "stage_complementarity", residuals.stage_complementarity_reference)

    def assemble(p, pt, Bk, BN, shift, masks, offsets=None):
        if shift is None:
            return step_mod.build_qp(p, pt, Bk, BN, masks, offsets)
        eye = np.eye(p.n + p.m)
        return step_mod.build_qp(p, pt, Bk + (shift[:-1])[:, None, None] * eye, BN + shift[-1] * np.eye(p.n),
                                 masks, offsets)

    monkeypatch.setattr(step_mod, "assemble_qp", assemble)
    monkeypatch.setattr(step_mod, "hessian_scale", lambda Bk, BN: max(
        1e-300, float(np.max(np.abs(Bk), initial=0.0)), float(np.max(np.abs(BN), initial=0.0))))
    monkeypatch.setattr(phases, "hessian_scale", step_mod.hessian_scale)


def _fingerprint(res):
    return (res.status, res.iterations, res.qp_iterations, res.objective, res.x.tobytes(), res.u.tobytes(),
            [sorted((k, repr(v)) for k, v in h.items()) for h in res.history])


@pytest.mark.parametrize("config", ["sqp-ip", "sqp-bfgs"])
def test_solves_take_the_same_iterates_as_the_numpy_forms(monkeypatch, config):
    solver = make_solver(load_config(CONFIGS / f"{config}.ini"))
    problems = [lambda: zambezi_problem("zambezi12", N=24), lambda: zambezi_problem("zambezi12", N=36, start="sif")]
    compiled = [_fingerprint(solver.solve(f())) for f in problems]
    _reference_paths(monkeypatch)
    reference = [_fingerprint(solver.solve(f())) for f in problems]
    assert compiled == reference
