"""Non-finite values from a problem: the evaluation raises NonFiniteEvaluationError (a
ProblemDefinitionError naming function, stage and array), and every solver recognises it by type:
a line search treats the trial point as "step too long", an unusable initial point is
INVALID_PROBLEM, a definition bug (wrong shape) is not mistaken for it and propagates."""

import numpy as np
import pytest

import olado
from olado.errors import NonFiniteEvaluationError, ProblemDefinitionError
from olado.problems import DOCP
from olado.result import Status


class Cliff(DOCP):
    """x+ = x + u (N = 3), min sum 0.005 u^2 + sqrt(1 + (x_N - 3)^2): a pseudo-Huber final cost,
    so Newton-type steps from u = 0 overshoot far past the solution x_N = 2.99; the dynamics
    return NaN where x + u > ``cliff`` (``nan_returned`` counts how often)."""

    vectorized = False

    def __init__(self, cliff=3.5):
        super().__init__(1, 1, 3, [0.0])
        self.cliff = cliff
        self.nan_returned = 0

    def dynamics(self, k, x, u):
        if x[0] + u[0] > self.cliff:
            self.nan_returned += 1
            return self.beyond(x, u)
        return x + u

    def beyond(self, x, u):
        return np.array([np.nan])

    def stage_cost(self, k, x, u):
        return 0.005 * float(u @ u)

    def final_cost(self, x):
        return float(np.sqrt(1.0 + (x[0] - 3.0) ** 2))


class VectorizedCliff(Cliff):
    vectorized = True

    def dynamics(self, k, x, u):
        out = x + u
        out[x[:, 0] + u[:, 0] > self.cliff] = np.inf
        return out

    def stage_cost(self, k, x, u):
        return 0.005 * np.sum(u * u, axis=1)


class WrongShapeBeyond(Cliff):
    """Beyond the cliff the dynamics return a vector of the wrong length: a definition bug."""

    def beyond(self, x, u):
        return np.array([1.0, 2.0])


class NaNCostAtStart(Cliff):
    """The stage cost is NaN at u = 0, the default initial guess."""

    def stage_cost(self, k, x, u):
        return float("nan") if not np.any(u) else super().stage_cost(k, x, u)


@pytest.mark.parametrize("cls", [Cliff, VectorizedCliff])
def test_a_non_finite_value_raises_the_typed_error_naming_function_stage_and_array(cls):
    p = cls()
    X = np.array([[0.0], [1.0], [3.0], [3.2]])
    U = np.array([[1.0], [2.0], [1.0]])          # x + u: 1, 3, 4 > 3.5 at stage 2
    with pytest.raises(NonFiniteEvaluationError) as err:
        p.eval_dynamics(X, U)
    assert isinstance(err.value, ProblemDefinitionError)
    assert (err.value.function, err.value.stage, err.value.array) == ("dynamics", 2, "x_next")
    assert "non-finite" in str(err.value) and "k=2" in str(err.value)
    p.eval_dynamics(X, np.array([[1.0], [2.0], [0.0]]))       # below the cliff: fine


def test_a_wrong_shape_is_a_definition_error_not_a_non_finite_one():
    p = WrongShapeBeyond()
    with pytest.raises(ProblemDefinitionError) as err:
        p.eval_dynamics(np.zeros((4, 1)), np.array([[0.0], [0.0], [4.0]]))
    assert not isinstance(err.value, NonFiniteEvaluationError)


def test_the_ddp_rollout_raises_the_typed_error():
    from olado.solvers.control.ddp import _rollout

    p = Cliff()
    Xbar, Ubar = np.zeros((4, 1)), np.zeros((3, 1))
    with pytest.raises(NonFiniteEvaluationError) as err:
        _rollout(p, Xbar, Ubar, np.full((3, 1), 2.0), np.zeros((3, 1, 1)), 1.0)   # x + u: 2, 4 at stage 1
    assert (err.value.function, err.value.stage) == ("dynamics", 1)


SOLVERS = [("sqp", {}), ("ddp", {}), ("stagewise-newton", {}), ("newton", {}), ("gradient", {}), ("cg", {}),
           ("penalty", {}), ("pdmin", {"direction": "steepest-descent", "initial_step": 30.0}), ("ipopt", {}),
           ("ipm", {}), ("fqlnk", {})]


@pytest.mark.parametrize("solver, options", SOLVERS, ids=[s for s, _ in SOLVERS])
def test_every_solver_steps_back_from_non_finite_trial_points(solver, options):
    """The first steps of each method reach past the cliff (NaN dynamics); the method shortens
    them and ends at the solution of the problem without a cliff."""
    if solver == "ipopt":
        pytest.importorskip("cyipopt")
    ref = olado.solve(Cliff(cliff=np.inf), solver=solver, **options)
    p = Cliff()
    r = olado.solve(p, solver=solver, **options)
    assert p.nan_returned > 0                       # the case is exercised
    assert r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-10)
    assert r.x[-1, 0] == pytest.approx(2.99003273, abs=1e-7)


@pytest.mark.parametrize("solver", ["pdmin", "gradient"])
def test_a_non_finite_initial_point_is_an_invalid_problem_for_the_control_space_methods(solver):
    r = olado.solve(NaNCostAtStart(), solver=solver)
    assert r.status == Status.INVALID_PROBLEM
    assert "non-finite" in r.message


@pytest.mark.parametrize("solver", ["sqp", "ddp", "ipopt", "ipm", "fqlnk"])
def test_a_non_finite_initial_point_raises_the_typed_error(solver):
    if solver == "ipopt":
        pytest.importorskip("cyipopt")
    with pytest.raises(NonFiniteEvaluationError):
        olado.solve(NaNCostAtStart(), solver=solver)


@pytest.mark.parametrize("solver", ["sqp", "newton", "penalty", "ipopt", "ipm", "fqlnk"])
def test_a_definition_bug_at_a_trial_point_propagates(solver):
    """The same trial points with a wrong-shape return instead of NaN: not a recoverable
    evaluation failure, the solve stops with the ProblemDefinitionError."""
    if solver == "ipopt":
        pytest.importorskip("cyipopt")
    with pytest.raises(ProblemDefinitionError) as err:
        olado.solve(WrongShapeBeyond(), solver=solver)
    assert not isinstance(err.value, NonFiniteEvaluationError)
    assert "expected shape" in str(err.value)
