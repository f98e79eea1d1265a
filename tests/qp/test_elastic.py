"""The elastic (relaxed) stage QP (olado/qp/elastic.py): the QP itself when that is consistent and
the penalty exceeds its multipliers; the least l1 violation of its linearized constraints when
it is not (checked against an LP solved by HiGHS on the sparse form)."""

import numpy as np
import pytest
import scipy.optimize as so
import scipy.sparse as sp

from olado.qp import make_qp_solver
from olado.qp.elastic import ElasticQP
from olado.qp.stageqp import qp_kkt_residuals

from fixtures.qp_problems import random_qp, replace


def _with_final_rows(qp, seed=0):
    """qp with a final equality row and finite bounds of x_N through its solution (still
    consistent, and the solution still feasible)."""
    rng = np.random.default_rng(seed)
    ref = make_qp_solver("mehrotra", tol=1e-11).solve(qp)
    EN = rng.standard_normal((1, qp.n))
    xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
    xl[-1, -1] = ref.X[-1, -1] - 0.3
    return replace(qp, EN=EN, eN=-EN @ ref.X[-1], x_lower=xl, x_upper=xu)


@pytest.mark.parametrize("seed, fixed", [(0, False), (1, True), (2, False)])
def test_elastic_qp_of_a_consistent_qp_is_that_qp(seed, fixed):
    qp = _with_final_rows(random_qp(seed, eq=True, fixed=fixed), seed)
    solver = make_qp_solver("mehrotra", tol=1e-11)
    ref = solver.solve(qp)
    assert ref.success
    mults = max(float(np.max(np.abs(a), initial=0.0)) for a in (ref.nu, ref.yc_lower, ref.yc_upper, ref.zx_lower,
                                                                  ref.zx_upper, ref.yN_lower, ref.yN_upper))
    el = ElasticQP(qp, eta=10.0 * mults + 1.0)
    assert el.n_slacks > 0
    res, slacks = el.restore(solver.solve(el.relaxed))
    assert res.success
    assert slacks.total() < 1e-7
    assert np.allclose(res.X, ref.X, atol=1e-6) and np.allclose(res.U, ref.U, atol=1e-6)
    # the restored multipliers are multipliers of the original QP (its KKT conditions hold)
    kkt = qp_kkt_residuals(qp, res)
    assert kkt["stationarity"] < 1e-6 and kkt["primal"] < 1e-7 and kkt["complementarity"] < 1e-6
    assert np.allclose(res.lam, ref.lam, atol=1e-5) and np.allclose(res.nu, ref.nu, atol=1e-5)


def _least_violation_lp(qp, relax_dynamics=False):
    """min sum of slacks over the linearized constraints of qp with the dynamics (unless
    ``relax_dynamics``), x_0 and the control bounds exact (the elastic QP's relaxation), as an LP
    in the sparse form."""
    d = qp.to_sparse()
    nv = qp.n_vars
    N, n, m = qp.N, qp.n, qp.m
    n_exact = n if relax_dynamics else n + N * n     # x_0 and dynamics rows come first in A_eq
    A_eq, b_eq = d["A_eq"].tocsr(), d["b_eq"]
    n_rel = A_eq.shape[0] - n_exact
    G, hl, hu = d["G"].tocsr(), d["h_lower"], d["h_upper"]
    lb, ub = d["lb"], d["ub"]
    xmask = qp.pack(np.ones((N + 1, n)), np.zeros((N, m))).astype(bool)
    xmask[:n] = False                            # x_0: fixed by its row
    rows_lo = [(G, hl)] + [(sp.identity(nv, format="csr")[xmask], lb[xmask])]
    rows_hi = [(G, hu)] + [(sp.identity(nv, format="csr")[xmask], ub[xmask])]
    # variables: y, p, q (equality slacks), s (lower sides), t (upper sides)
    blocks_eq = [A_eq[n_exact:], sp.identity(n_rel), -sp.identity(n_rel)]
    ineq_rows, ineq_rhs = [], []
    lo_mats = [(M[np.isfinite(v)], v[np.isfinite(v)]) for M, v in rows_lo]
    hi_mats = [(M[np.isfinite(v)], v[np.isfinite(v)]) for M, v in rows_hi]
    ns = sum(M.shape[0] for M, _ in lo_mats); nt = sum(M.shape[0] for M, _ in hi_mats)
    nz = nv + 2 * n_rel + ns + nt
    Mlo = sp.vstack([M for M, _ in lo_mats]); vlo = np.concatenate([v for _, v in lo_mats])
    Mhi = sp.vstack([M for M, _ in hi_mats]); vhi = np.concatenate([v for _, v in hi_mats])
    # -(M y + s) <= -lo ;  M y - t <= hi
    ineq_rows.append(sp.hstack([-Mlo, sp.csr_matrix((ns, 2 * n_rel)), -sp.identity(ns), sp.csr_matrix((ns, nt))]))
    ineq_rhs.append(-vlo)
    ineq_rows.append(sp.hstack([Mhi, sp.csr_matrix((nt, 2 * n_rel + ns)), -sp.identity(nt)]))
    ineq_rhs.append(vhi)
    Aeq = sp.vstack([sp.hstack([A_eq[:n_exact], sp.csr_matrix((n_exact, nz - nv))]),
                     sp.hstack(blocks_eq + [sp.csr_matrix((n_rel, ns + nt))])])
    umask = ~qp.pack(np.ones((N + 1, n)), np.zeros((N, m))).astype(bool)
    bounds = [(lb[i], ub[i]) if umask[i] else (None, None) for i in range(nv)] + [(0, None)] * (nz - nv)
    bounds = [(None if b is None or not np.isfinite(b) else b, None if c is None or not np.isfinite(c) else c)
              for b, c in bounds]
    cost = np.concatenate([np.zeros(nv), np.ones(nz - nv)])
    lp = so.linprog(cost, A_ub=sp.vstack(ineq_rows), b_ub=np.concatenate(ineq_rhs), A_eq=Aeq,
                    b_eq=b_eq, bounds=bounds, method="highs")
    assert lp.status == 0, lp.message
    return lp.fun


@pytest.mark.parametrize("method", ["mehrotra", "gondzio", "clarabel"])
def test_elastic_qp_of_an_inconsistent_qp_leaves_the_least_l1_violation(method):
    qp = _with_final_rows(random_qp(3, eq=True), 3)
    xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
    xl[3, 0], xu[3, 0] = 40.0, np.inf     # out of reach of the dynamics with bounded controls
    qp = replace(qp, x_lower=xl, x_upper=xu, q=np.zeros_like(qp.q), r=np.zeros_like(qp.r))
    assert make_qp_solver("mehrotra").solve(qp).status.value == "infeasible"
    best = _least_violation_lp(qp)
    assert best > 1.0                 # really inconsistent
    el = ElasticQP(qp, eta=1e4)       # (olado's interior point stalls on eta >= 1e6: near-LP scaling)
    kw = {"tol": 1e-10} if method != "clarabel" else {}
    res, slacks = el.restore(make_qp_solver(method, **kw).solve(el.relaxed))
    assert res.success, res.message
    assert slacks.total() == pytest.approx(best, rel=1e-6)
    # the slacks are the linearized violations at the step: recompute the x bound's
    assert slacks.x[3, 0] == pytest.approx(max(0.0, 40.0 - res.X[3, 0]), abs=1e-6)
    # u bounds and dynamics stay exact
    assert np.all(res.U >= qp.u_lower - 1e-8) and np.all(res.U <= qp.u_upper + 1e-8)
    dyn = np.einsum("kij,kj->ki", qp.A, res.X[:-1]) + np.einsum("kij,kj->ki", qp.B, res.U) + qp.c - res.X[1:]
    assert np.max(np.abs(dyn)) < 1e-7


@pytest.mark.parametrize("case", ["bound3", "boundN", "final-row"])
def test_elastic_qp_with_relaxed_dynamics_leaves_the_least_l1_violation_of_every_row(case):
    """relax_dynamics (the feasibility restoration's QP): the dynamics rows get slacks too, so the
    QP minimizes the l1 model of every row's violation -- never more than with exact dynamics,
    and equal to the LP that relaxes them. An unreachable bound on x_3 or on x_N (the final rows
    moved to stage N-1 see that stage's dynamics slacks), or a final equality row 10 times the
    scale of the states out of reach (then a dynamics slack removes its violation at a tenth of
    the cost, and relaxing the dynamics is strictly better; the controls bounded so that they
    cannot reach it)."""
    qp = _with_final_rows(random_qp(3, eq=True), 3)
    xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
    kw = {}
    if case == "final-row":
        kw.update(EN=10.0 * qp.EN, eN=10.0 * qp.eN + 50.0, u_upper=np.minimum(qp.u_upper, 1.0))
    else:
        stage = 3 if case == "bound3" else qp.N
        xl[stage, 0], xu[stage, 0] = 40.0, np.inf
    qp = replace(qp, x_lower=xl, x_upper=xu, q=np.zeros_like(qp.q), r=np.zeros_like(qp.r), **kw)
    best = _least_violation_lp(qp, relax_dynamics=True)
    exact = _least_violation_lp(qp)
    assert 0.1 < best <= exact + 1e-9
    if case == "final-row":
        assert best < exact - 0.1
    el = ElasticQP(qp, eta=1e4, relax_dynamics=True)
    assert el.n_slacks == ElasticQP(qp, eta=1e3).n_slacks + 2 * qp.n
    res, slacks = el.restore(make_qp_solver("mehrotra", tol=1e-10).solve(el.relaxed))
    assert res.success, res.message
    assert slacks.total() == pytest.approx(best, rel=1e-6)
    # the slacks are the linearized violations at the step: the dynamics residuals, the final
    # row's and the x bounds' recomputed
    dyn = np.einsum("kij,kj->ki", qp.A, res.X[:-1]) + np.einsum("kij,kj->ki", qp.B, res.U) + qp.c - res.X[1:]
    assert np.allclose(slacks.h, np.abs(dyn), atol=1e-6)
    assert np.allclose(slacks.eN, np.abs(qp.EN @ res.X[-1] + qp.eN), atol=1e-6)
    bound = np.maximum(qp.x_lower - res.X, 0.0) + np.maximum(res.X - qp.x_upper, 0.0)
    assert np.allclose(slacks.x[1:], bound[1:], atol=1e-6)
    assert np.all(res.U >= qp.u_lower - 1e-8) and np.all(res.U <= qp.u_upper + 1e-8)
