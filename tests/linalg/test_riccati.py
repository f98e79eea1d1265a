"""The Riccati LQ-DOCP solver against a dense solve of the same KKT system (paper 001 sec. 4.2.3)."""

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from olado.linalg import NotPositiveDefiniteError, RiccatiFactorization


def dense_kkt_system(Q, S, R, q, r, A, B, c, x0, E=None, F=None, e=None, EN=None, eN=None, Dx=None, Du=None,
                     n_eq=None):
    """The full KKT matrix and right-hand side of the LQ-DOCP, with the multipliers in the order
    [x0 rows, dynamics rows k=0..N-1, stage equality rows (the first n_eq[k] of stage k), final
    equality rows]; returns (K, rhs, unpack) with unpack(z) = (X, U) of a solution z."""
    N, n, m = B.shape
    nz = n + m
    nv = N * nz + n

    def xi(k):
        return k * nz + np.arange(n)

    def ui(k):
        return k * nz + n + np.arange(m)

    H = np.zeros((nv, nv)); g = np.zeros(nv)
    for k in range(N):
        H[np.ix_(xi(k), xi(k))] += Q[k] + (np.diag(Dx[k]) if Dx is not None else 0)
        H[np.ix_(xi(k), ui(k))] += S[k]; H[np.ix_(ui(k), xi(k))] += S[k].T
        H[np.ix_(ui(k), ui(k))] += R[k] + (np.diag(Du[k]) if Du is not None else 0)
        g[xi(k)] += q[k]; g[ui(k)] += r[k]
    H[np.ix_(xi(N), xi(N))] += Q[N] + (np.diag(Dx[N]) if Dx is not None else 0); g[xi(N)] += q[N]
    rows, rhs = [], []
    C = np.zeros((n, nv)); C[:, xi(0)] = np.eye(n); rows.append(C); rhs.append(x0)
    for k in range(N):
        C = np.zeros((n, nv)); C[:, xi(k)] = A[k]; C[:, ui(k)] = B[k]; C[:, xi(k + 1)] = -np.eye(n)
        rows.append(C); rhs.append(-c[k])
    if E is not None:
        for k in range(N):
            nk = E.shape[1] if n_eq is None else n_eq[k]
            C = np.zeros((nk, nv)); C[:, xi(k)] = E[k, :nk]; C[:, ui(k)] = F[k, :nk]
            rows.append(C); rhs.append(-e[k, :nk])
    if EN is not None:
        C = np.zeros((EN.shape[0], nv)); C[:, xi(N)] = EN; rows.append(C); rhs.append(-eN)
    C = np.vstack(rows); d = np.concatenate(rhs)
    K = np.block([[H, C.T], [C, np.zeros((C.shape[0], C.shape[0]))]])

    def unpack(z):
        return np.array([z[xi(k)] for k in range(N + 1)]), np.array([z[ui(k)] for k in range(N)])
    return K, np.concatenate([-g, d]), unpack


def dense_kkt(Q, S, R, q, r, A, B, c, x0, E=None, F=None, e=None, EN=None, eN=None, Dx=None, Du=None):
    """Assemble and solve the full KKT system with numpy (:func:`dense_kkt_system`): X, U and
    the multipliers."""
    K, b, unpack = dense_kkt_system(Q, S, R, q, r, A, B, c, x0, E, F, e, EN, eN, Dx, Du)
    dense_kkt.last_condition = np.linalg.cond(K)
    sol = np.linalg.solve(K, b)
    nv = B.shape[0] * (B.shape[1] + B.shape[2]) + B.shape[1]
    X, U = unpack(sol)
    return X, U, sol[nv:]


def random_problem(rng, N, n, m, ne=0, neN=0, pure_state=False, cond=1.0):
    def spd(d):
        M = rng.standard_normal((d, d))
        return M @ M.T + 0.5 * np.eye(d)

    Q = np.array([spd(n) for _ in range(N + 1)]) * cond
    R = np.array([spd(m) for _ in range(N)])
    S = 0.1 * rng.standard_normal((N, n, m))
    A = 0.8 * rng.standard_normal((N, n, n)) / np.sqrt(n); B = rng.standard_normal((N, n, m))  # mild growth
    data = dict(Q=Q, S=S, R=R, A=A, B=B, q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)),
                c=rng.standard_normal((N, n)), x0=rng.standard_normal(n))
    if ne:
        E = rng.standard_normal((N, ne, n)); F = rng.standard_normal((N, ne, m)); e = rng.standard_normal((N, ne))
        if pure_state:
            # state-only rows on odd stages (passed back to the stage before); none on the fixed x0
            F[1::2] = 0.0
        data.update(E=E, F=F, e=e)
    if neN:
        data.update(EN=rng.standard_normal((neN, n)), eN=rng.standard_normal(neN))
    return data


def check_against_dense(d, tol=1e-8, max_condition=None):
    fac = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], E=d.get("E"), F=d.get("F"), EN=d.get("EN"),
                               Dx=d.get("Dx"), Du=d.get("Du"))
    sol = fac.solve(d["q"], d["r"], d["c"], d["x0"], e=d.get("e"), eN=d.get("eN"))
    X, U, mult = dense_kkt(**{k: d.get(k) for k in ("Q", "S", "R", "q", "r", "A", "B", "c", "x0", "E", "F", "e", "EN", "eN", "Dx", "Du")})
    if max_condition is not None:
        # the dense reference itself is unreliable on badly conditioned draws (closed-loop growth)
        assume(dense_kkt.last_condition < max_condition)
    N, n = d["B"].shape[:2]
    scale = max(1.0, np.abs(X).max(), np.abs(U).max())
    assert np.abs(sol.X - X).max() <= tol * scale
    assert np.abs(sol.U - U).max() <= tol * scale
    mscale = max(1.0, np.abs(mult).max())
    assert np.abs(sol.lam[0] + mult[:n]).max() <= tol * mscale          # lam_0 multiplies (xbar0 - x0)
    assert np.abs(sol.lam[1:] - mult[n:n + N * n].reshape(N, n)).max() <= tol * mscale
    s = n + N * n
    if "E" in d:
        ne = d["E"].shape[1]
        assert np.abs(sol.nu[:N, :ne] - mult[s:s + N * ne].reshape(N, ne)).max() <= tol * mscale
        s += N * ne
    if "EN" in d:
        assert np.abs(sol.nu[N, :d["EN"].shape[0]] - mult[s:]).max() <= tol * mscale
    return sol


@settings(max_examples=40, deadline=None)
@given(N=st.integers(1, 6), n=st.integers(1, 4), m=st.integers(1, 3), seed=st.integers(0, 10_000),
       with_bounds=st.booleans())
def test_unconstrained_recursion_matches_dense(N, n, m, seed, with_bounds):
    rng = np.random.default_rng(seed)
    d = random_problem(rng, N, n, m)
    if with_bounds:  # diagonal interior-point terms of simple bounds, eq. (25)
        d["Dx"] = rng.uniform(0, 100, (N + 1, n)); d["Du"] = rng.uniform(0, 100, (N, m))
    check_against_dense(d)


@settings(max_examples=40, deadline=None)
@given(N=st.integers(2, 6), n=st.integers(2, 4), m=st.integers(1, 3), seed=st.integers(0, 10_000),
       pure_state=st.booleans(), neN=st.integers(0, 2))
def test_equality_constrained_recursion_matches_dense(N, n, m, seed, pure_state, neN):
    rng = np.random.default_rng(seed)
    if pure_state:  # enough controls to satisfy the propagated rows (else the KKT matrix is singular)
        m, neN = m + 2, min(neN, 1)
    else:
        m = max(m, 1 + neN)
    d = random_problem(rng, N, n, m, ne=1, neN=min(neN, n, m), pure_state=pure_state)
    check_against_dense(d, tol=1e-7, max_condition=1e9)


def test_inconsistent_rows_on_the_fixed_initial_state_are_reported():
    rng = np.random.default_rng(8)
    d = random_problem(rng, 2, 2, 1, ne=1, neN=1)   # 3 rows, 2 controls: one row lands on x0
    sol = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], E=d["E"], F=d["F"], EN=d["EN"]).solve(
        d["q"], d["r"], d["c"], d["x0"], e=d["e"], eN=d["eN"])
    assert sol.x0_residual > 1e-3


def test_fixed_final_state():
    rng = np.random.default_rng(1)
    d = random_problem(rng, 8, 3, 2, neN=3)
    d["EN"] = np.eye(3); d["eN"] = -np.array([1.0, 2.0, 3.0])
    sol = check_against_dense(d)
    assert np.allclose(sol.X[-1], [1, 2, 3])


@pytest.mark.parametrize("theta", [0.3, 0.7, 1.1, 2.5])
@pytest.mark.parametrize("stage_row", [False, True])
def test_state_row_the_control_reaches_after_two_steps(theta, stage_row):
    """Double integrator in rotated coordinates with a position constraint (relative degree 2):
    G_{k+1} B_k cancels to rounding noise (~1e-18), which must count as a zero u-part (the row
    passes on to the stage before), not as a pivot -- that made Q_uu look indefinite at k = 0."""
    h, N = 0.1, 4
    T = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    A = np.array([T @ np.array([[1.0, h], [0.0, 1.0]]) @ T.T] * N)
    B = np.array([T @ np.array([[0.0], [h]])] * N)
    pos = np.array([[1.0, 0.0]]) @ T.T
    assert np.abs(pos @ B[0]).max() < 1e-15   # the cancellation this test is about (exactly 0 with some BLAS)
    rng = np.random.default_rng(3)
    d = dict(Q=np.array([np.eye(2)] * (N + 1)), S=np.zeros((N, 2, 1)), R=np.array([np.eye(1)] * N), A=A, B=B,
             q=rng.standard_normal((N + 1, 2)), r=rng.standard_normal((N, 1)), c=np.zeros((N, 2)),
             x0=np.array([0.1, -0.2]))
    if stage_row:   # x_2 position fixed by a state row at stage 2 only (n_eq = 0, 0, 1, 0)
        n_eq = np.array([0, 0, 1, 0])
        E = np.zeros((N, 1, 2)); E[2] = pos; F = np.zeros((N, 1, 1)); e = np.zeros((N, 1)); e[2] = -0.05
        sol = RiccatiFactorization(d["Q"], d["S"], d["R"], A, B, E=E, F=F, n_eq=n_eq).solve(
            d["q"], d["r"], d["c"], d["x0"], e=e)
        K, rhs, unpack = dense_kkt_system(d["Q"], d["S"], d["R"], d["q"], d["r"], A, B, d["c"], d["x0"],
                                          E=E, F=F, e=e, n_eq=n_eq)
        X, U = unpack(np.linalg.solve(K, rhs))
        assert np.abs(sol.X - X).max() < 1e-9 and np.abs(sol.U - U).max() < 1e-9
    else:           # final position fixed
        d.update(EN=pos, eN=np.array([-0.3]))
        sol = check_against_dense(d, tol=1e-9)
    assert abs((pos @ sol.X[2 if stage_row else N])[0] - (0.05 if stage_row else 0.3)) < 1e-12


def test_ill_conditioned_blocks():
    rng = np.random.default_rng(2)
    d = random_problem(rng, 5, 3, 2)
    d["Dx"] = np.full((6, 3), 1e8); d["Du"] = np.full((5, 2), 1e-8)
    d["Dx"][:, 0] = 1e-8
    check_against_dense(d, tol=1e-6)


def test_stage_inequality_terms_equal_explicit_hessian_terms():
    rng = np.random.default_rng(4)
    d = random_problem(rng, 4, 3, 2)
    Ci = rng.standard_normal((4, 2, 5)); sig = rng.uniform(0.1, 10, (4, 2)); ci = rng.standard_normal((4, 2))
    a = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], Ci=Ci, sigma=sig).solve(d["q"], d["r"], d["c"], d["x0"], ci=ci)
    Q, S, R, q, r = d["Q"].copy(), d["S"].copy(), d["R"].copy(), d["q"].copy(), d["r"].copy()
    for k in range(4):
        H = Ci[k].T @ np.diag(sig[k]) @ Ci[k]
        Q[k] += H[:3, :3]; S[k] += H[:3, 3:]; R[k] += H[3:, 3:]
        gk = Ci[k].T @ (sig[k] * ci[k]); q[k] += gk[:3]; r[k] += gk[3:]
    b = RiccatiFactorization(Q, S, R, d["A"], d["B"]).solve(q, r, d["c"], d["x0"])
    assert np.allclose(a.X, b.X) and np.allclose(a.U, b.U) and np.allclose(a.lam, b.lam)


def test_several_right_hand_sides_one_factorization():
    rng = np.random.default_rng(5)
    d = random_problem(rng, 6, 3, 2, ne=1)
    fac = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], E=d["E"], F=d["F"])
    for seed in range(3):
        r2 = np.random.default_rng(100 + seed)
        d2 = dict(d, q=r2.standard_normal(d["q"].shape), c=r2.standard_normal(d["c"].shape), e=r2.standard_normal(d["e"].shape))
        sol = fac.solve(d2["q"], d2["r"], d2["c"], d2["x0"], e=d2["e"])
        X, U, _ = dense_kkt(d2["Q"], d2["S"], d2["R"], d2["q"], d2["r"], d2["A"], d2["B"], d2["c"], d2["x0"], d2["E"], d2["F"], d2["e"])
        assert np.allclose(sol.X, X, atol=1e-9) and np.allclose(sol.U, U, atol=1e-9)


def test_indefinite_reduced_hessian_names_the_stage_and_can_be_regularized():
    rng = np.random.default_rng(6)
    d = random_problem(rng, 5, 2, 2)
    d["R"][3] = -np.eye(2) * 50.0
    with pytest.raises(NotPositiveDefiniteError) as e:
        RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"])
    assert e.value.stage == 3 and "k=3" in str(e.value)
    RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], regularization=1e4)  # shifted: factorizes


def stationarity_residuals(d, sol, Ci=None, sig=None, ci=None, reg=0.0):
    """Residuals of the KKT rows of the plain (no equality rows) LQ-DOCP at sol, with the stage
    inequality terms sig * C^T (C z + ci) and the regularization reg * u in the u rows."""
    Q, S, R, A, B, q, r, c, x0 = (d[k] for k in ("Q", "S", "R", "A", "B", "q", "r", "c", "x0"))
    Dx, Du = d.get("Dx"), d.get("Du")
    N, n, m = B.shape
    X, U, lam = sol.X, sol.U, sol.lam
    gx, gu = np.zeros((N, n)), np.zeros((N, m))
    for k in range(N):
        gx[k] = Q[k] @ X[k] + S[k] @ U[k] + q[k] + A[k].T @ lam[k + 1] - lam[k]
        gu[k] = S[k].T @ X[k] + R[k] @ U[k] + r[k] + B[k].T @ lam[k + 1] + reg * U[k]
        if Dx is not None:
            gx[k] += Dx[k] * X[k]; gu[k] += Du[k] * U[k]
        if Ci is not None:
            g = Ci[k].T @ (sig[k] * (Ci[k] @ np.concatenate([X[k], U[k]]) + ci[k]))
            gx[k] += g[:n]; gu[k] += g[n:]
    gN = Q[N] @ X[N] + q[N] - lam[N] + (Dx[N] * X[N] if Dx is not None else 0.0)
    dyn = np.einsum("kij,kj->ki", A, X[:-1]) + np.einsum("kij,kj->ki", B, U) + c - X[1:]
    return max(np.abs(gx).max(), np.abs(gu).max(), np.abs(gN).max(), np.abs(dyn).max(), np.abs(X[0] - x0).max())


@settings(max_examples=30, deadline=None)
@given(N=st.integers(1, 6), n=st.integers(1, 5), m=st.integers(1, 4), seed=st.integers(0, 10_000),
       with_bounds=st.booleans(), ni=st.integers(0, 2), reg=st.sampled_from([0.0, 0.5]))
def test_fixed_size_and_any_size_plain_kernels_agree(N, n, m, seed, with_bounds, ni, reg):
    """The plain recursion compiled for the sizes (n + m <= FIXED_SIZE_MAX) and with run-time sizes
    give the same factorization and solution (up to rounding), and the multipliers lam_k = P_k x_k + p_k
    satisfy the KKT rows, with the stage inequality terms and the regularization."""
    import olado.linalg.codegen as codegen

    rng = np.random.default_rng(seed)
    d = random_problem(rng, N, n, m)
    if with_bounds:
        d["Dx"] = rng.uniform(0, 100, (N + 1, n)); d["Du"] = rng.uniform(0, 100, (N, m))
    kw = dict(Dx=d.get("Dx"), Du=d.get("Du"), regularization=reg)
    rhs = {}
    if ni:
        kw.update(Ci=rng.standard_normal((N, ni, n + m)), sigma=rng.uniform(0.0, 10.0, (N, ni)))
        kw["sigma"][0, 0] = 0.0   # a zero weight
        rhs["ci"] = rng.standard_normal((N, ni))
    results = []
    for fixed_max in (codegen.FIXED_SIZE_MAX, 0):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(codegen, "FIXED_SIZE_MAX", fixed_max)
            fac = RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], **kw)
            assert fac.unconstrained and (fac._size_tags is None) == (fixed_max == 0)
            results.append((fac, fac.solve(d["q"], d["r"], d["c"], d["x0"], **rhs)))
    (fa, sa), (fb, sb) = results
    for a, b in ((fa.P, fb.P), (fa.K, fb.K), (fa.Lww, fb.Lww), (sa.X, sb.X), (sa.U, sb.U), (sa.lam, sb.lam)):
        assert np.abs(a - b).max() <= 1e-10 * max(1.0, np.abs(a).max())
    assert np.array_equal(fa.P, fa.P.transpose(0, 2, 1)) and not np.triu(fa.Lww, 1).any()
    scale = max(1.0, np.abs(sa.X).max(), np.abs(sa.U).max(), np.abs(sa.lam).max())
    assert stationarity_residuals(d, sa, kw.get("Ci"), kw.get("sigma"), rhs.get("ci"), reg) <= 1e-9 * scale


@pytest.mark.parametrize("fixed", [True, False])
def test_indefinite_stage_hessian_on_both_plain_kernels(monkeypatch, fixed):
    """The failing stage is reported by the fixed-size and the any-size kernels alike, also when
    Q_uu is indefinite only through a stage inequality term, or is NaN."""
    import olado.linalg.codegen as codegen

    if not fixed:
        monkeypatch.setattr(codegen, "FIXED_SIZE_MAX", 0)
    rng = np.random.default_rng(7)
    d = random_problem(rng, 6, 3, 2)
    d["R"][4] = np.diag([1.0, -100.0])
    with pytest.raises(NotPositiveDefiniteError) as e:
        RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"])
    assert e.value.stage == 4
    d = random_problem(rng, 6, 3, 2)
    Ci = np.zeros((6, 1, 5)); Ci[2, 0, 3] = 1.0
    with pytest.raises(NotPositiveDefiniteError) as e:
        RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"], Ci=Ci, sigma=np.full((6, 1), -1e4))
    assert e.value.stage == 2
    d["R"][1, 0, 0] = np.nan
    with pytest.raises(NotPositiveDefiniteError) as e:
        RiccatiFactorization(d["Q"], d["S"], d["R"], d["A"], d["B"])
    assert e.value.stage == 1


@pytest.mark.parametrize("with_eq", [False, True])
def test_refactor_with_new_diagonal_terms_equals_a_fresh_factorization(with_eq):
    """refactor(Dx, Du, sigma, regularization) overwrites the factors in place and gives the
    solution of a fresh factorization with those terms (plain path and equality-row path), and
    solve(out=...) writes into the given arrays."""
    rng = np.random.default_rng(7)
    N, n, m, ni = 9, 3, 2, 2
    M = rng.standard_normal((N + 1, n + m, n + m))
    H = np.einsum("kij,klj->kil", M, M) + 0.1 * np.eye(n + m)
    Q, S, R = H[:, :n, :n], H[:N, :n, n:], H[:N, n:, n:]
    A = rng.standard_normal((N, n, n)) * 0.5; B = rng.standard_normal((N, n, m))
    Ci = rng.standard_normal((N, ni, n + m))
    kw = dict(Ci=Ci)
    if with_eq:
        kw.update(E=rng.standard_normal((N, 1, n)), F=rng.standard_normal((N, 1, m)), n_eq=np.arange(N) % 2)
    q, r, c, x0 = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m)), rng.standard_normal((N, n)), rng.standard_normal(n)
    ci = rng.standard_normal((N, ni))
    rhs = dict(ci=ci)
    if with_eq:
        rhs["e"] = rng.standard_normal((N, 1))
    f = RiccatiFactorization(Q, S, R[:N], A, B, Dx=np.ones((N + 1, n)), Du=np.ones((N, m)), sigma=np.ones((N, ni)), **kw)
    f.solve(q, r, c, x0, **rhs)
    for trial in range(3):
        Dx, Du = rng.uniform(1e-3, 1e3, (N + 1, n)), rng.uniform(1e-3, 1e3, (N, m))
        sig = rng.uniform(0.0, 10.0, (N, ni))
        P0 = f.P
        f.refactor(Dx=Dx, Du=Du, sigma=sig, regularization=1e-8 * trial)
        assert f.P is P0
        ref = RiccatiFactorization(Q, S, R[:N], A, B, Dx=Dx, Du=Du, sigma=sig, regularization=1e-8 * trial, **kw)
        out = (np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n)))
        a, b = f.solve(q, r, c, x0, out=out, **rhs), ref.solve(q, r, c, x0, **rhs)
        assert a.X is out[0] and a.U is out[1] and a.lam is out[2]
        for u, v in ((a.X, b.X), (a.U, b.U), (a.lam, b.lam), (a.nu, b.nu)):
            np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="out: U"):
        f.solve(q, r, c, x0, out=(out[0], np.empty((N, m + 1)), out[2]), **rhs)
