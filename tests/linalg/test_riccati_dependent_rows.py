"""The Riccati recursion with linearly dependent equality rows (paper 001 sec. 4.2.3): the state
rows passed back from stage to stage are compressed to an independent set, dependent rows only
impose a consistency condition on the constants (its violation is reported as the solve's
residual), and the multipliers still satisfy the KKT rows.  References: a least-squares solve of
the (singular) dense KKT system -- the primal part is unique when the reduced Hessian is positive
definite -- and the KKT rows themselves with the returned lam, nu."""

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from olado.linalg import RiccatiFactorization
from olado.result import Status
from olado.qp.interior_point import MehrotraQP

from fixtures.qp_problems import random_qp, replace  # noqa: E402
from test_riccati import dense_kkt_system  # noqa: E402


# ============================================================================= references
def dense_lstsq(d):
    """Primal part (X, U) of the dense KKT system of the LQ-DOCP d, by a minimum-norm least-squares
    solve (the matrix is singular when equality rows are dependent)."""
    keys = ("Q", "S", "R", "q", "r", "A", "B", "c", "x0", "E", "F", "e", "EN", "eN", "Dx", "Du")
    K, b, unpack = dense_kkt_system(*(d.get(k) for k in keys), n_eq=d.get("n_eq"))
    return unpack(np.linalg.lstsq(K, b, rcond=1e-12)[0])


def kkt_residuals(d, sol):
    """(stationarity, primal) max-norm residuals of the KKT rows at sol, with the Lagrangian
    J + sum lam_{k+1}.(A x + B u + c - x_{k+1}) + lam_0.(x0 - x_0) + sum nu_k.(E x + F u + e) + nu_N.(E_N x_N + e_N)."""
    Q, S, R, q, r, A, B, c, x0 = (d[k] for k in ("Q", "S", "R", "q", "r", "A", "B", "c", "x0"))
    E, F, e, EN, eN = (d.get(k) for k in ("E", "F", "e", "EN", "eN"))
    Dx, Du = d.get("Dx"), d.get("Du")
    N, n, m = B.shape
    X, U, lam, nu = sol.X, sol.U, sol.lam, sol.nu
    ne = None if E is None else (np.full(N, E.shape[1]) if d.get("n_eq") is None else d["n_eq"])
    stat, prim = [], [X[0] - x0]
    for k in range(N):
        gx = Q[k] @ X[k] + S[k] @ U[k] + q[k] + A[k].T @ lam[k + 1] - lam[k]
        gu = S[k].T @ X[k] + R[k] @ U[k] + r[k] + B[k].T @ lam[k + 1]
        if Dx is not None:
            gx = gx + Dx[k] * X[k]; gu = gu + Du[k] * U[k]
        if E is not None:
            nk = ne[k]
            gx = gx + E[k, :nk].T @ nu[k, :nk]; gu = gu + F[k, :nk].T @ nu[k, :nk]
            prim.append(E[k, :nk] @ X[k] + F[k, :nk] @ U[k] + e[k, :nk])
        stat += [gx, gu]
        prim.append(A[k] @ X[k] + B[k] @ U[k] + c[k] - X[k + 1])
    gN = Q[N] @ X[N] + q[N] - lam[N] + (Dx[N] * X[N] if Dx is not None else 0.0)
    if EN is not None:
        gN = gN + EN.T @ nu[N, :EN.shape[0]]
        prim.append(EN @ X[N] + eN)
    stat.append(gN)
    return np.abs(np.concatenate(stat)).max(), np.abs(np.concatenate(prim)).max()


def factor_and_solve(d):
    fac = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], E=d.get("E"), F=d.get("F"), n_eq=d.get("n_eq"),
                               EN=d.get("EN"), Dx=d.get("Dx"), Du=d.get("Du"))
    return fac, fac.solve(d["q"], d["r"], d["c"], d["x0"], e=d.get("e"), eN=d.get("eN"))


def check(d, tol=1e-8):
    """The Riccati solution equals the dense least-squares one, satisfies the KKT rows with its
    multipliers, and reports a zero (rounding) residual; returns (factorization, solution)."""
    fac, sol = factor_and_solve(d)
    X, U = dense_lstsq(d)
    scale = max(1.0, np.abs(X).max(), np.abs(U).max())
    assert np.abs(sol.X - X).max() <= tol * scale
    assert np.abs(sol.U - U).max() <= tol * scale
    mscale = max(scale, np.abs(sol.lam).max(), np.abs(sol.nu).max())
    stat, prim = kkt_residuals(d, sol)
    assert stat <= tol * mscale and prim <= tol * scale
    assert sol.x0_residual <= tol * scale
    assert fac.unconstrained or (fac.ng[:fac.N] <= fac.n).all()     # compressed (G_N = E_N as given)
    return fac, sol


def base_problem(rng, N, n, m):
    def spd(k):
        M = rng.standard_normal((k, k))
        return M @ M.T + 0.5 * np.eye(k)

    return dict(Q=np.array([spd(n) for _ in range(N + 1)]), R=np.array([spd(m) for _ in range(N)]),
                S=0.1 * rng.standard_normal((N, n, m)), A=0.8 * rng.standard_normal((N, n, n)) / np.sqrt(n),
                B=rng.standard_normal((N, n, m)), q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
                c=rng.standard_normal((N, n)), x0=rng.standard_normal(n))


def simulate(d, U):
    N, n, _ = d["B"].shape
    X = np.empty((N + 1, n)); X[0] = d["x0"]
    for k in range(N):
        X[k + 1] = d["A"][k] @ X[k] + d["B"][k] @ U[k] + d["c"][k]
    return X


def fix_all_states(d, X):
    """Rows x_k - X_k = 0 at every stage k >= 1 (stage 0: x_0 is fixed by its own row) and at N."""
    N, n, _ = d["B"].shape
    m = d["B"].shape[2]
    E = np.broadcast_to(np.eye(n), (N, n, n)).copy()
    d.update(E=E, F=np.zeros((N, n, m)), e=-X[:N].copy(), n_eq=np.r_[0, np.full(N - 1, n)], EN=np.eye(n), eN=-X[N])
    return d


# ============================================================================= (1) every state fixed
@pytest.mark.parametrize("n, m", [(3, 2), (3, 3), (2, 4)])
def test_every_state_fixed_on_the_factorization(n, m):
    rng = np.random.default_rng(11)
    N = 7
    d = base_problem(rng, N, n, m)
    Us = rng.standard_normal((N, m))
    Xs = simulate(d, Us)
    fac, sol = check(fix_all_states(d, Xs))
    assert (fac.ng[:N] <= n).all()
    np.testing.assert_allclose(sol.X, Xs, atol=1e-10)
    if m <= n:       # B_k of full column rank: the controls are fixed too
        np.testing.assert_allclose(sol.U, Us, atol=1e-9)
    # refactor (new diagonal terms, arrays reused) equals a fresh factorization
    d2 = dict(d, Dx=rng.uniform(0.1, 10, (N + 1, n)), Du=rng.uniform(0.1, 10, (N, m)))
    fac.refactor(Dx=d2["Dx"], Du=d2["Du"])
    a = fac.solve(d["q"], d["r"], d["c"], d["x0"], e=d["e"], eN=d["eN"])
    _, b = check(d2)
    for u, v in ((a.X, b.X), (a.U, b.U), (a.lam, b.lam), (a.nu, b.nu)):
        np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-12)


def _fixed_trajectory_qp(seed=0, N=6, n=3, m=2):
    qp = random_qp(seed, N=N, n=n, m=m, nc=0, ncN=0)
    U = np.clip(np.zeros((qp.N, qp.m)), qp.u_lower, qp.u_upper)
    X = np.empty((qp.N + 1, qp.n)); X[0] = qp.x0
    for k in range(qp.N):
        X[k + 1] = qp.A[k] @ X[k] + qp.B[k] @ U[k] + qp.c[k]
    return qp, X, U


def test_every_state_fixed_through_the_interior_point_qp():
    """The reproduction of the defect: the fixed states become equality rows, dependent with the
    dynamics; the QP now solves, at the fixed trajectory with the consistent controls."""
    qp, X, U = _fixed_trajectory_qp()
    res = MehrotraQP().solve(replace(qp, x_lower=X.copy(), x_upper=X.copy()))
    assert res.status is Status.SUCCESS, res.message
    np.testing.assert_allclose(res.X, X, atol=1e-9)
    np.testing.assert_allclose(res.U, U, atol=1e-7)


def test_states_fixed_at_the_optimal_trajectory_through_the_interior_point_qp():
    """The states x_1..x_N fixed at the QP's own optimum (with nonzero bound multipliers)."""
    qp = random_qp(0, nc=0, ncN=0)
    ref = MehrotraQP(tol=1e-10).solve(qp)
    xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
    xl[1:], xu[1:] = ref.X[1:], ref.X[1:]
    res = MehrotraQP().solve(replace(qp, x_lower=xl, x_upper=xu))
    assert res.status is Status.SUCCESS, res.message
    np.testing.assert_allclose(res.X, ref.X, atol=1e-9)
    np.testing.assert_allclose(res.U, ref.U, atol=1e-6)
    assert res.objective == pytest.approx(ref.objective, rel=1e-8, abs=1e-10)


# ============================================================================= (2), (3) dependent rows
def test_duplicated_stage_rows():
    rng = np.random.default_rng(3)
    N, n, m = 6, 3, 3
    d = base_problem(rng, N, n, m)
    Us = rng.standard_normal((N, m)); Xs = simulate(d, Us)
    E = rng.standard_normal((N, 4, n)); F = rng.standard_normal((N, 4, m))
    F[::2, 2:] = 0.0                                   # state-only rows on even stages (on x_0 at k = 0)
    E[:, 1], F[:, 1] = E[:, 0], F[:, 0]                # the same row twice
    E[:, 3], F[:, 3] = 2.0 * E[:, 2], 2.0 * F[:, 2]    # and a multiple
    d.update(E=E, F=F, e=-(np.einsum("kij,kj->ki", E, Xs[:N]) + np.einsum("kij,kj->ki", F, Us)))
    fac, sol = check(d, tol=1e-7)
    assert (fac.ng[:N] <= n).all()


def test_final_row_repeating_a_stage_rows_implication():
    """Stage row h.(A x + B u + c) - b = 0 at k = N-1 and final row h.x_N - b = 0: after the
    propagation they are the same row (exactly cancelling to rounding noise in the u elimination),
    and a final row given twice."""
    rng = np.random.default_rng(4)
    N, n, m = 5, 3, 2
    d = base_problem(rng, N, n, m)
    h = rng.standard_normal(n); b = 0.7
    E = np.zeros((N, 1, n)); F = np.zeros((N, 1, m)); e = np.zeros((N, 1)); ne = np.zeros(N, dtype=int)
    E[N - 1, 0] = h @ d["A"][N - 1]; F[N - 1, 0] = h @ d["B"][N - 1]; e[N - 1, 0] = h @ d["c"][N - 1] - b; ne[N - 1] = 1
    g2 = rng.standard_normal(n)
    d.update(E=E, F=F, e=e, n_eq=ne, EN=np.array([h, g2, g2]), eN=np.array([-b, 0.3, 0.3]))
    fac, sol = check(d)
    assert abs(h @ sol.X[N] - b) < 1e-10
    # the final row repeated on a stage row two stages earlier (through two dynamics steps) as a
    # state-only row at k = N-2 and u at k = N-1 fixed
    d2 = base_problem(rng, N, n, m)
    E = np.zeros((N, 2, n)); F = np.zeros((N, 2, m)); e = np.zeros((N, 2)); ne = np.zeros(N, dtype=int)
    ub = np.array([0.2, -0.4])
    F[N - 1] = np.eye(m); e[N - 1] = -ub; ne[N - 1] = 2                       # u_{N-1} = ub
    AA = d2["A"][N - 1] @ d2["A"][N - 2]
    E[N - 2, 0] = h @ AA; ne[N - 2] = 1
    F[N - 2, 0] = h @ d2["A"][N - 1] @ d2["B"][N - 2]
    e[N - 2, 0] = h @ (d2["A"][N - 1] @ d2["c"][N - 2] + d2["B"][N - 1] @ ub + d2["c"][N - 1]) - b
    d2.update(E=E, F=F, e=e, n_eq=ne, EN=h[None, :], eN=np.array([-b]))
    check(d2)


def test_more_final_rows_than_states():
    rng = np.random.default_rng(5)
    N, n, m = 4, 3, 3
    d = base_problem(rng, N, n, m)
    xN = rng.standard_normal(n)
    W = rng.standard_normal((5, n))                   # 5 rows, rank 3
    d.update(EN=W, eN=-W @ xN)
    fac, sol = check(d)
    np.testing.assert_allclose(sol.X[N], xN, atol=1e-10)


# ============================================================================= (4) inconsistent rows
def _unreachable(delta):
    """x_{k-1} and u_{k-1} fixed by stage rows, x_k fixed by a stage row to a value off by delta."""
    rng = np.random.default_rng(6)
    N, n, m = 6, 3, 2
    d = base_problem(rng, N, n, m)
    Us = 0.3 * rng.standard_normal((N, m)); Xs = simulate(d, Us)
    k = 3
    E = np.zeros((N, n + m, n)); F = np.zeros((N, n + m, m)); e = np.zeros((N, n + m)); ne = np.zeros(N, dtype=int)
    E[k - 1, :n] = np.eye(n); F[k - 1, n:] = np.eye(m); e[k - 1, :n] = -Xs[k - 1]; e[k - 1, n:] = -Us[k - 1]
    ne[k - 1] = n + m
    E[k, :n] = np.eye(n); e[k, :n] = -(Xs[k] + delta * np.array([1.0, -1.0, 0.5])); ne[k] = n
    d.update(E=E, F=F, e=e, n_eq=ne)
    return d


def test_inconsistent_dependent_rows_are_reported_by_the_residual():
    d = _unreachable(0.0)
    check(d)
    for delta in (1e-1, 1e-4):
        d = _unreachable(delta)
        fac, sol = factor_and_solve(d)
        assert (fac.ng <= fac.n).all()
        # the defect is the distance of the fixed x_k from the reachable point, in row units
        assert delta * 0.1 < sol.x0_residual < delta * 10
        assert np.isfinite(sol.X).all() and np.isfinite(sol.lam).all() and np.isfinite(sol.nu).all()


@pytest.mark.parametrize("fix_controls", [False, True])
def test_inconsistent_fixed_states_through_the_interior_point_qp(fix_controls):
    qp, X, U = _fixed_trajectory_qp()
    Xb = X.copy(); Xb[3] += 0.1 * np.array([1.0, -1.0, 0.5])      # not reachable from x_2 (B_2 has 2 columns)
    kw = dict(x_lower=Xb.copy(), x_upper=Xb.copy())
    if fix_controls:
        kw.update(u_lower=U.copy(), u_upper=U.copy())
    res = MehrotraQP().solve(replace(qp, **kw))          # never an exception
    # the starting point's solve sees the consistency defect of the dropped rows
    assert res.status is Status.INFEASIBLE, res.message
    assert "inconsistent" in res.message and res.iterations == 0


# ============================================================================= (5) random dependent rows
@settings(max_examples=60, deadline=None)
@given(N=st.integers(1, 5), n=st.integers(1, 4), m=st.integers(1, 3), seed=st.integers(0, 10_000),
       n_extra=st.integers(0, 6), with_bounds=st.booleans(), fixed_states=st.booleans())
def test_random_dependent_rows_match_dense_and_the_problem_without_them(N, n, m, seed, n_extra, with_bounds,
                                                                        fixed_states):
    """Base rows (0..2 per stage, some state-only, at most one final row; with ``fixed_states``
    also x_k fixed at random stages k >= 1, as the interior-point QP's fixed states) consistent
    with a simulated point, plus 0..n+2 dependent rows per stage: random combinations of the
    stage's own rows and of the next stage's state-only rows (final rows) lifted through the
    dynamics. The solution equals the dense one and that of the base rows alone; KKT rows hold."""
    n_extra = min(n_extra, n + 2)
    rng = np.random.default_rng(seed)
    d = base_problem(rng, N, n, m)
    if with_bounds:
        d["Dx"] = rng.uniform(0, 10, (N + 1, n)); d["Du"] = rng.uniform(0, 10, (N, m))
    Us = rng.standard_normal((N, m)); Xs = simulate(d, Us)      # the point the rows are consistent with
    nb = rng.integers(0, 3, N)
    base_E, base_F = [], []
    for k in range(N):
        Ek = rng.standard_normal((nb[k], n)); Fk = rng.standard_normal((nb[k], m))
        if nb[k] and rng.random() < 0.5:
            Fk[-1] = 0.0                               # a state-only row
        if fixed_states and k > 0 and rng.random() < 0.6:
            Ek = np.vstack([Ek, np.eye(n)]); Fk = np.vstack([Fk, np.zeros((n, m))])
        base_E.append(Ek); base_F.append(Fk)
    nb = np.array([r.shape[0] for r in base_E])
    neN = int(rng.integers(0, 2))
    EN = rng.standard_normal((neN, n))
    rows_E, rows_F = [], []
    for k in range(N):
        # pool of rows valid at stage k: own rows, and the state-only rows of stage k+1 (or the
        # final rows) through x_{k+1} = A x + B u + c (constants follow from the feasible point)
        pool_E, pool_F = [base_E[k]], [base_F[k]]
        if k + 1 < N:
            so = ~base_F[k + 1].any(axis=1)
            H = base_E[k + 1][so]
        else:
            H = EN
        pool_E.append(H @ d["A"][k]); pool_F.append(H @ d["B"][k])
        PE, PF = np.vstack(pool_E), np.vstack(pool_F)
        W = rng.standard_normal((n_extra, PE.shape[0])) if PE.shape[0] else np.zeros((0, 0))
        rows_E.append(np.vstack([base_E[k], W @ PE]) if PE.shape[0] else base_E[k])
        rows_F.append(np.vstack([base_F[k], W @ PF]) if PE.shape[0] else base_F[k])
    ne = np.array([r.shape[0] for r in rows_E])
    nmax = max(int(ne.max()), 1)
    E = np.zeros((N, nmax, n)); F = np.zeros((N, nmax, m)); e = np.zeros((N, nmax))
    nbmax = max(int(nb.max()), 1)
    Eb = np.zeros((N, nbmax, n)); Fb = np.zeros((N, nbmax, m)); eb = np.zeros((N, nbmax))
    for k in range(N):
        E[k, :ne[k]] = rows_E[k]; F[k, :ne[k]] = rows_F[k]
        e[k, :ne[k]] = -(rows_E[k] @ Xs[k] + rows_F[k] @ Us[k])
        Eb[k, :nb[k]] = base_E[k]; Fb[k, :nb[k]] = base_F[k]; eb[k, :nb[k]] = -(base_E[k] @ Xs[k] + base_F[k] @ Us[k])
    full = dict(d, E=E, F=F, e=e, n_eq=ne, EN=EN, eN=-EN @ Xs[N])
    base = dict(d, E=Eb, F=Fb, e=eb, n_eq=nb, EN=EN, eN=-EN @ Xs[N])
    _, a = check(full, tol=1e-6)
    _, b = factor_and_solve(base)
    scale = max(1.0, np.abs(b.X).max(), np.abs(b.U).max())
    assert np.abs(a.X - b.X).max() <= 1e-6 * scale and np.abs(a.U - b.U).max() <= 1e-6 * scale


def test_inconsistent_fixed_states_warm_started_are_reported_by_the_first_newton_step():
    """A warm start skips the starting-point solve: the first Newton solve's consistency defect
    (the same defect, the rows being linear) reports the inconsistency."""
    qp, X, U = _fixed_trajectory_qp()
    first = MehrotraQP().solve(qp)
    Xb = X.copy(); Xb[3] += 0.1 * np.array([1.0, -1.0, 0.5])
    res = MehrotraQP().solve(replace(qp, x_lower=Xb.copy(), x_upper=Xb.copy()), warm_start=first)
    assert res.status is Status.INFEASIBLE, res.message
    assert "inconsistent" in res.message and "Newton step" in res.message
