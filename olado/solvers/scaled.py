"""The option ``scaling``: every solver solves the scaled DOCP and returns the original's result.

:meth:`olado.solvers.base.Solver.solve` calls :func:`solve_scaled` when ``scaling`` is not
``none``: the scale factors are computed at the start point and the bounds
(:func:`olado.problems.scaling.compute_scaling`, seed 004), the solver's own ``_solve`` runs on
the :class:`~olado.problems.scaling.ScaledDOCP`, and :func:`unscale_result` maps the point, the
objective and the multipliers back. Olado's certificate then checks the success on the original
problem (Solver.solve), not on the scaled one (the solver runs with ``certify`` off). The same wrapper serves IPOPT: its user-scaling (``obj_scaling_factor``,
``x_scaling``, ``g_scaling``) has neither shifts nor the nonlinear transforms of seed 004 sec. 5,
and one mechanism for every solver gives the same scaled problem to each (docs/scaling.md).
IPOPT's own ``nlp_scaling_method`` is switched off for a scaled solve (the factors would compound).
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import NonFiniteEvaluationError, OladoError
from ..problems.scaling import DENSE_ENTRIES, ScaledDOCP, condition_ratio, compute_scaling, unscale_multipliers
from ..result import Result

#: the condition ratio of eq. (16) is reported for NLPs with at most this many variables (an
#: estimate above DENSE_ENTRIES Jacobian entries); larger ones: olado.problems.scaling.condition_ratio
REPORT_VARIABLES = 20_000


def solve_scaled(solver, problem, X0, U0) -> Result:
    """``solver._solve`` on ``problem`` scaled by ``solver.options.scaling`` from (X0, U0)."""
    t0 = time.perf_counter()
    method = solver.options.scaling
    try:
        scaling = compute_scaling(problem, method, X0, U0)
    except NonFiniteEvaluationError as exc:
        # no derivatives at the start point, no factors: the solver meets the problem as it is
        # (and reports the non-finite evaluation its own way)
        result = solver._solve(problem, X0, U0)
        result.info["scaling"] = {"method": method, "condition": {"note": f"not applied: {exc}"}}
        return result
    scaled = ScaledDOCP(problem, scaling)
    report = scaling_report(problem, scaled, X0, U0)
    report["setup_time_s"] = time.perf_counter() - t0
    Xs, Us = scaled.to_scaled(X0, U0)
    inner = _with_scaled_tolerances(solver, scaling, report)
    result = inner._solve(scaled, Xs, Us)
    return unscale_result(result, scaled, report)


def _with_scaled_tolerances(solver, scaling, report):
    """The solver with its tolerances for the scaled problem: the violation tolerance of
    :func:`scaled_violation_tolerance`, the optimality tolerance times the objective factor
    when that is below 1 (the scaled Lagrangian's gradient is c times the original's: a solver
    with an absolute stopping test, IPOPT, would otherwise stop 1/c too early)."""
    o = solver.options
    changes = {}
    viol = scaled_violation_tolerance(o.constr_viol_tol, scaling)
    if viol != o.constr_viol_tol:
        changes["constr_viol_tol"] = viol
    if scaling.objective < 1.0:
        changes["tol"] = max(o.tol * scaling.objective, min(o.tol, SMALLEST_TOLERANCE))
    report["scaled_tolerances"] = dict(changes)
    if getattr(o, "nlp_scaling_method", "none") != "none":
        # one scaling, not two: IPOPT's gradient-based factors on top of these compound the
        # objective factor (lq-box, N = 400: 1e-8 twice; IPOPT stops at J = 20.8 instead of 16.06)
        changes["nlp_scaling_method"] = "none"
        report["ipopt_nlp_scaling_method"] = "none (replaced by olado's scaling)"
    if getattr(o, "certify", False):
        # the certificate is of the original problem (Solver.solve, after the map back): its
        # spot check of the derivatives measures rounding from the function values, which the
        # shifts of eq. (3) cancel (a state at its shifted bound has the scaled value 0)
        changes["certify"] = False
    return type(solver)(o, **changes) if changes else solver


#: the scaled problem's tolerances are not made smaller than this
SMALLEST_TOLERANCE = 1e-14


def scaled_violation_tolerance(tol, scaling):
    """The constraint violation tolerance for the scaled problem: ``tol`` times the smallest
    factor between a scaled and an original constraint row (1/dx of the dynamics rows, w of the
    constraint rows, w/n for the inverse power at g = 0), so that a violation the solver accepts
    in the scaled problem is within ``tol`` in the original one (rows are only tightened; not
    below SMALLEST_TOLERANCE). IPOPT checks its unscaled violation for the same reason."""
    factors = [1.0 / np.max(scaling.dx[1:])] if scaling.dx.shape[0] > 1 else []
    for rows, kinds, power in ((scaling.stage_rows, scaling.stage_kind, scaling.stage_power),
                               (scaling.final_rows, scaling.final_kind, scaling.final_power)):
        if np.size(rows):
            at_zero = np.where(np.asarray(kinds) == "ip", 1.0 / np.asarray(power, dtype=float), 1.0)
            factors.append(float(np.min(rows * at_zero)))
    smallest = min([1.0] + factors)
    return max(tol * smallest, min(tol, SMALLEST_TOLERANCE))


def scaling_report(problem, scaled, X0, U0) -> dict:
    """The scale factors and seed 004's eq. (16) at the start point (for the Result's info)."""
    report = {"method": scaled.scaling.method, "factors": scaled.scaling.summary()}
    n_vars = problem.N * (problem.n + problem.m)
    if n_vars > REPORT_VARIABLES:
        report["condition"] = {"note": f"not computed ({n_vars} variables > {REPORT_VARIABLES}); "
                                       "olado.problems.scaling.condition_ratio computes it"}
        return report
    try:
        report["condition"] = condition_ratio(problem, scaled, X0, U0, dense_entries=DENSE_ENTRIES).to_dict()
    except (OladoError, ArithmeticError, ValueError) as exc:   # a start point where a Jacobian fails
        report["condition"] = {"note": f"not computed: {exc}"}
    return report


def unscale_result(result: Result, scaled: ScaledDOCP, report: dict) -> Result:
    """The scaled problem's Result in the original units: the trajectories (eq. (3)), the
    objective (J = J~ / c), the multipliers (:func:`olado.problems.scaling.unscale_multipliers`),
    the constraint violation recomputed on the original problem. The solver's own KKT residual,
    history and certificate stay in scaled units (info["scaling"] says so); the certificate is
    redone on the original problem by Solver.solve."""
    problem = scaled.inner
    X, U = scaled.to_original(result.x, result.u)
    result.x, result.u = X, U
    result.objective = float(result.objective) / scaled.scaling.objective
    if result.multipliers:
        try:
            result.multipliers = unscale_multipliers(scaled, result.multipliers, X, U)
        except OladoError as exc:
            report["multipliers_note"] = f"left in scaled units: {exc}"
    result.max_constraint_violation = _violation(problem, X, U, result.max_constraint_violation)
    if result.certificate is not None:
        report["scaled_certificate"] = result.certificate.to_dict()
        result.certificate = None
    report["scaled_units"] = "kkt_residual, history and scaled_certificate are the scaled problem's"
    result.info["scaling"] = report
    return result


def _violation(problem, X, U, fallback):
    """The max-norm constraint violation of the original problem at (X, U)."""
    from .diagnosis import ConstraintValues, largest_violation_of   # noqa: PLC0415

    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(U))):
        return fallback
    try:
        return largest_violation_of(problem, ConstraintValues.at(problem, X, U))[0]
    except OladoError:
        return fallback
