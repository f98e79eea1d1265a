"""FQLNK (seed 002; olado.solvers.fqlnk): the damped BFGS update by hand, the assembled KKT pieces
against finite differences, the ILUTP-GMRES step against a dense solve of the same KKT system,
the refusal of inequalities, a breakdown as a status, and whole solves against IPOPT
(configs/ipopt.ini) on the Earth-to-Mars transfer (``orbit-raising``) and on van der Pol."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

import olado
from olado.errors import ConfigError
from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.result import Status
from olado.solvers.base import Solver
from olado.solvers.fqlnk import solver as fq
from olado.solvers.fqlnk.bfgs import damped_bfgs_update, damping_theta, positive_definite_start
from olado.solvers.fqlnk.krylov import kkt_matrix, solve_kkt
from olado.solvers.sqp.state import Clock

from fixtures import CONFIGS

IPOPT = str(CONFIGS / "ipopt.ini")


# ---------------------------------------------------------------------------- damped BFGS (sec. 3.2)
def test_undamped_update_by_hand():
    """B = diag(2, 1), s = e1, y = (3, 1): s'y = 3 >= 0.2 s'Bs = 0.4, theta = 1, and
    B+ = B - diag(2, 0) + y y' / 3 = [[3, 1], [1, 4/3]]."""
    up = damped_bfgs_update(np.diag([2.0, 1.0]), np.array([1.0, 0.0]), np.array([3.0, 1.0]))
    assert up.theta == 1.0 and not up.skipped
    np.testing.assert_allclose(up.B, [[3.0, 1.0], [1.0, 4.0 / 3.0]], rtol=1e-15)
    np.testing.assert_allclose(up.B @ [1.0, 0.0], [3.0, 1.0], rtol=1e-15)     # the secant equation B+ s = y


def test_damped_update_by_hand():
    """Negative curvature s'y = -1 < 0.4: theta = 0.8 * 2 / (2 + 1) = 8/15, r = theta y + (1 - theta)
    B s = (0.4, 4/15), s'r = 0.4 = 0.2 s'Bs, B+ = diag(0, 1) + r r' / 0.4, positive definite."""
    B, s, y = np.diag([2.0, 1.0]), np.array([1.0, 0.0]), np.array([-1.0, 0.5])
    assert damping_theta(2.0, -1.0) == pytest.approx(8.0 / 15.0, rel=1e-15)
    up = damped_bfgs_update(B, s, y)
    r = np.array([0.4, 4.0 / 15.0])
    np.testing.assert_allclose(up.B, np.diag([0.0, 1.0]) + np.outer(r, r) / 0.4, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(up.B @ s, r, rtol=1e-14)            # secant equation with the damped r
    assert np.linalg.eigvalsh(up.B).min() > 0.0                    # det = 0.4 (1 + 8/45) - (4/15)^2 = 0.4


def test_damped_update_keeps_positive_definiteness():
    """Random positive definite B and arbitrary (s, y), often s'y < 0: B+ s = r, B+ symmetric
    positive definite, and s'r >= 0.2 s'Bs (the curvature the damping guarantees)."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        n = rng.integers(2, 8)
        M = rng.standard_normal((n, n))
        B = M @ M.T + 0.1 * np.eye(n)
        s, y = rng.standard_normal(n), rng.standard_normal(n)
        up = damped_bfgs_update(B, s, y)
        sBs, theta = s @ B @ s, up.theta
        r = theta * y + (1 - theta) * B @ s
        np.testing.assert_allclose(up.B @ s, r, rtol=1e-8, atol=1e-10 * np.abs(r).max())
        assert s @ r >= 0.2 * sBs * (1 - 1e-12)
        np.testing.assert_allclose(up.B, up.B.T, atol=1e-12)
        assert np.linalg.eigvalsh(up.B).min() > 0.0


def test_positive_definite_start_flips_negative_eigenvalues():
    """B^(0) = V max(|Lambda|, floor) V': for H with eigenvalues (-1, 3, 1e-9) in a rotated basis
    the start has eigenvalues (1, 3, floor = 1e-4 max(1, max|H_ii|)) on the same eigenvectors."""
    Q, _ = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))
    H = Q @ np.diag([-1.0, 3.0, 1e-9]) @ Q.T
    B, lowest = positive_definite_start(H, margin=1e-4)
    floor = 1e-4 * max(1.0, np.abs(np.diag(H)).max())
    assert lowest == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(B, Q @ np.diag([1.0, 3.0, floor]) @ Q.T, atol=1e-13)
    B2, d2 = positive_definite_start(np.diag([1.0, 3.0]))
    assert d2 == 0.0 and np.array_equal(B2, np.diag([1.0, 3.0]))


# ---------------------------------------------------------------------------- the KKT system
def start_state(problem, **options):
    o = fq.FQLNKOptions(**options)
    setup = fq.Setup(o, problem, fq.Limits(1e9), lambda info: False)
    X0, U0 = Solver.initial_point(problem, None)
    return setup, fq.initial_state(setup, X0, U0, Clock())


def perturbed(rng, v, layout):
    w = v + 0.05 * rng.standard_normal(v.size)
    w[layout.ny:] = np.abs(w[layout.ny:]) + 0.3       # slacks away from 0
    return w


@pytest.mark.parametrize("name, opts", [("orbit-raising", {"inequalities": "squared-slacks"}),
                                        ("hanging-chain", {})])
def test_assembly_against_finite_differences(name, opts):
    """G = dc/dv, grad_v L and H = grad_vv L (exact) as assembled from the stage derivatives,
    against central differences of the assembled c and grad_v L at a random point."""
    problem = PROBLEMS[name](N=6)
    setup, st = start_state(problem, **opts)
    L = setup.layout
    rng = np.random.default_rng(3)
    v = perturbed(rng, st.it.v, L)
    lam = rng.standard_normal(L.nc)
    pt = fq.point_at(setup, v, Clock())
    G, g, H = L.jacobian(pt, v).toarray(), L.lagrangian_gradient(pt, v, lam), L.hessian(pt, v, lam).toarray()
    h = 1e-6
    Gfd, Hfd = np.empty_like(G), np.empty_like(H)
    for j in range(L.nv):
        e = np.zeros(L.nv); e[j] = h
        pp, pm = fq.point_at(setup, v + e, Clock()), fq.point_at(setup, v - e, Clock())
        Gfd[:, j] = (L.constraints(pp, v + e) - L.constraints(pm, v - e)) / (2 * h)
        Hfd[:, j] = (L.lagrangian_gradient(pp, v + e, lam) - L.lagrangian_gradient(pm, v - e, lam)) / (2 * h)
    np.testing.assert_allclose(G, Gfd, atol=1e-6 * max(1.0, np.abs(G).max()))
    np.testing.assert_allclose(H, Hfd, atol=1e-5 * max(1.0, np.abs(H).max()))
    # grad_v L = grad J + G' lam: the gradient of J from differences of the objective
    gJ = np.empty(L.nv)
    for j in range(L.nv):
        e = np.zeros(L.nv); e[j] = h
        gJ[j] = (fq.point_at(setup, v + e, Clock()).J - fq.point_at(setup, v - e, Clock()).J) / (2 * h)
    np.testing.assert_allclose(g, gJ + G.T @ lam, atol=1e-6 * max(1.0, np.abs(g).max()))


@pytest.mark.parametrize("hessian", ["bfgs", "exact", "fd"])
def test_ilutp_gmres_step_against_a_dense_solve(hessian):
    """The Newton step of Algorithm 1 (step 4) by ILUTP-GMRES at eta = 1e-10 against numpy's dense
    solve of the same K dp = -F; the seed's eta = 1e-6 meets its forcing condition."""
    problem = PROBLEMS["orbit-raising"](N=8)
    setup, st = start_state(problem, inequalities="squared-slacks", hessian=hessian, forcing=1e-10)
    K = kkt_matrix(fq.hessian_block(setup, st), st.it.G)
    dense = np.linalg.solve(K.toarray(), -st.it.F)
    sol = solve_kkt(K, st.it.F, setup.options)
    assert sol.converged and sol.iterations >= 1
    np.testing.assert_allclose(sol.dp, dense, rtol=1e-7, atol=1e-8 * np.abs(dense).max())
    seed = solve_kkt(K, st.it.F, fq.FQLNKOptions())
    assert np.linalg.norm(st.it.F + K @ seed.dp) <= 1e-6 * np.linalg.norm(st.it.F)


def test_singular_kkt_matrix_is_a_message_not_an_exception():
    import scipy.sparse as sp

    K = sp.csc_matrix(np.zeros((3, 3)))
    sol = solve_kkt(K, np.ones(3), fq.FQLNKOptions())
    assert sol.dp is None and "ILUTP factorization of the KKT matrix failed" in sol.message


def test_ilu_breakdown_is_a_status(monkeypatch):
    """An ILUTP failure inside a solve ends it with NUMERICAL_ERROR and a sentence, no traceback."""
    def broken(*args, **kwargs):
        raise RuntimeError("Factor is exactly singular")

    monkeypatch.setattr(spla, "spilu", broken)
    r = olado.solve(PROBLEMS["vanderpol"](N=10), solver="fqlnk")
    assert r.status is Status.NUMERICAL_ERROR
    assert "Newton iteration 1" in r.message and "exactly singular" in r.message


# ---------------------------------------------------------------------------- refusal
def test_refuses_inequalities_naming_problem_and_what():
    p = zambezi_problem(N=12)
    with pytest.raises(ConfigError) as exc:
        olado.solve(p, solver="fqlnk")
    msg = str(exc.value)
    assert "section [fqlnk], key 'inequalities'" in msg
    assert repr(p.name) in msg and "finite bounds on the" in msg and "squared-slacks" in msg
    assert exc.value.section == "fqlnk" and exc.value.key == "inequalities"


def test_refuses_fixed_variables_with_squared_slacks():
    p = PROBLEMS["vanderpol"](N=10)
    p.u_bounds = (0.0, 0.0)
    with pytest.raises(ConfigError, match="fixes 10 variables by equal bounds"):
        olado.solve(p, solver="fqlnk", inequalities="squared-slacks")


# ---------------------------------------------------------------------------- against IPOPT
@pytest.mark.parametrize("hessian", ["bfgs", "exact", "fd"])
def test_vanderpol_against_ipopt(hessian):
    ref = olado.solve(PROBLEMS["vanderpol"](N=20), config=IPOPT)
    r = olado.solve(PROBLEMS["vanderpol"](N=20), solver="fqlnk", hessian=hessian)
    assert ref.status is Status.SUCCESS and r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-8)
    np.testing.assert_allclose(r.u, ref.u, atol=1e-5)
    assert r.certificate is not None and r.certificate.level == "success"


def test_earth_to_mars_bfgs_reaches_ipopts_optimum():
    """orbit-raising (seed 002 sec. 4.1) at N = 16 with the bound r >= 0.5 as a squared slack:
    the BFGS variant reaches IPOPT's r(t_f) = 1.52444 (the seed's 1.525 at its own grid)."""
    ref = olado.solve(PROBLEMS["orbit-raising"](N=16), config=IPOPT)
    r = olado.solve(PROBLEMS["orbit-raising"](N=16), solver="fqlnk", hessian="bfgs", inequalities="squared-slacks")
    assert ref.status is Status.SUCCESS and r.status is Status.SUCCESS, r.message
    assert r.x[-1, 0] == pytest.approx(ref.x[-1, 0], rel=1e-7)
    np.testing.assert_allclose(r.x, ref.x, atol=1e-5)
    assert r.info["slacks"] == 16 and r.info["newton_iterations"] > 10


def test_earth_to_mars_exact_newton_from_ipopts_point_converges_fast():
    """From IPOPT's optimum perturbed, the exact Hessian (the seed's AD) converges in a few
    Newton iterations to it; from the default start it stops at another KKT point (r(t_f) ~
    1.2245 at N = 16, docs/fqlnk.md), which the certificate accepts as first-order optimal."""
    ref = olado.solve(PROBLEMS["orbit-raising"](N=16), config=IPOPT)
    U = ref.u + 1e-3 * np.cos(np.arange(16))[:, None]
    r = olado.solve(PROBLEMS["orbit-raising"](N=16), solver="fqlnk", hessian="exact",
                    inequalities="squared-slacks", guess=U)
    assert r.status is Status.SUCCESS and r.iterations <= 8, r.message
    assert r.x[-1, 0] == pytest.approx(ref.x[-1, 0], rel=1e-8)


def test_full_steps_without_line_search():
    """line_search = none (the seed's "without backtracking", Fig. 4.10): near IPOPT's optimum of
    van der Pol every step is full and the exact Newton iteration converges to it; from the
    default start the full steps diverge, which ends as NUMERICAL_ERROR with a sentence, while the
    merit's backtracking converges."""
    ref = olado.solve(PROBLEMS["vanderpol"](N=20), config=IPOPT)
    near = ref.u + 1e-2 * np.sin(np.arange(20))[:, None]
    r = olado.solve(PROBLEMS["vanderpol"](N=20), solver="fqlnk", hessian="exact", line_search="none", guess=near)
    assert r.status is Status.SUCCESS, r.message
    assert all(e["alpha"] == 1.0 and e["merit"] == "none" for e in r.history)
    assert r.objective == pytest.approx(ref.objective, rel=1e-8)
    far = olado.solve(PROBLEMS["vanderpol"](N=20), solver="fqlnk", hessian="exact", line_search="none")
    assert far.status is Status.NUMERICAL_ERROR and far.message.startswith("Newton iteration ")
    assert olado.solve(PROBLEMS["vanderpol"](N=20), solver="fqlnk", hessian="exact").status is Status.SUCCESS


def test_seed_test_without_the_certificate_is_uncertified():
    """The seed's stopping test holds, olado's certificate cannot (a scaled stationarity of 1e-30
    asked for): after certificate_attempts further iterations the status is UNCERTIFIED with the
    certificate's sentence, never SUCCESS."""
    r = olado.solve(PROBLEMS["vanderpol"](N=10), solver="fqlnk", hessian="exact", tol=1e-30, certificate_tol=1e-30,
                    certificate_acceptable_tol=1e-30, certificate_attempts=2)
    assert r.status is Status.UNCERTIFIED
    assert "the seed's stopping test holds" in r.message and "after 2 further iterations" in r.message
    assert "stationarity" in r.message and r.certificate is not None and r.certificate.level != "success"
