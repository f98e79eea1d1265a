"""The DOCP class hierarchy: validation, simulation, finite differences, derivative checks."""

import numpy as np
import pytest

from olado.errors import ProblemDefinitionError
from olado.problems import DOCP, LagrangeDOCP, MayerDOCP, check_derivatives

from fixtures.toy_problems import Pendulum, PendulumFD, PendulumVectorized


def test_simulate_matches_hand_loop():
    p = Pendulum(N=5)
    U = np.linspace(-1, 1, 5)[:, None]
    X = p.simulate(U)
    x = p.x0.copy()
    for k in range(5):
        assert np.allclose(X[k], x)
        x = p.dynamics(k, x, U[k])
    assert np.allclose(X[5], x)
    assert p.objective(X, U) == pytest.approx(sum(p.stage_cost(k, X[k], U[k]) for k in range(5)) + X[5] @ X[5])


def test_vectorized_and_per_stage_problems_agree():
    rep = check_derivatives(Pendulum(N=7), PendulumVectorized(N=7), noise=0.5, rtol=1e-6)
    assert rep.ok, str(rep)
    assert rep["dynamics"].max_abs_error == 0.0


@pytest.mark.parametrize("method,tol", [("forward", 1e-6), ("backward", 1e-6), ("central", 1e-9)])
def test_finite_differences_match_analytic(method, tol):
    pa = Pendulum(N=6)
    pf = PendulumFD(N=6, fd_method=method)
    U = pa.initial_guess() + 0.3
    X = pa.simulate(U)
    for a, b in zip(pa.eval_dynamics_jacobians(X, U), pf.eval_dynamics_jacobians(X, U)):
        assert np.max(np.abs(a - b)) < tol
    for a, b in zip(pa.eval_stage_cost_gradients(X, U), pf.eval_stage_cost_gradients(X, U)):
        assert np.max(np.abs(a - b)) < tol
    for a, b in zip(pa.eval_stage_constraint_jacobians(X, U), pf.eval_stage_constraint_jacobians(X, U)):
        assert np.max(np.abs(a - b)) < tol
    assert np.allclose(pa.eval_final_constraint_jacobian(X[-1]), pf.eval_final_constraint_jacobian(X[-1]), atol=tol)


def test_fd_hessians_match_analytic():
    pa, pf = Pendulum(N=5), PendulumFD(N=5)
    rng = np.random.default_rng(3)
    U = rng.uniform(-1, 1, (5, 1))
    X = pa.simulate(U)
    P, L = rng.standard_normal((5, 2)), rng.standard_normal((5, 1))
    for a, b in zip(pa.eval_stage_hessians(X, U, 0.7, P, L), pf.eval_stage_hessians(X, U, 0.7, P, L)):
        assert np.max(np.abs(a - b)) < 2e-6
    lN = np.array([0.4])
    assert np.allclose(pa.eval_final_hessian(X[-1], 0.7, lN), pf.eval_final_hessian(X[-1], 0.7, lN), atol=2e-6)


def test_check_derivatives_passes_for_correct_and_locates_wrong_derivative():
    assert check_derivatives(Pendulum(N=8), noise=0.4).ok

    class Wrong(Pendulum):
        def dynamics_jacobian(self, k, x, u):
            A, B = super().dynamics_jacobian(k, x, u)
            if k == 3:
                A = A.copy(); A[1, 0] += 0.05
            return A, B

    rep = check_derivatives(Wrong(N=8), noise=0.4)
    assert not rep.ok
    bad = rep["dynamics_jacobian fx"]
    assert not bad.ok and bad.stage == 3 and bad.entry == (1, 0)
    assert "FAIL" in str(rep)


def test_derivative_sources_report():
    assert Pendulum().derivative_sources()["dynamics_jacobian"] == "analytic"
    assert PendulumFD().derivative_sources()["dynamics_jacobian"].startswith("finite differences")
    assert Pendulum(derivatives="fd").derivative_sources()["stage_hessian"].startswith("finite")


# ---------------------------------------------------------------- bounds
def test_bounds_stationary_nonstationary_and_later_setting():
    p = Pendulum(N=4, x_bounds=([-1, -np.inf], [2, np.inf]))
    assert p.x_lower.shape == (5, 2) and np.all(p.x_lower[:, 0] == -1) and np.all(np.isinf(p.x_upper[:, 1]))
    ul = np.arange(4.0)[:, None] - 10
    p.u_bounds = (ul, None)
    assert np.array_equal(p.u_lower, ul) and np.all(np.isinf(p.u_upper))
    p.u_bounds = (-3, 3)
    assert np.all(p.u_lower == -3)


@pytest.mark.parametrize("bounds,text", [
    (([0, 0, 0], None), "x_bounds"),
    (([1, 1], [0, 0]), "stage k=0"),
    (([np.nan, 0], None), "NaN"),
    ((1,), "pair"),
])
def test_bad_bounds_are_named(bounds, text):
    with pytest.raises(ProblemDefinitionError, match=text):
        Pendulum(N=3, x_bounds=bounds)


def test_wrong_x0_and_dimensions():
    with pytest.raises(ProblemDefinitionError, match="x0"):
        Pendulum.__bases__[0].__init__(Pendulum.__new__(Pendulum), 2, 1, 3, [1.0, 2.0, 3.0])
    with pytest.raises(ProblemDefinitionError, match="positive integer"):
        Pendulum(N=0)


# ---------------------------------------------------------------- user function errors
class BadShape(Pendulum):
    def dynamics(self, k, x, u):
        if k == 2:
            return np.zeros(3)
        return super().dynamics(k, x, u)


class NonFinite(Pendulum):
    def stage_cost(self, k, x, u):
        return np.nan if k == 4 else super().stage_cost(k, x, u)


class VecBadShape(PendulumVectorized):
    def stage_constraints(self, k, x, u):
        return np.zeros((len(k), 2))


class VecNonFinite(PendulumVectorized):
    def dynamics(self, k, x, u):
        out = super().dynamics(k, x, u)
        out[k == 5, 1] = np.inf
        return out


def test_wrong_shape_names_function_stage_and_array():
    p = BadShape(N=6)
    with pytest.raises(ProblemDefinitionError) as e:
        p.simulate(p.initial_guess())
    msg = str(e.value)
    assert "dynamics()" in msg and "stage k=2" in msg and "x_next" in msg and "(3,)" in msg


def test_non_finite_value_names_stage():
    p = NonFinite(N=6)
    U = p.initial_guess(); X = p.simulate(U)
    with pytest.raises(ProblemDefinitionError, match=r"stage_cost\(\).*stage k=4"):
        p.eval_stage_costs(X, U)


def test_vectorized_errors_name_stage():
    p = VecNonFinite(N=8)
    U = p.initial_guess(); X = np.ones((9, 2))
    with pytest.raises(ProblemDefinitionError, match=r"dynamics\(\).*stage k=5.*x_next"):
        p.eval_dynamics(X, U)
    q = VecBadShape(N=8)
    with pytest.raises(ProblemDefinitionError, match=r"stage_constraints\(\).*\(8, 1\)"):
        q.eval_stage_constraints(X, U)


def test_wrong_trajectory_shapes():
    p = Pendulum(N=4)
    with pytest.raises(ProblemDefinitionError, match="controls of shape"):
        p.eval_dynamics(np.zeros((5, 2)), np.zeros((3, 1)))
    with pytest.raises(ProblemDefinitionError, match="u"):
        p.simulate(np.zeros((4, 2)))


def test_missing_functions_are_reported():
    class NoCost(DOCP):
        def dynamics(self, k, x, u):
            return x

        def final_cost(self, x):
            return 0.0

    with pytest.raises(ProblemDefinitionError, match="MayerDOCP"):
        NoCost(1, 1, 3, [0.0])

    class Cons(Pendulum):
        stage_constraints = DOCP.stage_constraints

    with pytest.raises(ProblemDefinitionError, match="stage_constraints"):
        Cons(N=3)


# ---------------------------------------------------------------- special forms
class Integrator(LagrangeDOCP):
    def dynamics(self, k, x, u):
        return x + u

    def stage_cost(self, k, x, u):
        return float(x @ x + u @ u)


class MayerIntegrator(MayerDOCP):
    def dynamics(self, k, x, u):
        return x + u

    def final_cost(self, x):
        return float((x - 3.0) @ (x - 3.0))


def test_lagrange_and_mayer_forms():
    p = Integrator(1, 1, 3, [1.0])
    U = np.ones((3, 1)); X = p.simulate(U)
    assert np.allclose(X[:, 0], [1, 2, 3, 4])
    assert p.objective(X, U) == pytest.approx(1 + 4 + 9 + 3)
    assert np.allclose(p.eval_final_hessian(X[-1], 1.0), 0.0)
    q = MayerIntegrator(1, 1, 3, [1.0])
    assert q.objective(X, U) == pytest.approx(1.0)
    assert np.allclose(q.eval_stage_cost_gradients(X, U)[1], 0.0)
    assert check_derivatives(q).ok


def test_initial_guess_respects_bounds():
    p = Pendulum(N=3, u_bounds=([0.5], None))
    assert np.all(p.initial_guess() == 0.5)
    p.u_bounds = (-1, 3)
    assert np.all(p.initial_guess() == 1.0)


def test_counters_count_evaluations():
    p = PendulumVectorized(N=10)
    p.reset_counters()
    U = p.initial_guess(); X = p.simulate(U)
    p.eval_dynamics(X, U)
    assert p.counters["dynamics"] == 2


def test_fast_path_errors_name_stage_and_array():
    """The evaluation layer's fast path (a float64 array of the expected shape after one compiled
    finite check) leaves the detailed messages to the slow path: a NaN in a vectorized
    derivative tuple names the stage and the array, a wrong shape says so, a list of arrays is
    accepted as before, and a Python float final cost is taken as it is."""
    from olado.errors import NonFiniteEvaluationError, ProblemDefinitionError
    from olado.problems.zambezi import Zambezi

    class Bad(Zambezi):
        mode = None

        def dynamics_jacobian(self, k, x, u):
            fx, fu = super().dynamics_jacobian(k, x, u)
            if self.mode == "nan":
                fu = fu.copy()
                fu[5, 2, 3] = np.nan
            elif self.mode == "shape":
                fu = fu[:, :, :-1]
            elif self.mode == "list":
                return [fx, fu]
            return fx, fu

    p = Bad(N=12)
    U = p.initial_guess()
    X = p.simulate(U)
    ref = p.eval_dynamics_jacobians(X, U)
    p.mode = "list"
    for a, b in zip(p.eval_dynamics_jacobians(X, U), ref):
        np.testing.assert_array_equal(a, b)
    p.mode = "nan"
    with pytest.raises(NonFiniteEvaluationError, match=r"stage k=5.*'fu'.*at entry \(2, 3\)"):
        p.eval_dynamics_jacobians(X, U)
    p.mode = "shape"
    with pytest.raises(ProblemDefinitionError, match=r"'fu'.*expected shape \(12, 6, 7\) \(one row per stage\)"):
        p.eval_dynamics_jacobians(X, U)
    assert type(p.eval_final_cost(X[-1])) is float
