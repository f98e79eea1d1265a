"""Interior-point QP methods (olado.qp.interior_point) against Clarabel, each other and known statuses."""

import numpy as np
import pytest

from fixtures.qp_problems import clarabel_solution, random_qp, replace, zambezi_qp
from olado.errors import ConfigError
from olado.linalg import RiccatiFactorization
from olado.linalg.backend import KKT_SOLVERS
from olado.qp import make_qp_solver
from olado.qp.interior_point import FrankeQP, GondzioQP, MehrotraQP, WeightedCorrectorQP
from olado.qp.interior_point.kernels import _implied_newton_residual
from olado.qp.interior_point.kkt_map import _kkt_map
from olado.qp.interior_point.point import _Rhs
from olado.qp.interior_point.presolve import _Prepared
from olado.qp.interior_point.step import _StepContext
from olado.qp.stageqp import StageQP, qp_kkt_residuals
from olado.result import Status

METHODS = (MehrotraQP, GondzioQP, WeightedCorrectorQP, FrankeQP)


# ============================================================================= test problems
def assert_kkt_small(res, tol=1e-7):
    assert res.kkt["stationarity"] <= tol, res.kkt
    assert res.kkt["primal"] <= tol, res.kkt
    assert res.kkt["complementarity"] <= tol, res.kkt
    assert res.kkt["dual_sign"] == 0.0, res.kkt


# ============================================================================= agreement with Clarabel
@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
@pytest.mark.parametrize("case", [dict(seed=0), dict(seed=3), dict(seed=4, N=10, n=4, m=3),
                                  dict(seed=1, fixed=True), dict(seed=2, eq=True), dict(seed=5, fixed=True, eq=True)],
                         ids=lambda c: "-".join(f"{k}{v}" for k, v in c.items()))
def test_random_qps_agree_with_clarabel(cls, case):
    qp = random_qp(**case)
    Xr, Ur, Jr = clarabel_solution(qp)
    res = cls(tol=1e-10).solve(qp)
    assert res.status is Status.SUCCESS, res.message
    assert res.objective == pytest.approx(Jr, rel=1e-9, abs=1e-9)
    assert np.max(np.abs(res.X - Xr)) < 1e-6 and np.max(np.abs(res.U - Ur)) < 1e-6
    assert_kkt_small(res, 1e-8)
    assert res.kkt == qp_kkt_residuals(qp, res)
    assert res.solver == cls.name and res.iterations == len(res.history) and res.time_s > 0


def test_default_tolerance_gives_small_kkt_residuals():
    qp = random_qp(7)
    for cls in METHODS:
        res = cls().solve(qp)
        assert res.success, res.message
        assert_kkt_small(res, 1e-6)


def test_history_records_every_iteration():
    res = GondzioQP().solve(random_qp(0))
    assert len(res.history) == res.iterations > 0
    keys = {"iter", "mu", "primal", "dual", "gap", "objective", "alpha", "alpha_aff", "sigma", "safeguard", "correctors",
            "omega", "solves", "refinements", "regularization"}
    for i, h in enumerate(res.history, 1):
        assert keys <= set(h) and h["iter"] == i
        assert 0 < h["alpha"] <= 1 and 0 <= h["correctors"] <= 3
    mus = [h["mu"] for h in res.history]
    assert mus[-1] < 1e-6 * mus[0]


# ============================================================================= structure
def test_fixed_variables_are_held_and_their_multipliers_recovered():
    qp = random_qp(1, fixed=True)
    N = qp.N
    for cls in METHODS:
        res = cls(tol=1e-10).solve(qp)
        assert res.status is Status.SUCCESS, res.message
        assert res.U[1, 1] == qp.u_lower[1, 1]                         # eliminated control: exact value
        assert res.X[2, 0] == pytest.approx(qp.x_lower[2, 0], abs=1e-12)  # equality rows
        assert res.X[N, 1] == pytest.approx(qp.x_lower[N, 1], abs=1e-12)
        cz = qp.C[3, 1] @ np.concatenate([res.X[3], res.U[3]])
        assert cz == pytest.approx(qp.c_lower[3, 1], abs=1e-12)
        # multipliers of the fixed entries: one side only, and the KKT conditions hold
        for lo, hi in ((res.zu_lower[1, 1], res.zu_upper[1, 1]), (res.zx_lower[2, 0], res.zx_upper[2, 0]),
                       (res.zx_lower[N, 1], res.zx_upper[N, 1]), (res.yc_lower[3, 1], res.yc_upper[3, 1])):
            assert lo >= 0 and hi >= 0 and lo * hi == 0
        assert_kkt_small(res, 1e-8)


def test_horizon_one():
    qp = random_qp(11, N=1, n=2, m=2)
    Xr, Ur, Jr = clarabel_solution(qp)
    for cls in METHODS:
        res = cls(tol=1e-10).solve(qp)
        assert res.status is Status.SUCCESS, res.message
        assert np.allclose(res.X, Xr, atol=1e-6) and np.allclose(res.U, Ur, atol=1e-6)
        assert res.objective == pytest.approx(Jr, rel=1e-9)


def test_equality_only_qp_is_one_newton_step():
    qp = random_qp(2, nc=0, ncN=0, eq=True)
    qp = replace(qp, x_lower=None, x_upper=None, u_lower=None, u_upper=None)
    ref = RiccatiFactorization(qp.Q, qp.S, qp.R, qp.A, qp.B, E=qp.E, F=qp.F).solve(qp.q, qp.r, qp.c, qp.x0, e=qp.e)
    res = MehrotraQP().solve(qp)
    assert res.status is Status.SUCCESS and res.iterations == 1
    assert np.allclose(res.X, ref.X, atol=1e-10) and np.allclose(res.lam, ref.lam, atol=1e-9)


def test_x0_outside_its_bounds_and_crossed_bounds_are_infeasible():
    qp = random_qp(0)
    xl = qp.x_lower.copy(); xl[0, 0] = qp.x0[0] + 1.0
    res = MehrotraQP().solve(replace(qp, x_lower=xl, x_upper=np.maximum(qp.x_upper, xl)))
    assert res.status is Status.INFEASIBLE and "x0" in res.message
    ul = qp.u_lower.copy(); ul[2, 1] = qp.u_upper[2, 1] + 0.5
    res = MehrotraQP().solve(replace(qp, u_lower=ul))
    assert res.status is Status.INFEASIBLE and "lower bound above upper bound for u" in res.message


# ============================================================================= KKT back-ends
@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
def test_all_kkt_backends_give_the_same_iterates(cls):
    qp = random_qp(5, fixed=True, eq=True)
    runs = {kkt: cls(kkt=kkt, tol=1e-10).solve(qp) for kkt in KKT_SOLVERS}
    ref = runs["riccati"]
    assert ref.status is Status.SUCCESS
    for kkt, res in runs.items():
        assert res.status is Status.SUCCESS, (kkt, res.message)
        assert res.iterations == ref.iterations, kkt
        for h, h0 in zip(res.history, ref.history):
            assert h["alpha"] == pytest.approx(h0["alpha"], abs=1e-8), kkt
            assert h["mu"] == pytest.approx(h0["mu"], rel=1e-6, abs=1e-14), kkt
            assert h["correctors"] == h0["correctors"], kkt
        assert np.allclose(res.X, ref.X, atol=1e-9) and np.allclose(res.U, ref.U, atol=1e-9), kkt


# ============================================================================= methods
def test_gondzio_without_correctors_is_mehrotra():
    qp = random_qp(4)
    a, b = MehrotraQP().solve(qp), GondzioQP(max_correctors=0).solve(qp)
    assert a.iterations == b.iterations and np.array_equal(a.X, b.X)


def test_safeguard_path_converges():
    # safeguard_step = 1 forces the Salahi-Peng-Terlaky safeguard (sigma = gamma/(1-gamma)) every iteration
    qp = random_qp(0)
    res = MehrotraQP(safeguard_step=1.0, tol=1e-10).solve(qp)
    assert res.status is Status.SUCCESS, res.message
    assert all(h["safeguard"] and h["sigma"] == pytest.approx(1 / 9) for h in res.history)
    Xr, _, _ = clarabel_solution(qp)
    assert np.allclose(res.X, Xr, atol=1e-6)


def test_weighted_corrector_weights_lie_in_their_interval():
    res = WeightedCorrectorQP().solve(random_qp(3))
    assert res.success
    for h in res.history:
        assert min(h["alpha_aff"], 1.0) - 1e-12 <= h["omega"] <= 1.0


def test_make_qp_solver_and_options():
    assert isinstance(make_qp_solver("gondzio", max_correctors=2), GondzioQP)
    with pytest.raises(ConfigError):         # a ValueError
        make_qp_solver("simplex")
    with pytest.raises(ConfigError):
        MehrotraQP(step_to_boundary=0.5)
    with pytest.raises(ConfigError):
        MehrotraQP(kkt="cholmod")
    with pytest.raises(ConfigError):
        MehrotraQP(max_correctors=3)   # a Gondzio option, not Mehrotra's


# ============================================================================= warm start
@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
def test_warm_start_needs_fewer_iterations_on_a_perturbed_qp(cls):
    qp = random_qp(1, fixed=True)
    rng = np.random.default_rng(9)
    qp2 = replace(qp, q=qp.q + 0.01 * rng.standard_normal(qp.q.shape), r=qp.r + 0.01 * rng.standard_normal(qp.r.shape))
    solver = cls(tol=1e-10)
    first = solver.solve(qp)
    cold, warm = solver.solve(qp2), solver.solve(qp2, warm_start=first)
    assert cold.success and warm.success
    assert warm.iterations < cold.iterations
    assert np.allclose(warm.X, cold.X, atol=1e-6) and warm.objective == pytest.approx(cold.objective, rel=1e-9)


# ============================================================================= statuses
def _infeasible_qps():
    qp = random_qp(1)
    N, n, m = qp.N, qp.n, qp.m
    xl = np.full((N + 1, n), -np.inf); xl[N, 0] = 100.0
    C = np.zeros((N, 2, n + m)); C[:, 0, n] = 1.0; C[:, 1, n] = -1.0
    return {
        # the final row asks C_N x_N >= 50 of a boxed x_N
        "final-row": replace(qp, CN=np.eye(n)[:1], cN_lower=[50.0], cN_upper=[np.inf],
                             x_upper=np.where(np.isfinite(qp.x_upper), qp.x_upper, 1.0)),
        # x_N >= 100 is out of reach of |u| <= 0.1
        "dynamics": StageQP(Q=qp.Q, R=qp.R, q=qp.q, r=qp.r, A=qp.A, B=qp.B, c=qp.c, x0=qp.x0, x_lower=xl,
                            u_lower=-0.1 * np.ones((N, m)), u_upper=0.1 * np.ones((N, m))),
        # u_0 >= 1 and -u_0 >= 1
        "rows": StageQP(Q=qp.Q, R=qp.R, q=qp.q, r=qp.r, A=qp.A, B=qp.B, c=qp.c, x0=qp.x0, C=C, c_lower=np.ones((N, 2))),
    }


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
@pytest.mark.parametrize("name", ["final-row", "dynamics", "rows"])
def test_infeasible_qps_are_detected(cls, name):
    res = cls().solve(_infeasible_qps()[name])
    assert res.status is Status.INFEASIBLE, res.message
    assert "certificate" in res.message


def _unbounded_qps():
    qp = random_qp(2, nc=0, ncN=0)
    R = qp.R.copy(); R[:, 1, :] = 0.0; R[:, :, 1] = 0.0
    S = qp.S.copy(); S[:, :, 1] = 0.0
    B = qp.B.copy(); B[:, :, 1] = 0.0
    ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
    ul[:, 1], uu[:, 1] = -np.inf, np.inf
    N = 5
    return {
        # u_1 is free, has no curvature and no influence on the dynamics, and a linear cost
        "free-control": replace(qp, R=R, S=S, B=B, u_lower=ul, u_upper=uu),
        # x_{k+1} = x_k + u_k with u_k >= 0 and the cost -x_N
        "dynamics": StageQP(Q=np.zeros((N + 1, 1, 1)), R=np.zeros((N, 1, 1)), q=np.vstack([np.zeros((N, 1)), [[-1.0]]]),
                            r=np.zeros((N, 1)), A=np.ones((N, 1, 1)), B=np.ones((N, 1, 1)), c=np.zeros((N, 1)),
                            x0=np.zeros(1), u_lower=np.zeros((N, 1))),
    }


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
@pytest.mark.parametrize("name", ["free-control", "dynamics"])
def test_unbounded_qps_are_detected(cls, name):
    res = cls().solve(_unbounded_qps()[name])
    assert res.status is Status.UNBOUNDED, res.message
    assert "Certificate" in res.message


def test_max_iterations():
    res = MehrotraQP(max_iter=2).solve(random_qp(0))
    assert res.status is Status.MAX_ITERATIONS and res.iterations == 2
    assert np.all(np.isfinite(res.X))


def test_failed_factorization_is_a_numerical_error_naming_the_stage():
    """Strongly nonconvex in the free u_2: the cold start grows its weight until it factorizes
    (test below), the iterations' Newton matrices need more than max_regularization allows."""
    qp = random_qp(0, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -1e3 * np.eye(qp.m)
    ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
    ul[2], uu[2] = -np.inf, np.inf
    res = MehrotraQP(max_regularization=0.1).solve(replace(qp, R=R, u_lower=ul, u_upper=uu))
    assert res.status is Status.NUMERICAL_ERROR
    assert "stage k=2" in res.message


# ============================================================================= Zambezi
@pytest.fixture(scope="module")
def zambezi():
    qp = zambezi_qp()
    return qp, clarabel_solution(qp)


# Franke's method takes one step length (its definition and default); with separate ones its last
# iterate at tol = 1e-10 has complementarity 3e-11 and, along Zambezi's flat directions, a control
# 1e-5 from Clarabel's: that combination is not a method olado offers, so it is not tested
_METHOD_STEP_RULES = [(cls, rule) for cls in METHODS for rule in ("primal-dual", "common")
                      if not (cls is FrankeQP and rule == "primal-dual")]


@pytest.mark.parametrize("cls, step_rule", _METHOD_STEP_RULES, ids=lambda v: getattr(v, "name", v))
def test_zambezi_qp_agrees_with_clarabel(cls, step_rule, zambezi):
    qp, (Xr, Ur, Jr) = zambezi
    assert (qp.N, qp.n, qp.m) == (120, 6, 7)
    res = cls(tol=1e-10, step_rule=step_rule).solve(qp)
    assert res.status is Status.SUCCESS, res.message
    assert res.objective == pytest.approx(Jr, rel=1e-9)
    # volumes are O(10..100): compare relative to the size of the trajectory
    assert np.max(np.abs(res.X - Xr)) <= 1e-6 * (1 + np.max(np.abs(Xr)))
    assert np.max(np.abs(res.U - Ur)) <= 1e-6 * (1 + np.max(np.abs(Ur)))
    assert_kkt_small(res, 1e-8)
    assert res.iterations <= 30


def test_zambezi_warm_start(zambezi):
    qp, _ = zambezi
    rng = np.random.default_rng(3)
    scale = np.abs(qp.r).max()
    qp2 = replace(qp, r=qp.r + 0.01 * scale * rng.standard_normal(qp.r.shape))
    solver = WeightedCorrectorQP()
    first = solver.solve(qp)
    cold, warm = solver.solve(qp2), solver.solve(qp2, warm_start=first)
    assert cold.success and warm.success
    assert warm.iterations < cold.iterations


# ============================================================================= compiled kernels
def test_compiled_residuals_match_the_numpy_formulas():
    qp = random_qp(5, fixed=True, eq=True)
    P = _Prepared(qp)
    solver = MehrotraQP()
    it = solver._initial_point(P)
    rng = np.random.default_rng(1)
    it = it.plus(1.0, P.point(rng.standard_normal(it.v.shape)))     # a generic point (slacks != box gaps)
    res, pr, du, scales, obj, znorm, comp = solver._residuals(P, it)
    hx, hu = P.hess_z(it.X, it.U)
    gx, gu = P.constraint_grad(it.lam, it.nu, it.zu - it.zl)
    dyn, x0r, rE, rEN = P.eq_residuals(it.X, it.U)
    w = P.w_of(it.X, it.U)
    ref = dict(rx=hx + P.q + gx, ru=hu + P.r + gu, dyn=dyn, x0r=x0r, rE=rE, rEN=rEN,
               rl=np.where(P.fl, w - P.lo - it.tl, 0.0), rup=np.where(P.fu, P.hi - w - it.tu, 0.0))
    for name, val in ref.items():
        assert np.allclose(getattr(res, name), val, rtol=1e-12, atol=1e-12), name
    assert pr == pytest.approx(max(np.abs(ref[k]).max(initial=0.0) for k in ("dyn", "x0r", "rE", "rEN", "rl", "rup")))
    assert du == pytest.approx(max(np.abs(ref["rx"]).max(), np.abs(ref["ru"]).max()))
    obj_ref = 0.5 * (np.sum(hx * it.X) + np.sum(hu * it.U)) + np.sum(P.q * it.X) + np.sum(P.r * it.U)
    assert obj == pytest.approx(obj_ref, rel=1e-12)   # of the prepared (fixed-control-free) problem
    assert comp == pytest.approx(it.zl @ it.tl + it.zu @ it.tu, rel=1e-12)
    assert scales[1] == pytest.approx(1.0 + max(P.d_data, np.abs(hx).max(), np.abs(hu).max()))
    # the compiled maps of the infeasibility certificates: the constraint gradient alone (z = 0)
    # and, with zero multipliers, H z, the homogeneous equality residuals and the box values
    zero = P.zero_point()
    G, eqs, _ = P.linear_parts(zero.X, zero.U, it.lam, it.nu, it.zl, it.zu)
    assert G == pytest.approx(max(np.abs(gx).max(), np.abs(gu).max()), rel=1e-12)
    assert eqs == 0.0
    hd, eqs, dw = P.linear_parts(it.X, it.U, zero.lam, zero.nu, zero.zl, zero.zu)
    assert hd == pytest.approx(max(np.abs(hx).max(), np.abs(hu).max()), rel=1e-12)
    hom = P.eq_residuals(it.X, it.U, hom=True)
    assert eqs == pytest.approx(max(np.abs(a).max(initial=0.0) for a in hom), rel=1e-12)
    assert np.allclose(dw, w, rtol=1e-12, atol=1e-12)
    assert not zero.v.any()


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
def test_refinement_threshold_keeps_the_iterates(cls):
    # refinement_tol = 0 refines every solve down to 1e-3 tol; the default refines only solves
    # whose Newton residual is large relative to their right-hand side (none here)
    qp = random_qp(3)
    lazy, eager = cls(tol=1e-10).solve(qp), cls(tol=1e-10, refinement_tol=0.0).solve(qp)
    assert lazy.status is eager.status is Status.SUCCESS
    assert lazy.iterations == eager.iterations
    assert sum(h["refinements"] for h in lazy.history) <= sum(h["refinements"] for h in eager.history)
    for h, h0 in zip(lazy.history, eager.history):
        assert h["alpha"] == pytest.approx(h0["alpha"], abs=1e-8)
        assert h["mu"] == pytest.approx(h0["mu"], rel=1e-6, abs=1e-14)
    assert np.allclose(lazy.X, eager.X, atol=1e-10) and np.allclose(lazy.U, eager.U, atol=1e-10)


def test_primal_dual_step_rule_switches_to_common_steps_once_primal_feasible(zambezi):
    """step_rule = "primal-dual": separate step lengths while the primal residual is above its
    tolerance (they differ on the Zambezi QP), one common step length afterwards, so that the dual
    residual is not refilled by (alpha - alpha_dual) H dz and falls to the tolerance."""
    qp, _ = zambezi
    res = MehrotraQP(tol=1e-10, step_rule="primal-dual").solve(qp)
    assert res.status is Status.SUCCESS, res.message
    hist = res.history
    assert any(h["alpha"] != h["alpha_dual"] for h in hist)
    scale = 1.0 + max(np.max(np.abs(qp.c)), np.max(np.abs(np.concatenate([res.X.ravel(), res.U.ravel()]))))
    late = [h for h in hist if h["primal"] <= 1e-10 * scale]
    assert late and all(h["alpha"] == h["alpha_dual"] for h in late)
    assert_kkt_small(res, 1e-8)
    common = MehrotraQP(tol=1e-10, step_rule="common").solve(qp)
    assert all(h["alpha"] == h["alpha_dual"] for h in common.history)
    assert res.objective == pytest.approx(common.objective, rel=1e-10)


@pytest.mark.parametrize("curvature", [5.0, 20.0, 100.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_cold_start_of_a_strongly_nonconvex_boxed_qp(seed, curvature):
    """R_2 = -c I with u_2 boxed in [-1, 1]: the cold start's least-distance system with unit
    weights has no minimizer (Q_uu + I not positive definite at stage 2; before, the QP failed
    there), so its weight grows (1e-2, 1, 1e2 times 1 + max|H|): the starting point exists and
    satisfies the dynamics and x0, with strictly positive slacks and multipliers."""
    qp = random_qp(seed, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -curvature * np.eye(qp.m)
    ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
    ul[2], uu[2] = -1.0, 1.0
    bad = replace(qp, R=R, u_lower=ul, u_upper=uu)
    it = MehrotraQP()._initial_point(_Prepared(bad))
    X, U = it.X, it.U
    assert np.allclose(X[0], bad.x0, atol=1e-10)
    dyn = X[1:] - (np.einsum("kij,kj->ki", bad.A, X[:-1]) + np.einsum("kij,kj->ki", bad.B, U) + bad.c)
    assert np.max(np.abs(dyn)) <= 1e-9 * (1 + np.max(np.abs(X)))
    assert np.all(it.tl >= 0) and np.all(it.tu >= 0) and np.all(it.zl >= 0) and np.all(it.zu >= 0)
    assert np.any(it.zl > 0)
    res = MehrotraQP(tol=1e-10).solve(bad)
    assert "starting point" not in res.message
    if res.status is Status.SUCCESS:
        assert_kkt_small(res, 1e-8)


def test_failed_factorization_reports_the_regularization_tried():
    """QPResult.regularization: the delta at which the factorization last failed, so that a caller
    with a nonconvex Hessian (the SQP's inertia correction) knows the shift it must at least add.
    R_2 = -3 I with free u_2 (max|H| ~ 3): the start (unit diagonal) factorizes, later iterations
    need delta ~ 1, more than max_regularization = 0.1 relative allows."""
    qp = random_qp(0, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -3.0 * np.eye(qp.m)
    ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
    ul[2], uu[2] = -np.inf, np.inf
    bad = replace(qp, R=R, u_lower=ul, u_upper=uu)
    res = MehrotraQP(max_regularization=0.1).solve(bad)
    assert res.status is Status.NUMERICAL_ERROR
    assert 1e-3 < res.regularization <= 0.1 * 3.0
    assert "with regularization" in res.message
    # shifted by more than that the QP is convex: solved without extra regularization
    ok = MehrotraQP().solve(replace(bad, R=R + 5.0 * np.eye(qp.m)[None]))
    assert ok.status is Status.SUCCESS, ok.message
    assert ok.regularization == pytest.approx(1e-10)


@pytest.mark.parametrize("cls", [MehrotraQP, GondzioQP], ids=lambda c: c.name)
@pytest.mark.parametrize("seed", range(5))
def test_nonconvex_boxed_qp_converges_without_refining_against_the_indefinite_matrix(cls, seed):
    """H indefinite (R_2 = -I, Q_3 - I) but every variable boxed: a KKT point exists and the
    regularize mode reaches it. Its Newton matrices need delta*I far above rounding level, and
    iterative refinement against the unregularized (indefinite) matrix does not converge: it must
    stop after one correction per right-hand side that does not halve the residual, keeping the
    better direction (before, 3 corrections per solve made the steps worse: 12-33 iterations or a
    stall at seeds 0-4 instead of 8-11)."""
    qp = random_qp(seed, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -np.eye(qp.m)
    Q = qp.Q.copy(); Q[3] = Q[3] - np.eye(qp.n)
    res = cls(tol=1e-10).solve(replace(qp, R=R, Q=Q))
    assert res.status is Status.SUCCESS, res.message
    assert res.kkt["stationarity"] <= 1e-9 and res.kkt["complementarity"] <= 1e-9
    regularized = [h for h in res.history if h["regularization"] > 1e-9]
    assert regularized, "the test QP must need more than the base regularization"
    corrections = sum(h["refinements"] for h in regularized)
    assert corrections <= sum(h["solves"] for h in regularized) - corrections   # <= 1 per right-hand side
    assert res.iterations <= 12


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
def test_nonconvex_shift_mode_solves_the_shifted_qp(cls):
    """nonconvex = "shift": the delta a failed factorization needed becomes part of the Hessian;
    the result is the solution of the QP with H + delta I (checked against a solve of that QP
    given explicitly), QPResult.regularization is delta and the message says so."""
    qp = random_qp(0, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -3.0 * np.eye(qp.m)
    ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
    ul[2], uu[2] = -np.inf, np.inf
    bad = replace(qp, R=R, u_lower=ul, u_upper=uu)
    res = cls(nonconvex="shift", tol=1e-10).solve(bad)
    assert res.status is Status.SUCCESS, res.message
    d = res.regularization
    assert 0.1 < d < 100.0
    assert "shifted by" in res.message
    ref = cls(tol=1e-10).solve(replace(bad, Q=bad.Q + d * np.eye(qp.n), R=bad.R + d * np.eye(qp.m)))
    assert ref.status is Status.SUCCESS
    assert np.max(np.abs(res.U - ref.U)) <= 1e-7 * (1 + np.max(np.abs(ref.U)))
    assert res.objective == pytest.approx(ref.objective, rel=1e-9)
    assert res.kkt["stationarity"] <= 1e-8
    # a convex QP is not shifted
    ok = cls(nonconvex="shift").solve(qp)
    assert ok.status is Status.SUCCESS and "shifted" not in ok.message
    assert ok.regularization <= 1e-9


def test_kkt_map_fixed_size_kernel_agrees_with_any_size_kernel():
    """_kkt_map compiled for the block sizes (size tags) and for run-time sizes: same residuals
    and measures (up to rounding), on a QP with stage rows, final rows and equalities."""

    qp = random_qp(3, nc=2, ncN=1)
    P = _Prepared(qp)
    it = MehrotraQP()._initial_point(P)
    out = []
    for sizes in (P.sizes, (P.n, P.m, P.n + P.m)):
        res = _Rhs(P, np.full(P.rhs_layout.size, np.nan))
        _kkt_map(sizes, P.kkt_data, it.arrays, P.offsets, res.arrays, P.work_w, P.stats)
        out.append((res.buf.copy(), P.stats.copy()))
    assert isinstance(P.sizes[0], tuple)   # the fixed-size kernel was the first one
    assert np.all(np.isfinite(out[0][0]))
    np.testing.assert_allclose(out[0][0], out[1][0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("mu0", [1.0, 0.1])
def test_cold_start_is_centred_at_initial_mu(mu0):
    """The cold start has t_i z_i = initial_mu on every finite side, slacks >= 1, and zero slack
    and multiplier on infinite sides; both settings solve the QP to the same objective."""

    qp = random_qp(1, nc=2, ncN=1)
    P = _Prepared(qp)
    solver = MehrotraQP(initial_mu=mu0)
    it = solver._initial_point(P)
    for t, z, f in ((it.tl, it.zl, P.fl), (it.tu, it.zu, P.fu)):
        np.testing.assert_allclose((t * z)[f], mu0, rtol=1e-14)
        assert np.all(t[f] >= 1.0) and np.all(t[~f] == 0.0) and np.all(z[~f] == 0.0)
    assert solver.solve(qp).objective == pytest.approx(MehrotraQP().solve(qp).objective, rel=1e-8)


@pytest.mark.parametrize("split", [False, True])
def test_implied_newton_residual_matches_the_measured_one(split):
    """The Newton residual of the linear rows implied by the residuals before and after a step
    (what lets iterations skip the explicit kkt_map measurement) equals the one measured directly
    (_StepContext._newton_residual), for a common and for separate primal/dual step lengths."""

    qp = random_qp(5, nc=2, ncN=1)
    solver = MehrotraQP()
    P = _Prepared(qp)
    it = solver._initial_point(P)
    res, *_ = solver._residuals(P, it)
    ctx = _StepContext(solver, P, it, res, 1.0)
    rho_l, rho_u = -it.zl * it.tl, -it.zu * it.tu
    d = ctx._reduced_solve(res, rho_l, rho_u)
    d.X[...] += 1e-3 * np.sin(np.arange(d.X.size)).reshape(d.X.shape)   # a deliberately inexact direction
    d.lam[...] += 1e-3
    e, *_ = ctx._newton_residual(d, res, rho_l, rho_u)
    e_buf = e.buf.copy()
    ap, ad = (0.7, 0.4) if split else (0.6, 0.6)
    new = it.plus_split(ap, ad, d)
    res_new, *_ = solver._residuals(P, new)
    n_dual = (P.N + 1) * P.n + P.N * P.m
    implied = _implied_newton_residual(res_new.buf, res.buf, ap, ad, n_dual)
    direct = np.max(np.abs(e_buf[n_dual:])) if split else np.max(np.abs(e_buf))
    assert direct > 1e-4
    assert implied == pytest.approx(direct, rel=1e-8)


@pytest.mark.parametrize("cls", METHODS, ids=lambda c: c.name)
@pytest.mark.parametrize("seed,fixed", [(0, False), (3, True), (5, False)])
def test_acceptable_result_is_polished_on_its_active_set(cls, seed, fixed):
    """A solve stopped three iterations early (max_iter) ends ACCEPTABLE at its best iterate;
    polishing (the equality-constrained QP on the bounds active there) turns it into the exact
    solution: the same point as a solve to tol 1e-12, complementarity at rounding level, every
    multiplier of the right sign. With polish = False the result stays ACCEPTABLE."""
    qp = random_qp(seed, fixed=fixed)
    ref = cls(tol=1e-12).solve(qp)
    assert ref.status is Status.SUCCESS
    k = ref.iterations - 3
    plain = cls(tol=1e-10, max_iter=k, acceptable_tol=1e-2, polish=False).solve(qp)
    assert plain.status is Status.ACCEPTABLE
    res = cls(tol=1e-10, max_iter=k, acceptable_tol=1e-2).solve(qp)
    assert res.status is Status.SUCCESS and "Polished" in res.message, res.message
    assert np.abs(res.X - ref.X).max() <= 1e-9 and np.abs(res.U - ref.U).max() <= 1e-9
    assert res.objective == pytest.approx(ref.objective, rel=1e-10)
    assert res.kkt["stationarity"] <= 1e-9 and res.kkt["primal"] <= 1e-12
    assert res.kkt["complementarity"] <= 1e-14 and res.kkt["dual_sign"] == 0.0
    assert res.iterations > plain.iterations          # the polishing Newton steps are counted
    assert max(np.abs(plain.X - ref.X).max(), np.abs(plain.U - ref.U).max()) > 1e-9   # it did improve


def _prepared_with_direction(seed=5):
    """A prepared random QP (some infinite sides), its cold start and a Newton direction."""
    qp = random_qp(seed, nc=2, ncN=1)
    solver = MehrotraQP()
    P = _Prepared(qp)
    it = solver._initial_point(P)
    res, *_ = solver._residuals(P, it)
    ctx = _StepContext(solver, P, it, res, 1.0)
    d = ctx._reduced_solve(res, -it.zl * it.tl, -it.zu * it.tu)
    return P, it, d


def test_right_hand_side_kernels_return_the_max_norm_of_what_they_write():
    """The predictor, corrector and combined right-hand sides: the numpy formulas (-t z, target -
    scale dt dz, their sum; 0 on infinite sides) and max |rho_l, rho_u| as their return value
    (which the solve's refinement test reads instead of a pass of its own)."""
    from olado.qp.interior_point.kernels import _combined_rhs, _corrector_rhs, _predictor_rhs

    P, it, d = _prepared_with_direction()
    assert (~P.fl).any() and (~P.fu).any()
    rl, ru = np.full(P.nw, np.nan), np.full(P.nw, np.nan)
    big = _predictor_rhs(it.slacks, rl, ru)
    np.testing.assert_array_equal(rl, -it.zl * it.tl)
    np.testing.assert_array_equal(ru, -it.zu * it.tu)
    assert big == max(np.abs(rl).max(), np.abs(ru).max())
    for kernel, base in ((_corrector_rhs, 0.0), (_combined_rhs, 1.0)):
        args = (P.fl, P.fu, d.slacks, 0.3, 0.7, rl, ru) if kernel is _corrector_rhs else \
            (it.slacks, P.fl, P.fu, d.slacks, 0.3, 0.7, rl, ru)
        big = kernel(*args)
        want_l = np.where(P.fl, 0.3 - base * it.tl * it.zl - 0.7 * (d.tl * d.zl), 0.0)
        want_u = np.where(P.fu, 0.3 - base * it.tu * it.zu - 0.7 * (d.tu * d.zu), 0.0)
        np.testing.assert_allclose(rl, want_l, rtol=1e-15, atol=0.0)
        np.testing.assert_allclose(ru, want_u, rtol=1e-15, atol=0.0)
        assert big == max(np.abs(rl).max(), np.abs(ru).max())


def test_scaling_writes_the_diagonal_terms_of_the_base_regularization():
    """_scaling: 1/t on the finite sides, D = zl/tl + zu/tu, and Dx = (reg; D_x + reg),
    Du = D_u + reg -- what the factorization's numpy adds wrote before (same values)."""
    from olado.qp.interior_point.kernels import _scaling

    P, it, _ = _prepared_with_direction()
    inv_l, inv_u, D = np.empty(P.nw), np.empty(P.nw), np.empty(P.nw)
    Dx, Du = np.full((P.N + 1, P.n), np.nan), np.full((P.N, P.m), np.nan)
    reg = 1e-7
    _scaling(it.slacks, P.fl, P.fu, inv_l, inv_u, D, reg, Dx, Du)
    with np.errstate(divide="ignore"):
        np.testing.assert_array_equal(inv_l, np.where(P.fl, 1.0 / it.tl, 0.0))
        np.testing.assert_array_equal(inv_u, np.where(P.fu, 1.0 / it.tu, 0.0))
    np.testing.assert_array_equal(D, it.zl * inv_l + it.zu * inv_u)
    np.testing.assert_array_equal(Dx[0], reg)
    np.testing.assert_array_equal(Dx[1:], D[P.sl_x].reshape(P.N, P.n) + reg)
    np.testing.assert_array_equal(Du, D[P.sl_u].reshape(P.N, P.m) + reg)


@pytest.mark.parametrize("split", [False, True])
def test_step_into_writes_the_step_and_finds_non_finite_entries(split):
    """Point.step_into: the values of plus / plus_split in a reused point, and the finiteness
    of the new point from the same pass."""
    P, it, d = _prepared_with_direction()
    ap, ad = (0.7, 0.4) if split else (0.6, 0.6)
    want = it.plus_split(ap, ad, d) if split else it.plus(ap, d)
    out = P.iterate_buffer(it, it)
    out.max_step = 1.0
    got = it.step_into(ap, ad, d, out)
    assert got is out and out.max_step is None
    np.testing.assert_array_equal(got.v, want.v)
    assert got.finite()
    d.v[3] = np.inf
    assert not it.step_into(ap, ad, d, out).finite()


def test_iterate_buffers_are_never_the_current_or_the_best_iterate():
    """Three points in turn -- the starting point and two more --: the one handed out is neither
    argument, always one of the three (no allocation after the first call)."""
    P, it, _ = _prepared_with_direction()
    a = P.iterate_buffer(it, it)
    b = P.iterate_buffer(a, it)
    pool = (it, a, b)
    assert len({id(p) for p in pool}) == 3
    for cur in pool:
        for best in pool:
            got = P.iterate_buffer(cur, best)
            assert got is not cur and got is not best and any(got is p for p in pool)
