"""Automatic scaling (seed 004; olado/problems/scaling.py, olado/solvers/scaled.py): the scaled
problem's derivatives against finite differences, the maps between the two problems, eq. (16)
against a dense numpy computation, and scaled solves against unscaled ones."""

import numpy as np
import pytest

import olado
from olado.errors import ConfigError
from olado.problems import DOCP, check_derivatives, get_problems
from olado.problems.nlp import StructuredNLP
from olado.problems.scaling import (ScaledDOCP, compute_scaling, condition_number, condition_ratio,
                                    scale_problem, start_point, transform)


class BadlyScaled(DOCP):
    """A cart in metres with a heat-rate-like positive constraint 2 exp(x1/500) - 0.5 >= 0
    (> -1 everywhere: declared positive), a control limit 1e4 - u^2 >= 0, a final equality
    x2 = 0 and a cost that pulls x1 towards -1000 (so the positive constraint is active)."""

    name = "badly-scaled"
    positive_constraints = {"stage": [0]}
    h = 0.5

    def __init__(self, N=30):
        super().__init__(2, 1, N, [1000.0, 0.0], ([-2000.0, -500.0], [2000.0, 500.0]), (-150.0, 150.0),
                         n_stage_constraints=2, n_final_constraints=1, final_equalities=[0])

    def dynamics(self, k, x, u):
        h = self.h
        return np.array([x[0] + h * x[1], x[1] + h * (u[0] - 0.5 * np.sin(x[0] / 100.0) * x[1])])

    def dynamics_jacobian(self, k, x, u):
        h = self.h
        s, c = np.sin(x[0] / 100.0), np.cos(x[0] / 100.0)
        A = np.array([[1.0, h], [-h * 0.5 * c / 100.0 * x[1], 1.0 - h * 0.5 * s]])
        return A, np.array([[0.0], [h]])

    def stage_cost(self, k, x, u):
        return self.h * (1e-3 * (x[0] + 1000.0) ** 2 + 0.1 * u[0] ** 2)

    def stage_cost_gradient(self, k, x, u):
        return np.array([self.h * 2e-3 * (x[0] + 1000.0), 0.0]), np.array([self.h * 0.2 * u[0]])

    def final_cost(self, x):
        return 0.0

    def final_cost_gradient(self, x):
        return np.zeros(2)

    def stage_constraints(self, k, x, u):
        return np.array([2.0 * np.exp(x[0] / 500.0) - 0.5, 1e4 - u[0] ** 2])

    def stage_constraints_jacobian(self, k, x, u):
        return (np.array([[2.0 * np.exp(x[0] / 500.0) / 500.0, 0.0], [0.0, 0.0]]),
                np.array([[0.0], [-2.0 * u[0]]]))

    def final_constraints(self, x):
        return np.array([x[1]])

    def final_constraints_jacobian(self, x):
        return np.array([[0.0, 1.0]])


METHODS = ("iso", "jrn", "pjrn", "auto")


def _scaled_point(problem, scaled, noise=0.0, seed=1):
    X, U = start_point(problem)
    U = U + noise * np.random.default_rng(seed).standard_normal(U.shape)
    X = problem.simulate(U)
    return scaled.to_scaled(X, U)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("positive", [None, "log", "ip"])
def test_scaled_derivatives_match_finite_differences(method, positive):
    p = BadlyScaled(N=12)
    s = scale_problem(p, method, positive=positive)
    Xs, Us = _scaled_point(p, s, noise=20.0)
    report = check_derivatives(s, X=Xs, U=Us, rtol=2e-5, atol=1e-7, hessians=False)
    assert report.ok, str(report)
    assert _hessian_error(s, Xs, Us) < 1e-6


def _hessian_error(s, Xs, Us, h=1e-6):
    """Largest difference, relative to the largest entry, between the scaled problem's stage and
    final Hessians of the Lagrangian and central differences of its (checked) analytic
    gradients, with random multipliers."""
    rng = np.random.default_rng(7)
    N, n, m = s.N, s.n, s.m
    P, L, lN = rng.standard_normal((N, n)), rng.standard_normal((N, s.r)), rng.standard_normal(s.rN)
    Hxx, Hxu, Huu = s.eval_stage_hessians(Xs, Us, 1.3, P, L)
    H = np.concatenate([np.concatenate([Hxx, Hxu], 2), np.concatenate([np.transpose(Hxu, (0, 2, 1)), Huu], 2)], 1)
    Z = np.concatenate([Xs[:-1], Us], 1)
    F = np.empty_like(H)
    for j in range(n + m):
        Zp, Zm = Z.copy(), Z.copy()
        Zp[:, j] += h
        Zm[:, j] -= h
        gp = s._stage_lagrangian_gradients(Zp[:, :n], Zp[:, n:], 1.3, P, L, None)
        gm = s._stage_lagrangian_gradients(Zm[:, :n], Zm[:, n:], 1.3, P, L, None)
        F[:, :, j] = (gp - gm) / (2 * h)
    err = np.abs(H - F).max() / max(1.0, np.abs(H).max())

    def grad_final(x):
        g = 1.3 * s.eval_final_cost_gradient(x)
        return g + lN @ s.eval_final_constraint_jacobian(x) if s.rN else g
    HN = s.eval_final_hessian(Xs[-1], 1.3, lN)
    FN = np.column_stack([(grad_final(Xs[-1] + h * e) - grad_final(Xs[-1] - h * e)) / (2 * h) for e in np.eye(n)])
    return max(err, np.abs(HN - FN).max() / max(1.0, np.abs(HN).max()))


def test_nonlinear_transforms_reach_the_constraints():
    p = BadlyScaled(N=8)
    s = scale_problem(p, "auto")
    assert s.scaling.stage_kind == ("ip", "linear")
    X, U = start_point(p)
    g = p.eval_stage_constraints(X, U)
    n = s.scaling.stage_power[0]
    assert n == max(1, np.ceil(np.log1p(g[:, 0].max())))
    Xs, Us = s.to_scaled(X, U)
    gs = s.eval_stage_constraints(Xs, Us)
    np.testing.assert_allclose(gs[:, 0], (1.0 + g[:, 0]) ** (1.0 / n) - 1.0, rtol=1e-13)
    np.testing.assert_allclose(gs[:, 1], s.scaling.stage_rows[:, 1] * g[:, 1], rtol=1e-13)
    # eq. (9): log(1 + g), derivative 1/(1 + g), second -1/(1 + g)^2
    phi, d1, d2 = transform(("log",), np.array([[0.5]]), np.array([1.0]))
    assert (phi[0, 0], d1[0, 0], d2[0, 0]) == pytest.approx((np.log(1.5), 1 / 1.5, -1 / 2.25))


@pytest.mark.parametrize("name", ["vanderpol", "lq-box"])
@pytest.mark.parametrize("method", METHODS)
def test_builtin_scaled_derivatives(name, method):
    p = get_problems()[name](N=15)
    s = scale_problem(p, method)
    Xs, Us = _scaled_point(p, s)
    report = check_derivatives(s, X=Xs, U=Us, rtol=1e-5, atol=1e-7, hessians=False)
    assert report.ok, str(report)
    assert _hessian_error(s, Xs, Us) < 1e-6


@pytest.mark.parametrize("method", METHODS)
def test_scale_unscale_identities(method):
    p = BadlyScaled(N=10)
    s = scale_problem(p, method)
    rng = np.random.default_rng(3)
    X, U = rng.standard_normal((11, 2)) * 300, rng.standard_normal((10, 1)) * 50
    Xb, Ub = s.to_original(*s.to_scaled(X, U))
    np.testing.assert_allclose(Xb, X, rtol=1e-14, atol=1e-11)
    np.testing.assert_allclose(Ub, U, rtol=1e-14, atol=1e-12)
    Xs, Us = s.to_scaled(X, U)
    c = s.scaling.objective
    assert s.objective(Xs, Us) == pytest.approx(c * p.objective(X, U), rel=1e-13)
    # dynamics defects: the scaled one is the original divided by the next state's scale
    np.testing.assert_allclose(s.eval_dynamics(Xs, Us) - Xs[1:], (p.eval_dynamics(X, U) - X[1:]) / s.scaling.dx[1:],
                               rtol=1e-10, atol=1e-12)
    # simulation commutes with the change of variables, bounds and x0 map with it
    np.testing.assert_allclose(s.simulate(Us), s.to_scaled(p.simulate(U), U)[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s.to_original(s.x_lower, s.u_lower)[0], p.x_lower, rtol=1e-14)
    np.testing.assert_allclose(s.x0 * s.scaling.dx[0] + s.scaling.sx[0], p.x0, rtol=1e-14)


def test_iso_puts_bounded_variables_in_the_unit_interval():
    p = BadlyScaled(N=10)
    s = scale_problem(p, "iso")
    assert np.all(s.x_lower[1:] == 0.0) and np.all(s.x_upper[1:] == 1.0)
    assert np.all(s.u_lower == 0.0) and np.all(s.u_upper == 1.0)
    np.testing.assert_allclose(s.scaling.dx[0], [4000.0, 1000.0])   # eq. (4): x_U - x_L


def _dense_eq2(problem, X, U):
    """Eq. (2) as a dense matrix, built from the stage arrays directly (not through the NLP
    view): rows objective, dynamics (f^k - x^{k+1}), stage and final constraints; columns
    x^1 u^1 ... in the order u^0, x^1, u^1, ..., x^N (x^0 is fixed)."""
    p = problem
    N, n, m, r, rN = p.N, p.n, p.m, p.r, p.rN
    cols = N * (n + m)
    xcol = lambda k: m + (k - 1) * (n + m) + np.arange(n)          # noqa: E731 - x^k, k >= 1
    ucol = lambda k: k * (n + m) + np.arange(m)                    # noqa: E731
    A, B = p.eval_dynamics_jacobians(X, U)
    Cx, Cu = p.eval_stage_constraint_jacobians(X, U)
    lx, lu = p.eval_stage_cost_gradients(X, U)
    J = np.zeros((1 + N * n + N * r + rN, cols))
    for k in range(N):
        J[0, ucol(k)] = lu[k]
        if k:
            J[0, xcol(k)] += lx[k]
        rows = 1 + k * n + np.arange(n)
        J[np.ix_(rows, ucol(k))] = B[k]
        if k:
            J[np.ix_(rows, xcol(k))] = A[k]
        J[np.ix_(rows, xcol(k + 1))] -= np.eye(n)
        rows = 1 + N * n + k * r + np.arange(r)
        J[np.ix_(rows, ucol(k))] = Cu[k]
        if k:
            J[np.ix_(rows, xcol(k))] = Cx[k]
    J[0, xcol(N)] += p.eval_final_cost_gradient(X[-1])
    J[np.ix_(1 + N * n + N * r + np.arange(rN), xcol(N))] = p.eval_final_constraint_jacobian(X[-1])
    return J


@pytest.mark.parametrize("method", ["iso", "pjrn", "auto"])
def test_condition_ratio_against_dense_numpy(method):
    p = BadlyScaled(N=10)
    X, U = start_point(p)
    s = scale_problem(p, method, X, U)
    Xs, Us = s.to_scaled(X, U)
    expected0 = np.linalg.cond(_dense_eq2(p, X, U))
    expected1 = np.linalg.cond(_dense_eq2(s, Xs, Us))
    cr = condition_ratio(p, s, X, U)
    assert cr.kind == "dense SVD"
    assert cr.original == pytest.approx(expected0, rel=1e-8)
    assert cr.scaled == pytest.approx(expected1, rel=1e-8)
    assert cr.ratio == pytest.approx(expected0 / expected1, rel=1e-8)


@pytest.mark.parametrize("name", ["vanderpol", "lq-box"])
def test_condition_estimate_agrees_with_the_dense_svd(name):
    """The sparse estimate (Lanczos on the Gram matrix) on moderately conditioned cases (it
    squares the condition number, so it is not meant for 1e8 and beyond)."""
    p = get_problems()[name](N=20)
    X, U = start_point(p)
    s = scale_problem(p, "iso", X, U)
    dense = condition_ratio(p, s, X, U)
    est = condition_ratio(p, s, X, U, dense_entries=0)
    assert est.kind.startswith("estimate") and dense.kind == "dense SVD"
    assert est.original == pytest.approx(dense.original, rel=1e-6)
    assert est.scaled == pytest.approx(dense.scaled, rel=1e-6)


def test_condition_number_of_a_known_matrix():
    import scipy.sparse as sp
    M = sp.csc_matrix(np.diag([1e3, 2.0, 0.5]))
    assert condition_number(M)[0] == pytest.approx(2e3)


def test_none_is_the_identity_and_changes_nothing():
    p = get_problems()["vanderpol"](N=30)
    sc = compute_scaling(p, "none")
    assert sc.objective == 1.0 and np.all(sc.dx == 1.0) and np.all(sc.sx == 0.0)
    a = olado.solve(get_problems()["vanderpol"](N=30), solver="sqp")
    b = olado.solve(get_problems()["vanderpol"](N=30), solver="sqp", scaling="none")
    assert a.iterations == b.iterations and np.array_equal(a.x, b.x) and "scaling" not in b.info


def test_unknown_scaling_names_the_key():
    with pytest.raises(ConfigError, match="scaling"):
        olado.solve(get_problems()["vanderpol"](N=10), solver="sqp", scaling="equilibrate")
    with pytest.raises(ConfigError, match="scaling"):
        compute_scaling(get_problems()["vanderpol"](N=10), "bogus")


def _solutions_agree(a, b, *, rtol=1e-5, atol=1e-6, multipliers=("dynamics", "stage_constraints", "final_constraints")):
    assert a.success and b.success, (a.message, b.message)
    assert a.objective == pytest.approx(b.objective, rel=1e-6, abs=1e-9)
    scale_x = np.maximum(1.0, np.abs(b.x).max(axis=0))
    scale_u = np.maximum(1.0, np.abs(b.u).max(axis=0))
    np.testing.assert_allclose(a.x / scale_x, b.x / scale_x, rtol=rtol, atol=atol)
    np.testing.assert_allclose(a.u / scale_u, b.u / scale_u, rtol=rtol, atol=atol)
    for key in multipliers:
        ma, mb = np.asarray(a.multipliers[key]), np.asarray(b.multipliers[key])
        if ma.size:
            big = max(1.0, float(np.abs(mb).max()))
            np.testing.assert_allclose(ma / big, mb / big, atol=1e-4, err_msg=key)


@pytest.mark.parametrize("solver", ["sqp", "ipopt"])
@pytest.mark.parametrize("method", ["iso", "pjrn", "auto"])
def test_scaled_solution_maps_back_to_the_unscaled_one(solver, method):
    pytest.importorskip("cyipopt") if solver == "ipopt" else None
    ref = olado.solve(BadlyScaled(N=30), solver=solver, tol=1e-10)
    res = olado.solve(BadlyScaled(N=30), solver=solver, scaling=method, tol=1e-10)
    _solutions_agree(res, ref)
    # the positive constraint is active somewhere, so its multiplier map is exercised
    assert np.any(np.abs(ref.multipliers["stage_constraints"][:, 0]) > 1e-3)
    assert res.certificate is not None and res.certificate.holds
    info = res.info["scaling"]
    assert info["method"] == method and info["condition"]["ratio"] > 0


@pytest.mark.parametrize("name,N", [("lq-box", 40), ("vanderpol", 40)])
@pytest.mark.parametrize("solver", ["sqp", "ipopt"])
def test_builtins_scaled_and_unscaled_agree(name, N, solver):
    pytest.importorskip("cyipopt") if solver == "ipopt" else None
    ref = olado.solve(get_problems()[name](N=N), solver=solver, tol=1e-10)
    res = olado.solve(get_problems()[name](N=N), solver=solver, scaling="auto", tol=1e-10)
    _solutions_agree(res, ref, rtol=1e-4, atol=1e-4, multipliers=("dynamics", "bound_lower_u", "bound_upper_u"))
    if name == "lq-box":   # its control bounds are active: the bound multiplier map is exercised
        assert np.abs(ref.multipliers["bound_upper_u"]).max() + np.abs(ref.multipliers["bound_lower_u"]).max() > 1e-2


@pytest.mark.slow
@pytest.mark.parametrize("config", ["sqp-ip", "ipopt"])
@pytest.mark.parametrize("method", ["auto", "pjrn"])
def test_hang_glider_scaled_reaches_the_unscaled_solution(config, method):
    """The robustness entry (N = 101, its start point) with the preset: the same optimum."""
    from olado.config import load_config, make_solver
    from olado.problems.suites import load_suite

    pytest.importorskip("cyipopt") if config == "ipopt" else None
    entry = next(e for e in load_suite("robustness") if e.name == "hang-glider")
    path = f"{__file__.rsplit('/tests/', 1)[0]}/configs/{config}.ini"
    name = load_config(path).solver
    results = []
    for m in ("none", method):
        problem, guess = entry.build()
        results.append(make_solver(load_config(path, [f"{name}.scaling={m}"])).solve(problem, guess=guess))
    ref, res = results
    _solutions_agree(res, ref, rtol=1e-3, atol=1e-3, multipliers=())


def test_summary_reports_the_condition_ratio():
    res = olado.solve(get_problems()["vanderpol"](N=20), solver="sqp", scaling="iso")
    assert "scaling" in res.summary() and "eq. (16)" in res.summary()


def test_scaled_problem_is_a_docp_with_the_same_structure():
    p = BadlyScaled(N=10)
    s = scale_problem(p, "auto")
    assert isinstance(s, ScaledDOCP) and (s.n, s.m, s.N, s.r, s.rN) == (p.n, p.m, p.N, p.r, p.rN)
    nlp0, nlp1 = StructuredNLP(p), StructuredNLP(s)
    assert np.array_equal(nlp0.jacobian_structure()[0], nlp1.jacobian_structure()[0])
    assert np.array_equal(nlp0.jacobian_structure()[1], nlp1.jacobian_structure()[1])


@pytest.mark.parametrize("solver", ["ddp", "newton", "stagewise-newton", "penalty", "slsqp", "trust-constr"])
def test_every_solver_family_solves_the_scaled_problem(solver):
    """The option is honoured by the shared mechanism (Solver.solve), not per solver: the
    control-space, DDP, penalty and SciPy solvers reach the unscaled optimum."""
    a = olado.solve(get_problems()["vanderpol"](N=20), solver=solver)
    b = olado.solve(get_problems()["vanderpol"](N=20), solver=solver, scaling="auto")
    assert a.success and b.success
    assert b.objective == pytest.approx(a.objective, rel=1e-8)
    assert b.info["scaling"]["method"] == "auto"
    np.testing.assert_allclose(b.u, a.u, atol=1e-4)


class NaNAtStart(BadlyScaled):
    name = "nan-jacobian"

    def stage_constraints_jacobian(self, k, x, u):
        Cx, Cu = super().stage_constraints_jacobian(k, x, u)
        return Cx * np.nan, Cu


def test_a_start_without_derivatives_meets_the_solver_unscaled():
    """No factors at a start point where a Jacobian is not finite: the solver meets the problem as
    it is and answers as it does without scaling (here the SQP's error naming the function)."""
    from olado.errors import NonFiniteEvaluationError
    from olado.solvers.scaled import solve_scaled
    from olado.solvers.sqp.solver import SQPSolver

    with pytest.raises(NonFiniteEvaluationError, match="stage_constraints_jacobian") as unscaled:
        olado.solve(NaNAtStart(N=5), solver="sqp")
    with pytest.raises(NonFiniteEvaluationError, match="stage_constraints_jacobian") as scaled:
        olado.solve(NaNAtStart(N=5), solver="sqp", scaling="auto")
    assert str(scaled.value) == str(unscaled.value)
    # and a solver that returns a status gets the note
    class Quiet(SQPSolver):
        def _solve(self, problem, X0, U0):
            return olado.result.Result(status=olado.result.Status.NUMERICAL_ERROR, message="", objective=np.nan,
                                       x=X0, u=U0)
    p = NaNAtStart(N=5)
    res = solve_scaled(Quiet(scaling="auto"), p, *start_point(p))
    assert res.info["scaling"]["condition"]["note"].startswith("not applied")
