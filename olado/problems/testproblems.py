"""Built-in test problems with known answers: a linear-quadratic DOCP with analytic derivatives
and nonlinear control problems from the literature written on :class:`~olado.problems.ocp.OCP`.

Registered in :data:`PROBLEMS` (name -> factory(N=..., **kwargs)):

==================  =======================================================================
``lq``              linear-quadratic DOCP, n = 4, m = 2, stationary (A, B) with an unstable
                    mode; exact solution by the discrete Riccati recursion (:class:`LinearQuadratic`)
``lq-box``          the same with |u_i| <= umax (for the bound-constrained methods)
``vanderpol``       Van der Pol oscillator, Luus (2000) (:class:`VanDerPol`)
``vanderpol-box``   the same with -0.3 <= u <= 1 (Luus 2000)
``vanderpol-path``  the same with the path constraint x1 >= -0.4 (Vassiliadis et al. 1994) as a
                    state bound, plus the control bounds
``rayleigh``        Rayleigh problem, Maurer and Augustin (2001) (:class:`Rayleigh`)
``rayleigh-box``    the same with |u| <= 1
``cstr``            continuous stirred-tank reactor, Lapidus and Luus (1967), Luus (2000)
                    (:class:`CSTR`)
==================  =======================================================================

The nonlinear problems are continuous-time Lagrange problems  min int_0^T L(x, u) dt,
x' = f(x, u), discretized with piecewise-constant controls on N steps of length h (default
h = T/N) by explicit Euler or by the classical Runge-Kutta method (RK4, the default). The running
cost is integrated by the same scheme as an extra quadrature state c' = L(x, u), so that

    x^{k+1} = Phi_h(x^k, u^k)  (first n components of the step of (f, L)),
    f_0^k(x^k, u^k) = c-component of that step  (h L(x^k, u^k) for Euler),

i.e. paper 001 eqs. (1)-(2) with F^N = 0: OCP's transcription with one step per interval. The
model (f, L) is written once (:meth:`ODEProblem.ode_rhs`, :meth:`ODEProblem.ode_cost`); with the
``ad`` extra the values, the exact first derivatives and the Lagrangian Hessians of the step map
are CasADi's, compiled and vectorized over the stages, and the sequential simulation one compiled
loop (docs/continuous-time.md); without it the model is evaluated by numpy and differentiated
by finite differences.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import ProblemDefinitionError
from .autodiff.functions import exp
from .docp import DOCP
from .ocp import OCP

__all__ = ["LinearQuadratic", "VanDerPol", "Rayleigh", "CSTR", "ODEProblem", "PROBLEMS",
           "REGRESSION_VALUES"]


# ============================================================================ linear-quadratic
class LinearQuadratic(DOCP):
    """Linear-quadratic DOCP (paper 001 eqs. (1)-(2) with linear f^k and quadratic f_0^k, F^N):

        x^{k+1} = A x^k + B u^k,
        f_0^k = 1/2 x'Q x + x'S u + 1/2 u'R u,      F^N = 1/2 x'Q_N x,   x^0 fixed.

    The default data (n = 4, m = 2) has an unstable open-loop mode (A has the eigenvalue 1.1),
    [Q S; S' R] > 0 with a nonzero cross term S, and Q_N = 10 I. Without bounds the unique
    optimum is given by the backward Riccati recursion

        P_N = Q_N,  K_k = (R + B'P B)^{-1} (S' + B'P A),  P_k = Q + A'P A - (S + A'P B) K_k,
        u^k = -K_k x^k,   J* = 1/2 x0' P_0 x0

    (Bryson and Ho, Applied Optimal Control, 1975, sec. 2.3; the tests recompute it in numpy).
    ``umax`` adds the bounds |u_i| <= umax (``lq-box``). Any A, B, Q, S, R, Q_N, x0 may be given.
    Optimal values at N = 50: J* = 13.0669348 (``lq``), 16.0606421 (``lq-box``, umax = 1).
    """

    name = "lq"
    vectorized = True

    A_DEFAULT = np.array([[1.1, 0.2, 0.0, 0.0],
                          [0.0, 0.9, 0.1, 0.0],
                          [0.0, -0.1, 0.8, 0.1],
                          [0.1, 0.0, 0.0, 0.95]])
    B_DEFAULT = np.array([[0.0, 0.0],
                          [0.1, 0.0],
                          [0.0, 0.1],
                          [0.05, 0.1]])
    Q_DEFAULT = np.diag([1.0, 0.5, 0.5, 1.0])
    S_DEFAULT = np.array([[0.02, 0.0],
                          [0.0, 0.02],
                          [0.01, 0.0],
                          [0.0, 0.01]])
    R_DEFAULT = np.diag([0.1, 0.2])
    QN_DEFAULT = 10.0 * np.eye(4)
    X0_DEFAULT = np.array([1.0, -1.0, 0.5, 2.0])

    def __init__(self, N=50, *, A=None, B=None, Q=None, S=None, R=None, QN=None, x0=None,
                 umax=None, **options):
        A = self.A_DEFAULT if A is None else np.asarray(A, dtype=float)
        B = self.B_DEFAULT if B is None else np.asarray(B, dtype=float)
        n, m = B.shape
        self.A, self.B = A.copy(), B.copy()
        self.Q = (self.Q_DEFAULT if Q is None else np.asarray(Q, dtype=float)).copy()
        self.S = (self.S_DEFAULT if S is None else np.asarray(S, dtype=float)).copy()
        self.R = (self.R_DEFAULT if R is None else np.asarray(R, dtype=float)).copy()
        self.QN = (self.QN_DEFAULT if QN is None else np.asarray(QN, dtype=float)).copy()
        for arr, shape, nm in ((self.A, (n, n), "A"), (self.Q, (n, n), "Q"), (self.S, (n, m), "S"),
                               (self.R, (m, m), "R"), (self.QN, (n, n), "QN")):
            if arr.shape != shape:
                raise ProblemDefinitionError(f"expected shape {shape}, got {arr.shape}", function="__init__", array=nm)
        x0 = self.X0_DEFAULT if x0 is None else x0
        self.umax = umax
        if umax is not None:
            options.setdefault("u_bounds", (-float(umax), float(umax)))
            if "name" not in options:
                self.name = "lq-box"
        if "name" in options:
            self.name = options.pop("name")
        super().__init__(n, m, N, x0, **options)
        self._H = np.block([[self.Q, self.S], [self.S.T, self.R]])

    # values
    def dynamics(self, k, x, u):
        return x @ self.A.T + u @ self.B.T

    def stage_cost(self, k, x, u):
        return 0.5 * np.einsum("ki,ij,kj->k", x, self.Q, x) + np.einsum("ki,ij,kj->k", x, self.S, u) \
            + 0.5 * np.einsum("ki,ij,kj->k", u, self.R, u)

    def final_cost(self, x):
        return 0.5 * float(x @ self.QN @ x)

    # derivatives
    def dynamics_jacobian(self, k, x, u):
        K = len(k)
        return np.broadcast_to(self.A, (K,) + self.A.shape), np.broadcast_to(self.B, (K,) + self.B.shape)

    def stage_cost_gradient(self, k, x, u):
        return x @ self.Q + u @ self.S.T, x @ self.S + u @ self.R

    def final_cost_gradient(self, x):
        return self.QN @ x

    def stage_hessian(self, k, x, u, sigma, p, lam):
        K, n = len(k), self.n
        return (np.broadcast_to(sigma * self.Q, (K, n, n)), np.broadcast_to(sigma * self.S, (K, n, self.m)),
                np.broadcast_to(sigma * self.R, (K, self.m, self.m)))

    def final_hessian(self, x, sigma, lam):
        return sigma * self.QN

    def simulate(self, U):
        """States under controls U by the linear recursion (compiled: long horizons)."""
        U = self.check_array(U, (self.N, self.m), "simulate", "u")
        self.counters["dynamics"] += 1
        X = np.empty((self.N + 1, self.n))
        _linear_simulate(np.ascontiguousarray(self.A), np.ascontiguousarray(self.B), self.x0,
                         np.ascontiguousarray(U), X)
        return self._check_stacked(X, (self.N + 1, self.n), "simulate", "x")


@nb.njit(cache=True)
def _linear_simulate(A, B, x0, U, X):
    N, m = U.shape
    n = x0.shape[0]
    for i in range(n):
        X[0, i] = x0[i]
    for k in range(N):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += A[i, j] * X[k, j]
            for j in range(m):
                s += B[i, j] * U[k, j]
            X[k + 1, i] = s


# ============================================================================ ODE problems
class ODEProblem(OCP):
    """Base of the discretized continuous-time Lagrange problems (module docstring), written on
    :class:`~olado.problems.ocp.OCP`: ``N`` intervals of length h = T/N, one Euler or RK4 step
    each, the running cost integrated by the same step (OCP's transcription with ``substeps=1``
    is this module's). Exact derivatives with the ``ad`` extra, finite differences without it.

    Subclasses set ``T_DEFAULT``, ``X0_DEFAULT``, ``PARAMS`` and write :meth:`ode_rhs` and
    :meth:`ode_cost` (``x``, ``u`` indexed entries, ``self.params`` numbers).

    Parameters
    ----------
    N : number of steps (stages), any N >= 1.
    T : final time; default the literature's. Ignored when ``h`` is given.
    h : step length; default T/N (then the horizon is N*h).
    method : ``"rk4"`` (default) or ``"euler"``.
    x0 : initial state; default the literature's.
    params : the model's constants (default ``PARAMS``).
    path_constraints : OCP's ``path`` (g(t, x, u, p) >= 0 at k = 0..N-1; ``path`` is a variant's
        flag in :class:`VanDerPol`).
    x_bounds : DOCP's state bounds (stationary or per stage, rows 0..N; x0 may violate row 0).
    u_bounds, path_equalities, u_guess, name, mode, ad_backend : as for
        :class:`~olado.problems.ocp.OCP`.
    """

    T_DEFAULT = 1.0
    X0_DEFAULT = np.zeros(2)
    PARAMS = ()
    M = 1

    def __init__(self, N=50, *, T=None, h=None, method="rk4", x0=None, params=None, x_bounds=None,
                 path_constraints=None, **options):
        if method not in ("rk4", "euler"):
            raise ProblemDefinitionError(f"method must be 'rk4' or 'euler', got {method!r}", function="__init__", array="method")
        if not isinstance(N, (int, np.integer)) or isinstance(N, bool) or N < 1:
            raise ProblemDefinitionError(f"N must be a positive integer, got {N!r}", function="__init__", array="N")
        if h is None:
            T = float(self.T_DEFAULT if T is None else T)
            if not T > 0:
                raise ProblemDefinitionError(f"T must be positive, got {T!r}", function="__init__", array="T")
            h = T / N
        h = float(h)
        if not h > 0 or not np.isfinite(h):
            raise ProblemDefinitionError(f"h must be positive, got {h!r}", function="__init__", array="h")
        self.h, self.T = h, h * N
        self.params = np.array(self.PARAMS if params is None else params, dtype=float)
        x0 = self.X0_DEFAULT if x0 is None else x0
        options.setdefault("name", type(self).name)
        super().__init__(self._rhs, x0, controls=self.M, N=int(N), T=self.T, running_cost=self._cost,
                         method=method, path=path_constraints, **options)
        # DOCP's state bounds, on every stage: also on the fixed x^0, which may lie outside them
        # (moot there, issue 13; OCP would refuse such an x0)
        self.x_bounds = x_bounds

    def _rhs(self, t, x, u, p):
        return self.ode_rhs(x, u)

    def _cost(self, t, x, u, p):
        return self.ode_cost(x, u)

    def ode_rhs(self, x, u):
        """f(x, u), a list of n entries (every subclass writes it)."""
        raise ProblemDefinitionError(f"{type(self).__name__} must define ode_rhs(x, u)", function="ode_rhs")

    def ode_cost(self, x, u):
        """L(x, u), the running cost (every subclass writes it: these are Lagrange problems)."""
        raise ProblemDefinitionError(f"{type(self).__name__} must define ode_cost(x, u)", function="ode_cost")

    def stage_data(self):
        """OCP's rows (t_k, h, 0) with t_k = k h and every step exactly h (not a difference of
        grid points)."""
        return np.column_stack([self.h * np.arange(self.N), np.full(self.N, self.h), np.zeros(self.N)])

    def describe(self):
        return super().describe() + f"\n  {self.method} steps h = {self.h:g}, horizon T = {self.T:g}"


class VanDerPol(ODEProblem):
    """Van der Pol oscillator optimal control (Luus, Iterative Dynamic Programming, Chapman &
    Hall/CRC 2000, the Van der Pol problem; also Vassiliadis, Sargent and Pantelides, Ind. Eng.
    Chem. Res. 33 (1994) 2123-2133)::

        min int_0^5 (x1^2 + x2^2 + u^2) dt,
        x1' = (1 - x2^2) x1 - x2 + u,   x2' = x1,   x(0) = (0, 1).

    Variants: ``box`` adds Luus's control bounds -0.3 <= u <= 1 (``vanderpol-box``); ``path``
    adds in addition the path constraint x1(t) >= -0.4 of Vassiliadis et al. as the state bound
    x1^k >= -0.4, k = 0..N (``vanderpol-path``).

    Optimal values at N = 50 (IPOPT; :data:`REGRESSION_VALUES`): RK4 2.869255 (box 2.869366,
    path 2.956223), Euler 3.080345 (box 3.081408, path 3.162178).
    """

    name = "vanderpol"
    T_DEFAULT = 5.0
    X0_DEFAULT = np.array([0.0, 1.0])
    PARAMS = (0.0,)
    U_BOUNDS = (-0.3, 1.0)
    X1_MIN = -0.4

    def __init__(self, N=50, *, box=False, path=False, **options):
        name = "vanderpol"
        if box or path:
            options.setdefault("u_bounds", self.U_BOUNDS)
            name = "vanderpol-box"
        if path:
            options.setdefault("x_bounds", ([self.X1_MIN, -np.inf], None))
            name = "vanderpol-path"
        options.setdefault("name", name)
        super().__init__(N, **options)

    def ode_rhs(self, x, u):
        return [(1.0 - x[1] * x[1]) * x[0] - x[1] + u[0], x[0]]

    def ode_cost(self, x, u):
        return x[0] * x[0] + x[1] * x[1] + u[0] * u[0]


class Rayleigh(ODEProblem):
    """The Rayleigh problem (electric circuit with a tunnel diode; Maurer and Augustin,
    "Sensitivity analysis and real-time control of parametric optimal control problems using
    boundary value methods", in Online Optimization of Large Scale Systems, Springer 2001,
    pp. 17-55)::

        min int_0^4.5 (u^2 + x1^2) dt,
        x1' = x2,   x2' = -x1 + x2 (1.4 - p x2^2) + 4 u,   x(0) = (-5, -5),   p = 0.14.

    ``params = (1.4, p, 4)``. Variant ``box``: the control constraint |u| <= 1 of the same
    source (``rayleigh-box``). Optimal values at N = 50 (IPOPT; :data:`REGRESSION_VALUES`):
    RK4 29.792202 (box 44.606857), Euler 31.904625 (box 46.474999).
    """

    name = "rayleigh"
    T_DEFAULT = 4.5
    X0_DEFAULT = np.array([-5.0, -5.0])
    PARAMS = (1.4, 0.14, 4.0)

    def __init__(self, N=50, *, box=False, **options):
        if box:
            options.setdefault("u_bounds", (-1.0, 1.0))
        options.setdefault("name", "rayleigh-box" if box else "rayleigh")
        super().__init__(N, **options)

    def ode_rhs(self, x, u):
        a, p, b = self.params
        return [x[1], -x[0] + x[1] * (a - p * x[1] * x[1]) + b * u[0]]

    def ode_cost(self, x, u):
        return u[0] * u[0] + x[0] * x[0]


class CSTR(ODEProblem):
    """Continuous stirred-tank reactor with a first-order irreversible exothermic reaction
    (Lapidus and Luus, Optimal Control of Engineering Processes, Blaisdell 1967; Luus, Iterative
    Dynamic Programming, Chapman & Hall/CRC 2000; x1, x2 deviations of temperature and
    concentration from the steady state, u the coolant flow)::

        min int_0^0.78 (x1^2 + x2^2 + 0.1 u^2) dt,
        x1' = -(2 + u)(x1 + 0.25) + (x2 + 0.5) exp(25 x1 / (x1 + 2)),
        x2' = 0.5 - x2 - (x2 + 0.5) exp(25 x1 / (x1 + 2)),          x(0) = (0.09, 0.09).

    ``params = (25, 0.1)``. Unconstrained (the classic formulation has no control bounds).
    Optimal values at N = 50 from u = 2 (IPOPT; :data:`REGRESSION_VALUES`): RK4 0.1332669,
    Euler 0.1406363.

    The problem is multimodal and stiff near the runaway region (the uncontrolled reactor heats
    up). From u = 0, IPOPT stops at a local minimum J ~ 0.2444; from the default initial control
    ``u_init`` = 2 it finds J = 0.13310 (RK4, N = 200), 0.133096 (N = 800), the value known for
    this problem in the IDP literature (Luus 2000: 0.13309). Coarse steps admit spurious
    discrete minima (RK4, N = 50 from u = 1: J = 0.0318); explicit Euler needs h below about
    0.013 (N >= 60) to stay stable along the runaway trajectories.
    """

    name = "cstr"
    T_DEFAULT = 0.78
    X0_DEFAULT = np.array([0.09, 0.09])
    PARAMS = (25.0, 0.1)

    def __init__(self, N=50, *, u_init=2.0, **options):
        self.u_init = float(u_init)
        options.setdefault("u_guess", self.u_init)
        super().__init__(N, **options)

    def ode_rhs(self, x, u):
        g = self.params[0]
        e = exp(g * x[0] / (x[0] + 2.0))
        return [-(2.0 + u[0]) * (x[0] + 0.25) + (x[1] + 0.5) * e, 0.5 - x[1] - (x[1] + 0.5) * e]

    def ode_cost(self, x, u):
        return x[0] * x[0] + x[1] * x[1] + self.params[1] * u[0] * u[0]


# ============================================================================ registry
def _lq(N=50, **kw):
    """The ``lq`` problem; see :class:`LinearQuadratic`."""
    return LinearQuadratic(N=N, **kw)


def _lq_box(N=50, umax=1.0, **kw):
    """The ``lq-box`` problem: ``lq`` with |u_i| <= umax (default 1, active at the start)."""
    return LinearQuadratic(N=N, umax=umax, **kw)


def _maker(cls, doc, **fixed):
    def make(N=50, **kw):
        return cls(N=N, **fixed, **kw)
    make.__doc__ = doc
    return make


#: name -> factory(N=50, **kwargs)
PROBLEMS = {
    "lq": _lq,
    "lq-box": _lq_box,
    "vanderpol": _maker(VanDerPol, "Van der Pol oscillator (Luus 2000); see :class:`VanDerPol`."),
    "vanderpol-box": _maker(VanDerPol, "Van der Pol with -0.3 <= u <= 1 (Luus 2000).", box=True),
    "vanderpol-path": _maker(VanDerPol, "Van der Pol with x1 >= -0.4 and -0.3 <= u <= 1 (Vassiliadis et al. 1994).", path=True),
    "rayleigh": _maker(Rayleigh, "Rayleigh problem (Maurer and Augustin 2001); see :class:`Rayleigh`."),
    "rayleigh-box": _maker(Rayleigh, "Rayleigh problem with |u| <= 1 (Maurer and Augustin 2001).", box=True),
    "cstr": _maker(CSTR, "CSTR of Lapidus and Luus (1967); see :class:`CSTR`."),
}

#: (name, method) -> optimal objective found by IPOPT (tol 1e-10, from the problem's initial
#: guess) at N = 50 with the default data and steps h = T/N; regression values checked by
#: tests/test_testproblems.py. For comparison, RK4 with N = 1600: vanderpol 2.866955,
#: vanderpol-box 2.867263, vanderpol-path 2.953881, rayleigh 29.749001, rayleigh-box 44.617885;
#: cstr (N = 800) 0.133096.
REGRESSION_VALUES = {
    ("lq", None): 13.066934800149529,
    ("lq-box", None): 16.06064208099815,
    ("vanderpol", "rk4"): 2.869255028239001,
    ("vanderpol", "euler"): 3.080344660824816,
    ("vanderpol-box", "rk4"): 2.869365959964554,
    ("vanderpol-box", "euler"): 3.0814076531696295,
    ("vanderpol-path", "rk4"): 2.956222770180382,
    ("vanderpol-path", "euler"): 3.1621782555710567,
    ("rayleigh", "rk4"): 29.792202158387568,
    ("rayleigh", "euler"): 31.904625402148213,
    ("rayleigh-box", "rk4"): 44.60685721839581,
    ("rayleigh-box", "euler"): 46.47499872368283,
    ("cstr", "rk4"): 0.1332668673319282,
    ("cstr", "euler"): 0.14063630146357822,
}
