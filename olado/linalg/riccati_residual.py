"""The residual of the KKT rows of the LQ-DOCP (olado.linalg.riccati), compiled: what the
iterative refinement of a factorization with static pivots measures
(:meth:`olado.linalg.riccati.RiccatiFactorization._refine`)."""

from __future__ import annotations

import numba as nb

from .backend import RHS, Solution
from .codegen import as_bundle
from .riccati_kernels import Costs, Dynamics, EqualityRows, IPTerms


@nb.njit(cache=True)
def _kkt_residual(costs, dyn, eq, ipt, reg, rhs, sol, res):
    """The residual of the KKT rows of the LQ-DOCP (module docstring of olado.linalg.riccati:
    the Lagrangian's stationarity rows, the dynamics, the equality rows; with the regularization
    reg on Q_uu as factored) at ``sol`` = (X, U, lam, nu), written as a right-hand side into
    ``res`` (RHS: q, r the stationarity rows, c the dynamics rows, e, eN the equality rows; x0 and
    ci are left zero -- X[0] = x0 holds exactly). Returns (the largest magnitude of a term of the
    rows, the max-norm of the equality rows): the refinement of static pivots
    (RiccatiFactorization._refine) measures the residual relative to the first."""
    costs = as_bundle(costs, Costs)
    Q, S, R = costs.Q, costs.S, costs.R
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    eq = as_bundle(eq, EqualityRows)
    E, F, ne, EN = eq.E, eq.F, eq.ne, eq.EN
    ipt = as_bundle(ipt, IPTerms)
    Dx, Du, Ci, sig, ni = ipt.Dx, ipt.Du, ipt.Ci, ipt.sig, ipt.ni
    rhs = as_bundle(rhs, RHS)
    q, r, c, x0, e, eN, ci = rhs.q, rhs.r, rhs.c, rhs.x0, rhs.e, rhs.eN, rhs.ci
    sol = as_bundle(sol, Solution)
    X, U, lam, nu = sol.X, sol.U, sol.lam, sol.nu
    res = as_bundle(res, RHS)
    rq, rr, rc, rx0, re, reN, rci = res.q, res.r, res.c, res.x0, res.e, res.eN, res.ci
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    neN = EN.shape[0]
    size = 1.0
    infeas = 0.0
    for i in range(n):
        rx0[i] = 0.0
        size = max(size, abs(x0[i]))
    for k in range(N):
        for cc in range(rci.shape[1]):
            rci[k, cc] = 0.0
        for i in range(n):
            t0 = q[k, i]; t1 = Dx[k, i] * X[k, i]; t2 = -lam[k, i]
            s = t0 + t1 + t2
            size = max(size, abs(t0), abs(t1), abs(t2))
            for l in range(n):
                a = Q[k, i, l] * X[k, l]; b = A[k, l, i] * lam[k + 1, l]
                s += a + b
                size = max(size, abs(a), abs(b))
            for l in range(m):
                a = S[k, i, l] * U[k, l]
                s += a
                size = max(size, abs(a))
            rq[k, i] = s
        for i in range(m):
            t0 = r[k, i]; t1 = (Du[k, i] + reg) * U[k, i]
            s = t0 + t1
            size = max(size, abs(t0), abs(t1))
            for l in range(n):
                a = S[k, l, i] * X[k, l]; b = B[k, l, i] * lam[k + 1, l]
                s += a + b
                size = max(size, abs(a), abs(b))
            for l in range(m):
                a = R[k, i, l] * U[k, l]
                s += a
                size = max(size, abs(a))
            rr[k, i] = s
        for i in range(n):
            t0 = c[k, i]; t1 = -X[k + 1, i]
            s = t0 + t1
            size = max(size, abs(t0), abs(t1))
            for l in range(n):
                a = A[k, i, l] * X[k, l]
                s += a
                size = max(size, abs(a))
            for l in range(m):
                a = B[k, i, l] * U[k, l]
                s += a
                size = max(size, abs(a))
            rc[k, i] = s
        for j in range(e.shape[1]):
            re[k, j] = 0.0
        for j in range(ne[k]):
            w = nu[k, j]
            s = e[k, j]
            size = max(size, abs(s))
            for i in range(n):
                rq[k, i] += E[k, j, i] * w
                s += E[k, j, i] * X[k, i]
            for i in range(m):
                rr[k, i] += F[k, j, i] * w
                s += F[k, j, i] * U[k, i]
            re[k, j] = s
            infeas = max(infeas, abs(s))
        for cc in range(ni[k]):
            w = ci[k, cc]
            for i in range(n):
                w += Ci[k, cc, i] * X[k, i]
            for i in range(m):
                w += Ci[k, cc, n + i] * U[k, i]
            w *= sig[k, cc]
            for i in range(n):
                rq[k, i] += Ci[k, cc, i] * w
            for i in range(m):
                rr[k, i] += Ci[k, cc, n + i] * w
    for i in range(n):
        t0 = q[N, i]; t1 = Dx[N, i] * X[N, i]; t2 = -lam[N, i]
        s = t0 + t1 + t2
        size = max(size, abs(t0), abs(t1), abs(t2))
        for l in range(n):
            a = Q[N, i, l] * X[N, l]
            s += a
            size = max(size, abs(a))
        for j in range(neN):
            s += EN[j, i] * nu[N, j]
        rq[N, i] = s
    for j in range(neN):
        s = eN[j]
        size = max(size, abs(s))
        for i in range(n):
            s += EN[j, i] * X[N, i]
        reN[j] = s
        infeas = max(infeas, abs(s))
    return size, infeas
