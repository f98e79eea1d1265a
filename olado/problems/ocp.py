"""Continuous-time optimal control problems written once, without derivative code
(docs/continuous-time.md; issue 15 item 2).

The problem

    min   phi(t_f, x(t_f), p) + phi_0(t_0, x(t_0), p) + int_{t_0}^{t_f} L(t, x, u, p) dt
          [+ (t_f - t_0): minimum time]
    s.t.  x' = f(t, x, u, p),   x(t_0) = x_0 (components free within bounds where asked),
          g(t, x, u, p) >= 0 (path; some components = 0),  psi(t_f, x(t_f), p) >= 0 (terminal;
          some = 0),  bounds on x, u, p, t_f,

is turned into a DOCP (paper 001 eqs. (1)-(5)) by piecewise-constant controls on N intervals and
``substeps`` explicit Euler or RK4 steps per interval. The running cost is integrated by the same
scheme as a quadrature state c' = L, so stage k maps (x^k, u^k) to (x^{k+1}, f_0^k). Every
function is traced once in CasADi SX by :class:`~olado.problems.autodiff.AutoDiffDOCP`, so the
first and second derivatives through the integrator steps are exact (algorithmic
differentiation of the discrete map), vectorized over the stages.

Free final time, static parameters and free initial states enter through a *parameter stage*
(generalizing :mod:`olado.problems.continuous`): the DOCP state is augmented to
X = (x, T, p) (T = t_f - t_0 only when it is free), and stage 0 maps the fixed DOCP start X^0 to

    X^1 = (x_0 with its free components := v_F,  T := v_T,  p := v_p),   v = u^0 (its first entries),
    f_0^0 = 1/2 |u^0_rest|^2 + phi_0(t_0, x(t_0), p)   (the initial cost, if any),

so T, p and the free initial components are controls of stage 0, bounded by their bounds; they
stay constant afterwards (T' = 0, p' = 0). On stage 0 the path constraints have stand-ins:
1 >= 0 for an inequality, u^0[n_par + i] = 0 for the i-th equality (a regular Jacobian row).
With a free final time the intervals are on the normalized time tau in [0, 1],
dx/dtau = T f(t_0 + T tau, x, u, p) (time scaling), i.e. a step of physical length T dtau. The
DOCP then has N + 1 stages; without anything free it has N stages and no augmentation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ProblemDefinitionError
from .autodiff.model import AutoDiffDOCP
from .autodiff.vectors import vector_ops

__all__ = ["OCP", "OCPSolution"]

#: RK4 nodes c_i and weights b_i
_RK4_C = (0.0, 0.5, 0.5, 1.0)
_RK4_B = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)


@dataclass
class OCPSolution:
    """A DOCP solution read back in the OCP's terms: the grid ``t`` (N+1,), the states ``x``
    (N+1, n) at the grid points, the piecewise-constant controls ``u`` (N, m) (u[k] on
    [t[k], t[k+1])), the final time ``tf``, the parameters ``p`` (n_p,) and the initial state
    ``x0`` (n,)."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    tf: float
    p: np.ndarray
    x0: np.ndarray


def _pair(spec, size, name):
    """(lower, upper) arrays of length ``size`` from a pair of scalars / sequences / None."""
    if spec is None:
        spec = (None, None)
    if not isinstance(spec, (tuple, list)) or len(spec) != 2:
        raise ProblemDefinitionError("bounds must be a pair (lower, upper)", function="OCP", array=name)
    out = []
    for side, default in zip(spec, (-np.inf, np.inf)):
        arr = np.full(size, default) if side is None else np.asarray(side, dtype=float)
        if arr.ndim == 0:
            arr = np.full(size, float(arr))
        if arr.shape != (size,):
            raise ProblemDefinitionError(f"expected {size} entries, got shape {arr.shape}", function="OCP", array=name)
        out.append(arr.copy())
    if np.any(out[0] > out[1]):
        raise ProblemDefinitionError("a lower bound exceeds its upper bound", function="OCP", array=name)
    return out


def _guess(value, shape, name):
    """A start value broadcast to ``shape`` (a scalar, one row, or the full array)."""
    arr = np.asarray(value, dtype=float)
    try:
        return np.broadcast_to(arr, shape).copy()
    except ValueError:
        raise ProblemDefinitionError(f"expected shape {shape} or a row of it, got {arr.shape}",
                                     function="OCP", array=name) from None


def _call(fn, name, *args):
    """The user's function on symbolic arguments; an exception becomes a ProblemDefinitionError
    naming the function and the usual cause."""
    try:
        return fn(*args)
    except ProblemDefinitionError:
        raise
    except Exception as exc:
        raise ProblemDefinitionError(
            f"cannot be evaluated on symbolic arguments ({type(exc).__name__}: {str(exc).splitlines()[0][:200]}); "
            "OCP functions are traced once with CasADi symbols (or called on numpy arrays, one entry per "
            "stage): use + - * / ** and the functions of olado.problems.autodiff (sin, exp, fmax, ...), "
            "no Python branch on t, x, u or p",
            function=name) from exc


def _mask(spec, size, name):
    """A boolean mask of ``size`` entries from None, a mask, or a list of indices."""
    mask = np.zeros(size, dtype=bool)
    if spec is None:
        return mask
    arr = np.asarray(spec)
    if arr.dtype == bool:
        if arr.shape != (size,):
            raise ProblemDefinitionError(f"expected a mask of {size} entries", function="OCP", array=name)
        return arr.copy()
    idx = arr.astype(int).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= size):
        raise ProblemDefinitionError(f"index out of range 0..{size - 1}", function="OCP", array=name)
    mask[idx] = True
    return mask


class OCP(AutoDiffDOCP):
    """A continuous-time optimal control problem from the user's functions (module docstring).

    Every function takes CasADi SX column vectors ``x`` (n), ``u`` (m), ``p`` (n_p; empty without
    parameters) and the time ``t``, indexed as ``x[0]`` and combined with ``+ - * / **`` and the
    elementary functions of :mod:`olado.problems.autodiff`; vector results are lists of scalar
    expressions (or a CasADi vector)::

        rhs(t, x, u, p)           -> f (n entries)                  x' = f
        running_cost(t, x, u, p)  -> L (scalar)                     int L dt
        path(t, x, u, p)          -> g (r entries)                  g >= 0 (= 0 where path_equalities)
        final_cost(t, x, p)       -> phi (scalar), at t = t_f, x = x(t_f)
        initial_cost(t, x, p)     -> phi_0 (scalar), at t = t_0, x = x(t_0) (free x0 or parameters)
        terminal(t, x, p)         -> psi (r_N entries), at t_f      psi >= 0 (= 0 where terminal_equalities)

    Parameters
    ----------
    rhs, x0 : the right-hand side and the initial state (n,) (for free components: the guess).
    controls : m, the number of controls. parameters : n_p, the number of static parameters.
    N : number of control intervals. T : the horizon t_f - t_0, or None for a free final time
        (bounds ``T_bounds``, start ``T_guess``). minimum_time : add t_f - t_0 to the objective
        (needs ``T=None``). t0 : the initial time.
    x_bounds, u_bounds, p_bounds : (lower, upper) pairs (scalars, sequences or None); the state
        bounds hold at every grid point after the start, the path constraints at the start of
        every interval (t_0 .. t_{N-1}).
    free_x0 : indices (or a mask) of the initial-state components that are optimized, within
        ``x0_bounds`` (default ``x_bounds``).
    method : "rk4" (default) or "euler"; substeps : integrator steps per interval.
    u_guess : controls to start from, (m,) or (N, m) (default: midpoints of the bounds);
        p_guess : (n_p,); x_guess : states (N+1, n) for the simultaneous methods (default:
        simulated).
    grid : interval boundaries normalized to [0, 1] (N+1 increasing values from 0 to 1);
        default uniform.
    mode : the CasADi back-end's evaluator ("llvm" default, "numba", "vm", "jit").
    ad_backend : "auto" (default: "casadi" when CasADi is installed, else "numpy"), "casadi"
        (exact derivatives) or "numpy" (the functions evaluated on numpy arrays over the stages,
        derivatives by finite differences; no optional package needed).
    name : the problem's name in results and reports (default "ocp").

    ``ocp.N`` is the DOCP's number of stages (N + 1 with a parameter stage), ``ocp.intervals``
    the N given; :meth:`solution` reads a result back as t, x, u, t_f, p, x(t_0).
    """

    ad_backend = "auto"
    name = "ocp"

    def __init__(self, rhs, x0, *, controls, N=50, T=None, running_cost=None, final_cost=None, initial_cost=None,
                 path=None, path_equalities=None, terminal=None, terminal_equalities=None,
                 x_bounds=None, u_bounds=None, parameters=0, p_bounds=None, p_guess=None,
                 free_x0=None, x0_bounds=None, T_bounds=(0.0, np.inf), T_guess=None,
                 minimum_time=False, t0=0.0, method="rk4", substeps=1, u_guess=None, x_guess=None,
                 grid=None, mode="llvm", name=None, ad_backend="auto"):
        self._set_backend(ad_backend)
        self._check_arguments(rhs, method, N=N, substeps=substeps, controls=controls, parameters=parameters)
        self.x_init = np.asarray(x0, dtype=float).reshape(-1)
        self.nx, self.nu, self.np_ = len(self.x_init), int(controls), int(parameters)
        self.intervals, self.substeps, self.method, self.t0 = int(N), int(substeps), method, float(t0)
        self._set_time(T, minimum_time)
        self._f, self._L, self._phi, self._g, self._psi = rhs, running_cost, final_cost, path, terminal
        self._phi0 = initial_cost
        self.free_x0 = np.flatnonzero(_mask(free_x0, self.nx, "free_x0"))
        bounds = {"x": _pair(x_bounds, self.nx, "x_bounds"), "u": _pair(u_bounds, self.nu, "u_bounds"),
                  "p": _pair(p_bounds, self.np_, "p_bounds"), "T": _pair(T_bounds, 1, "T_bounds")}
        bounds["x0"] = _pair(x0_bounds, self.nx, "x0_bounds") if x0_bounds is not None else bounds["x"]
        self._check_x0(bounds["x"])
        self._T_guess = self._guess_T(T_guess, float(bounds["T"][0][0]), float(bounds["T"][1][0]))
        self._p_guess = np.zeros(self.np_) if p_guess is None else _guess(p_guess, (self.np_,), "p_guess")
        self._grid = self._make_grid(grid)
        self._u_guess = None if u_guess is None else _guess(u_guess, (self.intervals, self.nu), "u_guess")
        self._x_guess = None if x_guess is None else _guess(x_guess, (self.intervals + 1, self.nx), "x_guess")
        # the parameter stage: its controls set T, p and the free initial components, in that order
        self.n_par = int(self.free_time) + self.np_ + len(self.free_x0)
        self.has_parameter_stage = self.n_par > 0
        if initial_cost is not None and not self.has_parameter_stage:
            raise ProblemDefinitionError("initial_cost needs free initial states or parameters (with x(t0) fixed "
                                         "and no parameters it is a constant)", function="OCP", array="initial_cost")
        self.n_aug = self.nx + int(self.free_time) + self.np_
        # a safe control at which the integrator branch is evaluated on the parameter stage
        self._u_ref = np.clip(0.0, *bounds["u"])
        r, rN = self._trace_user_functions()
        self._path_equalities = _mask(path_equalities, r, "path_equalities")
        X0 = np.concatenate([self.x_init, [self._T_guess] if self.free_time else [], self._p_guess])
        XB, UB = self._docp_bounds(bounds)
        if name is not None:
            self.name = name
        super().__init__(self.n_aug, UB[0].shape[1], UB[0].shape[0], X0, x_bounds=XB, u_bounds=UB,
                         n_stage_constraints=r, n_final_constraints=rN,
                         stage_equalities=self._path_equalities, final_equalities=terminal_equalities)
        self.ad_options = {"mode": mode}

    # ------------------------------------------------------------------ construction helpers
    def _set_backend(self, ad_backend):
        if ad_backend not in ("auto", "casadi", "numpy"):
            raise ProblemDefinitionError(f"ad_backend must be 'auto', 'casadi' or 'numpy', got {ad_backend!r}",
                                         function="OCP", array="ad_backend")
        self.ad_backend = ad_backend
        self._ops = vector_ops(self.backend_used())

    @staticmethod
    def _check_arguments(rhs, method, **counts):
        if not callable(rhs):
            raise ProblemDefinitionError("rhs must be a function rhs(t, x, u, p)", function="OCP", array="rhs")
        if method not in ("rk4", "euler"):
            raise ProblemDefinitionError(f"method must be 'rk4' or 'euler', got {method!r}", function="OCP", array="method")
        lowest = {"N": 1, "substeps": 1, "controls": 0, "parameters": 0}
        for nm, val in counts.items():
            if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < lowest[nm]:
                raise ProblemDefinitionError(f"{nm} must be an integer >= {lowest[nm]}, got {val!r}", function="OCP", array=nm)

    def _set_time(self, T, minimum_time):
        self.free_time = T is None
        if minimum_time and not self.free_time:
            raise ProblemDefinitionError("minimum_time needs a free final time (T=None)", function="OCP", array="T")
        if not self.free_time and not float(T) > 0:
            raise ProblemDefinitionError(f"T must be positive, got {T!r}", function="OCP", array="T")
        self.horizon = None if self.free_time else float(T)
        self.minimum_time = bool(minimum_time)

    def _check_x0(self, x_bounds):
        """The fixed initial components must lie within the state bounds (the DOCP does not
        bound its fixed x^0: a violation would otherwise go unnoticed or read as infeasible)."""
        fixed = np.setdiff1d(np.arange(self.nx), self.free_x0)
        lo, hi = x_bounds
        bad = fixed[(self.x_init[fixed] < lo[fixed]) | (self.x_init[fixed] > hi[fixed])]
        if bad.size:
            i = int(bad[0])
            raise ProblemDefinitionError(f"x0[{i}] = {self.x_init[i]:g} lies outside its bounds "
                                         f"[{lo[i]:g}, {hi[i]:g}]", function="OCP", array="x0")

    def _docp_bounds(self, b):
        """The DOCP's state bounds (N_d + 1, n_aug) and control bounds (N_d, M): the physical
        state bounds after the initial point, the control bounds on the intervals, on the
        parameter stage the bounds of T, p and the free initial components."""
        # unused control entries cost 1/2 u^2 (zero at the optimum); on the parameter stage one
        # entry per path equality after the parameters (its stand-in equality, stage())
        n_eq = int(self._path_equalities.sum()) if self.has_parameter_stage else 0
        M = max(self.nu, self.n_par + n_eq, 1)
        first = int(self.has_parameter_stage)
        Nd = self.intervals + first
        XL, XU = np.full((Nd + 1, self.n_aug), -np.inf), np.full((Nd + 1, self.n_aug), np.inf)
        XL[first + 1:, :self.nx], XU[first + 1:, :self.nx] = b["x"]
        UL, UU = np.full((Nd, M), -np.inf), np.full((Nd, M), np.inf)
        UL[first:, :self.nu], UU[first:, :self.nu] = b["u"]
        if self.has_parameter_stage:
            lo = [b["T"][0] if self.free_time else [], b["p"][0], b["x0"][0][self.free_x0]]
            hi = [b["T"][1] if self.free_time else [], b["p"][1], b["x0"][1][self.free_x0]]
            UL[0, :self.n_par], UU[0, :self.n_par] = np.concatenate(lo), np.concatenate(hi)
        return (XL, XU), (UL, UU)

    def _guess_T(self, T_guess, lo, hi):
        if not self.free_time:
            return self.horizon
        if T_guess is not None:
            return float(T_guess)
        if np.isfinite(lo) and np.isfinite(hi):
            return 0.5 * (lo + hi)
        return max(1.0, lo) if np.isfinite(lo) else 1.0

    def _make_grid(self, grid):
        if grid is None:
            return np.linspace(0.0, 1.0, self.intervals + 1)
        g = np.asarray(grid, dtype=float).reshape(-1)
        if g.shape != (self.intervals + 1,) or g[0] != 0.0 or g[-1] != 1.0 or np.any(np.diff(g) <= 0):
            raise ProblemDefinitionError(f"grid must be N+1 = {self.intervals + 1} increasing values from 0 to 1",
                                         function="OCP", array="grid")
        return g

    def _trace_user_functions(self):
        """Call every user function once on symbols: wrong sizes and functions that cannot take
        symbolic arguments are refused here, by name; returns (r, r_N), the numbers of path and
        terminal constraints."""
        ops = self._ops
        t = ops.sym("t", 1, [self.t0])[0]
        x, u, p = ops.sym("x", self.nx, self.x_init), ops.sym("u", self.nu, self._u_ref), ops.sym("p", self.np_, self._p_guess)
        with np.errstate(all="ignore"):    # numpy: the sample point only counts the entries
            self._vec(_call(self._f, "rhs", t, x, u, p), self.nx, "rhs")
            for fn, name, args in ((self._L, "running_cost", (t, x, u, p)), (self._phi, "final_cost", (t, x, p)),
                                   (self._phi0, "initial_cost", (t, x, p))):
                if fn is not None:
                    self._vec(_call(fn, name, *args), 1, name)
            r = len(ops.entries(_call(self._g, "path", t, x, u, p))) if self._g is not None else 0
            rN = len(ops.entries(_call(self._psi, "terminal", t, x, p))) if self._psi is not None else 0
        return r, rN

    # ------------------------------------------------------------------ the traced DOCP
    def stage_data(self):
        """Row k: (tau_k, dtau_k, parameter-stage flag): the normalized start and length of the
        interval (physical when T is fixed), and 1 on the parameter stage."""
        scale = 1.0 if self.free_time else self.horizon
        tau, dtau = scale * self._grid[:-1], scale * np.diff(self._grid)
        rows = np.column_stack([tau, dtau, np.zeros(self.intervals)])
        if self.has_parameter_stage:
            rows = np.vstack([[0.0, 0.0, 1.0], rows])
        return rows

    def _split_state(self, x):
        """(physical x, T (symbol or number), p) of the augmented DOCP state."""
        n = self.nx
        T = x[n] if self.free_time else self.horizon
        j = n + int(self.free_time)
        p = x[j:j + self.np_] if self.np_ else self._ops.empty()
        return x[:n], T, p

    def _vec(self, value, size, fn):
        entries = self._ops.entries(value)
        if len(entries) != size:
            raise ProblemDefinitionError(f"returned {len(entries)} entries, expected {size}", function=fn)
        return self._ops.vertcat(*entries) if size else self._ops.empty()

    def _field(self, t, x, u, p):
        """(f, L) at one point: f a vector of n entries, L a scalar."""
        f = self._vec(_call(self._f, "rhs", t, x, u, p), self.nx, "rhs")
        L = self._vec(_call(self._L, "running_cost", t, x, u, p), 1, "running_cost") if self._L is not None \
            else self._ops.scalar(0.0)
        return f, L

    def _step(self, t, x, u, p, h):
        """One Euler or RK4 step of length h from (t, x): (x+, the quadrature of L)."""
        if self.method == "euler":
            f, L = self._field(t, x, u, p)
            return x + h * f, h * L
        xs, cost, k = x, 0.0, None
        for i, (c, b) in enumerate(zip(_RK4_C, _RK4_B)):
            y = x if i == 0 else x + (c * h) * k
            k, L = self._field(t + c * h, y, u, p)
            xs = xs + (b * h) * k
            cost = cost + (b * h) * L
        return xs, cost

    def _integrate(self, x, u, p, T, d):
        """The interval's map: ``substeps`` steps from the interval start; (x+, cost)."""
        tau, dtau = d[0], d[1]
        t = self.t0 + T * tau if self.free_time else self.t0 + tau
        H = T * dtau if self.free_time else dtau
        h = H / self.substeps
        cost = 0.0
        for j in range(self.substeps):
            x, c = self._step(t + j * h, x, u, p, h)
            cost = cost + c
        return x, cost

    def stage(self, x, u, d):
        ops = self._ops
        X, T, p = self._split_state(x)
        m, M = self.nu, self.m
        flag = d[2] if self.has_parameter_stage else 0.0
        # on the parameter stage the integrator branch sees a fixed safe control, not u^0
        uc = u[:m] if not self.has_parameter_stage or not m else (1 - flag) * u[:m] + flag * ops.const(self._u_ref)
        xs, cost = self._integrate(X, uc, p, T, d)
        tail = [T] if self.free_time else []
        x_next = ops.vertcat(xs, *tail, p)
        cost = cost + 0.5 * ops.sumsqr(u[m:]) if M > m else cost
        t = self.t0 + (T * d[0] if self.free_time else d[0])
        g = self._vec(_call(self._g, "path", t, X, uc, p), self.r, "path") if self.r else ops.empty()
        if not self.has_parameter_stage:
            return x_next, cost, g
        par_next, par_cost = self._parameter_map(x, u)
        x_next = flag * par_next + (1 - flag) * x_next
        cost = flag * par_cost + (1 - flag) * cost
        if self.r:
            g = (1 - flag) * g + flag * self._parameter_stage_constraints(u)
        return x_next, cost, g

    def _parameter_stage_constraints(self, u):
        """The path constraints' stand-ins on the parameter stage: 1 >= 0 for an inequality
        (inactive), u^0[n_par + i] = 0 for the i-th equality (a regular row on a control that has
        no other role), so that the constraint Jacobian keeps full rank there."""
        rows, i = [], 0
        for eq in self._path_equalities:
            rows.append(u[self.n_par + i] if eq else self._ops.scalar(1.0))
            i += int(eq)
        return self._ops.vertcat(*rows)

    def _parameter_map(self, x, u):
        """Stage 0: X^1 = (x_0 with the free components from u, T and p from u); cost 1/2 |rest|^2
        plus the initial cost at (t_0, x(t_0), p)."""
        n, j = self.nx, 0
        entries = [x[i] for i in range(self.n_aug)]
        if self.free_time:
            entries[n] = u[0]
            j = 1
        for i in range(self.np_):
            entries[n + int(self.free_time) + i] = u[j + i]
        j += self.np_
        for i, comp in enumerate(self.free_x0):
            entries[comp] = u[j + i]
        X1 = self._ops.vertcat(*entries)
        cost = 0.5 * self._ops.sumsqr(u[self.n_par:])
        if self._phi0 is not None:
            x1, _, p = self._split_state(X1)
            cost = cost + self._vec(_call(self._phi0, "initial_cost", self.t0, x1, p), 1, "initial_cost")
        return X1, cost

    def final(self, x):
        ops = self._ops
        X, T, p = self._split_state(x)
        tf = self.t0 + T
        cost = self._vec(_call(self._phi, "final_cost", tf, X, p), 1, "final_cost") if self._phi is not None \
            else ops.scalar(0.0)
        if self.minimum_time:
            cost = cost + T
        psi = self._vec(_call(self._psi, "terminal", tf, X, p), self.rN, "terminal") if self.rN else ops.empty()
        return cost, psi

    # ------------------------------------------------------------------ start point
    def initial_guess(self):
        """u_guess on the intervals (default the DOCP's midpoints of the bounds); on the
        parameter stage T_guess, p_guess and the free components of x0."""
        U = super().initial_guess()
        first = int(self.has_parameter_stage)
        if self._u_guess is not None:
            U[first:, :self.nu] = self._u_guess
        if self.has_parameter_stage:
            U[0] = 0.0
            U[0, :self.n_par] = self._parameter_values(self._T_guess, self._p_guess, self.x_init[self.free_x0])
        return U

    def _parameter_values(self, T, p, x0_free):
        return np.concatenate([[T] if self.free_time else [], p, x0_free])

    def initial_state_guess(self, U):
        """x_guess (N+1, n) with T and p from the parameter stage's controls, or None (simulate)."""
        if self._x_guess is None:
            return None
        g = self._x_guess
        X = np.empty((self.N + 1, self.n))
        X[0] = self.x0
        first = int(self.has_parameter_stage)
        X[first:, :self.nx] = g
        if self.has_parameter_stage:
            X[first:, self.nx:] = self._augmented_tail(U[0])
        return X

    def _augmented_tail(self, u0):
        T = [u0[0]] if self.free_time else []
        j = int(self.free_time)
        return np.concatenate([T, u0[j:j + self.np_]])

    # ------------------------------------------------------------------ reading a solution
    def solution(self, result) -> OCPSolution:
        """The solution of a result (or an (X, U) pair of DOCP trajectories) in the OCP's terms."""
        X, U = (result.x, result.u) if hasattr(result, "x") else result
        X, U = np.asarray(X, dtype=float), np.asarray(U, dtype=float)
        first = int(self.has_parameter_stage)
        x = X[first:, :self.nx]
        T = float(X[-1, self.nx]) if self.free_time else self.horizon
        j = self.nx + int(self.free_time)
        p = X[-1, j:j + self.np_].copy()
        return OCPSolution(t=self.t0 + T * self._grid, x=x.copy(), u=U[first:, :self.nu].copy(), tf=self.t0 + T,
                           p=p, x0=x[0].copy())

    @property
    def discretization(self) -> str:
        scheme = "RK4" if self.method == "rk4" else "explicit Euler"
        steps = f"{self.intervals} intervals x {self.substeps} {scheme} steps"
        time = "free final time (time scaling)" if self.free_time else f"on [{self.t0:g}, {self.t0 + self.horizon:g}]"
        par = f"; parameter stage sets {self.n_par} values (T, p, free x0)" if self.has_parameter_stage else ""
        return f"{steps}, {time}{par}"

    def describe(self):
        return super().describe() + f"\n  {self.discretization}"
