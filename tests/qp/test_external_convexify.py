"""External QP back-ends on QPs they cannot take as they are: an indefinite Hessian that is
positive definite on the null space of the equality rows (convexify = "augmented": P + rho A^T A,
the same solution and multipliers, checked against the Riccati solution), a QP that is not (a
failed QP, never an exception), and dense-only back-ends (quadprog)."""

import dataclasses

import numpy as np
import pytest

from olado.linalg import RiccatiFactorization
from olado.qp.external import ExternalQP, augmented_hessian, available_qp_backends
from olado.qp.stageqp import StageQP
from olado.result import Status

pytest.importorskip("qpsolvers")
BACKENDS = [b for b in ("osqp", "clarabel") if b in available_qp_backends()]
TIGHT = {"osqp": dict(eps_abs=1e-10, eps_rel=1e-10, polish=True, max_iter=100000),
         "clarabel": dict(tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)}


def _qp(shift, seed=0, N=5, n=3, m=2):
    """An equality-constrained stage QP whose state blocks are Q_k - shift I."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((N + 1, n, n)); Q = M @ M.transpose(0, 2, 1) + np.eye(n) - shift * np.eye(n)
    M2 = rng.standard_normal((N, m, m)); R = M2 @ M2.transpose(0, 2, 1) + np.eye(m)
    return StageQP(Q=Q, R=R, q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
                   A=0.5 * rng.standard_normal((N, n, n)), B=rng.standard_normal((N, n, m)),
                   c=rng.standard_normal((N, n)), x0=rng.standard_normal(n), S=0.1 * rng.standard_normal((N, n, m)),
                   E=rng.standard_normal((N, 1, n)), F=rng.standard_normal((N, 1, m)), e=rng.standard_normal((N, 1)),
                   EN=rng.standard_normal((1, n)), eN=rng.standard_normal(1))


def _riccati(qp):
    return RiccatiFactorization(qp.Q, qp.S, qp.R, qp.A, qp.B, E=qp.E, F=qp.F, EN=qp.EN).solve(
        qp.q, qp.r, qp.c, qp.x0, e=qp.e, eN=qp.eN)


def _indefinite_but_convex_on_the_null_space():
    """The largest shift of the ladder for which the Riccati recursion (positive definite reduced
    Hessians) still works, with an indefinite P."""
    for shift in (8.0, 6.0, 4.0, 3.0, 2.0):
        qp = _qp(shift)
        try:
            _riccati(qp)
        except Exception:   # noqa: BLE001 - NotPositiveDefiniteError: not convex on the null space
            continue
        if np.min(np.linalg.eigvalsh(qp.Q)) < 0.0:
            return qp
    pytest.fail("no indefinite QP with positive definite reduced Hessians in the ladder")


@pytest.mark.parametrize("backend", BACKENDS)
def test_augmented_convexification_solves_an_indefinite_qp_exactly(backend):
    qp = _indefinite_but_convex_on_the_null_space()
    P, q, rho = augmented_hessian(qp.to_sparse())
    assert rho > 0.0 and np.min(np.linalg.eigvalsh(P.toarray())) > -1e-8 * abs(P).max()
    ref = _riccati(qp)
    res = ExternalQP(backend, convexify="augmented", **TIGHT[backend]).solve(qp)
    assert res.status == Status.SUCCESS, res.message
    scale = max(1.0, np.abs(ref.lam).max())
    assert np.abs(res.X - ref.X).max() < 1e-6 and np.abs(res.U - ref.U).max() < 1e-6
    # the multipliers of the QP itself (the augmented term's gradient added back)
    assert np.abs(res.lam - ref.lam).max() < 1e-5 * scale and np.abs(res.nu - ref.nu).max() < 1e-5 * scale
    assert res.kkt["stationarity"] < 1e-6 * scale


def test_a_convex_qp_is_passed_unchanged():
    qp = _qp(0.0)
    d = qp.to_sparse()
    P, q, rho = augmented_hessian(d)
    assert rho == 0.0 and (P != d["P"]).nnz == 0 and np.array_equal(q, d["q"])


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_qp_not_convex_on_the_null_space_is_a_failed_qp(backend):
    qp = dataclasses.replace(_qp(0.0), R=-np.tile(np.eye(2), (5, 1, 1)) * 50.0)
    assert augmented_hessian(qp.to_sparse()) is None
    res = ExternalQP(backend, convexify="augmented").solve(qp)
    assert res.status == Status.NUMERICAL_ERROR and "nonconvex" in res.message


def test_osqp_on_a_nonconvex_qp_reports_a_status_instead_of_raising():
    assert "osqp" in BACKENDS      # a core dependency (pyproject.toml)
    qp = dataclasses.replace(_qp(0.0), R=-np.tile(np.eye(2), (5, 1, 1)) * 50.0)
    res = ExternalQP("osqp").solve(qp)     # OSQP raises OSQPException at setup: a failed QP
    assert not res.success and res.status in (Status.NUMERICAL_ERROR, Status.FAILED)


def test_dense_only_backend_quadprog():
    pytest.importorskip("quadprog")
    qp = _qp(0.0)
    ref = _riccati(qp)
    res = ExternalQP("quadprog").solve(qp)      # failed before: "problem has sparse matrices"
    assert res.status == Status.SUCCESS, res.message
    assert np.abs(res.X - ref.X).max() < 1e-8 and np.abs(res.lam - ref.lam).max() < 1e-6 * max(1, np.abs(ref.lam).max())
