"""Tests of the penalty / augmented Lagrangian method (olado/solvers/penalty.py): the penalized
subproblem's derivatives, agreement with IPOPT on constrained problems (stage inequality + final
equality; state bounds), the far smaller rho of the augmented Lagrangian, inner methods,
statuses and the ini presets."""

from __future__ import annotations

import os

import numpy as np
import pytest

import olado
from olado.config import load_config
from olado.errors import ConfigError
from olado.problems import PROBLEMS, check_derivatives
from olado.result import Status
from olado.solvers.control.penalty import PenalizedProblem, PenaltySolver, solve_lbfgsb

from fixtures.toy_problems import Pendulum, PendulumVectorized
from fixtures import REPO

ROOT = str(REPO)


@pytest.fixture(scope="module")
def pendulum_reference():
    pytest.importorskip("cyipopt")
    p = Pendulum(N=20)
    ref = olado.solve(p, solver="ipopt", tol=1e-11)
    assert ref.success
    return ref


@pytest.fixture(scope="module")
def vdp_path_reference():
    pytest.importorskip("cyipopt")
    p = PROBLEMS["vanderpol-path"](N=20)
    ref = olado.solve(p, solver="ipopt", tol=1e-11)
    assert ref.success
    return ref


# ============================================================================ the subproblem
@pytest.mark.parametrize("cls", [Pendulum, PendulumVectorized])
@pytest.mark.parametrize("keep", [True, False])
def test_penalized_problem_derivatives(cls, keep):
    p = cls(N=8)
    pen = PenalizedProblem(p, 30.0, keep_control_bounds=keep)
    rng = np.random.default_rng(0)
    pen.set_penalty(30.0, {"stage_constraints": np.abs(rng.standard_normal((8, 1))), "final_constraints": [0.4]})
    # a point with violated and satisfied stage inequalities (away from the kinks of max(0, .))
    U = np.linspace(-2.5, 2.5, 8)[:, None]
    rep = check_derivatives(pen, U=U)
    assert rep.ok, str(rep)


def test_penalized_problem_state_bounds_derivatives_and_values():
    p = PROBLEMS["vanderpol-path"](N=12)
    pen = PenalizedProblem(p, 50.0, keep_control_bounds=False)
    pen.set_penalty(50.0, {"bound_lower_x": np.full((13, 2), 0.2)})
    U = np.full((12, 1), -1.5)   # outside -0.3 <= u, drives x1 below -0.4
    X = p.simulate(U)
    assert X[:, 0].min() < -0.4
    rep = check_derivatives(pen, U=U, X=X)
    assert rep.ok, str(rep)
    # pure quadratic penalty values: rho/2 * squared violations
    pen.set_penalty(50.0, {"bound_lower_x": np.zeros((13, 2))})
    extra = pen.objective(X, U) - p.objective(X, U)
    v_x = np.maximum(-0.4 - X[1:, 0], 0.0)
    v_u = np.maximum(-0.3 - U[:, 0], 0.0) + np.maximum(U[:, 0] - 1.0, 0.0)
    assert extra == pytest.approx(25.0 * (v_x @ v_x + v_u @ v_u), rel=1e-12)
    viol, parts = pen.violations(X, U)
    assert viol == pytest.approx(max(v_x.max(), v_u.max()))
    assert parts["state_bounds"] == pytest.approx(v_x.max())


def test_penalized_problem_without_constraints_is_the_problem():
    p = PROBLEMS["vanderpol"](N=10)
    pen = PenalizedProblem(p, 1e3)
    assert not pen.penalizes_anything
    U = p.initial_guess() + 0.1
    X = p.simulate(U)
    assert pen.objective(X, U) == p.objective(X, U)


# ============================================================================ against IPOPT
def test_quadratic_penalty_reaches_ipopt_solution(pendulum_reference):
    ref = pendulum_reference
    p = Pendulum(N=20)
    res = PenaltySolver(constr_viol_tol=1e-7).solve(p)
    assert res.status is Status.SUCCESS, res.message
    assert res.max_constraint_violation <= 1e-7
    assert res.objective == pytest.approx(ref.objective, abs=1e-6)
    np.testing.assert_allclose(res.u, ref.u, atol=1e-4)
    # multiplier estimates rho * violation (IPOPT's sign convention)
    assert res.multipliers["final_constraints"] == pytest.approx(ref.multipliers["final_constraints"], abs=1e-4)
    np.testing.assert_allclose(res.multipliers["stage_constraints"], ref.multipliers["stage_constraints"], atol=1e-4)
    np.testing.assert_allclose(res.multipliers["dynamics"], ref.multipliers["dynamics"], atol=1e-4)
    # history per outer iteration; rho grew by the factor each time
    h = res.history
    assert len(h) == res.iterations and res.iterations >= 5
    assert [r["rho"] for r in h] == pytest.approx([10.0 * 10.0 ** i for i in range(len(h))])
    assert all(k in h[0] for k in ("rho", "violation", "inner_iterations", "objective", "penalized_objective"))
    assert h[-1]["violation"] == res.max_constraint_violation
    assert res.info["inner_iterations"] == sum(r["inner_iterations"] for r in h)
    assert res.solver == "penalty"


def test_augmented_lagrangian_needs_far_smaller_rho(pendulum_reference):
    ref = pendulum_reference
    p = Pendulum(N=20)
    pure = PenaltySolver(constr_viol_tol=1e-7).solve(p)
    al = PenaltySolver(augmented_lagrangian=True, constr_viol_tol=1e-9).solve(p)
    assert al.status is Status.SUCCESS, al.message
    assert al.max_constraint_violation <= 1e-9
    assert al.objective == pytest.approx(ref.objective, abs=1e-7)
    assert al.kkt_residual < 1e-6
    assert al.multipliers["final_constraints"] == pytest.approx(ref.multipliers["final_constraints"], abs=1e-6)
    assert pure.info["rho"] >= 1e6
    assert al.info["rho"] <= 1e3
    assert al.info["rho"] <= pure.info["rho"] / 1e3


@pytest.mark.parametrize("al", [False, True])
def test_state_bounds_reach_ipopt_solution(vdp_path_reference, al):
    ref = vdp_path_reference
    p = PROBLEMS["vanderpol-path"](N=20)
    tol = 1e-8 if al else 1e-6
    res = PenaltySolver(augmented_lagrangian=al, constr_viol_tol=tol).solve(p)
    assert res.status is Status.SUCCESS, res.message
    assert res.x[1:, 0].min() >= -0.4 - tol
    assert np.all(res.u >= -0.3) and np.all(res.u <= 1.0)    # lbfgsb keeps the control bounds
    assert res.objective == pytest.approx(ref.objective, abs=1e-6)
    assert res.multipliers["bound_lower_x"][1:, 0] == pytest.approx(ref.multipliers["bound_lower_x"][1:, 0], abs=1e-3)


@pytest.mark.parametrize("inner", ["pdmin", "newton", "variable-metric", "cg", "ddp", "stagewise-newton"])
def test_inner_methods(pendulum_reference, inner):
    ref = pendulum_reference
    p = Pendulum(N=20)
    res = PenaltySolver(inner=inner, augmented_lagrangian=True, constr_viol_tol=1e-8).solve(p)
    assert res.success, res.message
    assert res.objective == pytest.approx(ref.objective, abs=1e-6)
    assert res.max_constraint_violation <= 1e-8
    # without bound support in the inner method the control bounds are penalized, still met
    assert np.all(res.u >= -2.0 - 1e-8) and np.all(res.u <= 2.0 + 1e-8)


def test_unconstrained_problem_needs_one_iteration():
    pytest.importorskip("cyipopt")
    p = PROBLEMS["rayleigh-box"](N=30)
    ref = olado.solve(p, solver="ipopt", tol=1e-11)
    res = PenaltySolver().solve(p)
    assert res.status is Status.SUCCESS and res.iterations == 1
    # IPOPT relaxes bounds by ~1e-8 (bound_relax_factor): agreement to ~1e-6 relative
    assert res.objective == pytest.approx(ref.objective, rel=1e-6)


def test_lbfgsb_restarts_on_badly_scaled_problem():
    """lq-box: unstable dynamics make the reduced Hessian badly scaled; one L-BFGS-B run stops on
    'relative reduction of f' far from the optimum, the restarts reach it (IPOPT: 16.0606421)."""
    p = PROBLEMS["lq-box"](N=50)
    U, ok, nit, msg, _ = solve_lbfgsb(p, p.initial_guess(), tol=1e-8, max_iter=5000)
    assert ok
    assert p.objective(p.simulate(U), U) == pytest.approx(16.06064208099815, rel=1e-7)


# ============================================================================ statuses
def test_max_iter_status():
    p = Pendulum(N=20)
    res = PenaltySolver(max_iter=2).solve(p)
    assert res.status is Status.MAX_ITERATIONS
    assert res.iterations == 2 and len(res.history) == 2
    assert res.max_constraint_violation > 1e-6
    zero = PenaltySolver(max_iter=0).solve(p)
    assert zero.status is Status.MAX_ITERATIONS and zero.iterations == 0
    np.testing.assert_allclose(zero.u, p.initial_guess())


def test_rho_max_status():
    res = PenaltySolver(rho_max=1e3).solve(Pendulum(N=20))
    assert res.status is Status.FAILED
    assert "rho_max" in res.message
    assert res.history[-1]["rho"] == 1e3


def test_infeasible_status():
    """Pendulum with N = 10 cannot reach x0 = 0.2 under its constraints (IPOPT: infeasible too)."""
    res = PenaltySolver(augmented_lagrangian=True).solve(Pendulum(N=10))
    assert res.status is Status.INFEASIBLE, res.message
    assert res.max_constraint_violation > 1e-2
    pure = PenaltySolver().solve(Pendulum(N=10))
    assert pure.status is Status.INFEASIBLE
    assert pure.history[-1]["rho"] < 1e8


def test_callback_stop_and_time_limit():
    calls = []
    res = PenaltySolver(callback=lambda info: calls.append(info["rho"]) or len(calls) >= 2).solve(Pendulum(N=20))
    assert res.status is Status.USER_STOP and len(calls) == 2
    slow = PenaltySolver(max_time=1e-9).solve(Pendulum(N=20))
    assert slow.status is Status.MAX_TIME


def test_warm_start_from_result():
    p = Pendulum(N=20)
    first = PenaltySolver(augmented_lagrangian=True, constr_viol_tol=1e-8).solve(p)
    again = PenaltySolver(augmented_lagrangian=True, constr_viol_tol=1e-8).solve(p, guess=first)
    assert first.success and again.success
    assert again.objective == pytest.approx(first.objective, abs=1e-7)


# ============================================================================ configuration
def test_ini_presets():
    cfg = load_config(os.path.join(ROOT, "configs", "penalty.ini"))
    assert cfg.solver == "penalty"
    assert cfg.options.inner == "lbfgsb" and cfg.options.augmented_lagrangian is False
    al = load_config(os.path.join(ROOT, "configs", "penalty-al.ini"))
    assert al.options.augmented_lagrangian is True and al.options.constr_viol_tol == 1e-8
    res = olado.solve(Pendulum(N=20), config=os.path.join(ROOT, "configs", "penalty-al.ini"))
    assert res.solver == "penalty" and res.success


def test_ini_errors_and_raw_section(tmp_path):
    bad = tmp_path / "bad.ini"
    bad.write_text("[solver]\nname = penalty\n[penalty]\ninner = simplex\n")
    with pytest.raises(ConfigError) as err:
        load_config(bad)
    assert "inner" in str(err.value) and "lbfgsb" in str(err.value)
    raw = tmp_path / "raw.ini"
    raw.write_text("[solver]\nname = penalty\n[penalty]\ninner = cg\n[penalty.raw]\nmax_iter = 77\n")
    cfg = load_config(raw)
    assert cfg.options.inner_options == {"max_iter": 77}
    with pytest.raises(ConfigError):
        PenaltySolver(rho_factor=1.0)
