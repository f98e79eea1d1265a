"""Literature problems written on :class:`~olado.problems.ocp.OCP` with the class-attribute data of
:class:`~olado.problems.continuous.ContinuousDOCP` (docs/continuous-time.md).

A subclass declares STATES, CONTROLS, X0, T (None: free final time), T_BOUNDS, T_GUESS,
X_BOUNDS, U_BOUNDS, the equality masks and DEFAULT_N as a ContinuousDOCP does, and writes its
model once, as expressions (``x[0]``, ``+ - * / **`` and the functions of
:mod:`olado.problems.autodiff`)::

    ode_rhs(x, u)          -> f (n entries)          x' = f
    ode_cost(x, u)         -> L (optional)           int L dt
    ode_final_cost(x, T)   -> phi (optional)         at t = T
    ode_path(x, u)         -> g (N_PATH entries)     g >= 0 at k = 0..N-1 (fixed final time only)
    ode_terminal(x, T)     -> psi (N_TERMINAL)       psi >= 0 (= 0 where TERMINAL_EQUALITIES)

``MINIMUM_TIME = True`` adds T to the objective (with a free final time; at a fixed T, a
constant, it is left out). The DOCP is ContinuousDOCP's: N stages, i.e.
N intervals with a fixed final time and N - 1 with a free one (stage 0 is OCP's parameter stage,
which is ContinuousDOCP's); steps of length exactly h = T/N (1/(N - 1) normalized); the state
bounds on every stage (x^0 and the parameter stage's x^1 included) and a zero placeholder for T
in x^0, as ContinuousDOCP has them. Its derivatives are OCP's: exact first and second
derivatives with the ``ad`` extra (ContinuousDOCP's second derivatives are finite differences
unless the class derives from ExactHessians), finite differences without it.
"""

from __future__ import annotations

import numpy as np

from ..errors import ProblemDefinitionError
from .continuous import ContinuousData
from .ocp import OCP

__all__ = ["ContinuousOCP"]


class ContinuousOCP(ContinuousData, OCP):
    """A ContinuousDOCP-style problem on OCP (module docstring).

    Parameters
    ----------
    N : number of stages (default ``DEFAULT_N``); the integration steps are N (fixed final
        time) or N - 1 (free final time).
    method : ``"rk4"`` (default) or ``"euler"``.
    T : the final time of a fixed-time problem (default the class's ``T``).
    mode, ad_backend, name : as for :class:`~olado.problems.ocp.OCP`.
    """

    MINIMUM_TIME = False

    def __init__(self, N=None, *, method="rk4", T=None, **options):
        N = self.DEFAULT_N if N is None else N
        if isinstance(N, bool) or not isinstance(N, (int, np.integer)):
            raise ProblemDefinitionError(f"N must be a positive integer, got {N!r}", function="__init__", array="N")
        free = self.T is None
        if free and T is not None:
            raise ProblemDefinitionError("this problem has a free final time; T cannot be set",
                                         function="__init__", array="T")
        self.steps = int(N) - 1 if free else int(N)
        if self.steps < 1:
            raise ProblemDefinitionError(f"N must give at least one integration step, got N={N!r}",
                                         function="__init__", array="N")
        horizon = None if free else float(self.T if T is None else T)
        self.horizon = horizon        # (OCP sets it again; control_guess and state_guess may read it)
        self.h = 1.0 / self.steps if free else (horizon / self.steps if horizon > 0 else np.nan)
        self.n_phys = len(self.STATES)
        own = lambda nm: getattr(type(self), nm) is not getattr(ContinuousOCP, nm)  # noqa: E731
        # OCP calls the user's functions as f(t, x, u, p) and phi(t, x, p), t = t_f = T here
        hooks = {"running_cost": (own("ode_cost"), lambda t, x, u, p: self.ode_cost(x, u)),
                 "final_cost": (own("ode_final_cost"), lambda t, x, p: self.ode_final_cost(x, t)),
                 "path": (self.N_PATH > 0, lambda t, x, u, p: self.ode_path(x, u)),
                 "terminal": (self.N_TERMINAL > 0, lambda t, x, p: self.ode_terminal(x, t))}
        kwargs = {k: fn for k, (used, fn) in hooks.items() if used}
        u_guess, x_guess = self.control_guess(), self.state_guess()
        super().__init__(lambda t, x, u, p: self.ode_rhs(x, u), np.asarray(self.X0, dtype=float),
                         controls=len(self.CONTROLS), N=self.steps, T=horizon, T_bounds=self.T_BOUNDS,
                         T_guess=self.T_GUESS, minimum_time=self.MINIMUM_TIME and free, u_bounds=self.U_BOUNDS,
                         path_equalities=self.PATH_EQUALITIES, terminal_equalities=self.TERMINAL_EQUALITIES,
                         method=method, u_guess=u_guess, x_guess=x_guess, **kwargs, **options)
        self._contdocp_bounds()

    def _contdocp_bounds(self):
        """ContinuousDOCP's state bounds (every stage, T unbounded) and its x^0 (T placeholder 0)."""
        lo = np.full(self.n, -np.inf)
        hi = np.full(self.n, np.inf)
        if self.X_BOUNDS is not None:
            for side, arr in zip(self.X_BOUNDS, (lo, hi)):
                if side is not None:
                    arr[:self.n_phys] = np.asarray(side, dtype=float)
        self.x_bounds = (lo, hi)
        if self.free_time:
            self.x0 = self.x0.copy()
            self.x0[self.nx:] = 0.0

    # ------------------------------------------------------------------ the model (subclasses)
    def ode_rhs(self, x, u):
        """f(x, u): n entries."""
        raise ProblemDefinitionError(f"{type(self).__name__} must define ode_rhs(x, u)", function="ode_rhs")

    def ode_cost(self, x, u):
        """L(x, u), the running cost (optional)."""
        return 0.0

    def ode_final_cost(self, x, T):
        """phi(x(T), T), the final cost (optional)."""
        return 0.0

    def ode_path(self, x, u):
        """g(x, u) >= 0: N_PATH entries."""
        raise ProblemDefinitionError(f"{type(self).__name__} must define ode_path(x, u)", function="ode_path")

    def ode_terminal(self, x, T):
        """psi(x(T), T) >= 0: N_TERMINAL entries."""
        raise ProblemDefinitionError(f"{type(self).__name__} must define ode_terminal(x, T)", function="ode_terminal")

    def control_guess(self):
        """Controls (steps, m) to start from, or None: the midpoints of the bounds."""
        return None

    def state_guess(self):
        """Physical states (steps + 1, n) for the simultaneous methods, or None (simulated)."""
        return None

    # ------------------------------------------------------------------ the grid
    def stage_data(self):
        """OCP's rows with ContinuousDOCP's steps: (k h, h, 0) on the intervals, h exactly T/N
        (normalized 1/(N - 1) with a free final time, after the parameter stage's (0, 0, 1))."""
        rows = np.column_stack([self.h * np.arange(self.steps), np.full(self.steps, self.h), np.zeros(self.steps)])
        return np.vstack([[0.0, 0.0, 1.0], rows]) if self.has_parameter_stage else rows
