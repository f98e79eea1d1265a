"""Bad-input catalogue, part 2: problem definitions, starting guesses and faults in user functions.

A definition or a guess that cannot be used is a ProblemDefinitionError naming the function (or
the entry point), the stage and the array; a NaN where a finite value is needed its subclass
NonFiniteEvaluationError; faults at trial points are statuses; exceptions raised inside the
user's own functions pass through unchanged (docs/errors.md)."""

import numpy as np
import pytest

import olado
from olado.errors import ConfigError, NonFiniteEvaluationError, ProblemDefinitionError
from olado.problems import DOCP, PROBLEMS
from olado.result import Result, Status
from fixtures.bad_problems import (STAGE_VALUES, ComplexHessian, ConstrainedWalk, HessianWithoutMultipliers,
                                   JacobianNotATuple, NoSuperInit, NotCallableDynamics, RaisesItsOwn,
                                   RaisesKeyError, ThreeArgumentFinalCost, TwoArgumentDynamics, UsersOwnError,
                                   VectorizedWalk, Walk, expect, walk_returning)

PDE = ProblemDefinitionError


# ---------------------------------------------------------------------------- the problem argument
ARGUMENT_CASES = [
    ("int", 42, ["olado.solve()", "argument 'problem'", "DOCP instance", "int 42"]),
    ("none", None, ["argument 'problem'", "NoneType"]),
    ("list", [1, 2], ["argument 'problem'", "list"]),
    ("class-not-instance", Walk, ["argument 'problem'", "the class Walk", "Walk(...)"]),
    ("no-super-init", NoSuperInit(), ["NoSuperInit.__init__ did not call DOCP.__init__", "super().__init__"]),
    ("name-not-text", type("Named", (Walk,), {"name": 5})(), ["Named.name must be a string", "int 5"]),
]


@pytest.mark.parametrize("case_id,problem,names", ARGUMENT_CASES, ids=[c[0] for c in ARGUMENT_CASES])
def test_bad_problem_argument(case_id, problem, names):
    expect(PDE, names, olado.solve, problem, solver="slsqp")


def test_problem_given_by_name_is_a_config_error():
    expect(ConfigError, ["'zambezi12'", "PROBLEMS[name]"], olado.solve, "zambezi12")


def test_solver_instance_guards_its_problem_argument_too():
    from olado.config import make_solver, config_from_kwargs

    solver = make_solver(config_from_kwargs("slsqp"))
    expect(PDE, ["Solver.solve()", "argument 'problem'", "int"], solver.solve, 7)


# ---------------------------------------------------------------------------- the constructor
def walk(**kw):
    return Walk(**kw)


CONSTRUCTOR_CASES = [
    ("n-zero", lambda: DOCP.__init__(Walk.__new__(Walk), 0, 1, 4, [1.0]), ["'n'", "positive integer", "0"]),
    ("m-negative", lambda: DOCP.__init__(Walk.__new__(Walk), 1, -1, 4, [1.0]), ["'m'", "positive integer"]),
    ("N-fraction", lambda: walk(N=1.5), ["'N'", "positive integer", "1.5"]),
    ("N-bool", lambda: walk(N=True), ["'N'", "positive integer", "True"]),
    ("N-text", lambda: walk(N="4"), ["'N'", "positive integer", "'4'"]),
    ("N-beyond-memory", lambda: walk(N=10**12), ["'N'", "cannot fit in memory", "GiB", "bytes per stage"]),
    ("constraints-negative", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, [1.0], n_stage_constraints=-1),
     ["'n_stage_constraints'", "non-negative integer"]),
    ("x0-wrong-shape", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, [1.0, 2.0]), ["'x0'", "expected shape (1,)"]),
    ("x0-complex", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, [1j]), ["'x0'", "complex"]),
    ("x0-none", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, None), ["'x0'", "None"]),
    ("x0-nan", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, [np.nan]), ["'x0'", "non-finite"]),
    ("x0-text", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, ["a"]), ["'x0'", "text"]),
    ("bounds-not-a-pair", lambda: walk(u_bounds=(0, 1, 2)), ["'u_bounds'", "pair (lower, upper)"]),
    ("bounds-wrong-shape", lambda: walk(x_bounds=(np.zeros(3), None)), ["'x_bounds'", "expected shape (1,)", "(3,)"]),
    ("bounds-nan", lambda: walk(u_bounds=(np.nan, 1.0)), ["'u_bounds'", "NaN"]),
    ("bounds-crossed", lambda: walk(u_bounds=(2.0, 1.0)), ["'u_bounds'", "lower bound 2.0 > upper bound 1.0", "k=0"]),
    ("bounds-text", lambda: walk(u_bounds=("a", 1.0)), ["'u_bounds'", "text"]),
    ("bounds-complex", lambda: walk(u_bounds=(1j, 1.0)), ["'u_bounds'", "complex"]),
    ("bounds-none-inside", lambda: walk(x_bounds=([None], 1.0)), ["'x_bounds'", "None"]),
    ("bounds-object", lambda: walk(x_bounds=(object(), 1.0)), ["'x_bounds'", "object"]),
    ("equalities-text", lambda: DOCP.__init__(ConstrainedWalk.__new__(ConstrainedWalk), 1, 1, 4, [1.0],
                                              n_final_constraints=1, final_equalities=["a"]),
     ["'final_equalities'", "integer indices"]),
    ("equalities-out-of-range", lambda: DOCP.__init__(ConstrainedWalk.__new__(ConstrainedWalk), 1, 1, 4, [1.0],
                                                      n_final_constraints=1, final_equalities=[3]),
     ["'final_equalities'", "0..0", "[3]"]),
    ("equalities-without-constraints", lambda: walk(stage_equalities=[0]), ["'stage_equalities'", "no such constraints"]),
    ("mask-wrong-length", lambda: DOCP.__init__(ConstrainedWalk.__new__(ConstrainedWalk), 1, 1, 4, [1.0],
                                                n_final_constraints=1, final_equalities=[True, False]),
     ["'final_equalities'", "mask of length 1"]),
    ("derivatives", lambda: walk(derivatives="exact"), ["'derivatives'", "'auto' or 'fd'", "'exact'"]),
    ("fd-method", lambda: walk(fd_method="sideways"), ["'fd_method'", "central", "'sideways'"]),
    ("fd-step-zero", lambda: walk(fd_step=0.0), ["'fd_step'", "(0, 1)"]),
    ("fd-step-text", lambda: walk(fd_step="1e-6"), ["'fd_step'", "'1e-6'"]),
    ("missing-dynamics", lambda: type("NoDyn", (DOCP,), {"stage_cost": Walk.stage_cost, "final_cost": Walk.final_cost})(
        1, 1, 4, [1.0]), ["dynamics()", "must define dynamics"]),
    ("missing-final-cost", lambda: type("NoFinal", (DOCP,), {"stage_cost": Walk.stage_cost, "dynamics": Walk.dynamics})(
        1, 1, 4, [1.0]), ["final_cost()", "LagrangeDOCP"]),
    ("constraints-undefined", lambda: DOCP.__init__(Walk.__new__(Walk), 1, 1, 4, [1.0], n_stage_constraints=2),
     ["stage_constraints()", "n_stage_constraints=2", "not defined"]),
    ("dynamics-not-callable", NotCallableDynamics, ["dynamics()", "dynamics(k, x, u)", "int 5"]),
    ("dynamics-signature", TwoArgumentDynamics, ["dynamics()", "dynamics(k, x, u)", "dynamics(x, u)"]),
    ("final-cost-signature", ThreeArgumentFinalCost, ["final_cost()", "final_cost(x)", "(k, x, u)"]),
    ("hessian-signature", HessianWithoutMultipliers, ["stage_hessian()", "sigma, p, lam"]),
    ("zambezi-family", lambda: PROBLEMS["zambezi"].__globals__["zambezi_problem"]("zambezi99"),
     ["Zambezi()", "'family'", "zambezi99"]),
    ("zambezi-N-not-years", lambda: PROBLEMS["zambezi12"](N=13), ["Zambezi()", "'N'", "multiple of 12"]),
    ("zambezi-year", lambda: PROBLEMS["zambezi12"](N=12, year=1800), ["Zambezi()", "'year'", "1930..1965"]),
    ("zambezi-start", lambda: PROBLEMS["zambezi12"](N=12, start="somewhere"), ["Zambezi()", "'start'", "'somewhere'"]),
    ("zambezi-beyond-memory", lambda: PROBLEMS["zambezi12"](N=12 * 10**10), ["Zambezi()", "'N'", "cannot fit in memory"]),
]


@pytest.mark.parametrize("case_id,build,names", CONSTRUCTOR_CASES, ids=[c[0] for c in CONSTRUCTOR_CASES])
def test_bad_problem_definition(case_id, build, names):
    expect(PDE, names, build)


def test_function_replaced_after_construction_is_caught_at_the_entry_point():
    p = Walk()
    p.stage_cost = "not a function"
    expect(PDE, ["stage_cost()", "stage_cost(k, x, u)", "str"], olado.solve, p, solver="slsqp")


# ---------------------------------------------------------------------------- starting guesses
GUESS_CASES = [
    ("text", "abc", PDE, ["guess()", "'u'", "text"]),
    ("dict", {"u": 1}, PDE, ["guess()", "'u'", "dict"]),
    ("wrong-shape", np.zeros((3, 1)), PDE, ["guess()", "'u'", "expected shape (4, 1)", "(3, 1)"]),
    ("complex", np.zeros((4, 1)) + 1j, PDE, ["guess()", "'u'", "complex"]),
    ("none-entries", [[None]] * 4, PDE, ["guess()", "'u'", "None"]),
    ("ragged", [[1.0], [1.0, 2.0], [1.0], [1.0]], PDE, ["guess()", "'u'", "cannot convert"]),
    ("nan", np.full((4, 1), np.nan), NonFiniteEvaluationError, ["guess()", "'u'", "non-finite", "k=0"]),
    ("scalar", 3.0, PDE, ["guess()", "'u'", "expected shape (4, 1)"]),
    ("pair-with-bad-states", (np.zeros((6, 1)), np.zeros((4, 1))), PDE, ["guess()", "'x'", "expected shape (5, 1)"]),
    ("pair-with-none-controls", (np.zeros((5, 1)), None), PDE, ["guess()", "'u'", "None"]),
]


@pytest.mark.parametrize("case_id,guess,error,names", GUESS_CASES, ids=[c[0] for c in GUESS_CASES])
def test_bad_guess(case_id, guess, error, names):
    expect(error, names, olado.solve, Walk(), solver="slsqp", guess=guess)


def test_result_of_another_problem_as_guess():
    other = olado.solve(Walk(N=6), solver="slsqp")
    expect(PDE, ["guess()", "'u'", "expected shape (4, 1)", "(6, 1)"], olado.solve, Walk(), solver="slsqp",
           guess=other)


# ---------------------------------------------------------------------------- faults in user functions
STAGE_FUNCTIONS = {"dynamics": "x_next", "stage_cost": "cost"}


def _stage_value_for(function, factory):
    if function == "stage_cost":  # a scalar function: the same mistakes, one entry
        return lambda k, x, u: (lambda v: v[0] if isinstance(v, np.ndarray) and v.shape == (1,) else v)(
            factory(k, x, u))
    return factory


FAULT_CASES = [(f, label) for f in STAGE_FUNCTIONS for label in STAGE_VALUES
               if not (f == "stage_cost" and label in ("wrong-shape",))]


@pytest.mark.parametrize("function,label", FAULT_CASES, ids=[f"{f}-{lbl}" for f, lbl in FAULT_CASES])
def test_stage_function_returning_the_wrong_thing(function, label):
    factory, words = STAGE_VALUES[label]
    cls = walk_returning(function, _stage_value_for(function, factory))
    error = NonFiniteEvaluationError if label == "nan" else PDE
    expect(error, [f"{function}()", "k=0", f"'{STAGE_FUNCTIONS[function]}'", *words],
           olado.solve, cls(), solver="slsqp")


def test_final_cost_returning_none_says_so():
    cls = walk_returning("final_cost", lambda x: None)
    err = expect(PDE, ["final_cost()", "'cost'", "returned None"], olado.solve, cls(), solver="slsqp")
    assert "nan" not in str(err)


def test_final_cost_returning_complex():
    cls = walk_returning("final_cost", lambda x: complex(x[0], 1.0))
    expect(PDE, ["final_cost()", "'cost'", "complex"], olado.solve, cls(), solver="slsqp")


def test_complex_dynamics_are_refused_not_truncated():
    """Before: numpy dropped the imaginary parts with a warning per call and the solve reported
    success. Now the first evaluation is an error naming function, stage and array."""
    cls = walk_returning("dynamics", lambda k, x, u: x + u + (1e-3j if k == 2 else 0))
    expect(PDE, ["dynamics()", "k=2", "'x_next'", "complex", "0.001j"], olado.solve, cls(), solver="slsqp")


def test_vectorized_complex_dynamics_name_the_first_complex_stage():
    class V(VectorizedWalk):
        def dynamics(self, k, x, u):
            out = (x + u).astype(complex)
            out[k == 3] += 1j
            return out

    p = V()
    X, U = np.zeros((5, 1)), np.zeros((4, 1))
    expect(PDE, ["dynamics()", "k=3", "'x_next'", "complex"], p.eval_dynamics, X, U)


def test_stage_constraints_returning_none_entries():
    class C(ConstrainedWalk):
        def stage_constraints(self, k, x, u):
            return [None]

    expect(PDE, ["stage_constraints()", "k=0", "'g'", "None"], olado.solve, C(), solver="slsqp")


def test_final_constraints_wrong_shape():
    class C(ConstrainedWalk):
        def final_constraints(self, x):
            return np.array([x[0], 1.0])

    expect(PDE, ["final_constraints()", "'gN'", "expected shape (1,)", "(2,)"], olado.solve, C(), solver="slsqp")


def test_jacobian_not_a_tuple():
    expect(PDE, ["dynamics_jacobian()", "k=0", "tuple of 2 arrays"], olado.solve, JacobianNotATuple(),
           solver="slsqp")


def test_complex_hessian_block():
    p = ComplexHessian()
    X, U = p.simulate(np.zeros((4, 1))), np.zeros((4, 1))
    expect(PDE, ["stage_hessian()", "k=0", "'hxx'", "complex"], p.eval_stage_hessians, X, U, 1.0,
           np.zeros((4, 1)))


def test_gradient_returning_none():
    cls = walk_returning("final_cost_gradient", lambda x: None)
    expect(PDE, ["final_cost_gradient()", "returned None"], cls().eval_final_cost_gradient, np.zeros(1))


@pytest.mark.parametrize("cls,error", [(RaisesItsOwn, UsersOwnError), (RaisesKeyError, KeyError)],
                         ids=["own-exception", "key-error"])
def test_users_own_exception_passes_through_unchanged(cls, error):
    with pytest.raises(error) as info:
        olado.solve(cls(), solver="slsqp")
    assert type(info.value) is error      # not wrapped, not converted


class NaNAtStart(Walk):
    def stage_cost(self, k, x, u):
        return float("nan") if not np.any(u) else super().stage_cost(k, x, u)


@pytest.mark.parametrize("solver", ["pdmin", "gradient"])
def test_nan_at_the_initial_point_is_a_status_for_control_space_methods(solver):
    result = olado.solve(NaNAtStart(), solver=solver)
    assert result.status is Status.INVALID_PROBLEM and not result.success
    assert "non-finite" in result.message and "stage_cost" in result.message


@pytest.mark.parametrize("solver", ["sqp", "ipopt"])
def test_nan_at_the_initial_point_is_the_typed_error_for_simultaneous_methods(solver):
    expect(NonFiniteEvaluationError, ["stage_cost()", "k=0", "'cost'", "non-finite"], olado.solve,
           NaNAtStart(), solver=solver)


def test_nan_at_trial_points_is_survived():
    """NaN only far from the solution: IPOPT backtracks and converges (a status, not an error)."""
    class Cliff(Walk):
        def dynamics(self, k, x, u):
            return x + u if abs(u[0]) < 3.0 else np.array([np.nan])

    result = olado.solve(Cliff(), solver="ipopt", tol=1e-10)
    assert result.success
    reference = olado.solve(Walk(), solver="ipopt", tol=1e-10)
    assert abs(result.objective - reference.objective) < 1e-8


def test_result_type_is_unchanged_for_good_problems():
    result = olado.solve(Walk(), solver="slsqp")
    assert isinstance(result, Result) and result.success
