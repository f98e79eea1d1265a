"""StageQP: the stage-wise QP (14) and its sparse form agree with the Riccati solver."""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from olado.linalg import RiccatiFactorization
from olado.qp.stageqp import StageQP


def _random_qp(seed=0, N=4, n=3, m=2):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((N + 1, n, n)); Q = M @ M.transpose(0, 2, 1) + np.eye(n)
    M2 = rng.standard_normal((N, m, m)); R = M2 @ M2.transpose(0, 2, 1) + np.eye(m)
    return StageQP(Q=Q, R=R, q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
                   A=0.5 * rng.standard_normal((N, n, n)), B=rng.standard_normal((N, n, m)),
                   c=rng.standard_normal((N, n)), x0=rng.standard_normal(n), S=0.1 * rng.standard_normal((N, n, m)),
                   E=rng.standard_normal((N, 1, n)), F=rng.standard_normal((N, 1, m)), e=rng.standard_normal((N, 1)),
                   EN=rng.standard_normal((1, n)), eN=rng.standard_normal(1))


def test_sparse_form_equality_qp_matches_riccati():
    qp = _random_qp()
    d = qp.to_sparse()
    K = sp.bmat([[d["P"], d["A_eq"].T], [d["A_eq"], None]]).tocsc()
    sol = spla.spsolve(K, np.concatenate([-d["q"], d["b_eq"]]))
    X, U = qp.unpack(sol[: qp.n_vars])
    ric = RiccatiFactorization(qp.Q, qp.S, qp.R, qp.A, qp.B, E=qp.E, F=qp.F, EN=qp.EN).solve(
        qp.q, qp.r, qp.c, qp.x0, e=qp.e, eN=qp.eN)
    assert np.allclose(X, ric.X, atol=1e-10) and np.allclose(U, ric.U, atol=1e-10)
    y = sol[: qp.n_vars]
    assert np.isclose(qp.objective(X, U), 0.5 * y @ (d["P"] @ y) + d["q"] @ y)


def test_sparse_form_of_inequalities_and_bounds():
    qp = _random_qp(1)
    N, n, m = qp.N, qp.n, qp.m
    rng = np.random.default_rng(2)
    qp2 = StageQP(Q=qp.Q, R=qp.R, q=qp.q, r=qp.r, A=qp.A, B=qp.B, c=qp.c, x0=qp.x0,
                  C=rng.standard_normal((N, 2, n + m)), c_lower=-np.ones((N, 2)), c_upper=np.full((N, 2), np.inf),
                  CN=np.eye(n)[:1], cN_lower=[-1.0], cN_upper=[1.0], u_lower=-np.ones((N, m)), u_upper=np.ones((N, m)))
    d = qp2.to_sparse()
    X = rng.standard_normal((N + 1, n)); U = rng.standard_normal((N, m))
    y = qp2.pack(X, U)
    g = d["G"] @ y
    assert np.allclose(g[: 2 * N].reshape(N, 2), np.einsum("kij,kj->ki", qp2.C, np.hstack([X[:-1], U])))
    assert np.isclose(g[-1], X[-1, 0])
    assert np.array_equal(d["lb"], qp2.pack(qp2.x_lower, qp2.u_lower))
    eq = d["A_eq"] @ y - d["b_eq"]
    assert np.allclose(eq[:n], X[0] - qp2.x0)
    assert np.allclose(eq[n:].reshape(N, n), np.einsum("kij,kj->ki", qp2.A, X[:-1]) + np.einsum("kij,kj->ki", qp2.B, U) + qp2.c - X[1:])


def test_kkt_residuals_vanish_at_the_riccati_solution_and_see_perturbations():
    from olado.qp.stageqp import QPResult, qp_kkt_residuals
    from olado.result import Status

    qp = _random_qp(3)
    N, n, m = qp.N, qp.n, qp.m
    s = RiccatiFactorization(qp.Q, qp.S, qp.R, qp.A, qp.B, E=qp.E, F=qp.F, EN=qp.EN).solve(
        qp.q, qp.r, qp.c, qp.x0, e=qp.e, eN=qp.eN)
    z = lambda *shape: np.zeros(shape)  # noqa: E731
    res = QPResult(Status.SUCCESS, "", s.X, s.U, s.lam, s.nu, z(N + 1, n), z(N + 1, n), z(N, m), z(N, m),
                   z(N, 0), z(N, 0), z(0), z(0))
    k = qp_kkt_residuals(qp, res)
    assert k["stationarity"] < 1e-10 and k["primal"] < 1e-10 and k["complementarity"] == 0.0
    res.U = res.U + 1e-3
    assert qp_kkt_residuals(qp, res)["primal"] > 1e-4
