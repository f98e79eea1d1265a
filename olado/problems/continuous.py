"""Discretized continuous-time optimal control problems with hand-written derivatives:
:class:`ContinuousDOCP`, and :class:`ContinuousData`, the class data it shares with
:class:`~olado.problems.continuous_ocp.ContinuousOCP`.

Write a new problem on :class:`~olado.problems.continuous_ocp.ContinuousOCP` (the same class
data, the model once as expressions, exact first and second derivatives by automatic
differentiation) or on :class:`olado.OCP` (docs/continuous-time.md). ContinuousDOCP stays for
subclasses that supply their own derivatives; of the built-in problems only free-flying-robot
(:mod:`olado.problems.literature`, its docstring says why) is one.

A problem is written as its continuous-time model

    min  phi(x(T)) + int_0^T L(x, u) dt
    s.t. x' = f(x, u),  x(0) = x0,  g(x, u) >= 0 (path),  psi(x(T)) >= 0 (terminal; some = 0),
         state and control bounds,

and turned into a DOCP (paper 001 eqs. (1)-(5)) with piecewise-constant controls and explicit
Euler or RK4 steps (:mod:`olado.problems.integrators`): x^{k+1} = the step of f from x^k under
u^k, f_0^k = the step's quadrature of L, F^N = phi, g^k = g(x^k, u^k), g^N = psi, bounds at every
stage.

Fixed final time ``T``: N steps of length h = T/N.

Free final time (``T = None``) is written with the time scaling as an extra state: in the
normalized time tau in [0, 1] the model is x' = T f(x, u), with T a state that the first stage
sets from its control, a *parameter stage*::

    stage 0:       x^1 = (x0, u^0_0)   -- the physical states unchanged, T := u^0_0 (T bounds on u^0_0);
                   f_0^0 = 1/2 |u^0_{1:}|^2 (the other controls of stage 0 have no role: this cost
                   makes them 0 at every optimum and adds nothing to the objective there);
    stages k >= 1: one step of length h = 1/(N - 1) of (T f, 0) from x^k under u^k.

So a free-time problem with N stages has N - 1 integration steps. Path constraints are not
offered for free-time problems (they would meet the parameter stage); state bounds are.

A subclass declares its data as class attributes (STATES, CONTROLS, X0, T, bounds, the numbers
of path and terminal constraints) and writes the model with exact first derivatives where they
are simple (:meth:`model`; a model may leave its Jacobian to central differences of its values,
which the integrator's step derivatives then use), and where it has them :meth:`mayer`,
:meth:`path`, :meth:`terminal`. Second derivatives are finite differences of the first
derivatives (the DOCP default) unless the class also derives from :class:`ExactHessians` and its
model returns second derivatives.
"""

from __future__ import annotations

import numpy as np

from ..errors import ProblemDefinitionError
from .docp import DOCP
from .integrators import rk_step, rk_step_derivatives

__all__ = ["ContinuousData", "ContinuousDOCP", "ExactHessians"]


def _bounds_pair(spec, size):
    """(lo, hi) arrays of length ``size`` from a pair of sequences / scalars / None."""
    lo, hi = spec if spec is not None else (None, None)
    lo = np.full(size, -np.inf) if lo is None else np.broadcast_to(np.asarray(lo, dtype=float), (size,)).copy()
    hi = np.full(size, np.inf) if hi is None else np.broadcast_to(np.asarray(hi, dtype=float), (size,)).copy()
    return lo, hi


class ContinuousData:
    """The class-attribute data of a literature problem, shared by :class:`ContinuousDOCP` and
    :class:`~olado.problems.continuous_ocp.ContinuousOCP`: names, start, final time, bounds, the
    numbers and equality masks of the path and terminal constraints, the default N."""

    name = "continuous"
    STATES: tuple = ()
    CONTROLS: tuple = ()
    X0: tuple = ()
    #: fixed final time, or None for a free final time (the parameter stage)
    T: float | None = 1.0
    T_BOUNDS = (0.0, np.inf)
    T_GUESS = 1.0
    X_BOUNDS = None          # (lower, upper) of the physical states, or None
    U_BOUNDS = None          # (lower, upper) of the controls, or None
    N_PATH = 0
    PATH_EQUALITIES = None
    N_TERMINAL = 0
    TERMINAL_EQUALITIES = None
    DEFAULT_N = 50


class ContinuousDOCP(ContinuousData, DOCP):
    """A continuous-time optimal control problem discretized by Euler or RK4 (module docstring).

    Parameters
    ----------
    N : number of stages; the integration steps are N (fixed final time) or N - 1 (free final
        time: stage 0 is the parameter stage). Default ``DEFAULT_N``.
    method : ``"rk4"`` (default) or ``"euler"``.
    T : the final time of a fixed-time problem (default the literature's ``T``).
    """

    vectorized = True

    def __init__(self, N=None, *, method="rk4", T=None, **options):
        N = self.DEFAULT_N if N is None else N
        if method not in ("rk4", "euler"):
            raise ProblemDefinitionError(f"method must be 'rk4' or 'euler', got {method!r}", function="__init__", array="method")
        if isinstance(N, bool) or not isinstance(N, (int, np.integer)):
            raise ProblemDefinitionError(f"N must be a positive integer, got {N!r}", function="__init__", array="N")
        self.free_time = self.T is None
        if self.free_time and T is not None:
            raise ProblemDefinitionError("this problem has a free final time; T cannot be set",
                                         function="__init__", array="T")
        if self.free_time and self.N_PATH:
            raise ProblemDefinitionError("path constraints are not offered with a free final time",
                                         function="__init__", array="N_PATH")
        for hook, needed in (("model", True), ("path", self.N_PATH > 0), ("terminal", self.N_TERMINAL > 0)):
            if needed and getattr(type(self), hook) is getattr(ContinuousDOCP, hook):
                raise ProblemDefinitionError(f"{type(self).__name__} does not define {hook}(), which it needs "
                                             f"(N_PATH = {self.N_PATH}, N_TERMINAL = {self.N_TERMINAL})",
                                             function=hook)
        self.steps = int(N) - 1 if self.free_time else int(N)
        if self.steps < 1:
            raise ProblemDefinitionError(f"N must give at least one integration step, got N={N!r}",
                                         function="__init__", array="N")
        self.horizon = None if self.free_time else float(self.T if T is None else T)
        if self.horizon is not None and not self.horizon > 0:
            raise ProblemDefinitionError(f"T must be positive, got {T!r}", function="__init__", array="T")
        self.h = 1.0 / self.steps if self.free_time else self.horizon / self.steps
        self.method = method
        self._rk4 = method == "rk4"
        self.n_phys = len(self.STATES)
        m = len(self.CONTROLS)
        x0 = np.asarray(self.X0, dtype=float)
        xl, xu = _bounds_pair(self.X_BOUNDS, self.n_phys)
        ul, uu = _bounds_pair(self.U_BOUNDS, m)
        N = int(N)
        if self.free_time:
            x0 = np.append(x0, 0.0)                 # placeholder: stage 0 sets T from u^0_0
            xl, xu = np.append(xl, -np.inf), np.append(xu, np.inf)
            ul, uu = np.tile(ul, (N, 1)), np.tile(uu, (N, 1))
            ul[0], uu[0] = -np.inf, np.inf
            ul[0, 0], uu[0, 0] = self.T_BOUNDS
        if "name" in options:
            self.name = options.pop("name")
        super().__init__(len(x0), m, N, x0, x_bounds=(xl, xu), u_bounds=(ul, uu),
                         n_stage_constraints=self.N_PATH, n_final_constraints=self.N_TERMINAL,
                         stage_equalities=self.PATH_EQUALITIES, final_equalities=self.TERMINAL_EQUALITIES,
                         **options)

    # ================================================================== the model (subclasses)
    def model(self, X, U, order):
        """(F (K, n+1), J (K, n+1, n+m) or None, H (K, n+1, n+m, n+m) or None) at the rows of
        the physical states X (K, n) and controls U (K, m): F = (f, L), J its Jacobian w.r.t.
        z = (x, u) (order >= 1; None: central differences of F), H its second derivatives
        (order 2, ExactHessians only)."""
        raise NotImplementedError

    def mayer(self, x, order):
        """(phi, grad (n,), hess (n, n) or None) of the final cost at the DOCP state x (with the
        time-scaling state last for a free-time problem). Default: no final cost."""
        return 0.0, np.zeros(self.n), (np.zeros((self.n, self.n)) if order >= 2 else None)

    def path(self, X, U, order):
        """(G (K, r), Gx (K, r, n), Gu (K, r, m), Gzz (K, r, n+m, n+m)) of the path constraints
        G >= 0 (derivatives None below their order)."""
        raise NotImplementedError

    def terminal(self, x, order):
        """(psi (rN,), Jacobian (rN, n) or None, Hessians (rN, n, n) or None) of the terminal
        constraints at the DOCP state x."""
        raise NotImplementedError

    def control_guess(self):
        """Controls (steps, m) to start from, or None: the DOCP default (midpoints of bounds)."""
        return None

    def state_guess(self):
        """Physical states (steps + 1, n) to start the simultaneous methods from, or None: the
        states simulated from the controls."""
        return None

    # ================================================================== helpers
    def _rhs(self, X, U):
        """The integrated right-hand side in the DOCP state (free time: scaled by T)."""
        n = self.n_phys
        F = self.model(X[:, :n], U, 0)[0]
        if not self.free_time:
            return F
        T = X[:, n:n + 1]
        return np.concatenate([T * F[:, :n], np.zeros_like(T), T * F[:, n:]], axis=1)

    def _model_derivatives(self, X, U, order):
        """The model's (F, J, H); a model that returns no Jacobian gets one by central
        differences of F (the derivatives of the integrator step stay exact given J)."""
        F, J, H = self.model(X, U, order)
        if J is None and order >= 1:
            Z = np.concatenate([X, U], axis=1)
            n = X.shape[1]
            step = (np.finfo(float).eps ** (1.0 / 3.0)) * np.maximum(1.0, np.abs(Z))
            J = np.empty(F.shape + (Z.shape[1],))
            for j in range(Z.shape[1]):
                Zp, Zm = Z.copy(), Z.copy()
                Zp[:, j] += step[:, j]
                Zm[:, j] -= step[:, j]
                Fp = self.model(Zp[:, :n], Zp[:, n:], 0)[0]
                Fm = self.model(Zm[:, :n], Zm[:, n:], 0)[0]
                J[:, :, j] = (Fp - Fm) / (Zp[:, j:j + 1] - Zm[:, j:j + 1])
        return F, J, H

    def _rhs_derivatives(self, X, U, order):
        n = self.n_phys
        F, J, H = self._model_derivatives(X[:, :n], U, order)
        if not self.free_time:
            return F, J, H
        K, m = X.shape[0], self.m
        T = X[:, n]
        nz = n + 1 + m
        rows = list(range(n)) + [n + 1]        # f rows and the L row of the augmented output
        cols = list(range(n)) + list(range(n + 1, nz))   # z columns without T
        Fa = np.zeros((K, n + 2))
        Fa[:, rows] = T[:, None] * F
        r2, c2 = np.ix_(rows, cols)
        Ja = np.zeros((K, n + 2, nz))
        Ja[:, r2, c2] = T[:, None, None] * J
        Ja[:, rows, n] = F                      # d(T F)/dT
        Ha = None
        if order >= 2:
            Ha = np.zeros((K, n + 2, nz, nz))
            ri, ci, cj = np.ix_(rows, cols, cols)
            Ha[:, ri, ci, cj] = T[:, None, None, None] * H
            Ha[:, r2, c2, n] = J
            Ha[:, r2, n, c2] = J
        return Fa, Ja, Ha

    def _split(self, k, K):
        """Boolean mask of the rows that are integration steps (all but the parameter stage)."""
        if not self.free_time:
            return None
        k = np.asarray(k).reshape(-1)
        if k.size == 1 and K > 1:
            k = np.full(K, int(k[0]))
        return k != 0

    # ================================================================== DOCP stage functions
    def _values(self, k, x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        steps = self._split(k, x.shape[0])
        if steps is None:
            return rk_step(self._rhs, x, u, self.h, self._rk4)
        Xn = np.empty_like(x)
        C = np.empty(x.shape[0])
        if steps.any():
            Xn[steps], C[steps] = rk_step(self._rhs, x[steps], u[steps], self.h, self._rk4)
        par = ~steps
        if par.any():
            Xn[par, :self.n_phys] = x[par, :self.n_phys]
            Xn[par, self.n_phys] = u[par, 0]
            C[par] = 0.5 * np.sum(u[par, 1:] ** 2, axis=1)
        return Xn, C

    def dynamics(self, k, x, u):
        return self._values(k, x, u)[0]

    def stage_cost(self, k, x, u):
        return self._values(k, x, u)[1]

    def _step_derivatives(self, k, x, u, order):
        """(D (K, n+1, n+m), D2 or None) of the stage map (x, u) -> (x+, f_0) on all rows."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        steps = self._split(k, x.shape[0])
        if steps is None:
            return rk_step_derivatives(self._rhs_derivatives, x, u, self.h, self._rk4, order)
        K, n, m = x.shape[0], self.n, self.m
        D = np.zeros((K, n + 1, n + m))
        D2 = np.zeros((K, n + 1, n + m, n + m)) if order >= 2 else None
        if steps.any():
            Ds, D2s = rk_step_derivatives(self._rhs_derivatives, x[steps], u[steps], self.h, self._rk4, order)
            D[steps] = Ds
            if order >= 2:
                D2[steps] = D2s
        par = np.flatnonzero(~steps)
        if par.size:
            ip = np.arange(self.n_phys)
            D[np.ix_(par, ip, ip)] = np.eye(self.n_phys)
            D[par, self.n_phys, n] = 1.0                      # T^1 = u^0_0
            D[par, n, n + 1:] = u[par, 1:]                   # d/du of 1/2 |u_{1:}|^2
            if order >= 2:
                j = np.arange(n + 1, n + m)
                D2[np.ix_(par, [n], j, j)] = np.eye(m - 1)
        return D, D2

    def dynamics_jacobian(self, k, x, u):
        D, _ = self._step_derivatives(k, x, u, 1)
        n = self.n
        return D[:, :n, :n], D[:, :n, n:]

    def stage_cost_gradient(self, k, x, u):
        D, _ = self._step_derivatives(k, x, u, 1)
        n = self.n
        return D[:, n, :n], D[:, n, n:]

    def final_cost(self, x):
        return float(self.mayer(np.asarray(x, dtype=float), 0)[0])

    def final_cost_gradient(self, x):
        return np.asarray(self.mayer(np.asarray(x, dtype=float), 1)[1], dtype=float)

    def stage_constraints(self, k, x, u):
        if not self.r:
            return np.zeros((np.size(k), 0))
        return self.path(np.asarray(x, dtype=float), np.asarray(u, dtype=float), 0)[0]

    def stage_constraints_jacobian(self, k, x, u):
        _, Gx, Gu, _ = self.path(np.asarray(x, dtype=float), np.asarray(u, dtype=float), 1)
        return Gx, Gu

    def final_constraints(self, x):
        if not self.rN:
            return np.zeros(0)
        return self.terminal(np.asarray(x, dtype=float), 0)[0]

    def final_constraints_jacobian(self, x):
        return self.terminal(np.asarray(x, dtype=float), 1)[1]

    # ================================================================== start point
    def initial_guess(self):
        """The problem's control guess (or the midpoints of the bounds); for a free final time
        the parameter stage holds ``T_GUESS`` and zeros."""
        U = DOCP.initial_guess(self)
        first = 1 if self.free_time else 0
        guess = self.control_guess()
        if guess is not None:
            U[first:] = np.asarray(guess, dtype=float).reshape(self.steps, self.m)
        if self.free_time:
            U[0] = 0.0
            U[0, 0] = self.T_GUESS
        return U

    def initial_state_guess(self, U):
        """The problem's state guess (the literature's start point) with the time-scaling state
        at the parameter stage's control, or None (simulate)."""
        guess = self.state_guess()
        if guess is None:
            return None
        guess = np.asarray(guess, dtype=float).reshape(self.steps + 1, self.n_phys)
        X = np.empty((self.N + 1, self.n))
        if not self.free_time:
            X[:] = guess
            X[0] = self.x0
            return X
        X[0] = self.x0
        X[1:, :self.n_phys] = guess
        X[1:, self.n_phys] = U[0, 0]
        return X

    # ================================================================== reporting
    @property
    def discretization(self) -> str:
        scheme = "RK4" if self._rk4 else "explicit Euler"
        if self.free_time:
            return (f"{scheme}, {self.steps} steps of normalized length 1/{self.steps}, free final time "
                    f"as a state set by a parameter stage (N = {self.N})")
        return f"{scheme}, {self.steps} steps of length h = {self.h:g} on [0, {self.horizon:g}]"

    def describe(self):
        return super().describe() + f"\n  {self.discretization}"


class ExactHessians:
    """Mixin for a :class:`ContinuousDOCP` whose model, path and terminal functions return exact
    second derivatives: the stage and final Hessian blocks are then exact too (the RK4 step's
    second derivatives by :func:`~olado.problems.integrators.rk_step_derivatives`)."""

    def stage_hessian(self, k, x, u, sigma, p, lam):
        _, D2 = self._step_derivatives(k, x, u, 2)
        n = self.n
        wts = np.empty((D2.shape[0], n + 1))
        wts[:, :n] = p
        wts[:, n] = sigma
        H = np.einsum("ka,kaij->kij", wts, D2)
        if self.r:
            Gzz = self.path(np.asarray(x, dtype=float), np.asarray(u, dtype=float), 2)[3]
            H = H + np.einsum("ka,kaij->kij", lam, Gzz)
        return H[:, :n, :n], H[:, :n, n:], H[:, n:, n:]

    def final_hessian(self, x, sigma, lam):
        x = np.asarray(x, dtype=float)
        H = sigma * np.asarray(self.mayer(x, 2)[2], dtype=float)
        if self.rN:
            H = H + np.einsum("a,aij->ij", lam, self.terminal(x, 2)[2])
        return H
