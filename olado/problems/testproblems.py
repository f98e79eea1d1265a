"""Built-in test problems with known answers: a linear-quadratic DOCP and nonlinear control problems
from the literature, vectorized, with analytic first and second derivatives.

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

i.e. paper 001 eqs. (1)-(2) with F^N = 0. Values (and the sequential simulation) run in one
compiled pass over the stages; the first and second derivatives of the step map are propagated
through the Runge-Kutta stages from the analytic derivatives of (f, L), all stages at once.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import ProblemDefinitionError
from .docp import DOCP
from .integrators import rk_step_derivatives

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
# Compiled right-hand sides (f, L) of the continuous-time problems, selected by a problem id, and
# the Euler / RK4 step over all stages. One cached kernel for all problems (numba cannot cache a
# kernel that takes a function argument).
_VDP, _RAYLEIGH, _CSTR = 0, 1, 2


@nb.njit(cache=True)
def _rhs(pid, prm, x, u, out):
    """out[:n] = f(x, u), out[n] = L(x, u) of problem ``pid``."""
    if pid == 0:      # Van der Pol (Luus 2000)
        x1, x2, v = x[0], x[1], u[0]
        out[0] = (1.0 - x2 * x2) * x1 - x2 + v
        out[1] = x1
        out[2] = x1 * x1 + x2 * x2 + v * v
    elif pid == 1:    # Rayleigh (Maurer and Augustin 2001)
        x1, x2, v = x[0], x[1], u[0]
        out[0] = x2
        out[1] = -x1 + x2 * (prm[0] - prm[1] * x2 * x2) + prm[2] * v
        out[2] = v * v + x1 * x1
    else:             # CSTR (Lapidus and Luus 1967)
        x1, x2, v = x[0], x[1], u[0]
        e = np.exp(prm[0] * x1 / (x1 + 2.0))
        out[0] = -(2.0 + v) * (x1 + 0.25) + (x2 + 0.5) * e
        out[1] = 0.5 - x2 - (x2 + 0.5) * e
        out[2] = x1 * x1 + x2 * x2 + prm[1] * v * v


@nb.njit(cache=True)
def _step(pid, prm, x, u, h, rk4, xn, work):
    """One Euler or RK4 step of (f, L) from x under u: next state into xn, returns the cost."""
    n = x.shape[0]
    k1, k2, k3, k4, y = work[0], work[1], work[2], work[3], work[4]
    _rhs(pid, prm, x, u, k1)
    if not rk4:
        for i in range(n):
            xn[i] = x[i] + h * k1[i]
        return h * k1[n]
    for i in range(n):
        y[i] = x[i] + 0.5 * h * k1[i]
    _rhs(pid, prm, y[:n], u, k2)
    for i in range(n):
        y[i] = x[i] + 0.5 * h * k2[i]
    _rhs(pid, prm, y[:n], u, k3)
    for i in range(n):
        y[i] = x[i] + h * k3[i]
    _rhs(pid, prm, y[:n], u, k4)
    for i in range(n):
        xn[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    return (h / 6.0) * (k1[n] + 2.0 * k2[n] + 2.0 * k3[n] + k4[n])


@nb.njit(cache=True)
def _step_all(pid, prm, X, U, h, rk4, Xn, C):
    """Steps from every row of X (K, n) under U (K, m): next states Xn and stage costs C."""
    n = X.shape[1]
    work = np.empty((5, n + 1))
    for k in range(X.shape[0]):
        C[k] = _step(pid, prm, X[k], U[k], h, rk4, Xn[k], work)


@nb.njit(cache=True)
def _simulate(pid, prm, x0, U, h, rk4, X):
    n = x0.shape[0]
    work = np.empty((5, n + 1))
    for i in range(n):
        X[0, i] = x0[i]
    for k in range(U.shape[0]):
        _step(pid, prm, X[k], U[k], h, rk4, X[k + 1], work)


class ODEProblem(DOCP):
    """Base of the discretized continuous-time Lagrange problems (module docstring).

    Subclasses set ``_pid`` (their branch of the compiled right-hand side), ``T_DEFAULT``,
    ``X0_DEFAULT``, ``params`` and implement :meth:`rhs_derivatives`.

    Parameters
    ----------
    N : number of steps (stages), any N >= 1.
    T : final time; default the literature's. Ignored when ``h`` is given.
    h : step length; default T/N (then the horizon is N*h).
    method : ``"rk4"`` (default) or ``"euler"``.
    x0 : initial state; default the literature's.
    """

    vectorized = True
    _pid = -1
    T_DEFAULT = 1.0
    X0_DEFAULT = np.zeros(2)
    M = 1

    def __init__(self, N=50, *, T=None, h=None, method="rk4", x0=None, params=None, **options):
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
        self.h, self.T, self.method = h, h * N, method
        self._rk4 = method == "rk4"
        self.params = np.array(self.PARAMS if params is None else params, dtype=float)
        if "name" in options:
            self.name = options.pop("name")
        x0 = self.X0_DEFAULT if x0 is None else x0
        super().__init__(len(self.X0_DEFAULT), self.M, N, x0, **options)

    # ------------------------------------------------------------------ continuous model
    def rhs_derivatives(self, X, U, order):
        """(F (K, n+1), J (K, n+1, n+m), H (K, n+1, n+m, n+m) or None) of (f, L) at the rows of
        X (K, n), U (K, m): values, first and (order 2) second derivatives w.r.t. z = (x, u)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ values
    def _values(self, x, u):
        x = np.ascontiguousarray(x, dtype=float)
        u = np.ascontiguousarray(u, dtype=float)
        Xn = np.empty_like(x)
        C = np.empty(x.shape[0])
        _step_all(self._pid, self.params, x, u, self.h, self._rk4, Xn, C)
        return Xn, C

    def dynamics(self, k, x, u):
        return self._values(x, u)[0]

    def stage_cost(self, k, x, u):
        return self._values(x, u)[1]

    def final_cost(self, x):
        return 0.0

    def simulate(self, U):
        """States under controls U (one compiled pass: long horizons)."""
        U = self.check_array(U, (self.N, self.m), "simulate", "u")
        self.counters["dynamics"] += 1
        X = np.empty((self.N + 1, self.n))
        _simulate(self._pid, self.params, self.x0, np.ascontiguousarray(U), self.h, self._rk4, X)
        return self._check_stacked(X, (self.N + 1, self.n), "simulate", "x")

    # ------------------------------------------------------------------ step derivatives
    def step_derivatives(self, X, U, order=1):
        """Derivatives of the step map z = (x, u) -> (x+, c) by forward propagation through the
        Euler / RK4 stages (:func:`olado.problems.integrators.rk_step_derivatives`):
        (D (K, n+1, n+m), D2 (K, n+1, n+m, n+m) or None)."""
        return rk_step_derivatives(self.rhs_derivatives, X, U, self.h, self._rk4, order)

    def dynamics_jacobian(self, k, x, u):
        D, _ = self.step_derivatives(x, u, 1)
        n = self.n
        return D[:, :n, :n], D[:, :n, n:]

    def stage_cost_gradient(self, k, x, u):
        D, _ = self.step_derivatives(x, u, 1)
        n = self.n
        return D[:, n, :n], D[:, n, n:]

    def final_cost_gradient(self, x):
        return np.zeros(self.n)

    def stage_hessian(self, k, x, u, sigma, p, lam):
        _, D2 = self.step_derivatives(x, u, 2)
        n = self.n
        wts = np.empty((D2.shape[0], n + 1))
        wts[:, :n] = p
        wts[:, n] = sigma
        H = np.einsum("ka,kaij->kij", wts, D2)
        return H[:, :n, :n], H[:, :n, n:], H[:, n:, n:]

    def final_hessian(self, x, sigma, lam):
        return np.zeros((self.n, self.n))

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
    _pid = _VDP
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

    def rhs_derivatives(self, X, U, order):
        x1, x2, v = X[:, 0], X[:, 1], U[:, 0]
        K = len(x1)
        F = np.stack([(1.0 - x2 * x2) * x1 - x2 + v, x1, x1 * x1 + x2 * x2 + v * v], axis=1)
        J = np.zeros((K, 3, 3))
        J[:, 0, 0] = 1.0 - x2 * x2
        J[:, 0, 1] = -2.0 * x1 * x2 - 1.0
        J[:, 0, 2] = 1.0
        J[:, 1, 0] = 1.0
        J[:, 2, 0] = 2.0 * x1
        J[:, 2, 1] = 2.0 * x2
        J[:, 2, 2] = 2.0 * v
        H = None
        if order >= 2:
            H = np.zeros((K, 3, 3, 3))
            H[:, 0, 0, 1] = H[:, 0, 1, 0] = -2.0 * x2
            H[:, 0, 1, 1] = -2.0 * x1
            H[:, 2, 0, 0] = H[:, 2, 1, 1] = H[:, 2, 2, 2] = 2.0
        return F, J, H


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
    _pid = _RAYLEIGH
    T_DEFAULT = 4.5
    X0_DEFAULT = np.array([-5.0, -5.0])
    PARAMS = (1.4, 0.14, 4.0)

    def __init__(self, N=50, *, box=False, **options):
        if box:
            options.setdefault("u_bounds", (-1.0, 1.0))
        options.setdefault("name", "rayleigh-box" if box else "rayleigh")
        super().__init__(N, **options)

    def rhs_derivatives(self, X, U, order):
        a, p, b = self.params
        x1, x2, v = X[:, 0], X[:, 1], U[:, 0]
        K = len(x1)
        F = np.stack([x2, -x1 + x2 * (a - p * x2 * x2) + b * v, v * v + x1 * x1], axis=1)
        J = np.zeros((K, 3, 3))
        J[:, 0, 1] = 1.0
        J[:, 1, 0] = -1.0
        J[:, 1, 1] = a - 3.0 * p * x2 * x2
        J[:, 1, 2] = b
        J[:, 2, 0] = 2.0 * x1
        J[:, 2, 2] = 2.0 * v
        H = None
        if order >= 2:
            H = np.zeros((K, 3, 3, 3))
            H[:, 1, 1, 1] = -6.0 * p * x2
            H[:, 2, 0, 0] = H[:, 2, 2, 2] = 2.0
        return F, J, H


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
    _pid = _CSTR
    T_DEFAULT = 0.78
    X0_DEFAULT = np.array([0.09, 0.09])
    PARAMS = (25.0, 0.1)

    def __init__(self, N=50, *, u_init=2.0, **options):
        self.u_init = float(u_init)
        super().__init__(N, **options)

    def initial_guess(self):
        """Constant control ``u_init`` (default 2: leads to the global minimum, see above)."""
        return np.full((self.N, 1), self.u_init)

    def rhs_derivatives(self, X, U, order):
        g, wu = self.params
        x1, x2, v = X[:, 0], X[:, 1], U[:, 0]
        K = len(x1)
        d = x1 + 2.0
        e = np.exp(g * x1 / d)
        de = e * (2.0 * g / d ** 2)                       # d/dx1 exp(g x1/(x1+2))
        c = x2 + 0.5
        F = np.stack([-(2.0 + v) * (x1 + 0.25) + c * e, 0.5 - x2 - c * e,
                      x1 * x1 + x2 * x2 + wu * v * v], axis=1)
        J = np.empty((K, 3, 3))
        J[:, 0, 0] = -(2.0 + v) + c * de
        J[:, 0, 1] = e
        J[:, 0, 2] = -(x1 + 0.25)
        J[:, 1, 0] = -c * de
        J[:, 1, 1] = -1.0 - e
        J[:, 1, 2] = 0.0
        J[:, 2, 0] = 2.0 * x1
        J[:, 2, 1] = 2.0 * x2
        J[:, 2, 2] = 2.0 * wu * v
        H = None
        if order >= 2:
            d2e = de * (2.0 * g / d ** 2) - e * (4.0 * g / d ** 3)
            H = np.zeros((K, 3, 3, 3))
            H[:, 0, 0, 0] = c * d2e
            H[:, 0, 0, 1] = H[:, 0, 1, 0] = de
            H[:, 0, 0, 2] = H[:, 0, 2, 0] = -1.0
            H[:, 1, 0, 0] = -c * d2e
            H[:, 1, 0, 1] = H[:, 1, 1, 0] = -de
            H[:, 2, 0, 0] = H[:, 2, 1, 1] = 2.0
            H[:, 2, 2, 2] = 2.0 * wu
        return F, J, H


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
