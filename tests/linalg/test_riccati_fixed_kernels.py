"""The fixed-size Riccati kernels (straight-line SIMD stage elimination, and the scalar-loop
kernel kept for large n) against the any-size kernels and a dense KKT solve."""

import numpy as np
import pytest

from olado.linalg import riccati as rc, riccati_fixed as rf, riccati_kernels as rk
from olado.linalg.codegen import size_tags


def _stage_data(N, n, m, ni=2, cond=1e2, seed=0):
    rng = np.random.default_rng(seed)
    nz = n + m
    Qm, _ = np.linalg.qr(rng.standard_normal((N + 1, nz, nz)))
    ev = np.exp(rng.uniform(np.log(1.0 / cond), 0.0, (N + 1, nz)))
    Z = np.einsum("kij,kj,klj->kil", Qm, ev, Qm)
    d = dict(Q=Z[:, m:, m:].copy(), S=Z[:N, m:, :m].copy(), R=Z[:N, :m, :m].copy(),
             A=rng.standard_normal((N, n, n)) / np.sqrt(n), B=rng.standard_normal((N, n, m)) / np.sqrt(n),
             Dx=rng.uniform(0, 0.1, (N + 1, n)), Du=rng.uniform(0, 0.1, (N, m)),
             Ci=rng.standard_normal((N, ni, nz)), sig=rng.uniform(0, 1, (N, ni)), ni=rng.integers(0, ni + 1, N))
    d["sig"][::3, 0] = 0.0
    return d


def _factor(kernel, d, tags=None, reg=0.0):
    N, n, m = d["A"].shape[0], d["A"].shape[1], d["B"].shape[2]
    P = np.full((N + 1, n, n), np.nan); K = np.full((N, m, n), np.nan); L = np.full((N, m, m), np.nan)
    args = (*stage_arrays(d), reg, tuple(rk.PlainFactors(P, K, L)))
    code = kernel(*args) if tags is None else kernel(tags, *args)
    return code, P, K, L


def stage_arrays(d):
    """The kernels' stage bundles (Costs, Dynamics, IPTerms) of the plain recursion's data d."""
    return (tuple(rk.Costs(d["Q"], d["S"], d["R"])), tuple(rk.Dynamics(d["A"], d["B"])),
            tuple(rk.IPTerms(d["Dx"], d["Du"], d["Ci"], d["sig"], d["ni"])))


@pytest.mark.parametrize("n,m", [(1, 1), (2, 3), (6, 7), (4, 12), (12, 3), (14, 4)])
def test_fixed_factor_matches_any_size_kernel(n, m):
    N = 40
    d = _stage_data(N, n, m, seed=10 * n + m)
    tags = size_tags(n, m)
    c0, P0, K0, L0 = _factor(rk._factor_unconstrained, d)
    kernels = [rf._factor_unconstrained_fixed] if n <= rf._STRAIGHT_N_MAX else []
    for kernel in kernels + [rf._factor_unconstrained_fixed_loops]:
        c, P, K, L = _factor(kernel, d, tags)
        assert c == c0 == -1
        np.testing.assert_allclose(P, P0, rtol=1e-11, atol=1e-11 * np.abs(P0).max())
        np.testing.assert_allclose(K, K0, rtol=1e-10, atol=1e-11 * np.abs(K0).max())
        np.testing.assert_allclose(L, L0, rtol=1e-11, atol=1e-11 * np.abs(L0).max())
        assert np.all(np.triu(L, 1) == 0.0)
        assert np.array_equal(P, P.transpose(0, 2, 1))
        # non-symmetric Q, R: only their symmetric parts count
        rng = np.random.default_rng(1)
        e = dict(d)
        for key in ("Q", "R"):
            M = rng.standard_normal(d[key].shape)
            e[key] = d[key] + 0.3 * (M - M.transpose(0, 2, 1))
        c, P2, K2, L2 = _factor(kernel, e, tags)
        assert c == -1
        np.testing.assert_allclose(P2, P, rtol=1e-11, atol=1e-11 * np.abs(P).max())
        np.testing.assert_allclose(K2, K, rtol=1e-10, atol=1e-11 * np.abs(K).max())


def test_fixed_factor_and_solve_against_dense_kkt():
    """The solution of a small problem through RiccatiFactorization equals the dense KKT solve."""
    N, n, m = 5, 6, 7
    d = _stage_data(N, n, m, seed=7)
    rng = np.random.default_rng(8)
    q, r, c, x0 = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m)), rng.standard_normal((N, n)), rng.standard_normal(n)
    ci = rng.standard_normal(d["sig"].shape)
    fact = rc.RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], Dx=d["Dx"], Du=d["Du"], Ci=d["Ci"],
                                   sigma=d["sig"], n_ineq=d["ni"], regularization=1e-3)
    assert fact._size_tags is not None
    sol = fact.solve(q, r, c, x0, ci=ci)
    # dense KKT in z = (x_0, u_0, x_1, u_1, ..., x_N), multipliers of x_0 = x0 and the dynamics
    nz = n + m
    nv = N * nz + n
    H = np.zeros((nv, nv)); g = np.zeros(nv)
    for k in range(N):
        o = k * nz
        Hk = np.zeros((nz, nz))
        Hk[:n, :n] = 0.5 * (d["Q"][k] + d["Q"][k].T) + np.diag(d["Dx"][k])
        Hk[:n, n:] = d["S"][k]; Hk[n:, :n] = d["S"][k].T
        Hk[n:, n:] = 0.5 * (d["R"][k] + d["R"][k].T) + np.diag(d["Du"][k] + 1e-3)
        gk = np.concatenate([q[k], r[k]])
        for cc in range(d["ni"][k]):
            Hk += d["sig"][k, cc] * np.outer(d["Ci"][k, cc], d["Ci"][k, cc])
            gk += d["sig"][k, cc] * ci[k, cc] * d["Ci"][k, cc]
        H[o:o + nz, o:o + nz] += Hk; g[o:o + nz] += gk
    H[-n:, -n:] += 0.5 * (d["Q"][N] + d["Q"][N].T) + np.diag(d["Dx"][N]); g[-n:] += q[N]
    E = np.zeros((n + N * n, nv)); e = np.zeros(n + N * n)
    E[:n, :n] = np.eye(n); e[:n] = x0
    for k in range(N):
        rows = slice(n + k * n, n + (k + 1) * n)
        E[rows, k * nz:k * nz + n] = d["A"][k]; E[rows, k * nz + n:(k + 1) * nz] = d["B"][k]
        E[rows, (k + 1) * nz:(k + 1) * nz + n] = -np.eye(n); e[rows] = -c[k]
    kkt = np.block([[H, E.T], [E, np.zeros((E.shape[0], E.shape[0]))]])
    z = np.linalg.solve(kkt, np.concatenate([-g, e]))[:nv]
    X = np.array([z[k * nz:k * nz + n] for k in range(N + 1)])
    U = np.array([z[k * nz + n:(k + 1) * nz] for k in range(N)])
    np.testing.assert_allclose(sol.X, X, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(sol.U, U, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kernel", ["_factor_unconstrained_fixed", "_factor_unconstrained_fixed_loops"])
def test_fixed_factor_reports_failing_stage(kernel):
    N, n, m = 30, 6, 7
    kernel = getattr(rc, kernel)
    tags = size_tags(n, m)
    d = _stage_data(N, n, m, seed=3)
    d["R"][17] -= 50.0 * np.eye(m)                      # Q_uu indefinite at stage 17
    assert _factor(kernel, d, tags)[0] == 17
    d = _stage_data(N, n, m, seed=3)
    d["R"][11, 2, 2] = np.nan                             # NaN pivot
    assert _factor(kernel, d, tags)[0] == 11
    d = _stage_data(N, n, m, seed=3)
    d["A"][20, 1, 3] = np.inf                             # P_20 not finite -> NaN pivots at stage 19
    assert _factor(kernel, d, tags)[0] == _factor(rk._factor_unconstrained, d)[0] == 19
    d = _stage_data(N, n, m, seed=3)
    d["R"][5] = 0.0; d["S"][5] = 0.0; d["Du"][5] = 0.0; d["B"][5] = 0.0   # Q_uu = 0: zero pivot
    assert _factor(kernel, d, tags)[0] == 5
