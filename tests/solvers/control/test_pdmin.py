"""PDMIN, projected descent for control-bounded DOCPs (paper 001 sec. 2.2): the three directions
reach IPOPT's solution and active set, agree with scipy's L-BFGS-B on the reduced problem, and
report every status."""

from pathlib import Path

import numpy as np
import pytest

import olado
import olado.solvers.control.pdmin  # noqa: F401  (registers "pdmin")
from olado.config import load_config
from olado.result import Status
from olado.solvers.control.control_space import ReducedProblem
from olado.solvers.control.pdmin import DIRECTIONS, PDMINSolver

from fixtures.pdmin_problems import BoundedPendulum, LinearTracking, double_tracking, scalar_tracking
from fixtures.toy_problems import Pendulum
from fixtures import REPO

CONFIGS = REPO / "configs"

PROBLEMS = {
    "lq-stationary": lambda: scalar_tracking(200),
    "lq-nonstationary": lambda: scalar_tracking(200, nonstationary=True),
    "lq-2x2-nonstationary": lambda: double_tracking(300),
    "nonlinear-pendulum": lambda: BoundedPendulum(60),
}


def ipopt_reference(p, tol=1e-12):
    pytest.importorskip("cyipopt")
    # bound_relax_factor 0: IPOPT's solution satisfies the bounds exactly (no 1e-8 relaxation)
    ref = olado.solve(p, solver="ipopt", tol=tol, ipopt_options={"bound_relax_factor": 0.0})
    assert ref.success, ref.message
    return ref


@pytest.fixture(scope="module")
def references():
    out = {}
    for name, make in PROBLEMS.items():
        p = make()
        out[name] = (p, ipopt_reference(p))
    return out


def at_bounds(p, U):
    return (U == p.u_lower) | (U == p.u_upper)


def test_the_test_problems_have_bounds_the_unconstrained_solution_violates():
    for name, make in PROBLEMS.items():
        p = make()
        p.u_bounds = (None, None)
        free = PDMINSolver(tol=1e-8).solve(p)
        assert free.success
        q = make()
        assert np.any((free.u < q.u_lower - 0.1) | (free.u > q.u_upper + 0.1)), name


@pytest.mark.parametrize("direction", DIRECTIONS)
@pytest.mark.parametrize("name", list(PROBLEMS))
def test_every_direction_reaches_the_ipopt_solution_and_active_set(references, name, direction):
    p, ref = references[name]
    r = olado.solve(p, solver="pdmin", direction=direction, tol=1e-10, max_iter=20000)
    assert r.status == Status.SUCCESS, r.message
    assert r.solver == "pdmin" and r.N == p.N
    assert r.objective == pytest.approx(ref.objective, rel=1e-11, abs=1e-11)
    assert np.allclose(r.u, ref.u, atol=1e-6) and np.allclose(r.x, ref.x, atol=1e-6)
    assert r.max_constraint_violation == 0.0
    assert np.all(r.u >= p.u_lower) and np.all(r.u <= p.u_upper)
    # the active set exactly: PDMIN's controls sit on the bounds where IPOPT's bound multipliers
    # are positive, and nowhere else
    z_ref = np.maximum(ref.multipliers["bound_lower_u"], ref.multipliers["bound_upper_u"])
    active = at_bounds(p, r.u)
    assert active.any() and not active.all()
    assert np.array_equal(active, z_ref > 1e-6)
    # bound multipliers from the gradient, dynamics multipliers = costates (IPOPT's convention)
    for key in ("bound_lower_u", "bound_upper_u", "dynamics"):
        assert np.allclose(r.multipliers[key], ref.multipliers[key], atol=1e-7), key
    assert np.all(r.multipliers["bound_lower_u"] >= 0) and np.all(r.multipliers["bound_upper_u"] >= 0)
    assert r.kkt_residual < 1e-9
    assert r.info["n_active"] == int(active.sum())


@pytest.mark.parametrize("direction", DIRECTIONS)
@pytest.mark.parametrize("name, N", [("lq-box", 20), ("vanderpol-box", 100), ("rayleigh-box", 100)])
def test_builtin_bound_constrained_problems(name, N, direction):
    """olado.problems.testproblems: lq-box only at a short horizon -- its open-loop eigenvalue 1.1
    makes the reduced Hessian's condition grow like 1.1^(2N), which no control-space (single
    shooting) method survives at N = 100."""
    from olado.problems.testproblems import PROBLEMS as BUILTIN

    p = BUILTIN[name](N=N)
    ref = ipopt_reference(p)
    r = PDMINSolver(direction=direction, tol=1e-9, max_iter=5000).solve(p)
    assert r.status == Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-11)
    assert np.allclose(r.u, ref.u, atol=1e-6)
    z_ref = np.maximum(ref.multipliers["bound_lower_u"], ref.multipliers["bound_upper_u"])
    active = at_bounds(p, r.u)
    assert active.any() and np.array_equal(active, z_ref > 1e-6)


def test_nonstationary_bounds_are_respected_per_stage(references):
    p, _ = references["lq-nonstationary"]
    r = PDMINSolver(tol=1e-9).solve(p)
    lower_active = r.u == p.u_lower
    upper_active = r.u == p.u_upper
    assert lower_active.any() and upper_active.any()
    # the bounds differ from stage to stage along the active arcs
    assert np.ptp(r.u[upper_active]) > 0.1 and np.ptp(r.u[lower_active]) > 0.1


@pytest.mark.parametrize("direction", DIRECTIONS)
def test_agrees_with_scipy_lbfgsb_on_the_reduced_problem(direction):
    from scipy.optimize import minimize

    p = double_tracking(300)
    rp = ReducedProblem(p)

    def fun(u):
        J, g, _, _ = rp.gradient(u.reshape(p.N, p.m))
        return J, g.ravel()

    bounds = np.column_stack([p.u_lower.ravel(), p.u_upper.ravel()])
    bounds[~np.isfinite(bounds)] = np.nan
    ref = minimize(fun, p.initial_guess().ravel(), jac=True, method="L-BFGS-B",
                   bounds=[tuple(None if np.isnan(v) else v for v in b) for b in bounds],
                   options={"ftol": 1e-15, "gtol": 1e-10, "maxiter": 20000, "maxfun": 40000})
    r = PDMINSolver(direction=direction, tol=1e-10, max_iter=20000).solve(p)
    assert r.success
    assert r.objective <= ref.fun + 1e-10 * abs(ref.fun)
    assert r.objective == pytest.approx(ref.fun, rel=1e-10)
    assert np.allclose(r.u.ravel(), ref.x, atol=1e-5)
    lo, hi = p.u_lower.ravel(), p.u_upper.ravel()
    assert np.array_equal(at_bounds(p, r.u).ravel(), (ref.x <= lo + 1e-9) | (ref.x >= hi - 1e-9))


def test_history_and_counts():
    p = BoundedPendulum(60)
    seen = []
    r = PDMINSolver(direction="lbfgs", tol=1e-8, callback=lambda info: seen.append(info["iter"])).solve(p)
    assert r.success
    h = r.history
    assert len(h) == r.iterations + 1 and [e["iter"] for e in h] == list(range(r.iterations + 1))
    for key in ("objective", "pg_norm", "n_active", "n_at_bound", "step", "line_search", "time_s"):
        assert key in h[0]
    J = [e["objective"] for e in h]
    assert all(b <= a for a, b in zip(J, J[1:]))          # Armijo: monotone
    assert h[-1]["pg_norm"] <= 1e-8 < h[0]["pg_norm"]
    assert all(e["step"] > 0 for e in h[1:])
    assert seen == list(range(r.iterations))              # called before each step
    assert r.iterations + 1 <= r.evaluations["gradient"] <= r.iterations + 1 + sum(e["line_search"] for e in h)
    assert r.evaluations["objective"] >= r.evaluations["gradient"]
    assert 0 < r.info["callback_share"] <= 1


def test_guess_outside_the_bounds_is_projected():
    p = scalar_tracking(100)
    r = PDMINSolver(tol=1e-9).solve(p, guess=np.full((100, 1), 50.0))
    assert r.success
    assert np.allclose(r.u, PDMINSolver(tol=1e-9).solve(p).u, atol=1e-7)


@pytest.mark.parametrize("preset, direction", [("pdmin-sd.ini", "steepest-descent"),
                                               ("pdmin-pr.ini", "polak-ribiere"),
                                               ("pdmin-lbfgs.ini", "lbfgs")])
def test_ini_presets(preset, direction):
    cfg = load_config(CONFIGS / preset)
    assert cfg.solver == "pdmin" and cfg.options.direction == direction
    p = scalar_tracking(100, nonstationary=True)
    r = olado.solve(p, config=CONFIGS / preset)
    assert r.success and r.options["direction"] == direction
    assert r.history[-1]["pg_norm"] <= cfg.options.tol


# ---------------------------------------------------------------------------------- statuses
def test_status_max_iterations():
    r = PDMINSolver(max_iter=3, direction="steepest-descent").solve(double_tracking(300))
    assert r.status == Status.MAX_ITERATIONS and r.iterations == 3 and not r.success
    assert "maximum number" in r.message


def test_status_max_time():
    r = PDMINSolver(max_time=1e-9).solve(double_tracking(300))
    assert r.status == Status.MAX_TIME and r.iterations <= 1


def test_status_user_stop():
    r = PDMINSolver(callback=lambda info: info["iter"] == 2).solve(BoundedPendulum(60))
    assert r.status == Status.USER_STOP and r.iterations == 2


def test_status_invalid_problem_for_general_constraints_and_state_bounds():
    r = olado.solve(Pendulum(N=8), solver="pdmin")
    assert r.status == Status.INVALID_PROBLEM
    assert "stage constraint" in r.message and "final constraint" in r.message
    assert "penalty" in r.message and "sqp" in r.message
    from olado.problems.testproblems import PROBLEMS as BUILTIN

    r = olado.solve(BUILTIN["vanderpol-path"](N=20), solver="pdmin")
    assert r.status == Status.INVALID_PROBLEM and "bounds on the states" in r.message
    p = scalar_tracking(50)
    p.x_bounds = (-1.0, 1.0)
    r = olado.solve(p, solver="pdmin")
    assert r.status == Status.INVALID_PROBLEM and "bounds on the states" in r.message


def test_status_numerical_error_when_the_gradient_is_wrong():
    class WrongGradient(LinearTracking):
        def stage_cost_gradient(self, k, x, u):
            gx, gu = super().stage_cost_gradient(k, x, u)
            return -gx, -gu - 1.0

    base = scalar_tracking(50)
    p = WrongGradient(50, base.A, base.B, base.Q, base.R, base.QN, base.ref, base.x0, (-1.5, 1.5))
    r = PDMINSolver(tol=1e-10).solve(p)
    assert r.status == Status.NUMERICAL_ERROR and "line search failed" in r.message


def test_unconstrained_problem_is_solved_too():
    p = scalar_tracking(100)
    p.u_bounds = (None, None)
    r = PDMINSolver(tol=1e-10).solve(p)
    assert r.success and r.info["n_active"] == 0
    assert np.max(np.abs(ReducedProblem(p).gradient(r.u)[1])) <= 1e-10


# ---------------------------------------------------------------------------------- large N
@pytest.mark.slow
def test_large_horizon_reaches_the_ipopt_solution():
    N = 100_000
    p = scalar_tracking(N, nonstationary=True)
    ref = ipopt_reference(p, tol=1e-10)
    for direction in DIRECTIONS:
        r = PDMINSolver(direction=direction, tol=1e-8).solve(p)
        assert r.success, (direction, r.message)
        assert r.objective == pytest.approx(ref.objective, rel=1e-10)
        assert r.objective <= ref.objective + 1e-9 * abs(ref.objective)
        assert np.allclose(r.u, ref.u, atol=1e-4)
        z_ref = np.maximum(ref.multipliers["bound_lower_u"], ref.multipliers["bound_upper_u"])
        active = at_bounds(p, r.u)
        strong = z_ref > 1e-4
        assert np.all(active[strong])                     # every strongly active bound found
        assert active.sum() == pytest.approx(strong.sum(), rel=1e-3)


def test_one_instance_solves_from_its_own_callback_and_keeps_no_solve_state():
    """The solver holds only options: a solve started from the callback of another (same
    instance) gives the results of separate instances, and a rejected problem reports no
    evaluation time of an earlier solve."""
    nested = {}

    def callback(info):
        if not nested:
            nested["r"] = None
            nested["r"] = solver.solve(scalar_tracking(50))
        return False

    solver = PDMINSolver(callback=callback)
    outer = solver.solve(BoundedPendulum(60))
    for r, ref in ((outer, PDMINSolver().solve(BoundedPendulum(60))), (nested["r"], PDMINSolver().solve(scalar_tracking(50)))):
        assert r.success and r.iterations == ref.iterations > 1
        assert r.objective == ref.objective and np.array_equal(r.u, ref.u)
    rejected = solver.solve(Pendulum(N=6))          # stage and final constraints: not PDMIN's
    assert rejected.status == Status.INVALID_PROBLEM
    assert rejected.info["callback_time_s"] == 0.0
