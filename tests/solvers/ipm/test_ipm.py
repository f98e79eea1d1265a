"""The interior-point NLP solver (olado.solvers.ipm): its Newton step against a dense KKT solve,
the filter's acceptance rules against hand computations, the inertia correction on a nonconvex
stage Hessian, and whole solves against IPOPT (configs/ipopt.ini) on the same problems."""

import dataclasses

import numpy as np
import pytest

import olado
from olado.config import load_config, make_solver
from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.result import Status
from olado.solvers.ipm.barrier import Bounds, Layout
from olado.solvers.ipm.filter import Filter, FilterConstants
from olado.solvers.ipm.newton import Constraints, InertiaConstants, KKTMatrix, Residuals

from fixtures import CONFIGS
from fixtures.toy_problems import Pendulum


# ---------------------------------------------------------------------------- the Newton step
def pack(X, U):
    return np.concatenate([X[1:].ravel(), U.ravel()])


def random_lq(rng, N=4, n=3, m=2, convex=True):
    """Stage Hessian blocks, dynamics and a barrier diagonal of a small LQ-DOCP."""
    H = rng.standard_normal((N + 1, n + m, n + m))
    H = np.einsum("kij,klj->kil", H, H) / (n + m) + (0.1 if convex else 0.0) * np.eye(n + m)
    Q = np.ascontiguousarray(H[:, :n, :n])
    S = np.ascontiguousarray(H[:N, :n, n:])
    R = np.ascontiguousarray(H[:N, n:, n:])
    A = rng.standard_normal((N, n, n)) * 0.5
    B = rng.standard_normal((N, n, m))
    Sx = rng.uniform(0.0, 2.0, (N + 1, n))
    Su = rng.uniform(0.0, 2.0, (N, m))
    return Q, S, R, A, B, Sx, Su


def dense_kkt(Q, S, R, A, B, Sx, Su, delta):
    """[W + Sigma + delta I, J^T; J, 0] over y = (x^1..x^N, u^0..u^{N-1}) (x^0 = 0 fixed) and the
    Jacobian J of h^k = A x^k + B u^k - x^{k+1}; returns (K, W + Sigma + delta I, J)."""
    N, n, m = B.shape
    nx, nv = N * n, N * (n + m)
    xi = lambda k: slice((k - 1) * n, k * n)                 # x^k, k >= 1  # noqa: E731
    ui = lambda k: slice(nx + k * m, nx + (k + 1) * m)        # noqa: E731
    W = np.zeros((nv, nv))
    for k in range(N):
        if k >= 1:
            W[xi(k), xi(k)] += Q[k]
            W[xi(k), ui(k)] += S[k]
            W[ui(k), xi(k)] += S[k].T
        W[ui(k), ui(k)] += R[k]
    W[xi(N), xi(N)] += Q[N]
    W += np.diag(np.concatenate([Sx[1:].ravel(), Su.ravel()])) + delta * np.eye(nv)
    J = np.zeros((nx, nv))
    for k in range(N):
        rows = slice(k * n, (k + 1) * n)
        if k >= 1:
            J[rows, xi(k)] = A[k]
        J[rows, ui(k)] = B[k]
        J[rows, xi(k + 1)] = -np.eye(n)
    K = np.block([[W, J.T], [J, np.zeros((nx, nx))]])
    return K, W, J


def test_newton_step_equals_the_dense_kkt_solve():
    """The Riccati solve of the iteration matrix is the solution of the dense primal-dual system
    (13) of Waechter and Biegler: steps dx, du and the new dynamics multipliers."""
    rng = np.random.default_rng(3)
    Q, S, R, A, B, Sx, Su = random_lq(rng)
    N, n, m = B.shape
    kkt = KKTMatrix(Q, S, R, A, B, Sx, Su)
    assert kkt.try_factor(0.3)
    q, r, c = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m)), rng.standard_normal((N, n))
    step = kkt.solve(q, r, Residuals(c, np.zeros((N, 0)), np.zeros(0), np.zeros((N, 0)), np.zeros(0)))
    dX, dU, lam = step.dX, step.dU, step.lam
    K, _, _ = dense_kkt(Q, S, R, A, B, Sx, Su, 0.3)
    rhs = -np.concatenate([q[1:].ravel(), r.ravel(), c.ravel()])
    sol = np.linalg.solve(K, rhs)
    np.testing.assert_allclose(pack(dX, dU), sol[:N * (n + m)], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(lam[1:].ravel(), sol[N * (n + m):], rtol=1e-10, atol=1e-12)
    assert np.all(dX[0] == 0.0)


def test_newton_step_with_equalities_and_slacked_inequalities_equals_the_dense_solve():
    """Stage and final equality rows and inequality rows d - s = 0 with their slacks: the
    eliminated system on the Riccati recursion gives the dense system's steps (dy, ds) and
    multipliers (lam, nu, nu_N, y_d, y_dN)."""
    rng = np.random.default_rng(11)
    Q, S, R, A, B, Sx, Su = random_lq(rng, N=4, n=3, m=3)
    N, n, m = B.shape
    ne, neN, ni, niN = 1, 1, 2, 1
    E, F = rng.standard_normal((N, ne, n)), rng.standard_normal((N, ne, m))
    EN = rng.standard_normal((neN, n))
    Ci, CNi = rng.standard_normal((N, ni, n + m)), rng.standard_normal((niN, n))
    Ss, SsN = rng.uniform(0.1, 3.0, (N, ni)), rng.uniform(0.1, 3.0, niN)
    delta = 0.2
    kkt = KKTMatrix(Q.copy(), S, R, A, B, Sx, Su, Constraints(E, F, EN, Ci, CNi, Ss, SsN))
    assert kkt.try_factor(delta)
    q, r = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))
    gs, gsN = rng.standard_normal((N, ni)), rng.standard_normal(niN)
    res = Residuals(rng.standard_normal((N, n)), rng.standard_normal((N, ne)), rng.standard_normal(neN),
                    rng.standard_normal((N, ni)), rng.standard_normal(niN))
    st = kkt.solve(q, r, res, gs, gsN)
    # the dense system over (y, s) and the multipliers of (h, e, eN, d - s, dN - sN)
    _, W, Jh = dense_kkt(Q, S, R, A, B, Sx, Su, delta)
    ny, ns = N * (n + m), N * ni + niN
    nx = N * n
    col_x = lambda k: slice((k - 1) * n, k * n)                # noqa: E731
    col_u = lambda k: slice(nx + k * m, nx + (k + 1) * m)       # noqa: E731
    Je = np.zeros((N * ne + neN, ny)); Jd = np.zeros((N * ni + niN, ny))
    for k in range(N):
        if k >= 1:
            Je[k * ne:(k + 1) * ne, col_x(k)] = E[k]
            Jd[k * ni:(k + 1) * ni, col_x(k)] = Ci[k][:, :n]
        Je[k * ne:(k + 1) * ne, col_u(k)] = F[k]
        Jd[k * ni:(k + 1) * ni, col_u(k)] = Ci[k][:, n:]
    Je[N * ne:, col_x(N)] = EN
    Jd[N * ni:, col_x(N)] = CNi
    Hs = np.diag(np.concatenate([Ss.ravel(), SsN]) + delta)
    Jc = np.block([[Jh, np.zeros((nx, ns))], [Je, np.zeros((Je.shape[0], ns))], [Jd, -np.eye(ns)]])
    H = np.block([[W, np.zeros((ny, ns))], [np.zeros((ns, ny)), Hs]])
    K = np.block([[H, Jc.T], [Jc, np.zeros((Jc.shape[0], Jc.shape[0]))]])
    rhs = -np.concatenate([q[1:].ravel(), r.ravel(), gs.ravel(), gsN, res.h.ravel(), res.e.ravel(), res.eN,
                           res.d.ravel(), res.dN])
    sol = np.linalg.solve(K, rhs)
    got = np.concatenate([pack(st.dX, st.dU), st.ds.ravel(), st.dsN, st.lam[1:].ravel(), st.nu.ravel(), st.nuN,
                          st.yd.ravel(), st.ydN])
    np.testing.assert_allclose(got, sol, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("rows", [False, True])
def test_a_matrix_that_takes_the_last_back_end_over_solves_as_a_fresh_one(rows):
    """The Newton matrix of the next iteration reuses the previous one's Riccati back-end (its
    blocks copied into the back-end's arrays, then a refactor): the same steps bit for bit as a
    matrix factored afresh, through an inertia correction; the previous matrix's inputs (the
    point's A, B) are not written into."""
    rng = np.random.default_rng(21)

    def system(seed, convex=True):
        r = np.random.default_rng(seed)
        Q, S, R, A, B, Sx, Su = random_lq(r, N=5, n=3, m=3)
        N, n, m = B.shape
        if not convex:
            R[2] -= 40.0 * np.eye(m)        # negative curvature: delta_w > 0 needed
        if not rows:
            return (Q, S, R, A, B, Sx, Su), None, Residuals(r.standard_normal((N, n)), np.zeros((N, 0)), np.zeros(0),
                                                            np.zeros((N, 0)), np.zeros(0))
        cons = Constraints(r.standard_normal((N, 1, n)), r.standard_normal((N, 1, m)), r.standard_normal((1, n)),
                           r.standard_normal((N, 2, n + m)), r.standard_normal((1, n)),
                           r.uniform(0.1, 3.0, (N, 2)), r.uniform(0.1, 3.0, 1))
        res = Residuals(r.standard_normal((N, n)), r.standard_normal((N, 1)), r.standard_normal(1),
                        r.standard_normal((N, 2)), r.standard_normal(1))
        return (Q, S, R, A, B, Sx, Su), cons, res

    def copy(blocks, cons):
        blocks = tuple(a.copy() for a in blocks)
        return blocks, None if cons is None else Constraints(*(a.copy() for a in dataclasses.astuple(cons)))

    blocks1, cons1 = copy(*system(1)[:2])
    point_A = blocks1[3]
    point_A_before = point_A.copy()
    first = KKTMatrix(*blocks1, cons1)
    assert first.factor(0.0) is not None
    backend = first.kkt
    prev, last = first, 0.0
    for seed in (2, 3, 4):
        blocks, cons, res = system(seed, convex=seed != 3)     # seed 3 needs the inertia correction
        reused = KKTMatrix(*copy(blocks, cons)[0], copy(blocks, cons)[1], reuse=prev)
        fresh = KKTMatrix(*copy(blocks, cons)[0], copy(blocks, cons)[1])
        d_reused, d_fresh = reused.factor(last), fresh.factor(last)
        assert d_reused == d_fresh is not None and (d_reused > 0.0) == (seed == 3)
        assert reused.kkt is backend                        # the back-end object carried over
        N, n, m = blocks[4].shape
        q, r = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))
        gs, gsN = (rng.standard_normal((N, 2)), rng.standard_normal(1)) if rows else (None, None)
        for a, b in zip(reused.solve(q, r, res, gs, gsN), fresh.solve(q, r, res, gs, gsN)):
            assert np.array_equal(a, b)
        assert prev.kkt is None                            # the old matrix gave its back-end away
        prev, last = reused, d_reused or last
    assert np.array_equal(point_A, point_A_before)      # the back-end holds its own copies


def test_inertia_correction_on_a_nonconvex_stage_hessian():
    """A stage block with negative curvature: delta_w = 0 fails, Algorithm IC raises delta_w from
    delta_0 by kappa_w^+ = 100 until the reduced Hessian is positive definite -- the dense KKT
    matrix then has inertia (N (n+m), N n, 0) -- and the one below it would not do."""
    rng = np.random.default_rng(5)
    Q, S, R, A, B, Sx, Su = random_lq(rng)
    N, n, m = B.shape
    R[2] -= 40.0 * np.eye(m)                               # strongly nonconvex controls at stage 2
    Sx[:] = 0.0; Su[:] = 0.0
    kkt = KKTMatrix(Q, S, R, A, B, Sx, Su)
    const = InertiaConstants()
    delta = kkt.factor(0.0, const)
    k = round(np.log(delta / const.delta_0) / np.log(const.kappa_plus_first))
    assert delta == pytest.approx(const.delta_0 * const.kappa_plus_first ** k) and k >= 1

    def inertia(d):
        ev = np.linalg.eigvalsh(dense_kkt(Q, S, R, A, B, Sx, Su, d)[0])
        return int((ev > 0).sum()), int((ev < 0).sum())

    assert inertia(0.0) != (N * (n + m), N * n)
    assert inertia(delta) == (N * (n + m), N * n)
    assert inertia(delta / const.kappa_plus_first) != (N * (n + m), N * n)
    # the next iteration starts from delta / 3 (kappa_w^-) and raises by 8
    kkt2 = KKTMatrix(Q, S, R, A, B, Sx, Su)
    d2 = kkt2.factor(delta, const)
    assert inertia(d2) == (N * (n + m), N * n) and d2 <= delta * const.kappa_minus * const.kappa_plus
    # a convex matrix needs no shift
    Q, S, R, A, B, Sx, Su = random_lq(rng)
    assert KKTMatrix(Q, S, R, A, B, Sx, Su).factor(0.0, const) == 0.0


# ---------------------------------------------------------------------------- the filter
def test_filter_dominance_and_augmentation():
    f = Filter.start(theta0=2.0)
    assert f.theta_max == 2e4 and f.theta_min == 2e-4
    assert f.acceptable(1e4, 1e9) and not f.acceptable(2e4, -1e9)        # F_0: theta >= theta_max
    f.add(1.0, 5.0)                       # corner ((1 - 1e-5) 1, 5 - 1e-8 1)
    t, p = 1.0 - 1e-5, 5.0 - 1e-8
    assert f.entries[-1] == (pytest.approx(t), pytest.approx(p))
    assert not f.acceptable(1.0, 5.0) and not f.acceptable(t, p)          # dominated (>= both)
    assert f.acceptable(0.99, 100.0) and f.acceptable(2.0, 4.0)           # better in one measure
    f.add(0.5, 6.0)
    assert len(f.entries) == 3
    f.add(0.1, 1.0)                       # dominates both corners: they are dropped
    assert len(f.entries) == 2
    f.reset()
    assert f.entries == [(f.theta_max, -np.inf)]


def test_filter_acceptance_rules():
    """Eqs. (18)-(20) of Waechter and Biegler by hand, constants of FilterConstants."""
    c = FilterConstants()
    f = Filter.start(theta0=1.0)          # theta_min = 1e-4
    # h-type: theta > theta_min, sufficient decrease in theta or in phi
    ok, ftype = f.accept(1.0, 1e-2, 1.0, -1.0, 1e-2 * (1 - 2 * c.gamma_theta), 2.0)
    assert ok and not ftype
    ok, _ = f.accept(1.0, 1e-2, 1.0, -1.0, 1e-2, 1.0 - 2 * c.gamma_phi * 1e-2)
    assert ok
    ok, _ = f.accept(1.0, 1e-2, 1.0, -1.0, 1e-2, 1.0)                    # neither decreases
    assert not ok
    # f-type: theta <= theta_min and the switching condition alpha (-g)^s_phi > delta theta^s_theta
    th, g, alpha = 1e-6, -1.0, 0.5
    assert f.switching(alpha, th, g) and not f.switching(alpha, th, +1.0)
    armijo = 1.0 + c.eta_phi * alpha * g
    assert f.accept(alpha, th, 1.0, g, 0.0, armijo - 1e-12) == (True, True)
    assert f.accept(alpha, th, 1.0, g, 0.0, armijo + 1e-9) == (False, False)  # theta decreased, Armijo fails
    # above theta_min the sufficient decrease decides, but an accepted step for which (19) and (20)
    # hold is f-type all the same (step A-8: no filter augmentation), as IPOPT's acceptor does
    assert f.accept(1.0, 1e-2, 1.0, -1.0, 0.5, 0.5) == (True, True)
    assert f.accept(1.0, 1e-2, 1.0, -1e-3, 5e-3, 1.0) == (True, False)       # (19) fails: h-type
    # the filter itself rejects first
    f.add(1.0, 0.0)
    assert f.accept(1.0, 2.0, 10.0, -1.0, 1.0, 0.5) == (False, False)
    # alpha_min (23)
    assert f.alpha_min(1e-2, -2.0) == pytest.approx(c.gamma_alpha * min(c.gamma_theta, c.gamma_phi * 1e-2 / 2.0))
    assert f.alpha_min(1e-6, -2.0) == pytest.approx(
        c.gamma_alpha * min(c.gamma_theta, c.gamma_phi * 1e-6 / 2.0, c.delta * 1e-6 ** c.s_theta / 2.0 ** c.s_phi))
    assert f.alpha_min(1e-2, 1.0) == pytest.approx(c.gamma_alpha * c.gamma_theta)


def test_filter_reset_heuristic_and_objective_increase_guard():
    """IPOPT's safeguards of the acceptance test: a barrier function rising by more than
    obj_max_inc orders of magnitude is rejected; after filter_reset_trigger acceptances in a row
    that each followed a rejection *by the filter*, the filter is cleared."""
    c = FilterConstants()
    f = Filter.start(theta0=1.0)
    assert f.accept(1.0, 1.0, 1.0, 1.0, 0.5, 1.0 + 10 ** (c.obj_max_inc + 1.0) * 1.01) == (False, False)
    assert f.accept(1.0, 1.0, 1.0, 1.0, 0.5, 1.0 + 10 ** (c.obj_max_inc + 1.0) * 0.99)[0]
    f.add(0.1, 0.0)                          # forbids theta >= 0.1 with phi >= 0
    for k in range(c.filter_reset_trigger):
        assert f.accept(1.0, 1.0, 1.0, 1.0, 0.5, 0.5) == (False, False)     # decrease ok, filter rejects
        assert f.rejected_by_filter
        assert f.accept(1.0, 1.0, 1.0, 1.0, 0.05, 0.5)[0]                   # accepted after it
        assert len(f.entries) == (2 if k < c.filter_reset_trigger - 1 else 1)
    assert f.resets == 1 and f.accept(1.0, 1.0, 1.0, 1.0, 0.5, 0.5)[0]     # the entry is gone
    # a rejection by the decrease test, not the filter, breaks the count
    f.add(0.1, 0.0)
    assert f.accept(1.0, 1.0, 1.0, 1.0, 0.5, 0.5) == (False, False) and f.rejected_by_filter
    assert f.accept(1.0, 1.0, 1.0, 1.0, 2.0, 2.0) == (False, False) and not f.rejected_by_filter
    assert f.accept(1.0, 1.0, 1.0, 1.0, 0.05, 0.5)[0] and f.filter_rejections == 0


def test_barrier_start_and_fraction_to_boundary():
    """The start is pushed inside (sec. 3.6) and the primal step stops at tau of the distance."""
    p = PROBLEMS["lq-box"](N=3)
    b = Bounds.of(p, Layout(p), relax=0.0)
    v = np.full(b.lo.size, 5.0)
    w = b.push(v)
    assert np.all(w[b.has_hi] <= b.hi[b.has_hi] - 1e-2 * np.maximum(1, np.abs(b.hi[b.has_hi])) + 1e-15)
    dv = np.zeros_like(w)
    i = np.flatnonzero(b.has_lo)[0]
    dv[i] = -10.0
    alpha = b.max_step(w, dv, 0.99)
    assert w[i] + alpha * dv[i] - b.lo[i] == pytest.approx(0.01 * (w[i] - b.lo[i]))


def test_compiled_slacks_gradient_and_dot_match_the_numpy_formulas():
    """Bounds.slacks (one compiled pass) is np.where(has_lo, v - lo, 1), np.where(has_hi, hi - v, 1)
    bit for bit; Bounds.gradient is barrier()'s gradient; barrier.dot is the dot product."""
    from olado.solvers.ipm.barrier import dot

    p = PROBLEMS["lq-box"](N=7)
    b = Bounds.of(p, Layout(p))
    assert b.has_lo.any() and (~b.has_lo).any() and (~b.has_hi).any()    # both branches of the kernel
    v = b.push(np.linspace(-3.0, 3.0, b.lo.size))
    sl, su = b.slacks(v)
    np.testing.assert_array_equal(sl, np.where(b.has_lo, v - b.lo, 1.0))
    np.testing.assert_array_equal(su, np.where(b.has_hi, b.hi - v, 1.0))
    np.testing.assert_array_equal(b.gradient(v, 0.3), b.barrier(v, 0.3)[1])
    w = np.cos(np.arange(v.size))
    assert dot(v, w) == pytest.approx(float(np.sum(v * w)), rel=1e-14, abs=1e-14)


# ---------------------------------------------------------------------------- whole solves
@pytest.fixture(scope="module")
def ipopt():
    pytest.importorskip("cyipopt")
    return make_solver(load_config(CONFIGS / "ipopt.ini"))


@pytest.fixture(scope="module")
def ipm():
    return make_solver(load_config(CONFIGS / "ipm.ini"))


CASES = {"lq-box": lambda: PROBLEMS["lq-box"](N=20), "vanderpol": lambda: PROBLEMS["vanderpol"](N=30),
         "vanderpol-path": lambda: PROBLEMS["vanderpol-path"](N=30), "rayleigh-box": lambda: PROBLEMS["rayleigh-box"](N=30),
         "zambezi12-24": lambda: zambezi_problem(N=24)}


@pytest.mark.parametrize("name", CASES)
def test_reaches_ipopts_solution_in_ipopts_iterations(name, ipm, ipopt):
    """The same algorithm as IPOPT on the same problem: IPOPT's objective to 1e-8, its solution
    to 1e-6 and its iteration count (+-2: rounding of a different linear algebra)."""
    a, b = ipm.solve(CASES[name]()), ipopt.solve(CASES[name]())
    assert a.status is Status.SUCCESS and a.certificate.level == "success", a.message
    assert a.objective == pytest.approx(b.objective, rel=1e-8)
    scale = 1.0 + max(np.abs(b.x).max(), np.abs(b.u).max())
    assert np.abs(a.x - b.x).max() <= 1e-6 * scale and np.abs(a.u - b.u).max() <= 1e-6 * scale
    np.testing.assert_allclose(a.multipliers["dynamics"], b.multipliers["dynamics"], atol=1e-5 * (1 + np.abs(b.multipliers["dynamics"]).max()))
    assert abs(a.iterations - b.iterations) <= 2


def test_vanderpol_takes_the_inertia_correction():
    """vanderpol's first Hessian is indefinite on the dynamics' null space: an iteration with
    delta_w > 0, and the solve still ends at the optimum."""
    r = olado.solve(PROBLEMS["vanderpol"](N=50), solver="ipm")
    assert r.status is Status.SUCCESS
    assert any(h["delta_w"] > 0 for h in r.history)


CONSTRAINED = {"pendulum": lambda: Pendulum(N=20), "rayleigh-mixed": lambda: PROBLEMS["rayleigh-mixed"](N=40),
               "bryson-denham": lambda: PROBLEMS["bryson-denham"](N=40),
               "hanging-chain": lambda: PROBLEMS["hanging-chain"](N=40)}


@pytest.mark.parametrize("name", CONSTRAINED)
def test_stage_and_final_constraints_reach_ipopts_solution(name, ipm, ipopt):
    """Mixed stage inequalities (slacks), final equalities and inequalities: IPOPT's objective,
    solution, constraint multipliers and iterations."""
    a, b = ipm.solve(CONSTRAINED[name]()), ipopt.solve(CONSTRAINED[name]())
    assert a.status is Status.SUCCESS and a.certificate.level == "success", a.message
    assert a.objective == pytest.approx(b.objective, rel=1e-8)
    scale = 1.0 + max(np.abs(b.x).max(), np.abs(b.u).max())
    assert np.abs(a.x - b.x).max() <= 1e-6 * scale and np.abs(a.u - b.u).max() <= 1e-6 * scale
    for key in ("stage_constraints", "final_constraints"):
        np.testing.assert_allclose(a.multipliers[key], b.multipliers[key], atol=1e-5 * (1 + np.abs(b.multipliers[key]).max(initial=0)))
    assert abs(a.iterations - b.iterations) <= 2


def test_iteration_limit_is_a_status_with_the_iterate():
    p = zambezi_problem(N=24)
    r = olado.solve(p, solver="ipm", max_iter=5)
    assert r.status is Status.MAX_ITERATIONS and "iteration limit 5" in r.message
    assert r.iterations == 5 and len(r.history) == 5 and np.isfinite(r.objective)


def test_callback_stop():
    r = olado.solve(zambezi_problem(N=24), solver="ipm", callback=lambda info: info["iter"] == 3)
    assert r.status is Status.USER_STOP and r.iterations == 3


class Unreachable(olado.problems.DOCP):
    """x+ = x + 0.1 u, |u| <= 1, x >= 1 after the start at 0: x^1 <= 0.1 cannot reach the bound."""

    name = "unreachable"
    vectorized = True

    def __init__(self, N=10):
        super().__init__(1, 1, N, [0.0], x_bounds=([1.0], [np.inf]), u_bounds=([-1.0], [1.0]))

    def dynamics(self, k, x, u):
        return x + 0.1 * u

    def stage_cost(self, k, x, u):
        return 0.5 * (x[:, 0] ** 2 + u[:, 0] ** 2)

    def final_cost(self, x):
        return 0.0


def test_unreachable_bounds_end_in_the_restoration_phase_as_infeasible():
    """The line search fails, the restoration phase cannot reduce the dynamics violation 0.9 of
    stage 0 (x^1 = 0.1 u^0 must be >= 1): INFEASIBLE with the sentence, the diagnosis names stage 0."""
    r = olado.solve(Unreachable(), solver="ipm")
    assert r.status is Status.INFEASIBLE and r.info["restorations"] >= 1
    assert "locally infeasible" in r.message
    assert r.infeasibility.largest == pytest.approx(0.9, rel=1e-4)
    assert r.infeasibility.arrays[0].array == "dynamics" and r.infeasibility.arrays[0].first_stage == 0


def test_the_iterates_follow_ipopts_through_watchdog_and_second_order_correction(ipopt):
    """obstacle's first 22 iterations: ten shortened steps (4-13), the watchdog's three full steps
    (14-16, IPOPT's "w"), the step accepted against the watched point (17), a second-order
    correction with delta_w = 1/3 of the last shift (18), backtracking (19-22): IPOPT's objective
    after every iteration, to 1e-7."""
    a = olado.solve(PROBLEMS["obstacle"](), solver="ipm", max_iter=22)
    b = olado.solve(PROBLEMS["obstacle"](), solver="ipopt", max_iter=22)
    got = [h["objective"] for h in a.history]
    ref = [h["objective"] for h in b.history[1:]]
    assert len(got) == len(ref) == 22
    np.testing.assert_allclose(got, ref, rtol=1e-7)
    assert [h["watchdog"] for h in a.history[13:17]] == [True, True, True, False]
    assert a.history[17]["soc"] >= 1 and a.history[17]["delta_w"] == pytest.approx(a.history[14]["delta_w"] / 3)


def _fd_columns(fun, Z, eps=1e-6):
    """Central differences of fun (stacked over stages) with respect to every column of Z."""
    cols = []
    for j in range(Z.shape[-1]):
        dZ = np.zeros_like(Z); dZ[..., j] = eps
        cols.append((fun(Z + dZ) - fun(Z - dZ)) / (2 * eps))
    return np.stack(cols, axis=-1)


def test_the_l1_restoration_problem_is_a_docp_with_consistent_derivatives():
    """The elastic restoration problem (olado.solvers.ipm.elastic) of a problem with dynamics,
    a stage inequality and a final equality: its Jacobians (states, controls, final) and cost
    gradients are the finite differences of its functions, its stage Hessian the difference of
    the Lagrangian gradients; at its start (eq. (33)) every relaxed row holds: x^{k+1} = f - p + n,
    g - p + n = s (the original slacks), g^N - p_N + n_N = 0, with p, n > 0 and the final pair
    the last stage's w (IPOPT's single pair)."""
    from olado.solvers.ipm.elastic import RHO, ElasticDOCP
    from olado.solvers.ipm.newton import Residuals

    p = Pendulum(N=4)
    rng = np.random.default_rng(2)
    X = rng.standard_normal((5, 2)) * 0.3
    X[0] = p.x0
    U = rng.uniform(-1, 1, (4, 1))
    s = rng.uniform(0.1, 1.0, (4, 1))
    g, gN = p.eval_stage_constraints(X, U), p.eval_final_constraints(X[-1])
    res = Residuals(p.eval_dynamics(X, U) - X[1:], np.zeros((4, 0)), gN, g - s, np.zeros(0))
    ep = ElasticDOCP(p, X, U, mu=0.1)
    Xe, Ue = ep.start(X, U, res, 0.1)
    assert Xe.shape == (5, ep.n) and Ue.shape == (4, ep.m) and np.all(Ue[:, 1:] > 0)
    np.testing.assert_allclose(ep.eval_dynamics(Xe, Ue), Xe[1:], atol=1e-12)
    np.testing.assert_allclose(ep.eval_stage_constraints(Xe, Ue), s, atol=1e-12)
    np.testing.assert_allclose(ep.eval_final_constraints(Xe[-1]), 0.0, atol=1e-12)
    w = ep.split(Ue)[-1]
    np.testing.assert_allclose(w[:-1], 0.1 / RHO)
    assert ep.elastic_sum(Xe, Ue) == pytest.approx(np.abs(res.h).sum() + np.abs(res.d).sum() + abs(gN[0]), rel=1e-3)
    Xe = Xe + 0.01 * rng.standard_normal(Xe.shape)       # a generic point
    Xe[0] = ep.x0
    A, B = ep.eval_dynamics_jacobians(Xe, Ue)
    Cx, Cu = ep.eval_stage_constraint_jacobians(Xe, Ue)
    lx, lu = ep.eval_stage_cost_gradients(Xe, Ue)
    np.testing.assert_allclose(B, _fd_columns(lambda UU: ep.eval_dynamics(Xe, UU), Ue), atol=1e-7)
    np.testing.assert_allclose(Cu, _fd_columns(lambda UU: ep.eval_stage_constraints(Xe, UU), Ue), atol=1e-7)

    def with_states(XX):
        full = Xe.copy(); full[:-1] = XX
        return full

    np.testing.assert_allclose(A, _fd_columns(lambda XX: ep.eval_dynamics(with_states(XX), Ue), Xe[:-1]), atol=1e-7)
    np.testing.assert_allclose(Cx, _fd_columns(lambda XX: ep.eval_stage_constraints(with_states(XX), Ue), Xe[:-1]),
                               atol=1e-7)
    np.testing.assert_allclose(ep.eval_final_constraint_jacobian(Xe[-1]),
                               _fd_columns(ep.eval_final_constraints, Xe[-1]), atol=1e-7)
    fd_lu = _fd_columns(lambda UU: np.array([ep.objective(Xe, UU)]), Ue)
    np.testing.assert_allclose(lu.sum(axis=0), fd_lu[0], rtol=1e-6, atol=1e-6)
    fd_lN = _fd_columns(lambda xN: np.array([ep.objective(np.vstack([Xe[:-1], xN]), Ue)]), Xe[-1])[0]
    np.testing.assert_allclose(ep.eval_final_cost_gradient(Xe[-1]), fd_lN, rtol=1e-6, atol=1e-6)
    # stage Hessian: derivative of the Lagrangian's u-gradient (sigma = 1, multipliers P, L)
    P, L = rng.standard_normal((4, ep.n)), rng.standard_normal((4, 1))
    Hxx, Hxu, Huu = ep.eval_stage_hessians(Xe, Ue, 1.0, P, L)

    def grad_u(UU):
        _, B_ = ep.eval_dynamics_jacobians(Xe, UU)
        _, Cu_ = ep.eval_stage_constraint_jacobians(Xe, UU)
        _, lu_ = ep.eval_stage_cost_gradients(Xe, UU)
        return lu_ + np.einsum("kij,ki->kj", B_, P) + np.einsum("kij,ki->kj", Cu_, L)

    np.testing.assert_allclose(Huu, _fd_columns(grad_u, Ue), atol=1e-6)


def test_l1_restoration_option_keeps_the_statuses_honest():
    """The Gauss-Newton phase (restoration = gauss-newton) on the unreachable bound: no false
    success, no infeasibility claim without a stationary point -- INFEASIBLE or FAILED with the
    sentence."""
    r = olado.solve(Unreachable(), solver="ipm", restoration="gauss-newton")
    assert r.status in (Status.INFEASIBLE, Status.FAILED) and r.info["restorations"] >= 1
    assert "restoration" in r.message


# ---------------------------------------------------------------------------- the l1 restoration against IPOPT
def _entry(name):
    from olado.problems.suites import load_suite

    return next(e for e in load_suite("robustness") if e.name == name).build()


@pytest.mark.parametrize("name", ["lq-unreachable", "cart-too-short"])
def test_the_l1_restoration_proves_infeasibility_where_ipopt_does(name, ipm, ipopt):
    """Deliberately infeasible entries (proofs in olado/problems/infeasible.py): INFEASIBLE as
    IPOPT says, with the certificate of the claim -- the l1 restoration problem converged (its
    scaled optimality error, the stationarity of the l1 violation, within its tolerance) at a
    point whose constraint violation stays far from 0 (at IPOPT's l1 minimizer's level)."""
    problem, guess = _entry(name)
    r = ipm.solve(problem, guess=guess)
    ref = ipopt.solve(problem, guess=guess)
    assert ref.status is Status.INFEASIBLE
    assert r.status is Status.INFEASIBLE and "locally infeasible" in r.message
    cert = r.info["infeasibility_certificate"]
    # the restoration converged at the level its status states: tol (1e-8) or IPOPT's acceptable
    # level (1e-6, acceptable_iter iterates in a row) -- at lq-unreachable's degenerate l1
    # minimizer the last digits are at the Newton systems' rounding floor, where either comes out
    # (N = 46..56: 3 of 6 at tol, 3 acceptable; benchmarks/RESULTS.md, "Multipliers of the general
    # Riccati recursion on unstable dynamics")
    level = {"success": cert["restoration_tol"], "acceptable": ipm.options.acceptable_tol}[cert["restoration_status"]]
    assert cert["restoration_tol"] <= 1e-8 and cert["restoration_optimality_error"] <= level <= 1e-6
    assert cert["max_violation"] > 1e-1 and cert["max_violation"] == pytest.approx(r.max_constraint_violation, rel=1e-6)
    assert cert["max_violation"] == pytest.approx(ref.max_constraint_violation, rel=0.05)
    _assert_l1_stationary(problem, r)


def _assert_l1_stationary(problem, r, rho=1000.0):
    """An independent check of the infeasibility claim at the returned point and multipliers
    (those of the l1 restoration problem): the first-order conditions of min rho |c|_1 on the
    bounds (Waechter and Biegler 2006, eq. (30) at mu -> 0) -- every multiplier within rho,
    y = rho sign(c) on every dynamics row that stays violated, and grad_(x,u) of y.c balanced by the
    bound multipliers up to the proximity term sqrt(mu) D_R (x - x_R) (<= 1e-6 rho)."""
    from olado.solvers.common import stage_gradient_terms
    from olado.solvers.sqp.state import Point

    pt = Point(problem, r.x, r.u)
    m = r.multipliers
    lam, Lg, LgN = m["dynamics"], m["stage_constraints"], m["final_constraints"]
    for y in (lam, Lg, LgN):
        assert np.all(np.abs(y) <= rho * (1 + 1e-6))
    viol = np.abs(pt.h) > 1e-6
    assert viol.any()
    np.testing.assert_allclose(lam[viol], rho * np.sign(pt.h[viol]), rtol=1e-6)
    rx, ru = stage_gradient_terms(problem, pt, lam, Lg, LgN, sigma=0.0)
    rx = rx - m["bound_lower_x"] + m["bound_upper_x"]
    ru = ru - m["bound_lower_u"] + m["bound_upper_u"]
    assert max(np.abs(rx[1:]).max(), np.abs(ru).max()) <= 1e-6 * rho


def test_the_l1_restoration_passes_where_ipopt_s_does(ipm, ipopt):
    """bang-bang-cart: ipm's iterates are IPOPT's up to IPOPT's restoration phase at iteration 7;
    the l1 restoration takes IPOPT's eight restoration iterations (8r-15r: the original objective
    after each to 1e-5), returns to the filter method where IPOPT does (the original violation
    reduced to 0.9 of its start, acceptable to the original filter) and goes on along IPOPT's
    iterates (16-22); the solve ends at IPOPT's optimum, certified, in IPOPT's count to a few."""
    problem, guess = _entry("bang-bang-cart")
    r = ipm.solve(problem, guess=guess)
    ref = ipopt.solve(problem, guess=guess)
    assert r.status is Status.SUCCESS and ref.status is Status.SUCCESS and r.info["restorations"] >= 1
    assert r.certificate.level == "success"
    assert r.objective == pytest.approx(ref.objective, rel=1e-7)
    ref_by_iter = {h["iter"]: h for h in ref.history}      # IPOPT logs the phase's last iteration twice
    got = [h["objective"] for h in r.history[:22]]
    np.testing.assert_allclose(got, [ref_by_iter[k]["objective"] for k in range(1, 23)], rtol=1e-5)
    assert [h["restoration"] for h in r.history[:16]] == [False] * 6 + [True] * 9 + [False]
    assert len(r.history) == r.iterations and abs(r.iterations - ref.iterations) <= 3


# ---------------------------------------------------------------------------- the adaptive mu update
@pytest.mark.parametrize("name", ["lq-box", "rayleigh-box", "zambezi12-24"])
def test_adaptive_mu_follows_ipopts_iterates(name, ipopt):
    """mu_strategy = adaptive (IPOPT's quality-function oracle, obj-constr-filter globalization):
    the barrier parameter and the objective after every iteration are IPOPT's with
    mu_strategy = adaptive (to 1e-8), and so is the iteration count."""
    a = olado.solve(CASES[name](), solver="ipm", mu_strategy="adaptive")
    b = make_solver(load_config(CONFIGS / "ipopt.ini", ["ipopt.mu_strategy=adaptive"])).solve(CASES[name]())
    assert a.status is Status.SUCCESS and b.status is Status.SUCCESS and a.iterations == b.iterations
    ref = {h["iter"]: h for h in b.history}
    np.testing.assert_allclose([h["objective"] for h in a.history],
                               [ref[k]["objective"] for k in range(1, a.iterations + 1)], rtol=1e-8)
    np.testing.assert_allclose([h["mu"] for h in a.history], [ref[k]["mu"] for k in range(1, a.iterations + 1)],
                               rtol=1e-6)


def test_the_quality_function_oracle_minimizes_over_sigma():
    """The golden-section search of the oracle (olado.solvers.ipm.adaptive) on a function with a
    known minimizer: inside the interval it lands within the section tolerance of the minimizer;
    when the minimum is at an end of the interval, that end is returned."""
    from olado.solvers.ipm.adaptive import golden_section, quality_function_sigma

    sigma = golden_section(lambda s: (s - 0.3) ** 2, 1e-6, 0.99)
    assert abs(sigma - 0.3) < 0.02
    assert golden_section(lambda s: s, 1e-6, 0.99) == pytest.approx(1e-6, abs=0.01)
    assert golden_section(lambda s: -s, 1.0, 50.0) == 50.0
    # q decreasing through sigma = 1: the upper side, capped by mu_max / avg
    assert quality_function_sigma(lambda s: (s - 5.0) ** 2, 1.0, 1e-11, 1e3) == pytest.approx(5.0, rel=0.05)
