"""A status for every fault (issues 13 and 18): the faults the robustness set found
(benchmarks/RESULTS.md, "Robustness set", notes), reproduced on small cases of the set itself.

* a KKT back-end that fails inside the QP (a singular matrix, a Krylov solve that does not
  converge) was a raw ``KKTSolveError`` out of ``Solver.solve``: now a failed QP, which the SQP
  answers as it answers a failed Riccati factorization (a larger Hessian shift, the elastic QP,
  the restoration phase), ending with a status whose sentence names the back-end;
* a long Krylov solve did not check ``max_time``: now every Krylov iteration does;
* the penalty methods raised ``NonFiniteEvaluationError`` when the start's controls simulate to
  non-finite states (the zambezi SIF start clipped into the control bounds): now INVALID_PROBLEM
  with a sentence naming the function, stage and array, as PDMIN and the reduced-gradient methods.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from olado.problems import PROBLEMS
from olado.problems.suites import load_suite
from olado.result import Status
from olado.solvers.control.pdmin import PDMINSolver
from olado.solvers.control.penalty import PenaltySolver
from olado.solvers.sqp.solver import SQPSolver


def entry(name):
    """(problem, guess) of a robustness-set entry."""
    return next(e for e in load_suite("robustness") if e.name == name).build()


# ---------------------------------------------------------------------------- KKT back-ends in the SQP
@pytest.mark.slow
def test_singular_kkt_matrix_of_an_infeasible_problem_is_diagnosed():
    """steering-too-short (a final state out of reach in N steps): the final rows are dependent
    on the dynamics, the sparse KKT matrix exactly singular ("the KKT matrix is singular" was
    raised out of solve). With the dual regularization the back-end solves it like the Riccati
    recursion, and the SQP reports the problem infeasible, naming the violated final constraint."""
    problem, guess = entry("steering-too-short")
    res = SQPSolver(qp="mehrotra", kkt="superlu-reduced", max_time=60.0).solve(problem, guess=guess)
    assert res.status is Status.INFEASIBLE, res.message
    assert "final_constraints" in res.message
    assert res.infeasibility is not None and "final_constraints" in {a.array for a in res.infeasibility.arrays}


@pytest.mark.slow
def test_singular_unreduced_kkt_matrix_ends_with_a_status():
    """The same with the unreduced system (24) (superlu-full): its regularized solves of the
    relaxed QP leave a defect near the rounding test of the equality rows. Since the
    infeasibility-verdict changes the SQP no longer reaches a verdict here within 10 s (the
    robustness set records max_iterations; docs/structure-exploiting-sqp.md); what this test
    holds is that the singular matrix gives a status with its reason, never the exception."""
    problem, guess = entry("steering-too-short")
    res = SQPSolver(qp="mehrotra", kkt="superlu-full", max_time=10.0).solve(problem, guess=guess)
    assert res.status in (Status.INFEASIBLE, Status.NUMERICAL_ERROR, Status.MAX_TIME, Status.MAX_ITERATIONS), res.message
    assert res.message
    if res.status is Status.INFEASIBLE:
        assert "final_constraints" in res.message


def test_krylov_solve_that_does_not_converge_is_a_status_naming_the_backend():
    """GMRES that cannot meet its tolerance in the QP (robot-arm: at the QP's starting point,
    the KKTSolveError was raised out of solve): every QP fails, the inertia correction and the
    restoration phase cannot help, and the SQP ends NUMERICAL_ERROR with the back-end's sentence."""
    problem = PROBLEMS["vanderpol"](N=20)
    solver = SQPSolver(qp="mehrotra", kkt="gmres", max_time=60.0,
                       qp_options={"kkt_options": {"maxiter": 3, "rtol": 1e-300}})
    res = solver.solve(problem)
    assert res.status is Status.NUMERICAL_ERROR, res.message
    assert "KKT solver 'gmres'" in res.message and "did not converge" in res.message
    assert "QP subproblem" in res.message


# ---------------------------------------------------------------------------- max_time in a Krylov solve
def test_max_time_is_checked_inside_a_long_krylov_solve():
    """One GMRES solve with a tolerance it cannot meet runs its whole maxiter (here 10^6
    iterations, minutes): the time limit must stop it, not the end of the solve. A correctness
    bound (limit + a generous margin for the Result's assembly on a loaded machine), not a speed
    assertion."""
    problem = PROBLEMS["vanderpol"](N=200)
    limit = 1.0
    solver = SQPSolver(qp="mehrotra", kkt="gmres", max_time=limit,
                       qp_options={"kkt_options": {"rtol": 1e-300, "maxiter": 10**6}})
    t0 = time.perf_counter()
    res = solver.solve(problem)
    elapsed = time.perf_counter() - t0
    assert res.status is Status.MAX_TIME, res.message
    assert elapsed < limit + 10.0
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.u))     # the last accepted iterate


# ---------------------------------------------------------------------------- sequential methods
@pytest.mark.parametrize("augmented", [False, True])
def test_penalty_method_at_controls_that_cannot_be_simulated(augmented):
    """zambezi9 N = 72 from the SIF start: the controls clipped into their bounds let the volumes
    diverge (inf at stage 35). The penalty method (sequential: x = x(u)) has no point to start
    from -- INVALID_PROBLEM, naming simulate(), the stage and the array, instead of the
    NonFiniteEvaluationError it raised."""
    problem, guess = entry("zambezi9-N72-sif")
    res = PenaltySolver(augmented_lagrangian=augmented).solve(problem, guess=guess)
    assert res.status is Status.INVALID_PROBLEM
    for name in ("simulate()", "stage k=35", "array 'x'", "clipped into their bounds", "sqp, ipopt"):
        assert name in res.message, name
    np.testing.assert_array_equal(res.x, guess[0])          # the guess's states, unchanged
    assert np.all(res.u >= problem.u_lower) and np.all(res.u <= problem.u_upper)


def test_pdmin_refuses_state_bounds_without_simulating():
    """PDMIN's INVALID_PROBLEM for a problem with state bounds simulated the clipped controls to
    fill its Result, and raised there on the same start."""
    problem, guess = entry("zambezi9-N72-sif")
    res = PDMINSolver().solve(problem, guess=guess)
    assert res.status is Status.INVALID_PROBLEM
    assert "bounds on the states" in res.message
