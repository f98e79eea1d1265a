"""Exact derivatives by automatic differentiation (olado.problems.autodiff, docs/autodiff.md).

The AD model of Zambezi against the hand-written kernels (values, first derivatives, Lagrangian
Hessians at random points; the same SQP iterates), an RK4-transcribed ODE with path and final
constraints against finite differences, the numba translation of the SX algorithm against
CasADi's own evaluation, and the error naming the extra when the back-end is missing. Tests that
need CasADi (the ``ad`` extra) or SymPy skip when it is absent.
"""

from __future__ import annotations

import numpy as np
import pytest

from olado.errors import AutoDiffNotAvailableError, ProblemDefinitionError
from olado.problems import check_derivatives
from olado.problems import autodiff
from olado.problems.autodiff import AutoDiffDOCP, cos, sin
from olado.problems.zambezi import Zambezi
from olado.problems.zambezi_ad import ZambeziAD


def _cartpole(x, u):
    """Cart-pole right-hand side and running cost (a symbolic-friendly function)."""
    th, v, w, F = x[1], x[2], x[3], u[0]
    mc, mp, ell, g = 1.0, 0.1, 0.5, 9.81
    s, c = sin(th), cos(th)
    den = mc + mp * s * s
    acc = (F + mp * s * (ell * w * w + g * c)) / den
    alpha = (-F * c - mp * ell * w * w * c * s - (mc + mp) * g * s) / (ell * den)
    return [v, w, acc, alpha], 0.5 * (x[0] * x[0] + th * th) + 0.01 * F * F


class CartPoleRK4(AutoDiffDOCP):
    """Cart-pole swing-down by RK4 steps of varying length (the step is stage data), a nonlinear
    path constraint and final equality constraints: every function of the DOCP is exercised."""

    def __init__(self, N=8, mode="llvm"):
        self.ad_options = {"mode": mode}
        super().__init__(4, 1, N, np.array([0.0, 0.3, 0.0, 0.0]), u_bounds=(-20, 20),
                         n_stage_constraints=2, n_final_constraints=2, final_equalities=[0])

    def stage_data(self):
        return np.linspace(0.05, 0.15, self.N)[:, None]      # the step length h^k

    def stage(self, x, u, d):
        h = d[0]
        k1, l1 = _cartpole(x, u)
        k2, l2 = _cartpole([x[i] + h / 2 * k1[i] for i in range(4)], u)
        k3, l3 = _cartpole([x[i] + h / 2 * k2[i] for i in range(4)], u)
        k4, l4 = _cartpole([x[i] + h * k3[i] for i in range(4)], u)
        x_next = [x[i] + h / 6 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i]) for i in range(4)]
        cost = h / 6 * (l1 + 2 * l2 + 2 * l3 + l4)
        g = [4.0 - x[0] * x[0] - u[0] * u[0] / 100, cos(x[1]) + 2.0]
        return x_next, cost, g

    def final(self, x):
        return 10 * (x[2] * x[2] + x[3] * x[3]), [x[0] - 0.1, 1.0 - x[1] * x[1] * sin(x[1])]


def _point(p, seed=1, scale=0.3):
    rng = np.random.default_rng(seed)
    U = p.initial_guess() + scale * rng.standard_normal((p.N, p.m))
    return p.simulate(U), U


# ============================================================================ without the extra
def test_missing_backend_names_the_extra(monkeypatch):
    real = autodiff.backends.importlib.util.find_spec
    monkeypatch.setattr(autodiff.backends.importlib.util, "find_spec",
                        lambda name, *a: None if name in ("casadi", "sympy") else real(name, *a))
    with pytest.raises(AutoDiffNotAvailableError, match=r"pip install olado\[ad\]") as info:
        ZambeziAD(N=12)
    assert isinstance(info.value, ImportError)
    with pytest.raises(AutoDiffNotAvailableError, match=r"olado\[ad-sympy\]"):
        ZambeziAD(N=12, backend="sympy")


def test_unknown_backend_is_refused():
    with pytest.raises(ProblemDefinitionError, match="unknown automatic-differentiation back-end 'jax'"):
        ZambeziAD(N=12, backend="jax")


def test_elementary_functions_work_on_numbers():
    assert sin(0.5) == np.sin(0.5) and cos(np.array([0.0]))[0] == 1.0
    assert autodiff.fmax(1.0, 2.0) == 2.0 and autodiff.atan2(1.0, 1.0) == np.arctan2(1.0, 1.0)


# ============================================================================ CasADi
@pytest.fixture(scope="module")
def casadi():
    return pytest.importorskip("casadi")


@pytest.mark.parametrize("mode", ["llvm", "vm", pytest.param("numba", marks=pytest.mark.slow)])
def test_zambezi_ad_equals_hand_written_kernels(casadi, mode):
    """Values, Jacobians, gradients and Lagrangian Hessians of the AD model equal the hand-written
    numba kernels to rounding, at random points with random multipliers."""
    hand, ad = Zambezi(N=36), ZambeziAD(N=36, backend_options={"mode": mode})
    for seed in (0, 1):
        X, U = _point(hand, seed, scale=0.5)
        report = check_derivatives(ad, hand, X, U, sigma=0.7, rtol=1e-12, atol=1e-14, seed=seed)
        assert report.ok, str(report)
    assert ad.setup_time > 0
    assert f"automatic differentiation (casadi, {mode})" in ad.describe()


def test_zambezi_ad_same_sqp_iterates(casadi):
    """sqp-ip on zambezi12 (N = 24): the AD model takes the same iterations to the same
    objective as the hand-written one."""
    import olado

    hand, ad = Zambezi(N=24), ZambeziAD(N=24)
    r_hand = olado.solve(hand, config="configs/sqp-ip.ini")
    r_ad = olado.solve(ad, config="configs/sqp-ip.ini")
    assert r_hand.success and r_ad.success, (r_hand.message, r_ad.message)
    assert r_ad.iterations == r_hand.iterations
    assert abs(r_ad.objective - r_hand.objective) <= 1e-10 * abs(r_hand.objective)
    np.testing.assert_allclose(r_ad.u, r_hand.u, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(r_ad.x, r_hand.x, rtol=1e-8, atol=1e-9)


def test_constrained_ad_problem_solved_by_sqp_and_ipopt(casadi):
    """The RK4 cart-pole with its path and final constraints, derivatives by AD only: sqp-ip and
    IPOPT (through the NLP view) reach the same optimum, and olado's certificate holds."""
    import olado

    pytest.importorskip("cyipopt")
    ref = olado.solve(CartPoleRK4(N=30), solver="ipopt")
    r = olado.solve(CartPoleRK4(N=30), config="configs/sqp-ip.ini")
    assert ref.success and r.success, (ref.message, r.message)
    assert abs(r.objective - ref.objective) <= 1e-6 * max(1.0, abs(ref.objective))
    np.testing.assert_allclose(r.u, ref.u, atol=1e-3)    # u is weighted 0.01 h: a flat objective


def test_ode_problem_derivatives_against_finite_differences(casadi):
    """An RK4 transcription with sin/cos, divisions, stage data, path and final constraints: the
    AD derivatives and Lagrangian Hessians (stage and final) against central differences."""
    p = CartPoleRK4(N=8)
    X, U = _point(p)
    report = check_derivatives(p, None, X, U, sigma=1.3, rtol=1e-6, atol=1e-7)
    assert report.ok, str(report)
    hxx, hxu, huu = p.eval_stage_hessians(X, U, 1.3, np.ones((p.N, 4)), np.ones((p.N, 2)))
    assert np.abs(hxx).max() > 1e-3 and np.abs(huu).max() > 1e-6     # not trivially zero
    assert np.allclose(hxx, np.transpose(hxx, (0, 2, 1)))


class Operations(AutoDiffDOCP):
    """A small model using every elementary function the module offers, for the translation."""

    def __init__(self, mode):
        self.ad_options = {"mode": mode}
        super().__init__(2, 1, 5, np.array([0.3, -0.2]), n_stage_constraints=2, n_final_constraints=1)

    def stage_data(self):
        return np.arange(1.0, 6.0)[:, None]

    def stage(self, x, u, d):
        a, b, v = x[0], x[1], u[0]
        x_next = [a + 0.1 * sin(b) * autodiff.exp(-a * a) + v / (2 + cos(a)) - d[0] * autodiff.tanh(v) / 50,
                  b + 0.1 * autodiff.sqrt(1 + b * b) + 0.01 * autodiff.atan2(a, 2.0 + b * b) + (2 + a * a) ** (0.5 * v)]
        cost = autodiff.log(1 + a ** 2) + b ** 3 / 7 + autodiff.fabs(v) * v + autodiff.cosh(v) - autodiff.sinh(a)
        g = [autodiff.atan(a) - autodiff.asin(0.5 * sin(b)) + autodiff.acos(0.3 * cos(v)),
             autodiff.fmax(a, b) * autodiff.fmin(a, v) + autodiff.tan(0.1 * a) + 1 / (3 + b)]
        return x_next, cost, g

    def final(self, x):
        return x[0] * x[0] - autodiff.exp(x[1]) * x[0], [x[0] ** 2 + x[1] ** 2 - 1]


def _hand_lotka():
    """LotkaFishing (olado.problems.literature) as the ContinuousDOCP it was: its class data with
    the model's hand-written (F, J, H), the reference of the ADModel test (the built-in is a
    ContinuousOCP now)."""
    from olado.problems.continuous import ContinuousDOCP, ExactHessians
    from olado.problems.literature import LotkaFishing

    data = {k: getattr(LotkaFishing, k) for k in ("name", "STATES", "CONTROLS", "C0", "C1", "X0", "T",
                                                   "U_BOUNDS", "DEFAULT_N", "control_guess")}

    def model(self, X, U, order):
        a, b, w = X[:, 0], X[:, 1], U[:, 0]
        K = len(w)
        F = np.stack([a - a * b - self.C0 * a * w, -b + a * b - self.C1 * b * w,
                      (a - 1) ** 2 + (b - 1) ** 2], axis=1)
        if order < 1:
            return F, None, None
        J = np.zeros((K, 3, 3))
        J[:, 0, 0], J[:, 0, 1], J[:, 0, 2] = 1 - b - self.C0 * w, -a, -self.C0 * a
        J[:, 1, 0], J[:, 1, 1], J[:, 1, 2] = b, -1 + a - self.C1 * w, -self.C1 * b
        J[:, 2, 0], J[:, 2, 1] = 2 * (a - 1), 2 * (b - 1)
        H = None
        if order >= 2:
            H = np.zeros((K, 3, 3, 3))
            H[:, 0, 0, 1] = H[:, 0, 1, 0] = -1.0
            H[:, 0, 0, 2] = H[:, 0, 2, 0] = -self.C0
            H[:, 1, 0, 1] = H[:, 1, 1, 0] = 1.0
            H[:, 1, 1, 2] = H[:, 1, 2, 1] = -self.C1
            H[:, 2, 0, 0] = H[:, 2, 1, 1] = 2.0
        return F, J, H

    return type("LotkaHand", (ExactHessians, ContinuousDOCP), dict(data, model=model)), LotkaFishing


def test_continuous_model_by_ad_equals_the_hand_written_model(casadi):
    """ADModel supplies ContinuousDOCP.model's (F, J, H): the Lotka-Volterra fishing right-hand
    side written once gives the hand-written model, and the DOCP built on it (RK4 through the
    model) the same derivatives and exact Hessians as the hand-written one -- and as the built-in
    lotka-fishing, a ContinuousOCP (its DOCP by OCP's own differentiation)."""
    from olado.problems.autodiff import ADModel

    LotkaHand, LotkaFishing = _hand_lotka()
    c0, c1 = LotkaHand.C0, LotkaHand.C1

    class LotkaAD(LotkaHand):
        _ad_model = ADModel(lambda x, u: ([x[0] - x[0] * x[1] - c0 * x[0] * u[0], -x[1] + x[0] * x[1] - c1 * x[1] * u[0]],
                                     (x[0] - 1) ** 2 + (x[1] - 1) ** 2), 2, 1)

        def model(self, X, U, order):
            return self._ad_model(X, U, order)

    hand, ad = LotkaHand(N=20), LotkaAD(N=20)
    rng = np.random.default_rng(4)
    X, U = rng.random((7, 2)) + 0.2, rng.random((7, 1))
    for order in (0, 1, 2):
        for a, b in zip(ad.model(X, U, order), hand.model(X, U, order)):
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-15)
    Xs, Us = _point(hand, scale=0.2)
    for other in (ad, LotkaFishing(N=20)):
        report = check_derivatives(other, hand, Xs, Us, rtol=1e-12, atol=1e-14)
        assert report.ok, str(report)


@pytest.mark.parametrize("mode", ["llvm", pytest.param("numba", marks=pytest.mark.slow)])
def test_compiled_translation_equals_casadi_evaluation(casadi, mode):
    """The SX algorithm compiled by LLVM (or numba) gives CasADi's own values (its virtual
    machine) for every elementary function and every DOCP function and derivative."""
    vm, compiled = Operations("vm"), Operations(mode)
    X, U = _point(vm, seed=3, scale=0.2)
    report = check_derivatives(compiled, vm, X, U, rtol=1e-13, atol=1e-14)
    assert report.ok, str(report)
    assert {"stage_constraints", "final_constraints", "stage_hessian huu"} <= {c.name for c in report.checks}


def test_stage_subsets_take_their_own_data(casadi):
    """A call on some stages (a line search's, DOCP.simulate's one stage) uses those stages'
    data rows, as the hand-written model does."""
    hand, ad = Zambezi(N=24), ZambeziAD(N=24)
    X, U = _point(hand)
    k = np.array([3, 17, 5])
    np.testing.assert_allclose(ad.dynamics(k, X[k], U[k]), hand.dynamics(k, X[k], U[k]), rtol=1e-14)
    np.testing.assert_allclose(ad.dynamics(7, X[7], U[7])[0], hand.dynamics(7, X[7:8], U[7:8])[0], rtol=1e-14)
    np.testing.assert_allclose(ad.simulate(U), hand.simulate(U), rtol=1e-13)


def test_wrong_output_size_is_named(casadi):
    class Bad(AutoDiffDOCP):
        ad_options = {"mode": "vm"}

        def __init__(self):
            super().__init__(2, 1, 3, np.zeros(2))

        def stage(self, x, u, d):
            return [x[0] + u[0]], x[1] * x[1]

    with pytest.raises(ProblemDefinitionError, match=r"stage\(\).*x_next.*returned 1 entries, the problem declares 2"):
        Bad().eval_dynamics(np.zeros((4, 2)), np.zeros((3, 1)))


# ============================================================================ SymPy (the measured alternative)
@pytest.mark.slow
def test_sympy_backend_equals_hand_written_kernels():
    pytest.importorskip("sympy")
    hand, ad = Zambezi(N=12), ZambeziAD(N=12, backend="sympy")
    X, U = _point(hand)
    report = check_derivatives(ad, hand, X, U, rtol=1e-12, atol=1e-14)
    assert report.ok, str(report)


class Blowup(AutoDiffDOCP):
    """x+ = x + h log(x) - u: from x0 = 2 with u = 1 the state falls below 0 at stage 3, where the
    logarithm is NaN."""

    def __init__(self):
        super().__init__(1, 1, 6, np.array([2.0]))

    def stage(self, x, u, d):
        return [x[0] + 0.5 * autodiff.log(x[0]) - u[0]], u[0] * u[0]


@pytest.mark.parametrize("mode", ["llvm", "vm"])
def test_simulation_is_the_stage_by_stage_recursion(casadi, mode):
    """simulate (eq. (2)): the compiled sequential loop of the LLVM evaluator gives DOCP's loop of
    one-stage calls exactly -- stage data included (the cart-pole's step lengths, Zambezi's
    inflows); other modes use DOCP's loop."""
    from olado.problems.docp import DOCP
    for p in (CartPoleRK4(N=30, mode=mode), ZambeziAD(N=48)):
        U = _point(p)[1]
        np.testing.assert_array_equal(p.simulate(U), DOCP.simulate(p, U))
    hand = Zambezi(N=48)
    np.testing.assert_allclose(ZambeziAD(N=48).simulate(hand.initial_guess()), hand.simulate(hand.initial_guess()),
                               rtol=1e-13)


def test_simulation_names_the_first_stage_that_is_not_finite(casadi):
    from olado.errors import NonFiniteEvaluationError
    p = Blowup()
    X = [2.0]
    for _ in range(3):
        X.append(X[-1] + 0.5 * np.log(X[-1]) - 1.0)
    assert X[2] > 0 > X[3]                              # x^3 < 0: x^4 = NaN
    with pytest.raises(NonFiniteEvaluationError, match=r"stage k=4, array .x."):
        p.simulate(np.ones((6, 1)))
