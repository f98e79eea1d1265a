"""The sparse KKT back-ends (olado.linalg.kkt) against the Riccati solver on the same LQ-DOCP systems."""

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from olado.errors import ConfigError
from olado.linalg import RiccatiFactorization
from olado.linalg.kkt import KKT_SOLVERS, KKTSolveError, make_kkt_solver

DIRECT = ("superlu-reduced", "superlu-full")
ITERATIVE = ("minres", "gmres")


def well_conditioned_problem(rng, N, n, m, ne=0, neN=0, ni=0, bounds=False, zero_weights=False):
    """Random LQ-DOCP with contracting dynamics, SPD cost blocks and equality rows whose control
    part is well away from rank deficiency, so the KKT matrix is well conditioned."""
    def spd(d, count):
        M = rng.standard_normal((count, d, d))
        return M @ M.transpose(0, 2, 1) / d + np.eye(d)

    mats = dict(Q=spd(n, N + 1), R=spd(m, N), S=0.1 * rng.standard_normal((N, n, m)),
                A=0.5 * rng.standard_normal((N, n, n)) / np.sqrt(n), B=rng.standard_normal((N, n, m)) / np.sqrt(n))
    rhs = dict(q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)), c=rng.standard_normal((N, n)),
               x0=rng.standard_normal(n))
    if ne:
        F = 0.3 * rng.standard_normal((N, ne, m))
        F[:, np.arange(ne), np.arange(ne)] += 1.5
        mats.update(E=rng.standard_normal((N, ne, n)), F=F)
        rhs["e"] = rng.standard_normal((N, ne))
        if zero_weights:   # some stages with fewer (or no) rows
            mats["n_eq"] = rng.integers(0, ne + 1, N)
    if neN:
        mats["EN"] = rng.standard_normal((neN, n))
        rhs["eN"] = rng.standard_normal(neN)
    if bounds:
        mats["Dx"] = rng.uniform(0.0, 10.0, (N + 1, n))
        mats["Du"] = rng.uniform(0.0, 10.0, (N, m))
        if zero_weights:
            mats["Dx"][rng.random((N + 1, n)) < 0.3] = 0.0
            mats["Du"][rng.random((N, m)) < 0.3] = 0.0
    if ni:
        mats["Ci"] = rng.standard_normal((N, ni, n + m))
        mats["sigma"] = rng.uniform(0.1, 10.0, (N, ni))
        rhs["ci"] = rng.standard_normal((N, ni))
        if zero_weights:
            mats["sigma"][rng.random((N, ni)) < 0.3] = 0.0
            mats["n_ineq"] = rng.integers(0, ni + 1, N)
    return mats, rhs


def assert_same_solution(sol, ref, tol):
    for name in ("X", "U", "lam", "nu"):
        a, b = getattr(sol, name), getattr(ref, name)
        assert a.shape == b.shape, name
        scale = max(1.0, np.abs(b).max(initial=0.0))
        assert np.abs(a - b).max(initial=0.0) <= tol * scale, (name, np.abs(a - b).max(initial=0.0), scale)


def solve_all(mats, rhs, names, **opts):
    ref = RiccatiFactorization(**mats).solve(**rhs)
    return ref, {name: make_kkt_solver(name, **mats, **opts.get(name, {})).solve(**rhs) for name in names}


@settings(max_examples=60, deadline=None)
@given(N=st.integers(1, 6), n=st.integers(1, 4), m=st.integers(1, 3), seed=st.integers(0, 10_000),
       ne=st.integers(0, 1), neN=st.integers(0, 1), ni=st.integers(0, 2), bounds=st.booleans(),
       zero_weights=st.booleans())
def test_every_backend_matches_riccati(N, n, m, seed, ne, neN, ni, bounds, zero_weights):
    rng = np.random.default_rng(seed)
    m = max(m, ne + neN)         # enough controls for the rows (else the KKT matrix is singular)
    mats, rhs = well_conditioned_problem(rng, N, n, m, ne=ne, neN=neN, ni=ni, bounds=bounds,
                                         zero_weights=zero_weights)
    ref = RiccatiFactorization(**mats).solve(**rhs)
    red = make_kkt_solver("superlu-reduced", **mats)
    cond = np.linalg.cond(red.K.toarray())
    assume(cond < 1e8)       # random rows can be nearly dependent; errors below scale with cond
    for name in DIRECT:
        sol = make_kkt_solver(name, **mats).solve(**rhs)
        assert_same_solution(sol, ref, 1e-14 * max(cond, 1e3))
        assert sol.x0_residual < 1e-10
    # to their tolerance: the true relative residual is below rtol, which cannot be asked below
    # the rounding floor ~ eps * cond of the residual itself (a hypothesis example, N = 1,
    # n = 3, seed 7343, stalled MINRES at 1.05e-11 with rtol = 1e-11)
    rtol = max(1e-11, 1e-15 * cond)
    for name in ITERATIVE:
        solver = make_kkt_solver(name, rtol=rtol, **mats)
        sol = solver.solve(**rhs)
        assert solver.residual <= rtol
        assert_same_solution(sol, ref, 1e-10 * max(cond, 1e3))


def test_single_stage_single_control():
    rng = np.random.default_rng(0)
    mats, rhs = well_conditioned_problem(rng, 1, 2, 1, bounds=True, ni=1)
    ref, sols = solve_all(mats, rhs, DIRECT + ITERATIVE)
    for name in DIRECT + ITERATIVE:
        assert_same_solution(sols[name], ref, 1e-8)


def test_reduced_system_size_and_symmetry():
    rng = np.random.default_rng(1)
    N, n, m = 3, 2, 2
    mats, _ = well_conditioned_problem(rng, N, n, m, ne=1, neN=1, ni=2, bounds=True)
    red = make_kkt_solver("superlu-reduced", **mats)
    # lam, x: N+1 stages of n; u: N*m; nu: N*ne + neN
    assert red.K.shape == ((N + 1) * 2 * n + N * m + N + 1,) * 2
    full = make_kkt_solver("superlu-full", **mats)
    # plus the inequality rows (all sigma > 0) and one row per bound term (all D > 0 here)
    assert full.K.shape[0] == red.K.shape[0] + N * 2 + (N + 1) * n + N * m
    for K in (red.K, full.K):
        assert abs(K - K.T).max() == 0.0


def test_full_system_drops_zero_weight_rows_and_can_fold_bounds():
    rng = np.random.default_rng(2)
    mats, rhs = well_conditioned_problem(rng, 4, 3, 2, ni=2, bounds=True)
    mats["sigma"][0, :] = 0.0
    mats["Dx"][:, 0] = 0.0
    mats["Du"][2] = 0.0
    ref = RiccatiFactorization(**mats).solve(**rhs)
    rows = make_kkt_solver("superlu-full", **mats)
    folded = make_kkt_solver("superlu-full", bounds_as_rows=False, **mats)
    red = make_kkt_solver("superlu-reduced", **mats)
    assert rows.K.shape[0] == red.K.shape[0] + (4 * 2 - 2) + (5 * 3 - 5) + (4 * 2 - 2)
    assert folded.K.shape[0] == red.K.shape[0] + 4 * 2 - 2
    for s in (rows, folded):
        assert_same_solution(s.solve(**rhs), ref, 1e-10)


def test_riccati_fast_path_when_no_row_is_active():
    """E given but n_eq all zero: the Riccati solver takes its plain-recursion path; the nu array
    keeps its shape and is zero."""
    rng = np.random.default_rng(3)
    mats, rhs = well_conditioned_problem(rng, 5, 3, 2, ne=1, bounds=True, ni=1)
    mats["n_eq"] = np.zeros(5, dtype=int)
    fac = RiccatiFactorization(**mats)
    assert fac.unconstrained
    ref = fac.solve(**rhs)
    assert ref.nu.shape == (6, 1) and not ref.nu.any()
    sol = make_kkt_solver("superlu-reduced", **mats).solve(**rhs)
    assert_same_solution(sol, ref, 1e-10)


@pytest.mark.parametrize("name", KKT_SOLVERS)
def test_several_right_hand_sides_on_one_factorization(name):
    rng = np.random.default_rng(4)
    mats, rhs = well_conditioned_problem(rng, 6, 3, 2, ne=1, neN=1, ni=2, bounds=True)
    solver = make_kkt_solver(name, **mats)
    ric = RiccatiFactorization(**mats)
    tol = 1e-10 if name not in ITERATIVE else 1e-7
    for seed in range(3):
        r2 = np.random.default_rng(100 + seed)
        rhs2 = {k: r2.standard_normal(v.shape) for k, v in rhs.items()}
        assert_same_solution(solver.solve(**rhs2), ric.solve(**rhs2), tol)


def test_unknown_name_lists_the_valid_ones():
    rng = np.random.default_rng(5)
    mats, _ = well_conditioned_problem(rng, 2, 2, 1)
    with pytest.raises(ConfigError) as err:
        make_kkt_solver("umfpack", **mats)
    for name in KKT_SOLVERS:
        assert name in str(err.value)
    assert "umfpack" in str(err.value)


def test_non_convergence_names_backend_iterations_and_residual():
    rng = np.random.default_rng(6)
    mats, rhs = well_conditioned_problem(rng, 20, 3, 2, bounds=True)
    solver = make_kkt_solver("minres", preconditioner="none", maxiter=3, **mats)
    with pytest.raises(KKTSolveError) as err:
        solver.solve(**rhs)
    e = err.value
    assert e.backend == "minres" and e.iterations == 3 and e.residual > 1e-10
    assert "minres" in str(e) and "3 iterations" in str(e) and "residual" in str(e)
    solver = make_kkt_solver("gmres", drop_tol=1.0, fill_factor=1.0, restart=2, maxiter=1, **mats)
    with pytest.raises(KKTSolveError, match="gmres"):
        solver.solve(**rhs)


def test_unpreconditioned_minres_converges_given_enough_iterations():
    rng = np.random.default_rng(7)
    mats, rhs = well_conditioned_problem(rng, 4, 2, 2, bounds=True)
    ref = RiccatiFactorization(**mats).solve(**rhs)
    sol = make_kkt_solver("minres", preconditioner="none", rtol=1e-12, maxiter=5000, **mats).solve(**rhs)
    assert_same_solution(sol, ref, 1e-6)


def _identical_rows(consistent):
    """Two identical equality rows at stage 1 (a singular KKT matrix), with equal constants
    (consistent) or constants 1 apart (no point satisfies both)."""
    rng = np.random.default_rng(8)
    mats, rhs = well_conditioned_problem(rng, 3, 2, 2, ne=2, bounds=True)
    mats["E"][1, 1] = mats["E"][1, 0]
    mats["F"][1, 1] = mats["F"][1, 0]
    rhs["e"][1, 1] = rhs["e"][1, 0] + (0.0 if consistent else 1.0)
    return mats, rhs


@pytest.mark.parametrize("name", KKT_SOLVERS)
def test_dependent_rows_are_solved_like_riccati(name):
    """Dependent equality rows make K singular: the sparse back-ends regularize the dual block
    (-delta_c I, refined away) as the Riccati recursion drops the rows -- the same primal
    solution and a zero residual of the rows when they are consistent."""
    mats, rhs = _identical_rows(consistent=True)
    ref = RiccatiFactorization(**mats).solve(**rhs)
    sol = make_kkt_solver(name, **mats).solve(**rhs)
    for a, b in ((sol.X, ref.X), (sol.U, ref.U)):
        np.testing.assert_allclose(a, b, atol=1e-8 * max(1.0, np.abs(b).max()))
    assert sol.x0_residual <= 1e-8 and ref.x0_residual <= 1e-8


@pytest.mark.parametrize("name", ["superlu-reduced", "superlu-full"])
def test_inconsistent_dependent_rows_report_their_defect(name):
    """Rows that contradict each other: the residual of the rows (x0_residual, which the QP turns
    into INFEASIBLE) is of the order of the contradiction, as Riccati's consistency defect."""
    mats, rhs = _identical_rows(consistent=False)
    ref = RiccatiFactorization(**mats).solve(**rhs)
    sol = make_kkt_solver(name, **mats).solve(**rhs)
    assert ref.x0_residual > 0.1
    assert 0.1 < sol.x0_residual <= 1.0 + 1e-8


@pytest.mark.parametrize("name", ["superlu-reduced", "superlu-full", "gmres"])
def test_singular_system_is_reported(name):
    """A control with no cost, no effect and no row (a zero column of K's primal block): singular
    also with the dual regularization -- KKTSolveError naming the back-end."""
    rng = np.random.default_rng(8)
    mats, rhs = well_conditioned_problem(rng, 3, 2, 2)
    mats["R"][:, 1, :] = mats["R"][:, :, 1] = 0.0
    mats["S"][:, :, 1] = 0.0
    mats["B"][:, :, 1] = 0.0
    with pytest.raises(KKTSolveError, match=name) as err:
        make_kkt_solver(name, **mats).solve(**rhs)
    assert "singular" in str(err.value)


def test_gmres_preconditioner_falls_back_when_the_incomplete_lu_breaks_down(monkeypatch):
    """A zero pivot in spilu ("Factor is exactly singular") is retried with COLAMD and less
    dropping, then with the complete LU: the solution still matches the Riccati solver."""
    import olado.linalg.kkt as kkt

    rng = np.random.default_rng(9)
    mats, rhs = well_conditioned_problem(rng, 6, 3, 2, bounds=True)
    ref = RiccatiFactorization(**mats).solve(**rhs)
    calls = []
    real_spilu = kkt.spla.spilu

    def spilu(A, **kw):
        calls.append(kw["permc_spec"])
        if kw["permc_spec"] == "NATURAL" or len(calls) > 2:
            raise RuntimeError("Factor is exactly singular")
        return real_spilu(A, **kw)

    monkeypatch.setattr(kkt.spla, "spilu", spilu)
    s = make_kkt_solver("gmres", **mats)
    assert s.ilu_fallback == 1 and calls == ["NATURAL", "COLAMD"]
    assert_same_solution(s.solve(**rhs), ref, 1e-8)
    s = make_kkt_solver("gmres", **mats)                     # both incomplete LUs fail: complete LU
    assert s.ilu_fallback == 2
    assert_same_solution(s.solve(**rhs), ref, 1e-8)
    assert s.iterations <= 2                                 # an exact preconditioner
