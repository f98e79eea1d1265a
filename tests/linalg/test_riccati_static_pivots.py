"""Static pivots of the Riccati recursion with terminal equality rows (olado.linalg.riccati,
PIVOT_TOL): a passed-back row whose u-part is tiny but above rank_tol was eliminated by that
control alone, with a gain of 1/|u-part| in K_k and its square in P_k; the rounding of P_k then
made the reduced Hessian of an earlier stage indefinite (particle-steering's certificate QP: "not
positive definite at stage k=46" while the whole KKT matrix is regular).  The row is now passed
back with its u-coupling left out and put back by iterative refinement.  References: the dense
KKT solve (numpy) and the interior-point QP on the sparse LU of the whole KKT matrix."""

import sys
from pathlib import Path

import numpy as np
import pytest

import olado
from olado.linalg import RiccatiFactorization
from olado.linalg.riccati import PIVOT_TOL
from olado.result import Status

from test_riccati import dense_kkt_system  # noqa: E402

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def steering_lq(N=50, dt=0.02, turn=3.0):
    """A particle steered by its thrust angle, linearized about a slowly turning angle
    theta_k = 0.3 + turn dt k: x = (p1, p2, v1, v2), B_k = a (dt^2/2, dt) x (-sin, cos)(theta_k);
    terminal rows on p2, v1, v2 (COPS 'steering' in LQ form). Two controls eliminate two of the
    rows; the third reaches stage N-3 with a u-part of relative size ~1e-6 (it depends on the
    turn of B_k over three steps)."""
    n, m = 4, 1
    A = np.broadcast_to(np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1.0]]), (N, n, n)).copy()
    th = 0.3 + turn * dt * np.arange(N)
    B = np.zeros((N, n, m))
    B[:, 0, 0], B[:, 1, 0] = -0.5 * dt ** 2 * np.sin(th), 0.5 * dt ** 2 * np.cos(th)
    B[:, 2, 0], B[:, 3, 0] = -dt * np.sin(th), dt * np.cos(th)
    Q = np.broadcast_to(1e-3 * np.eye(n), (N + 1, n, n)).copy()
    rng = np.random.default_rng(5)
    return dict(Q=Q, S=np.zeros((N, n, m)), R=np.ones((N, m, m)), A=A, B=B, EN=np.eye(n)[1:],
                q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
                c=1e-3 * rng.standard_normal((N, n)), x0=rng.standard_normal(n), eN=rng.standard_normal(3))


def _dense(d):
    K, b, unpack = dense_kkt_system(d["Q"], d["S"], d["R"], d["q"], d["r"], d["A"], d["B"], d["c"], d["x0"],
                                    EN=d["EN"], eN=d["eN"])
    return unpack(np.linalg.solve(K, b))


def _solve(d, **kw):
    fac = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], EN=d["EN"], **kw)
    return fac, fac.solve(d["q"], d["r"], d["c"], d["x0"], eN=d["eN"])


def _rel(a, b):
    return np.abs(a - b).max() / max(1.0, np.abs(b).max())


def weak_row_lq(N=8, delta=1e-9):
    """x = (x1, x2), one control, x_{k+1} = x_k + B_k u_k with B_k = (1, 1) except B_{N-1} = (1, 0)
    and B_{N-2} = (1, delta); both states fixed at N. u_{N-1} satisfies one terminal row, the
    other, x2 = -eN_2, reaches stage N-2 with the u-part delta (relative to its row) and stage N-3
    with the u-part 1. The KKT matrix is well conditioned (1.4e2)."""
    n, m = 2, 1
    A = np.broadcast_to(np.eye(n), (N, n, n)).copy()
    B = np.ones((N, n, m))
    B[N - 1, 1, 0] = 0.0
    B[N - 2, 1, 0] = delta
    rng = np.random.default_rng(7)
    return dict(Q=np.broadcast_to(np.eye(n), (N + 1, n, n)).copy(), S=np.zeros((N, n, m)), R=np.ones((N, m, m)), A=A,
                B=B, EN=np.eye(n), q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
                c=0.1 * rng.standard_normal((N, n)), x0=rng.standard_normal(n), eN=rng.standard_normal(n))


def test_weak_row_is_a_static_pivot_and_refined():
    d = weak_row_lq()
    X, U = _dense(d)
    fac, sol = _solve(d)
    N = fac.N
    # the weak row is passed back from stage N-2 (u-part 1e-9: between rank_tol and PIVOT_TOL)
    assert fac.rank_tol < fac.dropped[N - 2] < PIVOT_TOL and fac.rank[N - 2] == 0 and fac.perturbed
    assert _rel(sol.X, X) <= 1e-12 and _rel(sol.U, U) <= 1e-12
    # the refined solution satisfies the exact KKT rows with its multipliers
    resid, size, infeas = fac.kkt_residual(fac.data.rhs_arrays(d["q"], d["r"], d["c"], d["x0"], None, d["eN"], None),
                                           (sol.X, sol.U, sol.lam, sol.nu))
    assert max(np.abs(a).max(initial=0.0) for a in resid) <= 1e-12 * size and infeas <= 1e-12 * size
    # the exact pivot (gain 1e9 into K, its square into P) loses the solution entirely
    _, exact = _solve(d, pivot_tol=0.0)
    assert _rel(exact.U, U) > 1e-1


def test_static_pivots_leave_strong_rows_alone():
    """Rows whose u-parts are well above PIVOT_TOL: no static pivot, the factors of the exact
    pivots bit for bit."""
    d = steering_lq(turn=40.0)
    fac, sol = _solve(d)
    assert not fac.perturbed and not fac.dropped.any()
    fac0, sol0 = _solve(d, pivot_tol=0.0)
    assert np.array_equal(sol.X, sol0.X) and np.array_equal(sol.U, sol0.U) and np.array_equal(fac.P, fac0.P)


def test_an_unreachable_weak_row_falls_back_to_the_exact_pivot():
    """A terminal row that only the last control reaches, with a u-part of 1e-7 of its row:
    passed back it would reach x_0 unsatisfiable, so refinement cannot converge; the exact
    pivot is used instead: the solution of the exact pivots, with u_{N-1} = 1 (x2 goes from
    -1e-7 to 0 in the last step only)."""
    rng = np.random.default_rng(2)
    N, n, m = 4, 2, 1
    A = np.broadcast_to(np.eye(n), (N, n, n)).copy()
    B = np.zeros((N, n, m)); B[:, 0, 0] = 1.0
    B[N - 1, 1, 0] = 1e-7        # x2 is moved only by u_{N-1}, weakly
    d = dict(Q=np.broadcast_to(np.eye(n), (N + 1, n, n)).copy(), S=np.zeros((N, n, m)), R=np.ones((N, m, m)), A=A,
             B=B, EN=np.array([[0.0, 1.0]]), q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
             c=np.zeros((N, n)), x0=np.array([0.3, -1e-7]), eN=np.array([0.0]))
    fac, sol = _solve(d)
    assert not fac.perturbed and fac.rank[N - 1] == 1       # the exact pivot after the fallback
    _, exact = _solve(d, pivot_tol=0.0)
    assert np.array_equal(sol.X, exact.X) and np.array_equal(sol.U, exact.U)
    assert sol.U[N - 1, 0] == pytest.approx(1.0, rel=1e-8) and abs(sol.X[N, 1]) <= 1e-15
    np.testing.assert_allclose(sol.X[:N, 1], -1e-7, rtol=1e-12)


@pytest.mark.slow
def test_particle_steering_certificate_qp_on_riccati(monkeypatch):
    """The reproduction: the certificate's weighted least-squares QPs of particle-steering at
    IPOPT's solution (controls at their bounds weighted 1e-12, three terminal equalities, m = 1)
    on the Riccati back-end alone, against the same QPs on the sparse LU of the whole KKT
    matrix."""
    pytest.importorskip("cyipopt")
    from olado.problems.suites import load_suite
    from olado.qp import make_qp_solver
    from olado.solvers import certificate as C

    problem, guess = next(e for e in load_suite("robustness") if e.name == "particle-steering").build()
    r = olado.solve(problem, guess=guess, config=f"{CONFIGS}/ipopt.ini")
    assert r.status == Status.SUCCESS
    qps = []
    solve_weighted = C._solve_weighted

    def keep(qp):
        qps.append(qp)
        return solve_weighted(qp)

    monkeypatch.setattr(C, "LSQ_KKT", ("riccati",))
    monkeypatch.setattr(C, "_solve_weighted", keep)
    pt, bounds = C.StagePoint(problem, r.x, r.u), C.StageBounds.of(problem)
    ls = C.least_squares_multipliers(problem, pt, bounds, (np.maximum(1.0, np.abs(r.x)), np.maximum(1.0, np.abs(r.u))))
    assert not isinstance(ls, str), ls
    assert qps
    for qp in qps:
        ours = make_qp_solver("mehrotra", kkt="riccati", tol=C.LSQ_TOL, max_iter=50).solve(qp)
        ref = make_qp_solver("mehrotra", kkt="superlu-full", tol=C.LSQ_TOL, max_iter=50).solve(qp)
        assert ours.success and ref.success, (ours.message, ref.message)
        assert _rel(ours.X, ref.X) <= 1e-8 and _rel(ours.U, ref.U) <= 1e-8
