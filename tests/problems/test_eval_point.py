"""A point's values and first derivatives in one call: DOCP.eval_values and
DOCP.eval_first_derivatives (the solvers' Point evaluates through them), and Zambezi's compiled
one-pass versions of them and of its Hessian blocks.

The default entry points call the per-function eval_* methods in their order; Zambezi's fused
kernels must give the same bits and advance the same counters, and a NaN, a replaced stage
function or an unusual argument must take the default path, so that an error still names the
function, the stage and the array exactly as before.
"""

import numpy as np
import pytest

from olado.errors import NonFiniteEvaluationError, ProblemDefinitionError
from olado.problems import DOCP
from olado.problems.docp import FirstDerivatives, PointValues
from olado.problems.zambezi import Zambezi, zambezi_problem
from olado.solvers.sqp.state import Point

from fixtures.toy_problems import Pendulum, PendulumVectorized


def _point(p, seed=0):
    """A point off the simulated start: states and controls moved randomly."""
    rng = np.random.default_rng(seed)
    U = p.initial_guess() * (1.0 + 0.1 * rng.uniform(-1, 1, (p.N, p.m)))
    X = p.simulate(U) * (1.0 + 0.01 * rng.uniform(-1, 1, (p.N + 1, p.n)))
    return X, U


def _default(p, method, *args):
    """The DOCP default of ``method`` (the per-function path), with the counters it advances."""
    before = p.counters.copy()
    out = getattr(DOCP, method)(p, *args)
    return out, p.counters - before


def _batched(p, method, *args):
    before = p.counters.copy()
    out = getattr(p, method)(*args)
    return out, p.counters - before


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape and x.dtype == y.dtype
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("N", [12, 36])
def test_zambezi_fused_pass_equals_the_per_function_path(N):
    p = zambezi_problem("zambezi12", N=N)
    X, U = _point(p)
    for method in ("eval_values", "eval_first_derivatives"):
        fast, c_fast = _batched(p, method, X, U)
        ref, c_ref = _default(p, method, X, U)
        assert type(fast) is type(ref)
        _same(fast, ref)
        assert c_fast == c_ref
    P = np.random.default_rng(1).standard_normal((N, 6))
    for sigma in (1.0, np.float64(0.3), 0.0):
        fast, c_fast = _batched(p, "eval_stage_hessians", X, U, sigma, P, np.zeros((N, 0)))
        ref, c_ref = _default(p, "eval_stage_hessians", X, U, sigma, P, np.zeros((N, 0)))
        _same(fast, ref)
        assert c_fast == c_ref
        fast, c_fast = _batched(p, "eval_final_hessian", X[-1], sigma, None)
        ref, c_ref = _default(p, "eval_final_hessian", X[-1], sigma, None)
        _same([fast], [ref])
        assert c_fast == c_ref


def test_zambezi_values_match_the_numpy_reference():
    """The fused kernels against the reference numpy form of eq. (40) (Zambezi._next_volumes)
    and a hand sum of the objective."""
    p = zambezi_problem("zambezi12", N=24)
    X, U = _point(p, 3)
    v = p.eval_values(X, U)
    Vn = p._next_volumes(p._K, X[:-1], U)[0]
    np.testing.assert_allclose(v.f[:, :4], Vn, rtol=1e-14, atol=1e-12)
    np.testing.assert_array_equal(v.f[:, 4], U[:, 4])
    np.testing.assert_array_equal(v.f[:, 5], X[:-1, 4])
    J = sum(float(p.stage_cost(k, X[k:k + 1], U[k:k + 1])[0]) for k in range(p.N)) + p.final_cost(X[-1])
    assert v.J == pytest.approx(J, rel=1e-13)


def test_zambezi_fused_derivatives_match_finite_differences():
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p, 4)
    d = p.eval_first_derivatives(X, U)
    q = zambezi_problem("zambezi12", N=12, derivatives="fd")
    ref = q.eval_first_derivatives(X, U)          # derivatives="fd": the default path, central differences
    for a, b in zip(d, ref):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6 * max(1.0, float(np.max(np.abs(b), initial=0.0))))


class _UserStages(Pendulum):
    """A user problem with per-stage functions only (no eval_* overrides)."""


@pytest.mark.parametrize("cls", [_UserStages, PendulumVectorized])
def test_user_subclass_entry_points_equal_the_per_method_calls(cls):
    p = cls(N=7)
    X, U = _point(p, 2)
    v = p.eval_values(X, U)
    assert isinstance(v, PointValues)
    assert v.J == p.objective(X, U)
    _same(v[1:], (p.eval_dynamics(X, U), p.eval_stage_constraints(X, U), p.eval_final_constraints(X[-1])))
    d = p.eval_first_derivatives(X, U)
    assert isinstance(d, FirstDerivatives)
    _same(d, (*p.eval_stage_cost_gradients(X, U), p.eval_final_cost_gradient(X[-1]), *p.eval_dynamics_jacobians(X, U),
              *p.eval_stage_constraint_jacobians(X, U), p.eval_final_constraint_jacobian(X[-1])))
    pt = Point(p, X, U)                          # the solvers' point evaluates through them
    assert pt.J == v.J
    np.testing.assert_array_equal(pt.h, v.f - X[1:])
    np.testing.assert_array_equal(pt.A, d.A)


class _NaNAtStage(Pendulum):
    def dynamics(self, k, x, u):
        out = super().dynamics(k, x, u)
        return out * np.nan if k == 3 else out


def test_user_subclass_bad_value_is_named_with_stage_and_array():
    p = _NaNAtStage(N=6)
    X, U = _point(Pendulum(N=6), 2)
    with pytest.raises(NonFiniteEvaluationError, match=r"dynamics\(\).*stage k=3.*x_next"):
        p.eval_values(X, U)
    with pytest.raises(NonFiniteEvaluationError, match=r"dynamics\(\).*stage k=3.*x_next"):
        Point(p, X, U)


def _message(fn, *args):
    with pytest.raises(ProblemDefinitionError) as e:
        fn(*args)
    return type(e.value), str(e.value)


def test_zambezi_bad_point_raises_the_default_error():
    """A NaN in the point: the fused pass falls back, and the error (type and message: function,
    stage, array) is the per-function path's."""
    p = zambezi_problem("zambezi12", N=24)
    X, U = _point(p)
    U = U.copy()
    U[7, 2] = np.nan
    got = _message(p.eval_values, X, U)
    assert got == _message(lambda X, U: DOCP.eval_values(p, X, U), X, U)
    assert got[0] is NonFiniteEvaluationError and "stage k=7" in got[1] and "'cost'" in got[1]
    assert _message(p.eval_first_derivatives, X, U) == _message(lambda X, U: DOCP.eval_first_derivatives(p, X, U), X, U)
    X = X.copy()
    X[4, 0] = np.inf
    U[7, 2] = 1.0
    got = _message(p.eval_first_derivatives, X, U)
    assert got == _message(lambda X, U: DOCP.eval_first_derivatives(p, X, U), X, U)
    assert "stage k=4" in got[1]
    P = np.ones((24, 6))
    P[9, 1] = np.nan
    X = _point(p)[0]
    got = _message(p.eval_stage_hessians, X, U, 1.0, P)
    assert got == _message(lambda *a: DOCP.eval_stage_hessians(p, *a), X, U, 1.0, P)
    assert "'P'" in got[1]
    with pytest.raises(ProblemDefinitionError, match=r"expected controls of shape"):
        p.eval_values(X, U[:-1])


def test_zambezi_counters_unchanged_by_a_fallback():
    p = zambezi_problem("zambezi12", N=12)
    X, U = _point(p)
    U = U.copy()
    U[3, 0] = np.nan
    p.reset_counters()
    with pytest.raises(NonFiniteEvaluationError):
        p.eval_values(X, U)
    # the fused pass counted nothing; the default path counted the stage costs it refused
    assert p.counters["stage_cost"] == 1 and p.counters["dynamics"] == 0


class _OwnDynamics(Zambezi):
    """A Zambezi variant with its own dynamics and stage cost: the fused kernels must not bypass them."""

    def dynamics(self, k, x, u):
        return super().dynamics(k, x, u) + 1.0

    def stage_cost(self, k, x, u):
        return super().stage_cost(k, x, u) * 2.0

    def stage_cost_gradient(self, k, x, u):
        gx, gu = super().stage_cost_gradient(k, x, u)
        return 2.0 * gx, 2.0 * gu

    def stage_hessian(self, k, x, u, sigma, p, lam):
        return tuple(2.0 * h for h in super().stage_hessian(k, x, u, sigma, p, lam))


def test_replaced_stage_functions_are_called():
    p, q = _OwnDynamics(N=12), Zambezi(N=12)
    X, U = _point(q)
    v, w = p.eval_values(X, U), q.eval_values(X, U)
    np.testing.assert_array_equal(v.f, w.f + 1.0)
    assert v.J == pytest.approx(2 * w.J - p.final_cost(X[-1]), rel=1e-12)
    np.testing.assert_array_equal(p.eval_first_derivatives(X, U).lx, 2.0 * q.eval_first_derivatives(X, U).lx)
    P = np.ones((12, 6))
    np.testing.assert_array_equal(p.eval_stage_hessians(X, U, 1.0, P)[2], 2.0 * q.eval_stage_hessians(X, U, 1.0, P)[2])
    # a function replaced on the instance is called too
    q.dynamics = lambda k, x, u: Zambezi.dynamics(q, k, x, u) - 1.0
    np.testing.assert_array_equal(q.eval_values(X, U).f, w.f - 1.0)


def test_zambezi_simulate_follows_the_dynamics():
    """The compiled recursion of Zambezi.simulate against the generic stage-by-stage DOCP.simulate
    (which calls the dynamics): the same trajectory up to rounding, and a divergent one refused
    with the stage named."""
    p = zambezi_problem("zambezi12", N=48)
    U = p.initial_guess() * 1.1
    np.testing.assert_allclose(p.simulate(U), DOCP.simulate(p, U), rtol=1e-12, atol=1e-9)
    q = zambezi_problem("zambezi", N=420, start="sif")
    with pytest.raises(NonFiniteEvaluationError, match=r"simulate\(\), stage k=\d+, array 'x'"):
        q.simulate(q.initial_guess() * 3.0)
