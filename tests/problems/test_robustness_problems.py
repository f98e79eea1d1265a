"""The literature problems of the robustness set (olado/problems/{continuous, cops, literature,
variants, infeasible}.py): derivatives against finite differences, the RK4 step against hand
computations, the free-final-time parameter stage, analytic optima, the infeasibility proofs
(LP certificates and invariants) and the lazy registration."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.optimize

from fixtures import REPO
from olado.problems import PROBLEMS, check_derivatives
from olado.problems.catalog import CATALOG
from olado.problems.integrators import rk_step, rk_step_derivatives
from olado.problems.literature import DoubleIntegrator, Dubins

#: small sizes for the derivative checks (RK4 must stay stable: alp-rider has eigenvalues -10 and +2;
#: hypersonic-landing's Euler start needs 200 steps, and substeps at smaller N compile slowly; the shuttle's
#: 2000 s in 12 RK4 steps of 170 s leave the model's range)
SMALL_N = {"alp-rider": 100, "hang-glider": 41, "lq-unreachable": 20, "hypersonic-landing": 200,
           "shuttle-entry": 100, "shuttle-entry-heating": 100}
#: second differences of values are the reference for the Hessians: loose where the model is steep
HESSIAN_RTOL = {"goddard": 5e-2, "alp-rider": 1e-3, "hang-glider": 1e-2, "rigid-body": 1e-3, "robot-arm": 1e-3, "cart-pole": 1e-3,
                "orbit-raising": 1e-3, "particle-steering": 1e-3, "steering-too-short": 1e-3}


def _goddard_flight(p):
    """T = 0.2 at thrust 1 (the fuel lasts exactly): COPS's start (T = 1, thrust 1.75 with guessed
    states) makes RK4 at a few steps blow up through the stiff drag exp(-500 (h - 1))."""
    U = np.full((p.N, 1), 1.0)
    U[0, 0] = 0.2
    return U


#: problems whose derivatives are checked from another control trajectory than their start
START = {"goddard": _goddard_flight}


def _point(p, noise=0.01, seed=0):
    """The problem's start (its state guess or the simulated states) plus a little noise."""
    rng = np.random.default_rng(seed)
    U = START[p.name](p) if p.name in START else p.initial_guess()
    U = np.clip(U + noise * rng.standard_normal(U.shape) * np.maximum(1.0, np.abs(U)), p.u_lower, p.u_upper)
    X = None if p.name in START else p.initial_state_guess(U)
    # states of a guess get 1e-3 relative noise (goddard's drag exp(-500 (h - 1)) overflows below h ~ 0.9)
    X = p.simulate(U) if X is None else X + 1e-3 * rng.standard_normal(X.shape) * np.maximum(1.0, np.abs(X))
    X[0] = p.x0
    return X, U


def test_catalog_names_are_registered_and_build():
    for name, (module, summary) in CATALOG.items():
        assert name in PROBLEMS and summary.endswith(".")
        p = PROBLEMS[name]()
        assert p.name == name, (name, p.name)


def test_listing_imports_none_of_the_literature_modules():
    code = ("import sys; from olado.cli import main; main(['list']); "
            "mods = [m for m in ('cops', 'literature', 'infeasible', 'variants', 'continuous') "
            "if 'olado.problems.' + m in sys.modules]; print('LOADED', mods)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "LOADED []" in out.stdout and "goddard" in out.stdout


def test_cli_rejects_an_unknown_setting_of_a_lazy_problem(capsys):
    from olado.cli import main

    assert main(["solve", "dubins", "--start", "sif", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "takes no setting 'start'" in err and "Traceback" not in err


@pytest.mark.parametrize("name", list(CATALOG))
def test_first_derivatives_against_finite_differences(name):
    p = PROBLEMS[name](N=SMALL_N.get(name, 12))
    X, U = _point(p)
    report = check_derivatives(p, X=X, U=U, hessians=False, rtol=1e-5, atol=1e-7)
    assert report.ok, str(report)


@pytest.mark.parametrize("name", list(CATALOG))
def test_hessians_against_finite_differences(name):
    p = PROBLEMS[name](N=SMALL_N.get(name, 12))
    X, U = _point(p)
    report = check_derivatives(p, X=X, U=U, rtol=HESSIAN_RTOL.get(name, 1e-4), atol=1e-5)
    hessian_checks = [c for c in report.checks if "hessian" in c.name]
    assert all(c.ok for c in hessian_checks), str(report)


# ---------------------------------------------------------------------------- integrators
def _model(X, U):
    """x' = (x2, -sin x1 + u), L = x1^2 u^2: a nonlinear model with a state-control coupling."""
    return np.stack([X[:, 1], -np.sin(X[:, 0]) + U[:, 0], X[:, 0] ** 2 * U[:, 0] ** 2], axis=1)


def _model_derivatives(X, U, order):
    x1, u = X[:, 0], U[:, 0]
    K = len(u)
    J = np.zeros((K, 3, 3))
    J[:, 0, 1] = 1.0
    J[:, 1, 0], J[:, 1, 2] = -np.cos(x1), 1.0
    J[:, 2, 0], J[:, 2, 2] = 2 * x1 * u ** 2, 2 * x1 ** 2 * u
    H = np.zeros((K, 3, 3, 3))
    H[:, 1, 0, 0] = np.sin(x1)
    H[:, 2, 0, 0], H[:, 2, 2, 2] = 2 * u ** 2, 2 * x1 ** 2
    H[:, 2, 0, 2] = H[:, 2, 2, 0] = 4 * x1 * u
    return _model(X, U), J, H


@pytest.mark.parametrize("rk4", [True, False])
def test_step_derivatives_against_finite_differences(rk4):
    rng = np.random.default_rng(1)
    X, U, h = rng.standard_normal((5, 2)), rng.standard_normal((5, 1)), 0.3
    D, D2 = rk_step_derivatives(_model_derivatives, X, U, h, rk4, order=2)
    Z = np.concatenate([X, U], axis=1)
    step = lambda Z: np.concatenate(rk_step(_model, Z[:, :2], Z[:, 2:], h, rk4)[0:1] +  # noqa: E731
                                    (rk_step(_model, Z[:, :2], Z[:, 2:], h, rk4)[1][:, None],), axis=1)
    eps = 1e-6
    for j in range(3):
        dZ = np.zeros_like(Z)
        dZ[:, j] = eps
        fd = (step(Z + dZ) - step(Z - dZ)) / (2 * eps)
        assert np.allclose(D[:, :, j], fd, rtol=1e-7, atol=1e-8)
        Dp = rk_step_derivatives(_model_derivatives, (Z + dZ)[:, :2], (Z + dZ)[:, 2:], h, rk4)[0]
        Dm = rk_step_derivatives(_model_derivatives, (Z - dZ)[:, :2], (Z - dZ)[:, 2:], h, rk4)[0]
        assert np.allclose(D2[:, :, :, j], (Dp - Dm) / (2 * eps), rtol=1e-6, atol=1e-7)


def test_rk4_step_of_the_double_integrator_is_exact():
    """x'' = u with constant u: RK4 integrates the quadratic x and the cost u^2/2 exactly."""
    p = DoubleIntegrator(N=10)
    U = np.full((10, 1), -2.0)
    X = p.simulate(U)
    t = np.linspace(0, 1, 11)
    assert np.allclose(X[:, 0], t - t ** 2, atol=1e-14) and np.allclose(X[:, 1], 1 - 2 * t, atol=1e-14)
    assert p.objective(X, U) == pytest.approx(2.0, abs=1e-13)      # the analytic optimum J* = 2
    assert np.allclose(p.eval_final_constraints(X[-1]), 0.0, atol=1e-14)


# ---------------------------------------------------------------------------- free final time
def test_parameter_stage_sets_the_final_time():
    """Dubins: stage 0 copies the physical states and sets T := u^0_0; the N - 1 steps then
    cover [0, T]: a constant turn rate w turns the heading by w T exactly, and with w = 0 the car
    drives x(T) = T (both exact for RK4: the right-hand sides are constant or linear in t)."""
    p = Dubins(N=41)
    T = 3.0
    U = np.full((p.N, 1), 0.5)
    U[0, 0] = T
    X = p.simulate(U)
    assert np.array_equal(X[1, :3], p.x0[:3]) and np.all(X[1:, 3] == T)
    assert X[-1, 2] == pytest.approx(0.5 * T, abs=1e-13)
    assert p.objective(X, U) == T                      # minimum time: the objective is the T state
    U[1:] = 0.0
    X = p.simulate(U)
    assert X[-1, 0] == pytest.approx(T, abs=1e-13) and X[-1, 1] == 0.0
    assert p.steps == 40 and "parameter stage" in p.discretization


def test_parameter_stage_dummy_controls_carry_a_zero_at_optimum_cost():
    p = PROBLEMS["robot-arm"](N=11)
    U = p.initial_guess()
    X = p.simulate(U)
    U2 = U.copy()
    U2[0, 1:] = [0.3, -0.4]
    assert p.objective(X, U2) - p.objective(X, U) == pytest.approx(0.5 * (0.09 + 0.16))
    assert p.u_lower[0, 0] == p.T_BOUNDS[0] and p.u_upper[0, 0] == p.T_BOUNDS[1]
    assert np.isinf(p.u_lower[0, 1:]).all() and p.u_lower[1, 0] == -1.0


# ---------------------------------------------------------------------------- infeasibility proofs
def _lp_feasible(A, B, c, x0, N, target, umax):
    """Is there U (|U| <= umax) with x^{k+1} = A x^k + B u^k + c, x^0 = x0, x^N = target? (LP)"""
    n, m = B.shape
    # x^N = A^N x0 + sum_k A^(N-1-k) (B u^k + c)
    M = np.zeros((n, N * m))
    rhs = target - np.linalg.matrix_power(A, N) @ x0
    for k in range(N):
        P = np.linalg.matrix_power(A, N - 1 - k)
        M[:, k * m:(k + 1) * m] = P @ B
        rhs = rhs - P @ c
    res = scipy.optimize.linprog(np.zeros(N * m), A_eq=M, b_eq=rhs, bounds=[(-umax, umax)] * (N * m), method="highs")
    return res.status != 2   # 2: infeasible


def _affine_step(p):
    """(A, B, c) of a problem whose step is affine (checked at two points)."""
    x, u = np.zeros((1, p.n)), np.zeros((1, p.m))
    A, B = (a[0] for a in p.eval_dynamics_jacobians(np.zeros((p.N + 1, p.n)), np.zeros((p.N, p.m))))
    c = p.dynamics(np.array([1]), x, u)[0]
    x2, u2 = np.ones((1, p.n)), np.ones((1, p.m))
    assert np.allclose(p.dynamics(np.array([1]), x2, u2)[0], A @ x2[0] + B @ u2[0] + c)
    return A, B, c


def test_lq_unreachable_is_certified_by_an_lp():
    p = PROBLEMS["lq-unreachable"]()
    A, B, c = _affine_step(p)
    assert not _lp_feasible(A, B, c, p.x0, p.N, p.TARGET, 1.0)
    assert _lp_feasible(A, B, c, p.x0, p.N, np.zeros(4), 1.0)      # the LP does find reachable targets


def test_cart_too_short_is_certified_by_an_lp():
    p = PROBLEMS["cart-too-short"]()
    A, B, c = _affine_step(p)
    assert not _lp_feasible(A, B, c, p.x0, p.N, np.zeros(2), 1.0)
    longer = PROBLEMS["bang-bang-cart"]()              # 1 + sqrt 6 suffices (with a free final time)
    assert 3.0 < 1 + np.sqrt(6) < longer.T_BOUNDS[1]


@pytest.mark.parametrize("name,invariant", [
    ("catalyst-overfull", lambda X: X[-1, 0] + X[-1, 1] <= 1.0 + 1e-12),
    ("batch-overyield", lambda X: X[-1, 1] <= 1.0 + 1e-12),
    ("steering-too-short", lambda X: X[-1, 2] <= 40.0 + 1e-9),
])
def test_infeasible_variants_keep_their_invariant_under_random_controls(name, invariant):
    p = PROBLEMS[name]()
    rng = np.random.default_rng(2)
    for _ in range(50):
        U = p.u_lower + (p.u_upper - p.u_lower) * rng.random(p.u_lower.shape)
        assert invariant(p.simulate(U))


def test_contradicting_path_constraints_sum_to_a_negative_constant():
    p = PROBLEMS["vanderpol-contradict"]()
    rng = np.random.default_rng(3)
    U = rng.standard_normal((p.N, 1))
    X = p.simulate(U)
    assert np.allclose(p.eval_stage_constraints(X, U).sum(axis=1), -0.1)


def test_chain_too_short_length_is_at_least_the_chord():
    """Every discrete chain from (0, 1) to (1, 3) is at least sqrt 5 long (triangle inequality)."""
    p = PROBLEMS["chain-too-short"]()
    rng = np.random.default_rng(4)
    for _ in range(20):
        U = 2.0 + rng.standard_normal((p.N, 1))
        X = p.simulate(U)
        chord = np.hypot(1.0, X[-1, 0] - 1.0)
        assert X[-1, 1] >= chord - 1e-12 and p.length < np.sqrt(5)


def test_a_continuous_problem_without_a_hook_it_needs_is_refused_by_name():
    from olado.errors import ProblemDefinitionError
    from olado.problems.continuous import ContinuousDOCP

    class NoTerminal(ContinuousDOCP):
        STATES, CONTROLS, X0, T = ("x",), ("u",), (0.0,), 1.0
        N_TERMINAL, TERMINAL_EQUALITIES = 1, [0]

        def model(self, X, U, order):
            return np.stack([U[:, 0], U[:, 0] ** 2], axis=1), None, None

    class NoModel(ContinuousDOCP):
        STATES, CONTROLS, X0, T = ("x",), ("u",), (0.0,), 1.0

    with pytest.raises(ProblemDefinitionError, match=r"terminal\(\).*NoTerminal does not define terminal"):
        NoTerminal(N=4)
    with pytest.raises(ProblemDefinitionError, match=r"NoModel does not define model"):
        NoModel(N=4)
