"""The NLP-view solvers (IPOPT, SciPy SLSQP and trust-constr; paper 001 secs. 4.1, 4.3).

Checked against an independent dense KKT solve (equality-constrained LQ problem), against each
other (bounds and nonlinear inequalities), for their statuses, the missing-cyipopt error, and for
the multipliers they return (stationarity of the Lagrangian, eq. (28), on the NLP view).
"""

import sys

import numpy as np
import pytest

from olado.errors import ConfigError, SolverNotAvailableError
from olado.problems import DOCP, StructuredNLP
from olado.result import Status
from olado.solvers.registry import get_solver_class
from fixtures import REPO

cyipopt = pytest.importorskip("cyipopt")  # noqa: F841 - the IPOPT tests need the back-end

SOLVERS = ["ipopt", "slsqp", "trust-constr"]


def make(name, **options):
    return get_solver_class(name)(**options)


def tight(name):
    """Options for a tight solve: SLSQP's own stopping accuracy (ftol) is set explicitly."""
    return {"tol": 1e-10, "ftol": 1e-15} if name == "slsqp" else {"tol": 1e-10}


# ============================================================================ test problems
class LQ(DOCP):
    """Discrete double integrator, quadratic tracking cost, optional final equality v(N) = 0.

    x^{k+1} = A x^k + B u^k;  f0^k = 0.5 (x - r_k)' Q (x - r_k) + 0.5 R u^2;  F = 0.5 x' P x.
    """

    name = "lq"
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.005], [0.1]])
    Q = np.diag([1.0, 0.1])
    R = 0.01
    P = np.diag([5.0, 1.0])

    def __init__(self, N=8, final_rest=True, **kw):
        super().__init__(2, 1, N, [0.0, 0.0], n_final_constraints=int(final_rest),
                         final_equalities=[0] if final_rest else None, **kw)
        self.ref = np.column_stack([np.linspace(0.2, 1.0, N), np.zeros(N)])

    def dynamics(self, k, x, u):
        return self.A @ x + self.B @ u

    def stage_cost(self, k, x, u):
        d = x - self.ref[k]
        return 0.5 * d @ self.Q @ d + 0.5 * self.R * u[0] ** 2

    def final_cost(self, x):
        return 0.5 * x @ self.P @ x

    def final_constraints(self, x):
        return np.array([x[1]])

    def dynamics_jacobian(self, k, x, u):
        return self.A, self.B

    def stage_cost_gradient(self, k, x, u):
        return self.Q @ (x - self.ref[k]), np.array([self.R * u[0]])

    def final_cost_gradient(self, x):
        return self.P @ x

    def final_constraints_jacobian(self, x):
        return np.array([[0.0, 1.0]])

    def stage_hessian(self, k, x, u, sigma, p, lam):
        return sigma * self.Q, np.zeros((2, 1)), sigma * np.array([[self.R]])

    def final_hessian(self, x, sigma, lam):
        return sigma * self.P


def lq_dense_reference(p: LQ):
    """Solve the equality-constrained LQ problem by one dense KKT system, built directly from
    the problem data in its own variable order w = (x^1..x^N, u^0..u^{N-1}).

    Returns X, U, the dynamics multipliers (N, n) and the final multiplier, with the Lagrangian
    J + nu . (A x^k + B u^k - x^{k+1}) + nu_N . g^N (the NLP view's sign convention)."""
    n, m, N = p.n, p.m, p.N
    nx, nw = N * n, N * n + N * m
    xi = lambda k: slice((k - 1) * n, k * n)          # x^k, k = 1..N  # noqa: E731
    ui = lambda k: slice(nx + k * m, nx + (k + 1) * m)  # u^k           # noqa: E731
    H = np.zeros((nw, nw))
    h = np.zeros(nw)
    for k in range(1, N):
        H[xi(k), xi(k)] += p.Q
        h[xi(k)] -= p.Q @ p.ref[k]
    H[xi(N), xi(N)] += p.P
    for k in range(N):
        H[ui(k), ui(k)] += p.R
    rows = N * n + p.rN
    E = np.zeros((rows, nw))
    e = np.zeros(rows)
    for k in range(N):
        r = slice(k * n, (k + 1) * n)
        if k == 0:
            e[r] = -p.A @ p.x0
        else:
            E[r, xi(k)] = p.A
        E[r, ui(k)] = p.B
        E[r, xi(k + 1)] = -np.eye(n)
    if p.rN:
        E[N * n, xi(N)] = [0.0, 1.0]
    K = np.block([[H, E.T], [E, np.zeros((rows, rows))]])
    sol = np.linalg.solve(K, np.concatenate([-h, e]))
    w, nu = sol[:nw], sol[nw:]
    X = np.vstack([p.x0, w[:nx].reshape(N, n)])
    U = w[nx:].reshape(N, m)
    return X, U, nu[: N * n].reshape(N, n), nu[N * n:]


class BoundedLQ(LQ):
    """The LQ problem with active control bounds, an active state bound and an active mixed
    stage inequality g^k = 0.25 - x_1 - 0.05 u >= 0."""

    name = "bounded-lq"

    def __init__(self, N=10):
        self.ref = np.column_stack([np.linspace(0.2, 1.0, N), np.zeros(N)])
        DOCP.__init__(self, 2, 1, N, [0.0, 0.0], u_bounds=(-1.5, 1.5),
                      x_bounds=([-np.inf, -0.5], [np.inf, 0.5]), n_stage_constraints=1)

    def stage_constraints(self, k, x, u):
        return np.array([0.25 - x[0] - 0.05 * u[0]])

    def stage_constraints_jacobian(self, k, x, u):
        return np.array([[-1.0, 0.0]]), np.array([[-0.05]])


class Cart(DOCP):
    """A small nonlinear problem: x = (p, v), x^{k+1} = (p + dt v, v + dt (u cos p - 0.3 v |v|_s)),
    with a smooth |v|_s = sqrt(v^2 + 0.01), cost 0.5 (p - 1)^2 + 0.5 v^2 + 0.05 u^2 per stage,
    the nonlinear inequality 0.3 - v^2 - 0.2 u^2 >= 0, control bounds and a final position p = 1
    (equality). First derivatives analytic, second derivatives by finite differences."""

    name = "cart"
    dt = 0.2

    def __init__(self, N=15):
        super().__init__(2, 1, N, [0.0, 0.0], u_bounds=(-0.3, 1.0), n_stage_constraints=1,
                         n_final_constraints=1, final_equalities=[0])

    @staticmethod
    def _abs(v):
        return np.sqrt(v * v + 0.01)

    def dynamics(self, k, x, u):
        p, v = x
        return np.array([p + self.dt * v, v + self.dt * (u[0] * np.cos(p) - 0.3 * v * self._abs(v))])

    def dynamics_jacobian(self, k, x, u):
        p, v = x
        s = self._abs(v)
        dvv = 1 - self.dt * 0.3 * (s + v * v / s)
        A = np.array([[1.0, self.dt], [-self.dt * u[0] * np.sin(p), dvv]])
        B = np.array([[0.0], [self.dt * np.cos(p)]])
        return A, B

    def stage_cost(self, k, x, u):
        return 0.5 * (x[0] - 1.0) ** 2 + 0.5 * x[1] ** 2 + 0.05 * u[0] ** 2

    def stage_cost_gradient(self, k, x, u):
        return np.array([x[0] - 1.0, x[1]]), np.array([0.1 * u[0]])

    def final_cost(self, x):
        return 2.0 * x[1] ** 2

    def final_cost_gradient(self, x):
        return np.array([0.0, 4.0 * x[1]])

    def stage_constraints(self, k, x, u):
        return np.array([0.3 - x[1] ** 2 - 0.2 * u[0] ** 2])

    def stage_constraints_jacobian(self, k, x, u):
        return np.array([[0.0, -2 * x[1]]]), np.array([[-0.4 * u[0]]])

    def final_constraints(self, x):
        return np.array([x[0] - 1.0])

    def final_constraints_jacobian(self, x):
        return np.array([[1.0, 0.0]])


# ============================================================================ helpers
def stationarity(problem, result):
    """max |grad J + Jc^T lam - z_L + z_U| on the NLP view from the Result's multipliers."""
    nlp = StructuredNLP(problem)
    mult = result.multipliers
    lam = np.concatenate([mult["dynamics"].ravel(), mult["stage_constraints"].ravel(),
                          mult["final_constraints"].ravel()])
    zl = nlp.pack(mult["bound_lower_x"], mult["bound_lower_u"])
    zu = nlp.pack(mult["bound_upper_x"], mult["bound_upper_u"])
    y = nlp.pack(result.x, result.u)
    r = nlp.gradient(y) + nlp.jacobian_matrix(y).T @ lam - zl + zu
    return float(np.max(np.abs(r))), nlp, y, lam, zl, zu


# ============================================================================ LQ vs dense KKT
@pytest.mark.parametrize("name", SOLVERS)
def test_equality_constrained_lq_matches_dense_kkt(name):
    p = LQ(N=8)
    X, U, nu, nuN = lq_dense_reference(p)
    res = make(name, **(tight(name) if name != "trust-constr" else {"tol": 1e-9})).solve(p)
    assert res.status is Status.SUCCESS, res.message
    assert res.solver == name and res.N == 8 and res.problem == "lq"
    assert np.allclose(res.x, X, atol=1e-7) and np.allclose(res.u, U, atol=1e-6)
    assert res.objective == pytest.approx(p.objective(X, U), rel=1e-9, abs=1e-12)
    atol = 1e-6 if name != "slsqp" else 1e-4
    assert np.allclose(res.multipliers["dynamics"], nu, atol=atol)
    assert np.allclose(res.multipliers["final_constraints"], nuN, atol=atol)
    assert res.multipliers["stage_constraints"].shape == (8, 0)
    assert res.max_constraint_violation < 1e-9
    assert res.kkt_residual is not None and res.kkt_residual < (1e-6 if name != "slsqp" else 1e-4)
    assert res.evaluations["objective"] > 0 and res.evaluations["jacobian"] > 0
    assert 0.0 < res.info["callback_share"] <= 1.0


def test_ipopt_limited_memory_hessian_and_no_hessian_calls():
    p = LQ(N=8)
    X, U, _, _ = lq_dense_reference(p)
    res = make("ipopt", hessian="limited-memory", tol=1e-10).solve(p)
    assert res.success, res.message
    assert np.allclose(res.u, U, atol=1e-5)
    assert res.evaluations["hessian"] == 0


# ============================================================================ solvers agree
@pytest.mark.parametrize("problem_cls", [BoundedLQ, Cart])
def test_solvers_agree_with_bounds_and_inequalities(problem_cls):
    results = {}
    for name in SOLVERS:
        results[name] = make(name, **tight(name)).solve(problem_cls())
        assert results[name].success, (name, results[name].message)
    ref = results["ipopt"]
    # the problem must actually have active bounds and inequalities
    assert np.max(np.abs(ref.multipliers["bound_upper_u"]) + np.abs(ref.multipliers["bound_lower_u"])
                  + np.abs(ref.multipliers["bound_upper_x"][1:])) > 1e-3
    assert np.max(np.abs(ref.multipliers["stage_constraints"])) > 1e-3
    for name in ("slsqp", "trust-constr"):
        other = results[name]
        assert other.objective == pytest.approx(ref.objective, rel=1e-8, abs=1e-10), name
        assert np.allclose(other.u, ref.u, atol=2e-6), (name, np.max(np.abs(other.u - ref.u)))
        assert np.allclose(other.x, ref.x, atol=1e-6), name
        assert np.allclose(other.multipliers["dynamics"], ref.multipliers["dynamics"], atol=1e-4), name
        assert np.allclose(other.multipliers["stage_constraints"], ref.multipliers["stage_constraints"],
                           atol=1e-4), name


@pytest.mark.parametrize("name", SOLVERS)
@pytest.mark.parametrize("problem_cls", [BoundedLQ, Cart])
def test_multipliers_satisfy_stationarity_and_signs(name, problem_cls):
    p = problem_cls()
    res = make(name, **tight(name)).solve(p)
    assert res.success, res.message
    resid, nlp, y, lam, zl, zu = stationarity(p, res)
    assert resid < (1e-6 if name != "slsqp" else 1e-5), resid
    assert res.info["stationarity_residual"] == pytest.approx(resid, abs=1e-9)
    assert res.kkt_residual >= res.info["stationarity_residual"]
    assert res.kkt_residual < 1e-6 and res.info["complementarity_residual"] < 1e-6
    # shapes of the multipliers dictionary
    m = res.multipliers
    assert m["dynamics"].shape == (p.N, p.n) and m["stage_constraints"].shape == (p.N, p.r)
    assert m["final_constraints"].shape == (p.rN,)
    assert m["bound_lower_x"].shape == (p.N + 1, p.n) and m["bound_upper_u"].shape == (p.N, p.m)
    # sign convention: z >= 0; inequality multipliers of g >= 0 are <= 0 and complementary
    assert np.all(zl >= -1e-8) and np.all(zu >= -1e-8)
    g = m["stage_constraints"]
    assert np.all(g <= 1e-8)
    gval = nlp.constraints(y)[p.N * p.n: p.N * p.n + p.N * p.r].reshape(p.N, p.r)
    assert np.max(np.abs(g * gval)) < 1e-6
    lb, ub = nlp.variable_bounds()
    free = lb < ub
    with np.errstate(invalid="ignore"):
        assert np.max(np.nan_to_num(np.abs(zl * (y - lb))[free])) < 1e-6
        assert np.max(np.nan_to_num(np.abs(zu * (ub - y))[free])) < 1e-6


# ============================================================================ statuses
@pytest.mark.parametrize("name", SOLVERS)
def test_max_iter_one_gives_max_iterations(name):
    res = make(name, max_iter=1).solve(Cart())
    assert res.status is Status.MAX_ITERATIONS, res.message
    assert not res.success
    assert res.iterations <= 1
    assert np.isfinite(res.objective) and res.x.shape == (16, 2)


@pytest.mark.parametrize("name", SOLVERS)
def test_callback_returning_true_stops(name):
    seen = []

    def callback(info):
        seen.append(info)
        return len(seen) >= 2

    res = make(name, callback=callback).solve(Cart())
    assert res.status is Status.USER_STOP, res.message
    assert len(seen) == 2
    assert seen[-1]["x"].shape == (16, 2) and seen[-1]["u"].shape == (15, 1)
    assert "objective" in seen[-1] and "iter" in seen[-1]


@pytest.mark.parametrize("name", SOLVERS)
def test_max_time_gives_max_time(name):
    res = make(name, max_time=1e-9).solve(Cart())
    assert res.status is Status.MAX_TIME, res.message


def test_ipopt_status_messages_quote_ipopt():
    from olado.solvers.nlp.ipopt import map_ipopt_status

    for code, expected in [(0, Status.SUCCESS), (1, Status.ACCEPTABLE), (-1, Status.MAX_ITERATIONS),
                           (2, Status.INFEASIBLE), (-4, Status.MAX_TIME), (-5, Status.MAX_TIME),
                           (5, Status.USER_STOP), (-2, Status.NUMERICAL_ERROR),
                           (-3, Status.NUMERICAL_ERROR), (-13, Status.INVALID_PROBLEM),
                           (4, Status.UNBOUNDED), (-199, Status.FAILED), (12345, Status.FAILED)]:
        status, message = map_ipopt_status(code, b"ipopt says hi")
        assert status is expected, code
        assert f"IPOPT status {code}" in message and "ipopt says hi" in message


def test_ipopt_history_and_result_fields():
    p = Cart()
    res = make("ipopt").solve(p)
    assert res.success
    assert len(res.history) == res.iterations + 1  # iteration 0 is the starting point
    row = res.history[-1]
    for key in ("iter", "objective", "inf_pr", "inf_du", "mu", "alpha_pr", "alpha_du", "ls_trials"):
        assert key in row
    assert row["objective"] == pytest.approx(res.objective, rel=1e-10)
    assert res.info["ipopt_status"] == 0 and "successfully" in res.info["ipopt_status_msg"]
    assert res.info["callback_time_s"] > 0 and 0 < res.info["callback_share"] <= 1
    for kind in ("objective", "gradient", "constraints", "jacobian", "hessian"):
        assert res.evaluations[kind] > 0
    assert "callback_share" in res.summary()


def test_infeasible_problem_is_a_status_not_an_exception():
    class Unreachable(Cart):
        def __init__(self):
            DOCP.__init__(self, 2, 1, 3, [0.0, 0.0], u_bounds=(-0.1, 0.1), n_stage_constraints=1,
                          n_final_constraints=1, final_equalities=[0])

    res = make("ipopt").solve(Unreachable())
    assert res.status in (Status.INFEASIBLE, Status.NUMERICAL_ERROR), res.message
    assert res.max_constraint_violation > 1e-3


# ============================================================================ options
def test_raw_ipopt_options_are_passed_verbatim():
    res = make("ipopt", ipopt_options={"max_iter": 2, "mu_strategy": "adaptive"}).solve(Cart())
    assert res.status is Status.MAX_ITERATIONS
    assert res.info["ipopt_options"]["mu_strategy"] == "adaptive"
    # an integer given for a real-valued IPOPT option is accepted: IPOPT stops at once with
    # tol = 1 and reports success, which olado's certificate does not confirm
    res = make("ipopt", ipopt_options={"tol": 1}).solve(LQ(N=4))
    assert "Solve_Succeeded" in res.message
    assert res.status is Status.UNCERTIFIED and "scaled stationarity" in res.message


def test_bad_options_are_config_errors():
    with pytest.raises(ConfigError, match="hessian"):
        make("ipopt", hessian="newton")
    with pytest.raises(ConfigError, match="print_level"):
        make("ipopt", print_level=13)
    with pytest.raises(ConfigError, match="no_such_option"):
        make("ipopt", ipopt_options={"no_such_option": 1.0}).solve(LQ(N=3))
    with pytest.raises(ConfigError, match="hessian"):
        make("trust-constr", hessian="exact-ish")


@pytest.mark.parametrize("hessian", ["bfgs", "sr1"])
def test_trust_constr_quasi_newton(hessian):
    p = LQ(N=4)
    X, U, _, _ = lq_dense_reference(p)
    res = make("trust-constr", hessian=hessian, tol=1e-7).solve(p)
    assert res.success, res.message
    assert np.allclose(res.u, U, atol=5e-5)
    assert res.evaluations["hessian"] == 0


@pytest.mark.parametrize("config", ["ipopt", "ipopt-lbfgs", "slsqp", "trust-constr"])
def test_config_files_load_and_solve(config):
    from pathlib import Path

    from olado.config import load_config, make_solver

    path = REPO / "configs" / f"{config}.ini"
    solver = make_solver(load_config(path))
    assert solver.name == config.split("-lbfgs")[0]
    res = solver.solve(LQ(N=5))
    assert res.success, res.message


# ============================================================================ missing back-end
def test_missing_cyipopt_raises_with_install_hint(monkeypatch):
    from olado.solvers.nlp.ipopt import IpoptSolver

    monkeypatch.setitem(sys.modules, "cyipopt", None)  # makes `import cyipopt` fail
    assert IpoptSolver.available() is False
    with pytest.raises(SolverNotAvailableError, match=r"pip install \"cyipopt-wheels>=1.7.0.dev0\"") as err:
        IpoptSolver().solve(LQ(N=3))
    assert "cyipopt-wheels" in str(err.value) and "apt install" in str(err.value)
    assert isinstance(err.value, ImportError)
