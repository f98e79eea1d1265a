"""The numeric back-end of OCP and AutoDiffDOCP (ad_backend="numpy", the fallback without the
``ad`` extra; olado/problems/autodiff/numpy_backend.py, docs/autodiff.md "Without CasADi").

Forced on problems that also run on CasADi: the same values to the last bit (the same arithmetic
on numpy arrays), the derivatives within the accuracy of central differences, and solves that
reach the same optimum; the fallback chosen when CasADi is reported missing, said once, and
named in the result. The CasADi side of the comparisons skips without the extra.
"""

from __future__ import annotations

import importlib.util
import warnings

import numpy as np
import pytest

import olado
from olado.errors import AutoDiffNotAvailableError, ProblemDefinitionError
from olado.problems import check_derivatives
from olado.problems.autodiff import AutoDiffDOCP, backends, cos, sin
from olado.problems.ocp import OCP
from fixtures.ocp_problems import everything

SQP, IPOPT = "configs/sqp-ip.ini", "configs/ipopt.ini"


def power_limited_car(backend):
    """The documented example (docs/continuous-time.md): a path constraint, a state bound,
    terminal equalities and a free final time."""
    return OCP(rhs=lambda t, x, u, p: [x[1], u[0] - 0.1 * x[1] ** 2], x0=[0.0, 0.0], controls=1, N=60,
               T=None, T_bounds=(1.0, 100.0), T_guess=10.0, minimum_time=True,
               u_bounds=(-1.0, 1.0), x_bounds=([-np.inf, 0.0], None), path=lambda t, x, u, p: [1.0 - u[0] * x[1]],
               terminal=lambda t, x, p: [x[0] - 10.0, x[1]], terminal_equalities=[0, 1], ad_backend=backend)


def _point(p, seed=0, scale=0.2):
    U = p.initial_guess() + scale * np.random.default_rng(seed).standard_normal((p.N, p.m))
    return p.simulate(U), U


@pytest.mark.parametrize("method,substeps,equality", [("rk4", 2, False), ("euler", 3, False), ("rk4", 1, True)])
def test_numpy_back_end_is_the_casadi_docp(method, substeps, equality):
    """The same DOCP as the CasADi back-end: start, bounds and values equal (the same arithmetic),
    first derivatives to 1e-8 and Hessian blocks to 1e-6 (central differences, step eps^(1/3),
    second differences eps^(1/4))."""
    pytest.importorskip("casadi")
    a, b = everything(method, substeps, equality, ad_backend="numpy"), everything(method, substeps, equality, ad_backend="casadi")
    assert a.backend_used() == "numpy" and not a.provides("dynamics_jacobian") and b.provides("dynamics_jacobian")
    assert all("finite differences" in s for s in a.derivative_sources().values())
    np.testing.assert_array_equal(a.initial_guess(), b.initial_guess())
    np.testing.assert_array_equal(a.u_lower, b.u_lower)
    np.testing.assert_array_equal(a.x_upper, b.x_upper)
    X, U = _point(b)
    np.testing.assert_allclose(a.simulate(U), X, rtol=1e-14, atol=1e-15)
    values = check_derivatives(a, b, X, U, rtol=1e-14, atol=1e-15, hessians=False)
    for name in ("dynamics", "stage_cost", "final_cost", "stage_constraints", "final_constraints"):
        assert values[name].ok, str(values)
    assert check_derivatives(a, b, X, U, sigma=1.3, rtol=1e-8, atol=1e-9, hessians=False).ok
    report = check_derivatives(a, b, X, U, sigma=1.3, rtol=1e-6, atol=1e-7)
    assert report.ok, str(report)


@pytest.mark.parametrize("config", [SQP, "ipopt"])
def test_numpy_back_end_reaches_the_same_optimum(config):
    """The documented car on both back-ends: the same status and t_f (to the accuracy of the
    stopping test) by sqp-ip and IPOPT."""
    pytest.importorskip("casadi")
    if config == "ipopt":
        pytest.importorskip("cyipopt")
        config = IPOPT
    ra, rb = (olado.solve(power_limited_car(b), config=config) for b in ("numpy", "casadi"))
    assert ra.success and rb.success, (ra.message, rb.message)
    assert abs(ra.objective - rb.objective) < 1e-8 and abs(ra.objective - 7.161434) < 1e-6
    assert "pip install olado[ad]" in ra.info["derivatives"] and "derivatives" not in rb.info
    assert "derivatives  : derivatives by central finite differences" in ra.summary()


class Pendulum(AutoDiffDOCP):
    """An AutoDiffDOCP (stage data, path and final constraints) for the generic numpy model."""

    def __init__(self, backend, N=12):
        self.ad_backend = backend
        super().__init__(2, 1, N, np.array([0.3, 0.0]), u_bounds=(-2, 2), n_stage_constraints=1,
                         n_final_constraints=2, final_equalities=[0])

    def stage_data(self):
        return np.linspace(0.05, 0.1, self.N)[:, None]

    def stage(self, x, u, d):
        h = d[0]
        return [x[0] + h * x[1], x[1] + h * (-sin(x[0]) + u[0])], h * (x[0] ** 2 + u[0] ** 2), [1.0 - x[1] ** 2]

    def final(self, x):
        return 3 * x[0] ** 2, [x[1], 0.5 - x[0] * cos(x[0])]


def test_autodiff_docp_on_the_numpy_back_end():
    """An AutoDiffDOCP subclass runs on the numeric back-end unchanged: its values are the
    CasADi model's, its derivatives finite differences of them."""
    pytest.importorskip("casadi")
    a, b = Pendulum("numpy"), Pendulum("casadi")
    X, U = _point(b, scale=0.5)
    np.testing.assert_array_equal(a.simulate(U), X)
    assert check_derivatives(a, b, X, U, rtol=1e-6, atol=1e-7).ok
    assert "of the numpy-evaluated model" in a.describe()
    with pytest.raises(ProblemDefinitionError, match="provides no dynamics_jacobian"):
        a.dynamics_jacobian(np.arange(a.N), X[:-1], U)


class _Blowup(AutoDiffDOCP):
    """x+ = x + log(x)/2 - u from x0 = 2 under u = 1: x^3 < 0, so x^4 is NaN."""

    ad_backend = "numpy"

    def __init__(self):
        super().__init__(1, 1, 6, np.array([2.0]))

    def stage(self, x, u, d):
        return [x[0] + 0.5 * np.log(x[0]) - u[0]], u[0] * u[0]


def test_numpy_simulation_is_docps_loop():
    """simulate on the numpy back-end (NumpyModel.simulate: one model call per stage without
    DOCP's per-call handling) gives DOCP's loop of one-stage calls to the last bit -- stage data,
    parameter stage and substeps included -- and the same error, naming the first stage whose
    x^{k+1} is not finite."""
    from olado.errors import NonFiniteEvaluationError
    from olado.problems.docp import DOCP
    for p in (everything("rk4", 2, True, ad_backend="numpy"), everything("euler", 3, ad_backend="numpy"),
              power_limited_car("numpy")):
        U = p.initial_guess() + 0.2 * np.random.default_rng(1).standard_normal((p.N, p.m))
        calls = p.counters["dynamics"]
        np.testing.assert_array_equal(p.simulate(U), DOCP.simulate(p, U))
        assert p.counters["dynamics"] == calls + 2
    p = _Blowup()
    with pytest.raises(NonFiniteEvaluationError) as ours:
        p.simulate(np.ones((6, 1)))
    with pytest.raises(NonFiniteEvaluationError) as docps:
        DOCP.simulate(p, np.ones((6, 1)))
    assert str(ours.value) == str(docps.value) and "stage k=3" in str(ours.value)


@pytest.fixture
def no_casadi(monkeypatch):
    """CasADi reported missing (importlib's spec lookup), the one-time note not yet given."""
    real = importlib.util.find_spec
    monkeypatch.setattr(backends.importlib.util, "find_spec", lambda name, *a: None if name == "casadi" else real(name, *a))
    monkeypatch.setattr(backends, "_noted", False)


def test_without_casadi_auto_falls_back_once(no_casadi):
    """"auto" (the default) takes the numeric back-end, says so once per process by a warning
    naming the extra, and every result carries the note; asking for CasADi still names the
    extra; an unknown back-end is refused."""
    with pytest.warns(UserWarning, match=r"CasADi is not installed.*pip install olado\[ad\]"):
        car = power_limited_car("auto")
    assert car.backend_used() == "numpy"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = Pendulum("auto")
    assert again.backend_used() == "numpy"
    r = olado.solve(car, config=SQP)
    assert r.success and abs(r.objective - 7.161434) < 1e-6, r.message
    assert "pip install olado[ad]" in r.info["derivatives"]
    with pytest.raises(AutoDiffNotAvailableError, match=r"pip install olado\[ad\].*ad_backend='numpy'"):
        power_limited_car("casadi")
    with pytest.raises(ProblemDefinitionError, match="ad_backend must be 'auto', 'casadi' or 'numpy'"):
        power_limited_car("jax")


def test_a_branch_on_a_value_is_refused_on_numpy_too():
    """A Python branch on x fails when the functions are first called (on two sample stages),
    named, as it does on CasADi symbols."""
    with pytest.raises(ProblemDefinitionError, match=r"path.*no Python branch"):
        OCP(lambda t, x, u, p: [u[0]], [0.0], controls=1, T=1.0, ad_backend="numpy",
            path=lambda t, x, u, p: [x[0] if x[0] > 0 else -x[0]])


def test_built_ins_without_casadi():
    """The built-in ODE problems run on the numpy back-end: vanderpol-path (an OCP) reaches its
    regression objective by sqp-ip, and brachistochrone (a ContinuousOCP) has the CasADi
    problem's values to the bit and its first derivatives to FD accuracy."""
    from olado.problems.literature import Brachistochrone
    from olado.problems.testproblems import REGRESSION_VALUES, VanDerPol

    p = VanDerPol(N=50, path=True, ad_backend="numpy")
    r = olado.solve(p, config=SQP)
    assert r.success, r.message
    assert abs(r.objective - REGRESSION_VALUES[("vanderpol-path", "rk4")]) < 1e-6
    assert "finite differences" in r.info["derivatives"]
    pytest.importorskip("casadi")
    a, b = Brachistochrone(ad_backend="numpy"), Brachistochrone(ad_backend="casadi")
    X, U = _point(b, scale=0.05)
    assert check_derivatives(a, b, X, U, rtol=1e-15, atol=1e-15, hessians=False)["dynamics"].ok
    assert check_derivatives(a, b, X, U, rtol=1e-7, atol=1e-8, hessians=False).ok
