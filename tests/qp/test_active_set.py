"""The active-set QP (olado.qp.active_set): Goldfarb and Idnani's dual method on Riccati EQPs,
against Clarabel (solution, objective) and olado's Mehrotra method at a tight tolerance
(multipliers), with its statuses, warm start and initialization."""

import numpy as np
import pytest

from fixtures.qp_problems import assert_multipliers_match, clarabel_solution, random_qp, replace, zambezi_qp
from olado.errors import ConfigError
from olado.linalg import RiccatiFactorization
from olado.qp import OLADO_METHODS, QP_METHODS, make_qp_solver
from olado.qp.active_set import GoldfarbIdnaniQP
from olado.qp.interior_point import MehrotraQP
from olado.qp.stageqp import BOX_FIELDS, StageQP, qp_kkt_residuals
from olado.result import Status

CASES = [dict(seed=0), dict(seed=3), dict(seed=4, N=10, n=4, m=3), dict(seed=1, fixed=True), dict(seed=2, eq=True),
         dict(seed=5, fixed=True, eq=True), dict(seed=7, N=15, n=3, m=2)]
MULTIPLIERS = ("lam", "nu", "zx_lower", "zx_upper", "zu_lower", "zu_upper", "yc_lower", "yc_upper", "yN_lower", "yN_upper")


def kkt_small(res, tol=1e-9):
    k = res.kkt
    return k["stationarity"] <= tol and k["primal"] <= tol and k["complementarity"] <= tol and k["dual_sign"] == 0.0


# ============================================================================= agreement
@pytest.mark.parametrize("init", ["none", "bertsekas"])
@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(f"{k}{v}" for k, v in c.items()))
def test_random_qps_agree_with_clarabel_and_mehrotra(case, init):
    qp = random_qp(**case)
    Xr, Ur, Jr = clarabel_solution(qp)
    res = GoldfarbIdnaniQP(init=init).solve(qp)
    assert res.status is Status.SUCCESS, res.message
    assert res.objective == pytest.approx(Jr, rel=1e-9, abs=1e-9)
    assert np.max(np.abs(res.X - Xr)) < 1e-6 and np.max(np.abs(res.U - Ur)) < 1e-6
    assert res.kkt == qp_kkt_residuals(qp, res)
    assert kkt_small(res, 1e-10), res.kkt
    # the multipliers, in the QPResult convention, are those of the interior-point method
    ref = MehrotraQP(tol=1e-12).solve(qp)
    assert ref.success
    assert_multipliers_match(res, ref, MULTIPLIERS)
    assert res.solver == "active-set" and res.iterations == len(res.history) and res.time_s > 0


def test_active_set_marks_exactly_the_sides_held_at_their_bounds():
    qp = random_qp(4, N=10, n=4, m=3)
    res = GoldfarbIdnaniQP().solve(qp)
    vals = {"x": res.X, "u": res.U, "c": np.einsum("kij,kj->ki", qp.C, np.concatenate([res.X[:-1], res.U], axis=1)),
            "cN": qp.CN @ res.X[-1]}
    n_active = 0
    for kind, lo_name, hi_name, zl_name, zu_name in BOX_FIELDS:
        lo_act, hi_act = res.active_set[kind]
        lo, hi = getattr(qp, lo_name), getattr(qp, hi_name)
        assert np.allclose(vals[kind][lo_act], lo[lo_act], atol=1e-10)
        assert np.allclose(vals[kind][hi_act], hi[hi_act], atol=1e-10)
        # multipliers only on active sides
        assert np.all(getattr(res, zl_name)[~lo_act] == 0.0) and np.all(getattr(res, zu_name)[~hi_act] == 0.0)
        n_active += int(lo_act.sum() + hi_act.sum())
    assert n_active == res.history[-1]["active"] > 0


def test_horizon_one_and_equality_only_qp():
    qp = random_qp(11, N=1, n=2, m=2)
    Xr, Ur, Jr = clarabel_solution(qp)
    res = GoldfarbIdnaniQP().solve(qp)
    assert res.status is Status.SUCCESS and np.allclose(res.X, Xr, atol=1e-6) and res.objective == pytest.approx(Jr)
    # without inequalities the EQP of the equalities is the solution: no working-set change
    qp = random_qp(2, nc=0, ncN=0, eq=True)
    qp = replace(qp, x_lower=None, x_upper=None, u_lower=None, u_upper=None)
    ref = RiccatiFactorization(qp.Q, qp.S, qp.R, qp.A, qp.B, E=qp.E, F=qp.F).solve(qp.q, qp.r, qp.c, qp.x0, e=qp.e)
    res = GoldfarbIdnaniQP().solve(qp)
    assert res.status is Status.SUCCESS and res.iterations == 0
    assert np.allclose(res.X, ref.X, atol=1e-12) and np.allclose(res.lam, ref.lam, atol=1e-10)
    assert np.allclose(res.nu[:-1], ref.nu[:-1], atol=1e-10)


def test_fixed_entries_are_held_with_one_sided_multipliers():
    qp = random_qp(1, fixed=True)
    N = qp.N
    res = GoldfarbIdnaniQP().solve(qp)
    assert res.status is Status.SUCCESS
    assert res.U[1, 1] == pytest.approx(qp.u_lower[1, 1], abs=1e-12)
    assert res.X[2, 0] == pytest.approx(qp.x_lower[2, 0], abs=1e-12)
    assert res.X[N, 1] == pytest.approx(qp.x_lower[N, 1], abs=1e-12)
    for lo, hi in ((res.zu_lower[1, 1], res.zu_upper[1, 1]), (res.zx_lower[2, 0], res.zx_upper[2, 0]),
                   (res.zx_lower[N, 1], res.zx_upper[N, 1]), (res.yc_lower[3, 1], res.yc_upper[3, 1])):
        assert lo >= 0 and hi >= 0 and lo * hi == 0


# ============================================================================= degenerate
def _degenerate_qp():
    """x_{k+1} = x_k + u_k, x_0 = 0, 1 <= u_k <= 2 with a cost pushing u down, and x_1 >= 1: at the
    solution u_0 = 1 and x_1 = 1 are both active and linearly dependent (with x_0 = 0), and
    x_2 >= 2 is active and dependent as well; the multipliers are not unique."""
    N = 4
    one = np.ones((N, 1, 1))
    xl = np.full((N + 1, 1), -np.inf)
    xl[1], xl[2] = 1.0, 2.0
    return StageQP(Q=np.full((N + 1, 1, 1), 0.1), R=one.copy(), q=np.zeros((N + 1, 1)), r=np.full((N, 1), 5.0), A=one,
                   B=one, c=np.zeros((N, 1)), x0=np.zeros(1), x_lower=xl, u_lower=np.ones((N, 1)),
                   u_upper=np.full((N, 1), 2.0))


@pytest.mark.parametrize("init", ["none", "bertsekas"])
def test_degenerate_dependent_active_constraints(init):
    qp = _degenerate_qp()
    res = GoldfarbIdnaniQP(init=init).solve(qp)
    assert res.status is Status.SUCCESS, res.message
    assert np.allclose(res.U[:, 0], 1.0) and np.allclose(res.X[:, 0], np.arange(5.0))
    Xr, Ur, Jr = clarabel_solution(qp)
    assert res.objective == pytest.approx(Jr, rel=1e-10)
    assert kkt_small(res, 1e-10), res.kkt
    # the working set holds 4 independent sides (4 controls' worth of freedom): never u_0 and
    # x_1 together (x_1 = x_0 + u_0), nor x_1, u_1 and x_2
    u, x = res.active_set["u"][0][:, 0], res.active_set["x"][0][:, 0]
    assert u.sum() + x.sum() == 4 and not res.active_set["u"][1].any() and not res.active_set["x"][1].any()
    assert not (u[0] and x[1]) and not (x[1] and u[1] and x[2]) and not (u[0] and u[1] and x[2])


def test_tie_in_the_ratio_test_and_zero_multipliers():
    # two identical stage rows (one of them a copy): adding the second is the dependent case
    qp = random_qp(3, nc=2)
    C = qp.C.copy(); C[:, 1] = C[:, 0]
    lo, hi = qp.c_lower.copy(), qp.c_upper.copy()
    lo[:, 1], hi[:, 1] = 0.2, np.inf
    lo[:, 0], hi[:, 0] = 0.2, np.inf
    qp = replace(qp, C=C, c_lower=lo, c_upper=hi)
    res = GoldfarbIdnaniQP().solve(qp)
    assert res.status is Status.SUCCESS, res.message
    Xr, Ur, Jr = clarabel_solution(qp)
    assert res.objective == pytest.approx(Jr, rel=1e-8, abs=1e-10)
    assert kkt_small(res, 1e-9), res.kkt
    assert not np.any(res.active_set["c"][0][:, 0] & res.active_set["c"][0][:, 1])


# ============================================================================= warm start
def test_warm_start_from_the_solution_takes_no_working_set_change():
    for qp in (random_qp(4, N=10, n=4, m=3), zambezi_qp(N=48)):
        solver = GoldfarbIdnaniQP()
        first = solver.solve(qp)
        assert first.success and first.iterations > 0
        again = solver.solve(qp, warm_start=first)
        assert again.status is Status.SUCCESS and again.iterations == 0
        assert np.allclose(again.X, first.X, atol=1e-10) and again.objective == pytest.approx(first.objective, rel=1e-12)
        # from a result of another method (no active_set): its multipliers and slacks give the set
        ip = MehrotraQP(tol=1e-11).solve(qp)
        third = solver.solve(qp, warm_start=ip)
        assert third.status is Status.SUCCESS and third.iterations <= 2


def test_warm_start_on_a_perturbed_qp_takes_few_changes():
    qp = zambezi_qp(N=72)
    rng = np.random.default_rng(3)
    qp2 = replace(qp, r=qp.r + 0.01 * np.abs(qp.r).max() * rng.standard_normal(qp.r.shape))
    solver = GoldfarbIdnaniQP()
    first = solver.solve(qp)
    cold, warm = solver.solve(qp2), solver.solve(qp2, warm_start=first)
    assert cold.success and warm.success
    assert warm.iterations < 0.25 * cold.iterations
    assert np.allclose(warm.X, cold.X, atol=1e-8) and warm.objective == pytest.approx(cold.objective, rel=1e-10)


def test_bertsekas_initialization_saves_changes_on_zambezi():
    qp = zambezi_qp(N=48)
    a, b = GoldfarbIdnaniQP(init="none").solve(qp), GoldfarbIdnaniQP(init="bertsekas").solve(qp)
    assert a.success and b.success and a.objective == pytest.approx(b.objective, rel=1e-12)
    assert b.iterations < a.iterations


def test_zambezi_qp_agrees_with_clarabel():
    qp = zambezi_qp()
    Xr, Ur, Jr = clarabel_solution(qp)
    res = GoldfarbIdnaniQP().solve(qp)
    assert res.status is Status.SUCCESS, res.message
    assert res.objective == pytest.approx(Jr, rel=1e-9)
    assert np.max(np.abs(res.X - Xr)) <= 1e-6 * (1 + np.max(np.abs(Xr)))
    assert np.max(np.abs(res.U - Ur)) <= 1e-6 * (1 + np.max(np.abs(Ur)))
    assert kkt_small(res, 1e-9), res.kkt


# ============================================================================= statuses
def _infeasible_qps():
    qp = random_qp(1)
    N, n, m = qp.N, qp.n, qp.m
    xl = np.full((N + 1, n), -np.inf); xl[N, 0] = 100.0
    C = np.zeros((N, 2, n + m)); C[:, 0, n] = 1.0; C[:, 1, n] = -1.0
    return {
        "final-row": replace(qp, CN=np.eye(n)[:1], cN_lower=[50.0], cN_upper=[np.inf],
                             x_upper=np.where(np.isfinite(qp.x_upper), qp.x_upper, 1.0)),
        "dynamics": StageQP(Q=qp.Q, R=qp.R, q=qp.q, r=qp.r, A=qp.A, B=qp.B, c=qp.c, x0=qp.x0, x_lower=xl,
                            u_lower=-0.1 * np.ones((N, m)), u_upper=0.1 * np.ones((N, m))),
        "rows": StageQP(Q=qp.Q, R=qp.R, q=qp.q, r=qp.r, A=qp.A, B=qp.B, c=qp.c, x0=qp.x0, C=C, c_lower=np.ones((N, 2))),
    }


@pytest.mark.parametrize("name", ["final-row", "dynamics", "rows"])
def test_infeasible_qps_are_detected_naming_the_constraint(name):
    res = GoldfarbIdnaniQP().solve(_infeasible_qps()[name])
    assert res.status is Status.INFEASIBLE, res.message
    assert "linearly dependent" in res.message and "bound of" in res.message


def test_inconsistent_equalities_x0_and_crossed_bounds_are_infeasible():
    qp = random_qp(2, eq=True)
    E = qp.E.copy(); E[:, :] = 0.0
    F = qp.F.copy(); F[:, :] = 0.0
    e = np.ones_like(qp.e)                      # 0 x + 0 u + 1 = 0
    res = GoldfarbIdnaniQP().solve(replace(qp, E=E, F=F, e=e))
    assert res.status is Status.INFEASIBLE and "inconsistent" in res.message
    xl = qp.x_lower.copy(); xl[0, 0] = qp.x0[0] + 1.0
    res = GoldfarbIdnaniQP().solve(replace(qp, x_lower=xl, x_upper=np.maximum(qp.x_upper, xl)))
    assert res.status is Status.INFEASIBLE and "x0" in res.message
    ul = qp.u_lower.copy(); ul[2, 1] = qp.u_upper[2, 1] + 0.5
    res = GoldfarbIdnaniQP().solve(replace(qp, u_lower=ul))
    assert res.status is Status.INFEASIBLE and "lower bound above upper bound for u" in res.message


def test_max_iterations():
    res = GoldfarbIdnaniQP(max_iter=2, init="none").solve(random_qp(4, N=10, n=4, m=3))
    assert res.status is Status.MAX_ITERATIONS and res.iterations == 2
    assert "still violated" in res.message and np.all(np.isfinite(res.X))


def test_nonconvex_qp_is_a_numerical_error_naming_the_stage():
    qp = random_qp(0, nc=0, ncN=0)
    R = qp.R.copy(); R[2] = -1e3 * np.eye(qp.m)
    ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
    ul[2], uu[2] = -np.inf, np.inf
    res = GoldfarbIdnaniQP().solve(replace(qp, R=R, u_lower=ul, u_upper=uu))
    assert res.status is Status.NUMERICAL_ERROR
    assert "stage k=2" in res.message and "not strictly convex" in res.message
    assert res.regularization == 0.0


# ============================================================================= registry, options
def test_registry_make_qp_solver_and_options():
    assert "active-set" in OLADO_METHODS and "active-set" in QP_METHODS
    s = make_qp_solver("active-set", tol=1e-8, max_iter=30)
    assert isinstance(s, GoldfarbIdnaniQP) and s.options.tol == 1e-8
    assert s.options.max_iter == 3000          # working-set changes: 100 times the QP iteration limit
    with pytest.raises(ConfigError):
        GoldfarbIdnaniQP(init="fletcher")
    with pytest.raises(ConfigError):
        GoldfarbIdnaniQP(max_correctors=2)
