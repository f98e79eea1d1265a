"""The interior-point solver's memory on long horizons: what an iteration lets go and when
(take_step: the Newton matrix's blocks and Sigma, the old point's caches and slacks, before the
new point's derivatives; newton_system: the cost blocks after a factorization whose solves do
not read them, above the workspace's REUSE_MAX; finish: the last matrix), with the same iterates."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import olado.solvers.ipm.solver as S
from olado.linalg.riccati import RiccatiFactorization
from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.solvers.ipm.barrier import Bounds, Layout
from olado.solvers.ipm.newton import KKTMatrix


def _solver():
    from olado.config import load_config, make_solver

    return make_solver(load_config("configs/ipm.ini"))


def _history(result):
    keys = ("alpha", "alpha_z", "soc", "objective", "inf_pr", "inf_du", "mu", "delta_w", "restoration", "watchdog")
    return [tuple(None if isinstance(h[k], float) and np.isnan(h[k]) else h[k] for k in keys) for h in result.history]


#: the traced peak of a zambezi N = 1 200 solve (the iterations, finish and the certificate) in
#: bytes per stage above what was traced before it, with the large-N regime (no workspace reuse):
#: ~6 500 when the previous Newton matrix and the old point's derivatives were alive while the new
#: point's derivatives were evaluated (and the last matrix through finish); ~4 700 since
PEAK_PER_STAGE = 5_600


def test_the_peak_per_stage_of_a_long_horizon_falls_below_the_bound(monkeypatch):
    solver = _solver()
    solver.solve(zambezi_problem("zambezi", N=12))         # compiled kernels, cached data
    ref = solver.solve(zambezi_problem("zambezi", N=1200))  # (the workspace reused at this N)
    monkeypatch.setattr(S, "REUSE_MAX", 0)                  # every array new: the regime of N >~ 2 500
    problem = zambezi_problem("zambezi", N=1200)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        result = solver.solve(problem)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert result.status.success and result.iterations > 30
    # the same iterates with and without the releases (and the workspace)
    assert result.iterations == ref.iterations and _history(result) == _history(ref)
    assert result.objective == ref.objective and np.array_equal(result.x, ref.x)
    assert (peak - base) / problem.N < PEAK_PER_STAGE


@pytest.mark.parametrize("name", ["obstacle", "steering-too-short"])
def test_releases_above_reuse_max_take_the_same_iterates(name, monkeypatch):
    """The watchdog (which keeps its search's matrix), second-order corrections (which solve with
    a matrix whose costs went), inertia corrections and restoration phases: the same iterates,
    bit for bit, with the large-N releases as without (the workspace's small-N path)."""
    solver = _solver()
    ref = solver.solve(PROBLEMS[name]())
    monkeypatch.setattr(S, "REUSE_MAX", 0)
    res = solver.solve(PROBLEMS[name]())
    assert res.status == ref.status and res.iterations == ref.iterations
    assert _history(res) == _history(ref)
    assert res.objective == ref.objective and np.array_equal(res.x, ref.x) and np.array_equal(res.u, ref.u)


def _system(N=9, n=3, m=2, seed=1):
    rng = np.random.default_rng(seed)
    Q = np.stack([np.eye(n) * 2 + 0.1 * (M + M.T) for M in rng.normal(size=(N + 1, n, n))])
    S_ = 0.05 * rng.normal(size=(N, n, m))
    R = np.stack([np.eye(m) * 3.0] * N)
    A, B = rng.normal(size=(N, n, n)) * 0.5, rng.normal(size=(N, n, m))
    return Q, S_, R, A, B, rng.uniform(0.1, 1.0, (N + 1, n)), rng.uniform(0.1, 1.0, (N, m))


def test_release_costs_keeps_the_fixed_size_solve_and_refuses_the_others():
    Q, S_, R, A, B, Sx, Su = _system()
    kkt = KKTMatrix(Q.copy(), S_, R, A, B, Sx, Su)
    assert kkt.factor(0.0) == 0.0
    rng = np.random.default_rng(2)
    N, n, m = B.shape
    from olado.solvers.ipm.newton import Residuals

    res = Residuals(rng.normal(size=(N, n)), np.zeros((N, 0)), np.zeros(0), np.zeros((N, 0)), np.zeros(0))
    q, r = rng.normal(size=(N + 1, n)), rng.normal(size=(N, m))
    before = kkt.solve(q, r, res)
    before = [a.copy() for a in (before.dX, before.dU, before.lam)]
    assert kkt.release_costs()
    assert kkt.kkt._costs is None and kkt.Q.strides == (0, 0, 0) and kkt.R.shape == R.shape
    after = kkt.solve(q, r, res)
    assert all(np.array_equal(a, b) for a, b in zip(before, (after.dX, after.dU, after.lam)))
    # the recursion with equality rows reads Q, S, R in its solve: they stay
    E = np.zeros((N, 1, n))
    E[:, 0, 0] = 1.0
    general = RiccatiFactorization(Q, S_, R, A, B, E=E, F=np.zeros((N, 1, m)))
    assert not general.release_costs() and general._costs is not None
    # blocks above the fixed-size kernels' limit: the plain recursion reads them
    big = RiccatiFactorization(*_system(N=4, n=30, m=2)[:5])
    assert big.fixed_solve_operands() is None and not big.release_costs()


def test_release_blocks_lets_sigma_go_once_and_the_next_matrix_takes_over():
    Q, S_, R, A, B, Sx, Su = _system()
    first = KKTMatrix(Q.copy(), S_.copy(), R.copy(), A.copy(), B.copy(), Sx.copy(), Su.copy())
    assert first.factor(0.0) == 0.0
    backend = first.kkt
    first.release_blocks()
    assert first.released and first.Sx.strides == (0, 0) and first.Su.shape == Su.shape
    assert backend.data.Q.strides == (0, 0, 0)
    first.release_blocks()                                  # a second call: nothing
    second = KKTMatrix(Q.copy(), S_.copy(), R.copy(), A.copy(), B.copy(), Sx.copy(), Su.copy(), reuse=first)
    assert second.factor(0.0) == 0.0 and second.kkt is backend   # taken over
    fresh = KKTMatrix(Q.copy(), S_.copy(), R.copy(), A.copy(), B.copy(), Sx.copy(), Su.copy())
    assert fresh.factor(0.0) == 0.0
    assert np.array_equal(backend.P, fresh.kkt.P) and np.array_equal(backend.K, fresh.kkt.K)


def test_bounds_keep_only_the_new_iterate():
    p = zambezi_problem("zambezi12", N=24)
    L = Layout(p)
    b = Bounds.of(p, L)
    v0, v1 = np.zeros(L.size), np.ones(L.size)
    s0, s1 = b.slacks(v0), b.slacks(v1)
    b.keep_only(v1)
    assert b.slacks(v1) is s1
    again = b.slacks(v0)                                    # computed again: the same numbers
    assert again is not s0 and all(np.array_equal(a, c) for a, c in zip(again, s0))
