"""DDP and Pantoja's stagewise Newton method (olado.solvers.control.ddp): agreement with IPOPT on an LQ
problem (one iteration) and on nonlinear problems, local quadratic convergence, the stagewise
Newton step against a dense reduced Hessian, the eigenvalue shift on a nonconvex start, statuses
and the ini presets."""

from pathlib import Path

import numpy as np
import pytest

import olado
from olado.config import load_config
from olado.problems import DOCP
from olado.problems.testproblems import PROBLEMS, REGRESSION_VALUES
from olado.result import Result, Status
from olado.solvers.control import ddp  # noqa: F401 - registers "ddp" and "stagewise-newton"
from olado.solvers.control.control_space import ReducedProblem
from olado.solvers.control.ddp import stagewise_newton_step, unsupported_features

from fixtures.toy_problems import Pendulum
from fixtures import REPO

METHODS = ["ddp", "stagewise-newton"]


# ============================================================================ problems
class LQ(DOCP):
    """Random linear-quadratic DOCP with cross terms and linear terms (vectorized, analytic)."""

    name = "lq-ddp"
    vectorized = True

    def __init__(self, N=20, n=3, m=2, seed=0):
        rng = np.random.default_rng(seed)
        self.Am = np.eye(n) + 0.1 * rng.standard_normal((n, n))
        self.Bm = 0.2 * rng.standard_normal((n, m))
        Q = rng.standard_normal((n, n))
        self.Q = Q @ Q.T / n + 0.1 * np.eye(n)
        self.R = 0.5 * np.eye(m)
        self.S = 0.1 * rng.standard_normal((n, m))
        self.q, self.rr = 0.1 * rng.standard_normal(n), 0.1 * rng.standard_normal(m)
        self.QN = 2.0 * np.eye(n)
        super().__init__(n, m, N, rng.standard_normal(n))

    def dynamics(self, k, x, u):
        return x @ self.Am.T + u @ self.Bm.T

    def stage_cost(self, k, x, u):
        return (0.5 * np.einsum("ki,ij,kj->k", x, self.Q, x) + 0.5 * np.einsum("ki,ij,kj->k", u, self.R, u)
                + np.einsum("ki,ij,kj->k", x, self.S, u) + x @ self.q + u @ self.rr)

    def final_cost(self, x):
        return 0.5 * x @ self.QN @ x

    def dynamics_jacobian(self, k, x, u):
        K = len(k)
        return np.broadcast_to(self.Am, (K,) + self.Am.shape), np.broadcast_to(self.Bm, (K,) + self.Bm.shape)

    def stage_cost_gradient(self, k, x, u):
        return x @ self.Q + u @ self.S.T + self.q, u @ self.R + x @ self.S + self.rr

    def final_cost_gradient(self, x):
        return self.QN @ x

    def stage_hessian(self, k, x, u, sigma, p, lam):
        K = len(k)
        return tuple(sigma * np.broadcast_to(M, (K,) + M.shape) for M in (self.Q, self.S, self.R))

    def final_hessian(self, x, sigma, lam):
        return sigma * self.QN


class Swing(DOCP):
    """Pendulum swung towards the upright position (per stage, analytic derivatives): the
    dynamics are nonlinear, so the second-order dynamics terms matter."""

    name = "swing"
    dt = 0.1

    def __init__(self, N=30, **kw):
        super().__init__(2, 1, N, [0.0, 0.0], **kw)

    def dynamics(self, k, x, u):
        dt = self.dt
        return np.array([x[0] + dt * x[1], x[1] + dt * (-np.sin(x[0]) - 0.1 * x[1] + u[0])])

    def stage_cost(self, k, x, u):
        return 0.05 * u[0] ** 2 + 0.01 * (x[0] - np.pi) ** 2

    def final_cost(self, x):
        return 5.0 * ((x[0] - np.pi) ** 2 + x[1] ** 2)

    def dynamics_jacobian(self, k, x, u):
        dt = self.dt
        return np.array([[1.0, dt], [-dt * np.cos(x[0]), 1 - 0.1 * dt]]), np.array([[0.0], [dt]])

    def stage_cost_gradient(self, k, x, u):
        return np.array([0.02 * (x[0] - np.pi), 0.0]), np.array([0.1 * u[0]])

    def final_cost_gradient(self, x):
        return 10.0 * np.array([x[0] - np.pi, x[1]])

    def stage_hessian(self, k, x, u, sigma, p, lam):
        hxx = np.array([[0.02 * sigma + p[1] * self.dt * np.sin(x[0]), 0.0], [0.0, 0.0]])
        return hxx, np.zeros((2, 1)), np.array([[0.1 * sigma]])

    def final_hessian(self, x, sigma, lam):
        return 10.0 * sigma * np.eye(2)


class DoubleWell(DOCP):
    """Nonconvex in u (stage cost (u^2 - 1)^2 / 4 + |x|^2 / 2), pendulum dynamics; vectorized.
    At u = 0 every stage's H_uu is -1: the reduced Hessian is indefinite."""

    name = "double-well"
    vectorized = True
    dt = 0.1

    def __init__(self, N=15, **kw):
        super().__init__(2, 1, N, [0.5, 0.0], **kw)

    def dynamics(self, k, x, u):
        dt = self.dt
        return np.stack([x[:, 0] + dt * x[:, 1], x[:, 1] + dt * (-np.sin(x[:, 0]) + u[:, 0])], axis=1)

    def stage_cost(self, k, x, u):
        return 0.25 * (u[:, 0] ** 2 - 1) ** 2 + 0.5 * (x * x).sum(1)

    def final_cost(self, x):
        return float(x @ x)

    def dynamics_jacobian(self, k, x, u):
        K, dt = len(k), self.dt
        A = np.zeros((K, 2, 2))
        A[:, 0, 0] = 1.0; A[:, 0, 1] = dt; A[:, 1, 0] = -dt * np.cos(x[:, 0]); A[:, 1, 1] = 1.0
        B = np.zeros((K, 2, 1)); B[:, 1, 0] = dt
        return A, B

    def stage_cost_gradient(self, k, x, u):
        return x.copy(), (u[:, 0] ** 3 - u[:, 0])[:, None]

    def final_cost_gradient(self, x):
        return 2.0 * x

    def stage_hessian(self, k, x, u, sigma, p, lam):
        K = len(k)
        hxx = np.zeros((K, 2, 2))
        hxx[:, 0, 0] = sigma + p[:, 1] * self.dt * np.sin(x[:, 0]); hxx[:, 1, 1] = sigma
        return hxx, np.zeros((K, 2, 1)), (sigma * (3 * u[:, 0] ** 2 - 1))[:, None, None]

    def final_hessian(self, x, sigma, lam):
        return 2.0 * sigma * np.eye(2)


def dense_reduced_hessian(problem, U):
    rp = ReducedProblem(problem)
    _, g, _, _ = rp.gradient(U)
    size = U.size
    H = np.column_stack([rp.hessian_vector(U, np.eye(size)[:, j].reshape(U.shape)).ravel() for j in range(size)])
    return 0.5 * (H + H.T), g.ravel()


def ipopt_reference(problem, guess=None):
    pytest.importorskip("cyipopt")
    r = olado.solve(problem, solver="ipopt", guess=guess, tol=1e-12)
    assert r.success
    return r


def grad_norms(result):
    return [h["grad_norm"] for h in result.history]


# ============================================================================ LQ: one iteration
@pytest.mark.parametrize("method", METHODS)
def test_lq_one_iteration_matches_ipopt(method):
    p = LQ()
    ref = ipopt_reference(p)
    r = olado.solve(p, solver=method)
    assert r.status == Status.SUCCESS and r.iterations == 1
    assert r.history[0]["step"] == 1.0 and r.history[0]["shift"] == 0.0
    assert r.kkt_residual < 1e-12
    assert np.allclose(r.u, ref.u, atol=1e-9, rtol=0)
    assert np.allclose(r.x, ref.x, atol=1e-9, rtol=0)
    assert r.objective == pytest.approx(ref.objective, rel=1e-12)
    # the expected decrease of an LQ problem is exact
    h = r.history[0]
    assert h["expected_decrease"] == pytest.approx(h["actual_decrease"], rel=1e-10)
    # costates are the dynamics multipliers of the NLP (IPOPT's sign convention)
    assert np.allclose(r.multipliers["dynamics"], ref.multipliers["dynamics"], atol=1e-8)


# ============================================================================ built-in problems
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["lq", "vanderpol", "rayleigh", "cstr"])
def test_builtin_problems_reach_the_ipopt_solution(method, name):
    ref = ipopt_reference(PROBLEMS[name](N=50))
    r = olado.solve(PROBLEMS[name](N=50), solver=method, tol=1e-9)
    assert r.status == Status.SUCCESS, r.message
    assert np.allclose(r.u, ref.u, atol=1e-7, rtol=0)
    assert r.objective == pytest.approx(ref.objective, rel=1e-11)
    key = (name, None) if name == "lq" else (name, "rk4")
    assert r.objective == pytest.approx(REGRESSION_VALUES[key], rel=1e-9)
    if name == "lq":
        assert r.iterations == 1
    else:   # quadratic tail (e.g. rayleigh, DDP: 7.0e-03 7.4e-05 2.7e-08 1.6e-15)
        g = grad_norms(r)
        tail = [(a, b) for a, b in zip(g, g[1:]) if a < 0.1 and b > 1e-14]
        assert tail and all(b <= 100.0 * a * a for a, b in tail[-2:]), g


@pytest.mark.parametrize("name", ["lq-box", "vanderpol-box", "vanderpol-path", "rayleigh-box"])
def test_builtin_bounded_problems_are_pointed_elsewhere(name):
    for method in METHODS:
        r = olado.solve(PROBLEMS[name](N=20), solver=method)
        assert r.status == Status.INVALID_PROBLEM and "pdmin" in r.message


# ============================================================================ nonlinear problems
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("make", [lambda: Swing(), lambda: Swing(derivatives="fd"),
                                  lambda: DoubleWell(), lambda: LQ(N=40, n=4, m=1, seed=3)],
                         ids=["swing", "swing-fd", "double-well", "lq-n4"])
def test_nonlinear_problems_reach_the_ipopt_solution(method, make):
    p = make()
    guess = np.ones((p.N, p.m)) if isinstance(p, DoubleWell) else None   # one well of the nonconvex cost
    ref = ipopt_reference(p, guess=guess)
    fd = p.derivatives == "fd"
    r = olado.solve(p, solver=method, guess=guess, tol=1e-6 if fd else 1e-9)
    assert r.status == Status.SUCCESS, r.message
    assert r.max_constraint_violation == 0.0
    assert np.allclose(r.u, ref.u, atol=1e-6 if fd else 1e-8, rtol=0)
    assert r.objective == pytest.approx(ref.objective, rel=1e-10)
    assert np.allclose(r.x, p.simulate(r.u), atol=1e-14)


@pytest.mark.parametrize("method", METHODS)
def test_local_quadratic_convergence(method):
    r = olado.solve(Swing(), solver=method, tol=1e-12)
    assert r.status == Status.SUCCESS
    g = grad_norms(r)
    # Swing from u = 0 (DDP):   2.2e+00 1.7e-02 6.3e-04 2.6e-07 4.3e-14
    #          (stagewise Newton) ... 3.6e-02 5.2e-03 1.1e-05 2.9e-10
    assert g[-1] <= 1e-12
    tail = [(a, b) for a, b in zip(g, g[1:]) if a < 0.1 and b > 1e-14]   # above the rounding floor
    assert len(tail) >= 3
    for a, b in tail:
        assert b <= 10.0 * a * a, (a, b, g)
    assert all(h["step"] == 1.0 and h["shift"] == 0.0 for h in r.history[-3:])


def test_second_order_dynamics_terms_give_ddp_its_rate():
    """Without V_x . f_xx (iLQR) the same problem converges only linearly."""
    full = olado.solve(Swing(), solver="ddp", tol=1e-9)
    ilqr = olado.solve(Swing(), solver="ddp", tol=1e-9, second_order_dynamics=False)
    assert full.success and ilqr.success
    assert np.allclose(full.u, ilqr.u, atol=1e-7)
    assert full.iterations + 3 <= ilqr.iterations
    g = grad_norms(ilqr)
    assert g[-1] / g[-2] > 1e-3       # linear: the ratio does not collapse


# ============================================================================ Newton step
@pytest.mark.parametrize("shift", [0.0, 0.3])
@pytest.mark.parametrize("make", [lambda: Swing(N=8), lambda: DoubleWell(N=6), lambda: LQ(N=5)],
                         ids=["swing", "double-well", "lq"])
def test_stagewise_newton_step_is_the_dense_newton_step(make, shift):
    p = make()
    rng = np.random.default_rng(4)
    U = rng.uniform(0.6, 1.4, (p.N, p.m))     # DoubleWell: H_uu > 0 there
    H, g = dense_reduced_hessian(p, U)
    assert np.linalg.eigvalsh(H + shift * np.eye(g.size)).min() > 0
    du = stagewise_newton_step(p, U, shift=shift)
    ref = -np.linalg.solve(H + shift * np.eye(g.size), g)
    assert np.allclose(du.ravel(), ref, atol=1e-10 * max(1.0, np.abs(ref).max()), rtol=0)


def test_stagewise_newton_first_iterate_is_the_newton_point():
    p = Swing(N=8)
    U0 = np.full((8, 1), 0.5)
    r = olado.solve(p, solver="stagewise-newton", guess=U0, max_iter=1)
    assert r.history[0]["step"] == 1.0 and r.history[0]["shift"] == 0.0
    H, g = dense_reduced_hessian(p, U0)
    assert np.allclose(r.u.ravel(), U0.ravel() - np.linalg.solve(H, g), atol=1e-10)


def test_newton_step_refuses_an_indefinite_hessian():
    p = DoubleWell(N=6)
    U = np.zeros((6, 1))
    H, _ = dense_reduced_hessian(p, U)
    assert np.linalg.eigvalsh(H).min() < 0
    with pytest.raises(ValueError, match="not positive definite"):
        stagewise_newton_step(p, U)
    lam_min = np.linalg.eigvalsh(H).min()
    stagewise_newton_step(p, U, shift=-lam_min + 1e-3)     # shifted past the lowest eigenvalue: fine


# ============================================================================ shift on a nonconvex start
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("regularization,schedule", [("control", "tassa"), ("state", "tassa"), ("control", "inertia")])
def test_shift_kicks_in_on_a_nonconvex_start(method, regularization, schedule):
    p = DoubleWell()
    U0 = np.full((p.N, 1), 0.01)
    H0, _ = dense_reduced_hessian(p, U0)
    assert np.linalg.eigvalsh(H0).min() < 0
    r = olado.solve(p, solver=method, guess=U0, regularization=regularization, shift_schedule=schedule)
    assert r.status == Status.SUCCESS, r.message
    assert r.history[0]["shift"] > 0 and r.history[0]["backward_passes"] > 1
    assert r.history[-1]["shift"] < r.history[0]["shift"]
    obj = [h["objective"] for h in r.history]
    assert all(b < a for a, b in zip(obj, obj[1:]))       # monotone descent
    # a strict local minimum: positive definite reduced Hessian, and IPOPT started there stays
    H, g = dense_reduced_hessian(p, r.u)
    assert np.abs(g).max() <= 1e-8 and np.linalg.eigvalsh(H).min() > 0
    ref = ipopt_reference(p, guess=r.u)
    assert np.allclose(r.u, ref.u, atol=1e-8) and r.objective == pytest.approx(ref.objective, rel=1e-12)


def test_both_methods_agree_on_the_nonconvex_problem():
    p = DoubleWell()
    U0 = np.full((p.N, 1), 0.01)
    a = olado.solve(p, solver="ddp", guess=U0)
    b = olado.solve(p, solver="stagewise-newton", guess=U0)
    assert a.success and b.success
    assert np.allclose(a.u, b.u, atol=1e-8)


# ============================================================================ statuses
@pytest.mark.parametrize("method", METHODS)
def test_constrained_problem_is_invalid(method):
    p = Pendulum(N=5)          # stage constraint, final equality, control bounds
    assert len(unsupported_features(p)) == 3
    r = olado.solve(p, solver=method)
    assert r.status == Status.INVALID_PROBLEM and not r.success
    assert "pdmin" in r.message and "penalty" in r.message
    assert r.iterations == 0


@pytest.mark.parametrize("method", METHODS)
def test_bounded_problem_is_invalid(method):
    p = Swing(u_bounds=(-1.0, 1.0))
    r = olado.solve(p, solver=method)
    assert r.status == Status.INVALID_PROBLEM and "bounds on the controls" in r.message and "pdmin" in r.message
    p = Swing(x_bounds=([-10, -10], [10, 10]))
    r = olado.solve(p, solver=method)
    assert r.status == Status.INVALID_PROBLEM and "bounds on the states" in r.message


@pytest.mark.parametrize("method", METHODS)
def test_max_iterations_user_stop_and_max_time(method):
    r = olado.solve(Swing(), solver=method, max_iter=2)
    assert r.status == Status.MAX_ITERATIONS and r.iterations == 2 and len(r.history) == 2
    seen = []
    r = olado.solve(Swing(), solver=method, callback=lambda info: seen.append(info) or len(seen) >= 3)
    assert r.status == Status.USER_STOP and r.iterations == 3
    assert set(seen[0]) >= {"iter", "objective", "grad_norm", "shift", "step", "expected_decrease"}
    r = olado.solve(Swing(), solver=method, max_time=1e-9)
    assert r.status == Status.MAX_TIME and r.iterations == 0


@pytest.mark.parametrize("method", METHODS)
def test_acceptable_when_no_decrease_is_measurable(method):
    r = olado.solve(LQ(), solver=method, tol=1e-30)
    assert r.status == Status.ACCEPTABLE and r.success
    assert "expected decrease" in r.message and r.kkt_residual < 1e-13


@pytest.mark.parametrize("method", METHODS)
def test_shift_limit_is_a_numerical_error(method):
    p = DoubleWell()
    r = olado.solve(p, solver=method, guess=np.full((p.N, 1), 0.01), shift_max=1e-3)
    assert r.status == Status.NUMERICAL_ERROR and "shift_max" in r.message


def test_result_round_trip(tmp_path):
    r = olado.solve(Swing(), solver="ddp")
    path = r.save(tmp_path / "ddp.json")
    back = Result.load(path)
    assert back.status == r.status and np.array_equal(back.u, r.u) and back.history[-1]["grad_norm"] == r.kkt_residual
    assert "ddp" in r.summary() and r.info["method"] == "ddp"


# ============================================================================ presets
@pytest.mark.parametrize("method", METHODS)
def test_ini_presets(method):
    path = REPO / "configs" / f"{method}.ini"
    cfg = load_config(path)
    assert cfg.solver == method
    r = olado.solve(Swing(), config=path)
    assert r.solver == method and r.status == Status.SUCCESS


def test_iteration_log(capsys):
    olado.solve(Swing(), solver="stagewise-newton", verbose=2)
    out = capsys.readouterr().out
    assert "|grad|" in out and "shift" in out and "exp.decr" in out
    assert "status       : success" in out


@pytest.mark.parametrize("method", METHODS)
def test_one_instance_solves_from_its_own_callback(method):
    """The solver holds only options: a solve started from the callback of another one on the
    same instance (inertia schedule, whose last shift carries over between iterations) gives the
    results of separate instances."""
    from olado.solvers import get_solver_class

    cls = get_solver_class(method)
    nested = {}

    def callback(info):
        if not nested:
            nested["r"] = None
            nested["r"] = solver.solve(Swing())
        return False

    p = DoubleWell()
    guess = np.full((p.N, 1), 0.01)
    solver = cls(shift_schedule="inertia", callback=callback)
    outer = solver.solve(p, guess=guess)
    ref = cls(shift_schedule="inertia").solve(DoubleWell(), guess=guess)
    ref_nested = cls(shift_schedule="inertia").solve(Swing())
    for r, q in ((outer, ref), (nested["r"], ref_nested)):
        assert r.success and r.iterations == q.iterations > 1
        assert r.objective == q.objective and np.array_equal(r.u, q.u)
        assert [h["shift"] for h in r.history] == [h["shift"] for h in q.history]
    assert any(h["shift"] > 0 for h in ref.history)        # the schedule is exercised
