"""The fixed-size solve kernel (_solve_unconstrained_fixed: straight-line SIMD sweeps) against
the any-size kernel _solve_unconstrained and a dense KKT solve."""

import numpy as np
import pytest

from olado.linalg import riccati as rc, riccati_fixed as rf, riccati_kernels as rk
from olado.linalg.backend import RHS, Solution
from olado.linalg.codegen import size_tags


def _problem(N, n, m, ni, seed):
    rng = np.random.default_rng(seed)
    nz = n + m
    Qm, _ = np.linalg.qr(rng.standard_normal((N + 1, nz, nz)))
    ev = np.exp(rng.uniform(np.log(1e-2), 0.0, (N + 1, nz)))
    Z = np.einsum("kij,kj,klj->kil", Qm, ev, Qm)
    d = dict(Q=Z[:, m:, m:].copy(), S=Z[:N, m:, :m].copy(), R=Z[:N, :m, :m].copy(),
             A=rng.standard_normal((N, n, n)) / np.sqrt(n), B=rng.standard_normal((N, n, m)) / np.sqrt(n),
             Dx=rng.uniform(0, 0.1, (N + 1, n)), Du=rng.uniform(0, 0.1, (N, m)),
             Ci=rng.standard_normal((N, ni, nz)), sig=rng.uniform(0, 1, (N, ni)),
             ni=rng.integers(0, ni + 1, N) if ni else np.zeros(N, dtype=np.int64))
    if ni:
        d["sig"][::3, 0] = 0.0
        d["ni"][-3:] = ni                  # stage rows in runs and alone
    rhs = dict(q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)), c=rng.standard_normal((N, n)),
               x0=rng.standard_normal(n), ci=rng.standard_normal((N, ni)))
    return d, rhs


def _factor(d, n, m):
    N = d["A"].shape[0]
    tags = size_tags(n, m)
    P = np.empty((N + 1, n, n)); K = np.empty((N, m, n)); L = np.empty((N, m, m))
    kernel = rf._factor_unconstrained_fixed if n <= rf._STRAIGHT_N_MAX else rf._factor_unconstrained_fixed_loops
    assert kernel(tags, *stage_arrays(d), 0.0, tuple(rk.PlainFactors(P, K, L))) == -1
    return tags, P, K, L


def stage_arrays(d):
    """The kernels' stage bundles (Costs, Dynamics, IPTerms) of the plain recursion's data d."""
    return (tuple(rk.Costs(d["Q"], d["S"], d["R"])), tuple(rk.Dynamics(d["A"], d["B"])),
            tuple(rk.IPTerms(d["Dx"], d["Du"], d["Ci"], d["sig"], d["ni"])))


def rhs_of(d, rhs):
    N, n, m = d["B"].shape
    return tuple(RHS(rhs["q"], rhs["r"], rhs["c"], rhs["x0"], np.zeros((N, 0)), np.zeros(0), rhs["ci"]))


def _solve_fixed(d, rhs, tags, P, K, L):
    N, n, m = d["B"].shape
    X = np.empty((N + 1, n)); U = np.empty((N, m)); lam = np.empty((N + 1, n))
    rf._solve_unconstrained_fixed(tags, *stage_arrays(d)[1:], tuple(rk.PlainFactors(P, K, L)), rhs_of(d, rhs),
                                  tuple(Solution(X, U, lam, np.zeros((N + 1, 0)))))
    return X, U, lam


def _solve_any(d, rhs, P, K, L):
    N, n, m = d["B"].shape
    X = np.empty((N + 1, n)); U = np.empty((N, m)); lam = np.empty((N + 1, n))
    rk._solve_unconstrained(*stage_arrays(d), tuple(rk.PlainFactors(P, K, L)), rhs_of(d, rhs),
                            tuple(Solution(X, U, lam, np.zeros((N + 1, 0)))))
    return X, U, lam


def _dense_kkt(d, rhs):
    """X, U, lam of the LQ problem by one dense KKT solve."""
    N, n, m = d["B"].shape
    nz = n + m
    nv = N * nz + n
    nc = (N + 1) * n
    H = np.zeros((nv, nv)); g = np.zeros(nv)
    Aeq = np.zeros((nc, nv)); beq = np.zeros(nc)
    for k in range(N):
        o = k * nz
        Hk = np.block([[d["Q"][k], d["S"][k]], [d["S"][k].T, d["R"][k]]])
        Hk[np.arange(n), np.arange(n)] += d["Dx"][k]
        Hk[n + np.arange(m), n + np.arange(m)] += d["Du"][k]
        gk = np.concatenate([rhs["q"][k], rhs["r"][k]])
        for cc in range(d["ni"][k]):
            C, w = d["Ci"][k, cc], d["sig"][k, cc]
            Hk += w * np.outer(C, C)
            gk = gk + w * rhs["ci"][k, cc] * C
        H[o:o + nz, o:o + nz] = Hk
        g[o:o + nz] = gk
        # x_{k+1} = A x_k + B u_k + c_k with multiplier lam_{k+1}
        Aeq[(k + 1) * n:(k + 2) * n, o:o + n] = d["A"][k]
        Aeq[(k + 1) * n:(k + 2) * n, o + n:o + nz] = d["B"][k]
        Aeq[(k + 1) * n:(k + 2) * n, o + nz:o + nz + n] = -np.eye(n)
        beq[(k + 1) * n:(k + 2) * n] = rhs["c"][k]
    o = N * nz
    H[o:, o:] = d["Q"][N] + np.diag(d["Dx"][N])
    g[o:] = rhs["q"][N]
    Aeq[:n, :n] = -np.eye(n)
    beq[:n] = rhs["x0"]
    # stationarity H z + g + Aeq^T lam = 0, Aeq z + beq = 0  (lam_0 belongs to -x_0 + x0 = 0)
    M = np.block([[H, Aeq.T], [Aeq, np.zeros((nc, nc))]])
    sol = np.linalg.solve(M, -np.concatenate([g, beq]))
    z, lam = sol[:nv], sol[nv:].reshape(N + 1, n)
    X = np.concatenate([z[:N * nz].reshape(N, nz)[:, :n], z[None, N * nz:]])
    U = z[:N * nz].reshape(N, nz)[:, n:]
    return X, U, lam


@pytest.mark.parametrize("n,m,ni", [(1, 1, 0), (1, 1, 1), (6, 7, 0), (3, 2, 2), (2, 5, 1), (5, 1, 0),
                                    (8, 9, 2), (13, 4, 1)])
def test_fixed_solve_matches_any_size_kernel_and_dense_kkt(n, m, ni):
    N = 30
    d, rhs = _problem(N, n, m, ni, seed=100 * n + 10 * m + ni)
    tags, P, K, L = _factor(d, n, m)
    out = _solve_fixed(d, rhs, tags, P, K, L)
    ref = _solve_any(d, rhs, P, K, L)
    for a, b in zip(out, ref):
        assert np.all(np.isfinite(a))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * max(1.0, np.max(np.abs(b))))
    if N * (n + m) <= 600:
        for a, b in zip(out, _dense_kkt(d, rhs)):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-8 * max(1.0, np.max(np.abs(b))))


def test_fixed_solve_through_factorization_object():
    N, n, m = 25, 3, 2
    d, rhs = _problem(N, n, m, 2, seed=7)
    fac = rc.RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], Dx=d["Dx"], Du=d["Du"], Ci=d["Ci"],
                                  sigma=d["sig"], n_ineq=d["ni"])
    assert fac._size_tags is not None
    sol = fac.solve(rhs["q"], rhs["r"], rhs["c"], rhs["x0"], ci=rhs["ci"])
    for a, b in zip((sol.X, sol.U, sol.lam), _dense_kkt(d, rhs)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-8 * max(1.0, np.max(np.abs(b))))


@pytest.mark.parametrize("n,m", [(6, 7), (3, 2)])
def test_fixed_solve_propagates_non_finite_input(n, m):
    N = 20
    d, rhs = _problem(N, n, m, 1, seed=3)
    tags, P, K, L = _factor(d, n, m)
    k = 12
    rhs["r"][k, 0] = np.nan
    X, U, lam = _solve_fixed(d, rhs, tags, P, K, L)
    X0, U0, lam0 = _solve_any(d, rhs, P, K, L)
    # the NaN reaches k_k, hence every later state and control, and p_j, j <= k
    assert np.all(np.isnan(U[k:])) and np.all(np.isnan(X[k + 1:]))
    assert np.all(np.isnan(lam[:k + 1]))
    for a, b in zip((X, U, lam), (X0, U0, lam0)):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    # an infinite offset: NaN and inf where the any-size kernel has them
    d2, rhs2 = _problem(N, n, m, 0, seed=4)
    tags, P, K, L = _factor(d2, n, m)
    rhs2["c"][N - 1, 0] = np.inf
    X, U, lam = _solve_fixed(d2, rhs2, tags, P, K, L)
    X0, U0, lam0 = _solve_any(d2, rhs2, P, K, L)
    assert not np.all(np.isfinite(X[N]))
    for a, b in zip((X, U, lam), (X0, U0, lam0)):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
