"""Continuous-time problems written once (olado.problems.ocp.OCP, docs/continuous-time.md).

Against independent references: the minimum-time double integrator (T* = 2 sqrt(d) in closed
form, and exactly on an even grid), a free initial state with the continuous answer in closed form
(x(0) = 1/cosh 1, J = tanh 1; second-order convergence in h), a parameter estimated from a known
solution (fourth-order convergence with RK4 substeps), the built-in Van der Pol problems rebuilt
on the class (the same DOCP to rounding and the regression objectives), and the exact
derivatives through the integrator, the parameter stage and substeps against finite
differences. Skips without CasADi (the ``ad`` extra).
"""

from __future__ import annotations

import numpy as np
import pytest

import olado
from olado.errors import ProblemDefinitionError
from olado.problems import check_derivatives

casadi = pytest.importorskip("casadi")

from olado.problems.autodiff import cos, sin  # noqa: E402
from olado.problems.ocp import OCP  # noqa: E402
from fixtures.ocp_problems import everything  # noqa: E402
from olado.problems.testproblems import REGRESSION_VALUES, VanDerPol  # noqa: E402

SQP, IPOPT, PDMIN = "configs/sqp-ip.ini", "configs/ipopt.ini", "configs/pdmin-lbfgs.ini"


def _ipopt():
    pytest.importorskip("cyipopt")
    return IPOPT


def double_integrator_min_time(d=2.0, N=20):
    """Rest to rest over distance d, |u| <= 1, minimum time."""
    return OCP(lambda t, x, u, p: [x[1], u[0]], [0.0, 0.0], controls=1, N=N, T=None, T_bounds=(0.1, 10.0),
               u_bounds=(-1.0, 1.0), terminal=lambda t, x, p: [x[0] - d, x[1]], terminal_equalities=[0, 1],
               minimum_time=True)


@pytest.mark.parametrize("config", [SQP, "ipopt"])
def test_minimum_time_double_integrator(config):
    """T* = 2 sqrt(d), u = +1 then -1: on an even grid the switch is a grid point and RK4 is
    exact for piecewise-constant u, so the discrete optimum is the continuous one."""
    config = _ipopt() if config == "ipopt" else config
    d = 2.0
    ocp = double_integrator_min_time(d)
    r = olado.solve(ocp, config=config)
    assert r.success, r.message
    s = ocp.solution(r)
    assert abs(s.tf - 2 * np.sqrt(d)) < 1e-6 and abs(r.objective - s.tf) < 1e-12
    np.testing.assert_allclose(s.u[:, 0], np.r_[np.ones(10), -np.ones(10)], atol=1e-5)
    np.testing.assert_allclose(s.x[-1], [d, 0.0], atol=1e-7)
    np.testing.assert_allclose(s.t, np.linspace(0, s.tf, 21))
    # the states at the grid points are those of the continuous bang-bang trajectory
    t = s.t
    half = s.tf / 2
    pos = np.where(t <= half, t ** 2 / 2, d - (s.tf - t) ** 2 / 2)
    np.testing.assert_allclose(s.x[:, 0], pos, atol=1e-5)


def free_initial_state(N):
    """min int_0^1 (x^2 + u^2) dt, x' = u, x(1) = 1, x(0) free: x = cosh t / cosh 1, J = tanh 1."""
    return OCP(lambda t, x, u, p: [u[0]], [0.3], controls=1, N=N, T=1.0, free_x0=[0],
               running_cost=lambda t, x, u, p: x[0] ** 2 + u[0] ** 2,
               terminal=lambda t, x, p: [x[0] - 1.0], terminal_equalities=[0])


def test_free_initial_state_against_the_closed_form():
    """The transversality condition u(0) = 0 gives x(0) = 1/cosh 1, J = tanh 1; piecewise-
    constant controls converge at second order in h (halving h divides the error by about 4)."""
    errors = []
    for N in (20, 40):
        ocp = free_initial_state(N)
        r = olado.solve(ocp, config=SQP)
        assert r.success, r.message
        s = ocp.solution(r)
        errors.append(r.objective - np.tanh(1.0))
        h = 1.0 / N
        assert 0 < errors[-1] < 0.1 * h * h
        assert abs(s.x0[0] - 1.0 / np.cosh(1.0)) < 0.05 * h * h
    assert 3.5 < errors[0] / errors[1] < 4.5


def test_free_initial_state_at_its_bound_is_exact():
    """x' = u, min int u^2, x(1) = 1 with x(0) <= 0.5: x(0) = 0.5, u = 0.5, J = 0.25 exactly."""
    ocp = OCP(lambda t, x, u, p: [u[0]], [0.0], controls=1, N=8, T=1.0, free_x0=[0], x0_bounds=(-1.0, 0.5),
              running_cost=lambda t, x, u, p: u[0] ** 2, terminal=lambda t, x, p: [x[0] - 1.0],
              terminal_equalities=[0])
    for config in (SQP, _ipopt()):
        r = olado.solve(ocp, config=config)
        s = ocp.solution(r)
        assert r.success and abs(r.objective - 0.25) < 1e-7 and abs(s.x0[0] - 0.5) < 1e-7, (config, r.message)
        np.testing.assert_allclose(s.u, 0.5, atol=1e-6)


def test_initial_cost_on_a_free_initial_state():
    """x' = u, min x(0)^2 + int_0^1 u^2 dt, x(1) = 1: u = 1/2 constant, x(0) = 1/2, J = 1/2, exact
    on any grid."""
    ocp = OCP(lambda t, x, u, p: [u[0]], [0.0], controls=1, N=5, T=1.0, free_x0=[0],
              initial_cost=lambda t, x, p: x[0] ** 2, running_cost=lambda t, x, u, p: u[0] ** 2,
              terminal=lambda t, x, p: [x[0] - 1.0], terminal_equalities=[0])
    for config in (SQP, _ipopt()):
        r = olado.solve(ocp, config=config)
        s = ocp.solution(r)
        assert r.success and abs(r.objective - 0.5) < 1e-8 and abs(s.x0[0] - 0.5) < 1e-7, (config, r.message)
    with pytest.raises(ProblemDefinitionError, match="initial_cost needs"):
        OCP(lambda t, x, u, p: [u[0]], [0.0], controls=1, T=1.0, initial_cost=lambda t, x, p: x[0] ** 2)


def oscillator_fit(substeps, bounds=(0.5, 10.0)):
    """x'' = -k x, x(0) = 1, x'(0) = 0, fitted to cos(2t) on [0, 3]: k = 4. No control."""
    return OCP(lambda t, x, u, p: [x[1], -p[0] * x[0]], [1.0, 0.0], controls=0, N=30, T=3.0, parameters=1,
               p_bounds=bounds, p_guess=[3.0], running_cost=lambda t, x, u, p: (x[0] - cos(2 * t)) ** 2,
               substeps=substeps)


def test_parameter_estimation_recovers_the_parameter():
    """The fitted k converges to 4 at fourth order in the step (RK4): 4 substeps per interval
    divide the error by about 4^4; sqp-ip, IPOPT and PDMIN (the parameter's bounds are control
    bounds of the parameter stage) agree."""
    err = {}
    for sub in (1, 4):
        ocp = oscillator_fit(sub)
        res = [olado.solve(ocp, config=c) for c in (SQP, _ipopt(), PDMIN)]
        assert all(r.success for r in res), [r.message for r in res]
        ks = [ocp.solution(r).p[0] for r in res]
        assert max(ks) - min(ks) < 1e-6 * (1 if sub == 1 else 0.1) + 1e-7
        err[sub] = abs(ks[0] - 4.0)
    assert err[1] < 2e-4 and err[4] < 1e-6 and err[1] / err[4] > 100


def test_unconstrained_parameter_estimation_by_ddp():
    """Without bounds the problem is unconstrained: DDP reaches the same parameter."""
    ocp = oscillator_fit(2, bounds=None)
    ref = olado.solve(ocp, config=SQP)
    r = olado.solve(ocp, config="configs/ddp.ini")
    assert ref.success and r.success, (ref.message, r.message)
    assert abs(ocp.solution(r).p[0] - ocp.solution(ref).p[0]) < 1e-6


# ---------------------------------------------------------------------------- a built-in problem
def vanderpol_ocp(N=50, path=False, method="rk4"):
    """VanDerPol (olado.problems.testproblems) written on OCP."""
    return OCP(lambda t, x, u, p: [(1 - x[1] ** 2) * x[0] - x[1] + u[0], x[0]], [0.0, 1.0], controls=1, N=N, T=5.0,
               running_cost=lambda t, x, u, p: x[0] ** 2 + x[1] ** 2 + u[0] ** 2, method=method,
               u_bounds=(-0.3, 1.0) if path else None, x_bounds=([-0.4, -np.inf], None) if path else None)


@pytest.mark.parametrize("method", ["rk4", "euler"])
def test_vanderpol_on_ocp_is_the_built_in_docp(method):
    """The same DOCP as the hand-written VanDerPol: values, first derivatives and Lagrangian
    Hessians agree to rounding at a random point."""
    ocp, hand = vanderpol_ocp(method=method), VanDerPol(N=50, method=method)
    rng = np.random.default_rng(3)
    U = rng.standard_normal((50, 1))
    report = check_derivatives(ocp, hand, hand.simulate(U), U, rtol=1e-11, atol=1e-13)
    assert report.ok, str(report)


@pytest.mark.parametrize("path", [False, True])
def test_vanderpol_on_ocp_same_optimum(path):
    """sqp-ip and IPOPT on the OCP version reach the built-in problem's regression objective."""
    key = ("vanderpol-path" if path else "vanderpol", "rk4")
    ocp = vanderpol_ocp(path=path)
    for config in (SQP, _ipopt()):
        r = olado.solve(ocp, config=config)
        assert r.success, (config, r.message)
        assert abs(r.objective - REGRESSION_VALUES[key]) < 1e-6, (config, r.objective)


# ---------------------------------------------------------------------------- derivatives


@pytest.mark.parametrize("method,substeps,equality", [("rk4", 2, False), ("euler", 3, False), ("rk4", 1, True)])
def test_derivatives_against_finite_differences(method, substeps, equality):
    """Jacobians, gradients and the stage and final Lagrangian Hessians through the integrator,
    substeps and the parameter stage, against central differences."""
    p = everything(method, substeps, equality)
    # x (2), T, p (2); controls: max(2, T + p (2) + x0_1 [+ the equality's stand-in]); N + 1 stages
    assert (p.n, p.m, p.N) == (5, 5 if equality else 4, 7)
    rng = np.random.default_rng(0)
    U = p.initial_guess() + 0.2 * rng.standard_normal((p.N, p.m))
    report = check_derivatives(p, None, p.simulate(U), U, sigma=1.3, rtol=1e-6, atol=1e-7)
    assert report.ok, str(report)


def test_parameter_stage_sets_the_augmented_state():
    """Stage 0 copies T, p and the free x0 component from its controls; the stages after keep T
    and p constant and the physical time runs from t0 to t0 + T."""
    p = everything()
    U = p.initial_guess()
    X = p.simulate(U)
    np.testing.assert_allclose(X[1], [0.2, 0.0, 1.4, 0.3, 0.7])
    np.testing.assert_allclose(X[1:, 2:], np.broadcast_to([1.4, 0.3, 0.7], (7, 3)))
    U[0, :4] = [2.0, -0.1, 0.4, 0.25]
    X = p.simulate(U)
    np.testing.assert_allclose(X[1], [0.2, 0.25, 2.0, -0.1, 0.4])
    s = p.solution((X, U))
    assert s.tf == 2.5 and s.t[0] == 0.5 and s.x0[1] == 0.25
    np.testing.assert_allclose(s.p, [-0.1, 0.4])


@pytest.mark.parametrize("equality", [False, True])
def test_everything_solved_by_sqp_and_ipopt(equality):
    """The problem with every feature: sqp-ip and IPOPT reach the same optimum (with a path
    equality too: its stand-in on the parameter stage keeps the Jacobian regular)."""
    p = everything(equality=equality)
    ref = olado.solve(p, config=_ipopt())
    r = olado.solve(p, config=SQP)
    assert ref.success and r.success, (ref.message, r.message)
    assert abs(r.objective - ref.objective) < 1e-6 * max(1.0, abs(ref.objective))
    assert abs(p.solution(r).tf - p.solution(ref).tf) < 1e-5


# ---------------------------------------------------------------------------- refusals
def test_refusals_name_the_argument():
    f = lambda t, x, u, p: [u[0]]  # noqa: E731
    with pytest.raises(ProblemDefinitionError, match="minimum_time needs a free final time"):
        OCP(f, [0.0], controls=1, T=1.0, minimum_time=True)
    with pytest.raises(ProblemDefinitionError, match="method"):
        OCP(f, [0.0], controls=1, T=1.0, method="rk45")
    with pytest.raises(ProblemDefinitionError, match=r"rhs.*returned 2 entries, expected 1"):
        OCP(lambda t, x, u, p: [u[0], x[0]], [0.0], controls=1, T=1.0, N=4)
    with pytest.raises(ProblemDefinitionError, match=r"running_cost.*expected 1"):
        OCP(f, [0.0], controls=1, T=1.0, running_cost=lambda t, x, u, p: [u[0], x[0]])
    with pytest.raises(ProblemDefinitionError, match=r"path.*symbolic arguments.*no Python branch"):
        OCP(f, [0.0], controls=1, T=1.0, path=lambda t, x, u, p: [x[0] if x[0] > 0 else -x[0]])


# ---------------------------------------------------------------------------- the documented example
def power_limited_car(N=60):
    """docs/continuous-time.md and the README: minimum time to a stop 10 m away, |u| <= 1, drag,
    v >= 0, power u v <= 1 as a path constraint."""
    return olado.OCP(rhs=lambda t, x, u, p: [x[1], u[0] - 0.1 * x[1] ** 2], x0=[0.0, 0.0], controls=1, N=N,
                     T=None, T_bounds=(1.0, 100.0), T_guess=10.0, minimum_time=True,
                     u_bounds=(-1.0, 1.0), x_bounds=([-np.inf, 0.0], None),
                     path=lambda t, x, u, p: [1.0 - u[0] * x[1]],
                     terminal=lambda t, x, p: [x[0] - 10.0, x[1]], terminal_equalities=[0, 1])


def test_documented_example_by_sqp_and_ipopt():
    """sqp-ip and IPOPT agree; the arcs are those of the continuous problem: u = 1 while the speed
    is below sqrt(10) tanh(t / sqrt(10)) < 1 (the drag-limited acceleration from rest, closed form),
    then the power limit u v = 1 active, then u = -1."""
    car = power_limited_car()
    ref = olado.solve(car, config=_ipopt())
    r = olado.solve(car, config=SQP)
    assert ref.success and r.success, (ref.message, r.message)
    s = car.solution(r)
    assert abs(s.tf - car.solution(ref).tf) < 1e-6 and abs(s.tf - 7.161434) < 1e-6
    assert s.tf > 2 * np.sqrt(10.0)                    # slower than without drag and power limit
    v, u = s.x[:, 1], s.u[:, 0]
    free = s.t[:-1] < np.sqrt(10) * np.arctanh(1 / np.sqrt(10)) - 1e-9
    np.testing.assert_allclose(u[free], 1.0, atol=1e-6)
    np.testing.assert_allclose(v[:-1][free], np.sqrt(10) * np.tanh(s.t[:-1][free] / np.sqrt(10)), atol=1e-6)
    power = u * v[:-1]
    assert power.max() <= 1.0 + 1e-7 and np.sum(power > 1 - 1e-6) >= 30
    assert np.all(u[-15:] < -1 + 1e-6)


def test_documented_example_by_penalty_with_ddp_inside():
    """The augmented-Lagrangian penalty method with DDP as its inner method reaches the same t_f."""
    r = olado.solve(power_limited_car(), config="configs/penalty-al.ini", inner="ddp")
    assert r.success, r.message
    assert abs(r.objective - 7.161434082829409) < 1e-6


# ---------------------------------------------------------------------------- free final time vs ContinuousDOCP
def brachistochrone_ocp(N=50):
    """literature.Brachistochrone (a ContinuousDOCP with its own parameter stage) on OCP."""
    g = 9.81
    return OCP(lambda t, x, u, p: [x[2] * cos(u[0]), x[2] * sin(u[0]), g * sin(u[0])], [0.0, 0.0, 0.0],
               controls=1, N=N, T=None, T_bounds=(0.01, 10.0), T_guess=1.0, minimum_time=True,
               u_bounds=(-np.pi / 2, np.pi / 2), u_guess=np.pi / 4,
               terminal=lambda t, x, p: [x[0] - 1.0], terminal_equalities=[0])


def test_free_final_time_is_the_continuous_docp_transcription():
    """With a free final time OCP builds the DOCP that ContinuousDOCP builds by hand for the
    brachistochrone (N intervals = its N - 1 steps): the same values and first derivatives
    (its Hessians are finite differences: compared loosely), and the same optimum near the
    cycloid's T* = sqrt(pi / g)."""
    from olado.problems.literature import Brachistochrone

    ocp, hand = brachistochrone_ocp(50), Brachistochrone(N=51)
    assert (ocp.n, ocp.m, ocp.N) == (hand.n, hand.m, hand.N)
    U = hand.initial_guess() + 0.1 * np.random.default_rng(2).standard_normal((hand.N, 1))
    np.testing.assert_array_equal(ocp.initial_guess(), hand.initial_guess())
    X = hand.simulate(U)
    report = check_derivatives(ocp, hand, X, U, rtol=1e-11, atol=1e-13, hessians=False)
    assert report.ok, str(report)
    report = check_derivatives(ocp, hand, X, U, rtol=1e-4, atol=1e-6)
    assert report.ok, str(report)
    r_ocp = olado.solve(ocp, config=SQP)
    r_hand = olado.solve(hand, config=SQP)
    assert r_ocp.success and r_hand.success, (r_ocp.message, r_hand.message)
    assert abs(r_ocp.objective - r_hand.objective) < 1e-8
    assert abs(r_ocp.objective - np.sqrt(np.pi / 9.81)) < 1e-4


def rayleigh_ocp(N=50):
    """Rayleigh (testproblems, box variant) on OCP."""
    return OCP(lambda t, x, u, p: [x[1], -x[0] + x[1] * (1.4 - 0.14 * x[1] ** 2) + 4 * u[0]], [-5.0, -5.0],
               controls=1, N=N, T=4.5, running_cost=lambda t, x, u, p: u[0] ** 2 + x[0] ** 2, u_bounds=(-1.0, 1.0))


def bang_bang_cart_ocp(N=50):
    """literature.BangBangCart (minimum time, free T by ContinuousDOCP's parameter stage) on OCP."""
    return OCP(lambda t, x, u, p: [x[1], u[0]], [1.0, 1.0], controls=1, N=N, T=None, T_bounds=(0.1, 20.0),
               T_guess=4.0, minimum_time=True, u_bounds=(-1.0, 1.0), u_guess=0.0,
               terminal=lambda t, x, p: [x[0], x[1]], terminal_equalities=[0, 1])


@pytest.mark.parametrize("name", ["rayleigh-box", "bang-bang-cart"])
def test_more_built_ins_on_ocp(name):
    """Two more built-in problems written on OCP: the same DOCP (start, values, first derivatives
    to rounding; bang-bang-cart's own Hessians are finite differences: compared loosely) and the
    same optimum by sqp-ip (rayleigh-box)."""
    from olado.problems import get_problems

    hand = get_problems()[name](N=51 if name == "bang-bang-cart" else 50)
    ocp = bang_bang_cart_ocp() if name == "bang-bang-cart" else rayleigh_ocp()
    assert (ocp.n, ocp.m, ocp.N, ocp.rN) == (hand.n, hand.m, hand.N, hand.rN)
    np.testing.assert_array_equal(ocp.initial_guess(), hand.initial_guess())
    np.testing.assert_array_equal(ocp.u_bounds, hand.u_bounds)
    U = hand.initial_guess() + 0.1 * np.random.default_rng(5).standard_normal((hand.N, 1))
    X = hand.simulate(U)
    exact = name == "rayleigh-box"
    assert check_derivatives(ocp, hand, X, U, rtol=1e-11, atol=1e-12, hessians=exact).ok
    assert check_derivatives(ocp, hand, X, U, rtol=1e-4, atol=1e-6).ok
    if exact:     # (bang-bang-cart: 32 sqp-ip iterations each way, 3.4502106346; the brachistochrone test solves a free-time one)
        r_ocp, r_hand = olado.solve(ocp, config=SQP), olado.solve(hand, config=SQP)
        assert r_ocp.success and r_hand.success, (r_ocp.message, r_hand.message)
        assert abs(r_ocp.objective - r_hand.objective) < 1e-8 * max(1.0, abs(r_hand.objective))
        assert abs(r_ocp.objective - REGRESSION_VALUES[(name, "rk4")]) < 1e-6


# ---------------------------------------------------------------------------- time, grid, guesses
@pytest.mark.parametrize("free", [False, True])
def test_time_reaches_the_rk4_stages_on_a_nonuniform_grid(free):
    """x' = t^3 from x(t0) = 0: RK4 (Simpson's rule in t) is exact for cubics, so x at the grid
    points is (t^4 - t0^4)/4 on any grid, with a fixed or a free (time-scaled) final time."""
    grid = np.array([0.0, 0.1, 0.35, 0.5, 0.9, 1.0])
    ocp = OCP(lambda t, x, u, p: [t ** 3 + 0 * u[0]], [0.0], controls=1, N=5, grid=grid, t0=0.5,
              T=None if free else 2.0, T_guess=2.0)
    U = ocp.initial_guess()
    s = ocp.solution((ocp.simulate(U), U))
    np.testing.assert_allclose(s.t, 0.5 + 2.0 * grid)
    np.testing.assert_allclose(s.x[:, 0], (s.t ** 4 - 0.5 ** 4) / 4, rtol=1e-13)


def test_guesses_and_x0_are_checked():
    f = lambda t, x, u, p: [u[0]]  # noqa: E731
    with pytest.raises(ProblemDefinitionError, match="x0.*outside its bounds"):
        OCP(f, [2.0], controls=1, T=1.0, x_bounds=(0.0, 1.0))
    OCP(f, [2.0], controls=1, T=1.0, x_bounds=(0.0, 1.0), free_x0=[0])      # free: a guess only
    with pytest.raises(ProblemDefinitionError, match="u_guess"):
        OCP(f, [0.0], controls=1, N=4, T=1.0, u_guess=np.zeros(3))
    ocp = OCP(f, [0.0], controls=1, N=4, T=1.0, u_guess=np.arange(4.0)[:, None])
    np.testing.assert_array_equal(ocp.initial_guess()[:, 0], np.arange(4.0))
    x_guess = np.linspace(0, 1, 5)[:, None]
    ocp = OCP(f, [0.0], controls=1, N=4, T=None, T_guess=3.0, x_guess=x_guess)
    X = ocp.initial_state_guess(ocp.initial_guess())
    np.testing.assert_array_equal(X[1:, 0], x_guess[:, 0])
    np.testing.assert_array_equal(X[1:, 1], 3.0)
