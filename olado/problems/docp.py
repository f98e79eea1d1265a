"""The discrete-time optimal control problem (DOCP) of paper 001, eqs. (1)-(5).

    min_u  J = sum_{k=0}^{N-1} f_0^k(x^k, u^k) + F^N(x^N)                       (1)
    s.t.   x^{k+1} = f^k(x^k, u^k),  k = 0..N-1,  x^0 = xbar^0                   (2)
           g^k(x^k, u^k) >= 0,  g^N(x^N) >= 0   (components may be equalities)   (3)
           x_L^k <= x^k <= x_U^k (k = 0..N),  u_L^k <= u^k <= u_U^k (k = 0..N-1)  (4)-(5)

A user subclasses :class:`DOCP` (Bolza form), :class:`LagrangeDOCP` (no final cost) or
:class:`MayerDOCP` (no stage cost) and overrides the stage functions. Stage functions are written
per stage (``vectorized = False``: ``dynamics(k, x, u)`` with an int ``k``) or for all stages at
once (``vectorized = True``: ``k`` is an int array (K,), ``x`` is (K, n), ``u`` is (K, m)).

Derivatives come from the problem's analytic methods when it overrides them, otherwise from
finite differences (forward, backward or central). Solvers use only the ``eval_*`` methods,
which always work on all stages at once, validate every array a user function returns (shape,
finiteness) and raise :class:`~olado.errors.ProblemDefinitionError` naming the function, the stage
and the array when something is wrong -- for a NaN or inf its subclass
:class:`~olado.errors.NonFiniteEvaluationError`, which the solvers catch by type (at a trial point
of a line search it means "step too long").
"""

from __future__ import annotations

import math
import os
from collections import Counter
from typing import NamedTuple

import numpy as np

from ..errors import NonFiniteEvaluationError, ProblemDefinitionError
from .signatures import check_signatures

_EPS = np.finfo(float).eps

#: user functions and the analytic derivative methods that belong to them
_DERIVATIVE_OF = {
    "dynamics_jacobian": "dynamics",
    "stage_cost_gradient": "stage_cost",
    "final_cost_gradient": "final_cost",
    "stage_constraints_jacobian": "stage_constraints",
    "final_constraints_jacobian": "final_constraints",
    "stage_hessian": None,
    "final_hessian": None,
}


_all_finite_kernel = None

def _all_finite(arr):
    """True when every entry of the float64 array ``arr`` is finite (one compiled pass,
    :func:`olado.problems._kernels.all_finite`: no temporary, no BLAS call -- BLAS threads compete
    with the solver's)."""
    global _all_finite_kernel
    if _all_finite_kernel is None:
        from ._kernels import all_finite   # noqa: PLC0415 - numba loads on first use
        _all_finite_kernel = all_finite
    if arr.ndim == 0:
        return math.isfinite(arr[()])
    return _all_finite_kernel(arr)


_all_finite_pair = None


def _all_finite_arrays(arrays):
    """True when every entry of the float64 arrays ``arrays`` (a tuple) is finite: one compiled
    call per two arrays (the stage functions' derivative tuples), the detailed scan of
    :meth:`DOCP._check_stacked` only where this fails."""
    global _all_finite_pair
    if _all_finite_pair is None:
        from ._kernels import all_finite_pair   # noqa: PLC0415 - numba loads on first use
        _all_finite_pair = all_finite_pair
    for i in range(0, len(arrays) - 1, 2):
        if not _all_finite_pair(arrays[i], arrays[i + 1]):
            return False
    return len(arrays) % 2 == 0 or _all_finite(arrays[-1])


def _plain(value, shape):
    """True when ``value`` is a float64 ndarray of exactly ``shape``: what a well-written stage
    function returns, accepted by the validation's fast path without conversion."""
    return type(value) is np.ndarray and value.dtype == np.float64 and value.shape == shape


#: user functions and derivative methods (overridable) and the arguments olado calls them with
CALL_ARGUMENTS = {
    "dynamics": ("k", "x", "u"),
    "stage_cost": ("k", "x", "u"),
    "final_cost": ("x",),
    "stage_constraints": ("k", "x", "u"),
    "final_constraints": ("x",),
    "dynamics_jacobian": ("k", "x", "u"),
    "stage_cost_gradient": ("k", "x", "u"),
    "final_cost_gradient": ("x",),
    "stage_constraints_jacobian": ("k", "x", "u"),
    "final_constraints_jacobian": ("x",),
    "stage_hessian": ("k", "x", "u", "sigma", "p", "lam"),
    "final_hessian": ("x", "sigma", "lam"),
    "initial_guess": (),
    "initial_state_guess": ("U",),
}


class PointValues(NamedTuple):
    """The values of the DOCP at a point (X, U) (:meth:`DOCP.eval_values`): the objective J of
    eq. (1), the dynamics f^k(x^k, u^k) (N, n) of eq. (2), the stage constraints g (N, r) and the
    final constraints gN (rN,) of eq. (3)."""

    J: float
    f: np.ndarray
    g: np.ndarray
    gN: np.ndarray


class FirstDerivatives(NamedTuple):
    """The first derivatives of the DOCP at a point (X, U) (:meth:`DOCP.eval_first_derivatives`):
    the stage cost gradients lx (N, n), lu (N, m), the final cost gradient lN (n,), the dynamics
    Jacobians A (N, n, n), B (N, n, m), the stage constraint Jacobians Cx (N, r, n), Cu (N, r, m)
    and the final constraint Jacobian CN (rN, n) -- the data of the QP (8)-(10) of paper 001."""

    lx: np.ndarray
    lu: np.ndarray
    lN: np.ndarray
    A: np.ndarray
    B: np.ndarray
    Cx: np.ndarray
    Cu: np.ndarray
    CN: np.ndarray


def stage_floats(n, m, r=0):
    """Lower estimate of the float64 numbers every solver keeps per stage: x, u and their bounds,
    the dynamics Jacobians (A, B), the Hessian blocks, the constraint Jacobians, the multipliers."""
    return (n + m) * (3 + n + (n + m) + r) + n + r


def physical_memory():
    """This machine's memory in bytes (None where the system does not say)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def check_problem_size(n, m, N, r=0, function="__init__"):
    """Refuse, before anything is allocated, a horizon whose stage arrays alone (a lower estimate,
    :func:`stage_floats`) exceed this machine's memory; the message gives the estimate."""
    memory = physical_memory()
    per_stage = 8 * stage_floats(n, m, r)
    need = per_stage * int(N)
    if memory and need > memory:
        raise ProblemDefinitionError(
            f"N={N} stages cannot fit in memory: the stage arrays alone need at least "
            f"{need / 2**30:,.1f} GiB ({per_stage} bytes per stage for n={n}, m={m}, r={r}), "
            f"this machine has {memory / 2**30:,.1f} GiB", function=function, array="N")


def _stacked_shapes(nK, shapes, _cache={}):   # noqa: B006 - a deliberate memo
    """The shapes (nK,) + s of the stacked arrays of a stage method (memoized per (nK, shapes))."""
    key = (nK, tuple(shapes))
    found = _cache.get(key)
    if found is None:
        if len(_cache) > 256:
            _cache.clear()
        found = _cache[key] = tuple((nK,) + tuple(s) for s in shapes)
    return found


def _describe(value):
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


#: dtype kinds that convert to float64 without losing anything a user meant (bool, int, float)
_REAL_KINDS = "biuf"


def as_real_array(value, function, array, stage=None, *, stage0=None):
    """``value`` as a float64 array, or a :class:`ProblemDefinitionError` naming ``function``,
    ``array`` and the stage when it is not an array of real numbers: None, complex values (their
    imaginary parts would be dropped silently), text, objects or a ragged nest of lists.

    The one conversion behind :meth:`DOCP.check_array` (one stage) and the all-stages check
    (``stage0``: the stage of the first row, so that an error names the stage it found)."""
    if type(value) is np.ndarray and value.dtype == np.float64:
        return value
    got = "returned" if function in CALL_ARGUMENTS else "got"
    if value is None:
        raise ProblemDefinitionError(f"{got} None instead of a float array" + (
            " (a missing return statement?)" if got == "returned" else ""),
            function=function, stage=stage, array=array)
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ProblemDefinitionError(f"cannot convert to a float array ({exc})", function=function,
                                     stage=stage, array=array) from None
    kind = arr.dtype.kind
    if kind in _REAL_KINDS:
        return arr if arr.dtype == np.float64 else arr.astype(np.float64)
    if kind not in "cO":
        raise ProblemDefinitionError(f"expected real numbers, got dtype {arr.dtype} ({_dtype_words(kind)})",
                                     function=function, stage=stage, array=array)
    index = _first_bad_entry(arr, kind)
    if index is None:  # an object array of plain numbers
        return arr.astype(np.float64)
    entry = arr[index]
    if stage0 is not None and index:
        stage, index = stage0 + index[0], index[1:]
    at = f" at index {index}" if index else ""
    if kind == "c":
        raise ProblemDefinitionError(f"complex values (dtype {arr.dtype}){at}: {entry}; olado works in "
                                     "real arithmetic: real numbers only", function=function,
                                     stage=stage, array=array)
    what = "None" if entry is None else _a(type(entry).__name__)
    text = f"{got} {what}" if arr.ndim == 0 else f"an array holding {what}{at}"
    raise ProblemDefinitionError(f"{text}; expected real numbers", function=function, stage=stage, array=array)


def _first_bad_entry(arr, kind):
    """Index (a tuple) of the first entry of a complex or object array that is not a real number;
    for a complex array whose imaginary parts are all zero, its first entry (complex is refused
    as a type); None for an object array of plain numbers."""
    if kind == "c":
        bad = np.argwhere(np.atleast_1d(arr.imag != 0))
        first = tuple(int(i) for i in bad[0]) if len(bad) else (0,) * arr.ndim
        return first[:arr.ndim]
    flags = np.frompyfunc(_not_real, 1, 1)(arr)
    bad = np.argwhere(np.atleast_1d(np.asarray(flags, dtype=bool)))
    if not len(bad):
        return None
    return tuple(int(i) for i in bad[0])[:arr.ndim]


def _a(noun):
    return f"{'an' if noun[:1].lower() in 'aeiou' else 'a'} {noun}"


def _not_real(v):
    return not isinstance(v, (int, float, np.integer, np.floating, np.bool_))


def _dtype_words(kind):
    return {"U": "text", "S": "bytes", "M": "dates", "m": "time spans", "V": "records"}.get(kind, "not numbers")


def _as_bool_mask(spec, size, name):
    """Turn None / bool mask / index list into a bool mask of length ``size``."""
    mask = np.zeros(size, dtype=bool)
    if spec is None:
        return mask
    try:
        arr = np.asarray(spec)
    except (TypeError, ValueError) as exc:
        raise ProblemDefinitionError(f"expected a boolean mask or a list of indices ({exc})", function="__init__", array=name) from None
    if arr.dtype == bool:
        if arr.shape != (size,):
            raise ProblemDefinitionError(f"expected a boolean mask of length {size}, got shape {arr.shape}", function="__init__", array=name)
        return arr.copy()
    if arr.size and arr.dtype.kind not in "iu":
        raise ProblemDefinitionError(f"expected a boolean mask or a list of integer indices, got {_describe(spec)}",
                                     function="__init__", array=name)
    idx = arr.astype(int).ravel()
    if np.any(idx < 0) or np.any(idx >= size):
        raise ProblemDefinitionError(f"indices must lie in 0..{size - 1} (the constraint components), got {idx.tolist()}"
                                     if size else f"there are no such constraints (0 components), got indices {idx.tolist()}",
                                     function="__init__", array=name)
    mask[idx] = True
    return mask


def check_problem(problem, entry="olado.solve"):
    """The public entry points' guard on their ``problem`` argument: a constructed DOCP whose user
    functions can be called (:meth:`DOCP.check_functions`); ProblemDefinitionError naming the
    argument (and ``entry``, the function that received it) otherwise."""
    if isinstance(problem, type) and issubclass(problem, DOCP):
        raise ProblemDefinitionError(f"argument 'problem' is the class {problem.__name__}, not an "
                                     f"instance: build one first, e.g. {problem.__name__}(...)", function=entry)
    if not isinstance(problem, DOCP):
        raise ProblemDefinitionError("argument 'problem' must be a DOCP instance (of a subclass of "
                                     f"olado.DOCP, LagrangeDOCP or MayerDOCP), got {_describe(problem)}",
                                     function=entry)
    missing = [a for a in ("n", "m", "N", "x0", "x_lower", "u_lower", "counters", "_K") if not hasattr(problem, a)]
    if missing:
        raise ProblemDefinitionError(f"{type(problem).__name__}.__init__ did not call DOCP.__init__ "
                                     f"(super().__init__(n, m, N, x0, ...)): attribute '{missing[0]}' is "
                                     "missing", function=entry)
    if not isinstance(problem.name, str):
        raise ProblemDefinitionError(f"{type(problem).__name__}.name must be a string (it names the problem "
                                     f"in results), got {_describe(problem.name)}", function=entry)
    problem.check_functions()
    return problem


class DOCP:
    """Bolza-form DOCP, paper 001 eqs. (1)-(5). Subclass and override the stage functions.

    Parameters
    ----------
    n, m, N : state dimension, control dimension, horizon (number of stages).
    x0 : fixed initial state, shape (n,).
    x_bounds, u_bounds : ``(lower, upper)``; each a scalar, stationary (n,)/(m,) or
        nonstationary (N+1, n)/(N, m) array, ``None`` meaning unbounded; +-inf allowed.
    n_stage_constraints, n_final_constraints : r (components of g^k) and r^N (of g^N).
    stage_equalities, final_equalities : boolean masks or index lists of the components of g^k /
        g^N that are equalities ``= 0`` (the rest are ``>= 0``). Equality final constraints give
        a fixed final state, e.g. ``g^N(x) = x - x_target``.
    derivatives : ``"auto"`` (analytic where the subclass provides a method, finite differences
        elsewhere) or ``"fd"`` (finite differences everywhere).
    fd_method : ``"forward"``, ``"backward"`` or ``"central"``.
    fd_step : relative step; default sqrt(eps) for one-sided and eps**(1/3) for central
        differences (eps**(1/4) for second differences of function values).
    """

    name = "docp"
    vectorized = False

    def __init__(self, n, m, N, x0, x_bounds=None, u_bounds=None, *, n_stage_constraints=0,
                 n_final_constraints=0, stage_equalities=None, final_equalities=None,
                 derivatives="auto", fd_method="central", fd_step=None):
        for val, nm in ((n, "n"), (m, "m"), (N, "N")):
            if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < 1:
                raise ProblemDefinitionError(f"{nm} must be a positive integer, got {val!r}", function="__init__", array=nm)
        self.n, self.m, self.N = int(n), int(m), int(N)
        for val, nm in ((n_stage_constraints, "n_stage_constraints"), (n_final_constraints, "n_final_constraints")):
            if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < 0:
                raise ProblemDefinitionError(f"must be a non-negative integer, got {val!r}", function="__init__", array=nm)
        self.r, self.rN = int(n_stage_constraints), int(n_final_constraints)
        check_problem_size(self.n, self.m, self.N, self.r)
        self.x0 = self.check_array(x0, (self.n,), "__init__", "x0")
        self.stage_equality_mask = _as_bool_mask(stage_equalities, self.r, "stage_equalities")
        self.final_equality_mask = _as_bool_mask(final_equalities, self.rN, "final_equalities")
        if not isinstance(derivatives, str) or derivatives not in ("auto", "fd"):
            raise ProblemDefinitionError(f"derivatives must be 'auto' or 'fd', got {derivatives!r}", function="__init__", array="derivatives")
        if not isinstance(fd_method, str) or fd_method not in ("forward", "backward", "central"):
            raise ProblemDefinitionError(f"fd_method must be forward, backward or central, got {fd_method!r}", function="__init__", array="fd_method")
        if fd_step is not None and (isinstance(fd_step, bool) or not isinstance(fd_step, (int, float, np.integer, np.floating))
                                    or not 0 < fd_step < 1):
            raise ProblemDefinitionError(f"fd_step must be None (the default steps) or a relative step in (0, 1), "
                                         f"got {fd_step!r}", function="__init__", array="fd_step")
        self.derivatives, self.fd_method, self.fd_step = derivatives, fd_method, fd_step
        self.counters = Counter()
        self._K = np.arange(self.N)
        self.x_bounds = x_bounds
        self.u_bounds = u_bounds
        for fn in ("dynamics", "stage_cost", "final_cost"):
            if not self._overrides(fn):
                hint = {"stage_cost": " (use MayerDOCP for a problem without stage cost)",
                        "final_cost": " (use LagrangeDOCP for a problem without final cost)"}.get(fn, "")
                raise ProblemDefinitionError(f"{type(self).__name__} must define {fn}{hint}", function=fn)
        if self.r and not self._overrides("stage_constraints"):
            raise ProblemDefinitionError(f"n_stage_constraints={self.r} but stage_constraints is not defined", function="stage_constraints")
        if self.rN and not self._overrides("final_constraints"):
            raise ProblemDefinitionError(f"n_final_constraints={self.rN} but final_constraints is not defined", function="final_constraints")
        self.check_functions()

    # ======================================================================== user functions
    def dynamics(self, k, x, u):
        """State equation f^k(x^k, u^k), eq. (2)."""
        raise ProblemDefinitionError("dynamics is not defined", function="dynamics")

    def stage_cost(self, k, x, u):
        """Stage cost f_0^k(x^k, u^k), eq. (1)."""
        raise ProblemDefinitionError("stage_cost is not defined", function="stage_cost")

    def final_cost(self, x):
        """Final cost F^N(x^N), eq. (1)."""
        raise ProblemDefinitionError("final_cost is not defined", function="final_cost")

    def stage_constraints(self, k, x, u):
        """Stage constraints g^k(x^k, u^k) >= 0 (or = 0 where flagged), eq. (3)."""
        if self.vectorized:
            return np.zeros((np.size(k), 0))
        return np.zeros(0)

    def final_constraints(self, x):
        """Final constraints g^N(x^N) >= 0 (or = 0 where flagged), eq. (3)."""
        return np.zeros(0)

    # Optional analytic derivatives: defined here only so that subclasses can override them.
    def dynamics_jacobian(self, k, x, u):
        """(f_x, f_u) of the state equation."""
        raise NotImplementedError

    def stage_cost_gradient(self, k, x, u):
        """(l_x, l_u), gradient of the stage cost."""
        raise NotImplementedError

    def final_cost_gradient(self, x):
        """Gradient of the final cost."""
        raise NotImplementedError

    def stage_constraints_jacobian(self, k, x, u):
        """(g_x, g_u) of the stage constraints."""
        raise NotImplementedError

    def final_constraints_jacobian(self, x):
        """Jacobian of the final constraints."""
        raise NotImplementedError

    def stage_hessian(self, k, x, u, sigma, p, lam):
        """(H_xx, H_xu, H_uu) of sigma*f_0^k + p.f^k + lam.g^k (block of eq. (12))."""
        raise NotImplementedError

    def final_hessian(self, x, sigma, lam):
        """H_xx of sigma*F^N + lam.g^N (last block of eq. (12))."""
        raise NotImplementedError

    # ======================================================================== bounds
    @property
    def x_bounds(self):
        return self.x_lower, self.x_upper

    @x_bounds.setter
    def x_bounds(self, value):
        self.x_lower, self.x_upper = self._bounds(value, self.N + 1, self.n, "x_bounds")

    @property
    def u_bounds(self):
        return self.u_lower, self.u_upper

    @u_bounds.setter
    def u_bounds(self, value):
        self.u_lower, self.u_upper = self._bounds(value, self.N, self.m, "u_bounds")

    def _bounds(self, value, rows, cols, name):
        if value is None:
            value = (None, None)
        if not isinstance(value, (tuple, list)) or len(value) != 2:
            raise ProblemDefinitionError("bounds must be a pair (lower, upper)", array=name)
        out = []
        for side, default in zip(value, (-np.inf, np.inf)):
            if side is None:
                arr = np.full((rows, cols), default)
            else:
                arr = as_real_array(side, "__init__", name)
                if arr.ndim == 0:
                    arr = np.full((rows, cols), float(arr))
                elif arr.shape == (cols,):
                    arr = np.broadcast_to(arr, (rows, cols)).copy()
                elif arr.shape == (rows, cols):
                    arr = arr.copy()
                else:
                    raise ProblemDefinitionError(
                        f"expected shape ({cols},) (stationary) or ({rows}, {cols}) (per stage), got {arr.shape}", array=name)
            if np.isnan(arr).any():
                k = int(np.argwhere(np.isnan(arr))[0, 0])
                raise ProblemDefinitionError("NaN in bounds", stage=k, array=name)
            out.append(arr)
        lo, hi = out
        bad = lo > hi
        if bad.any():
            k, j = (int(v) for v in np.argwhere(bad)[0])
            raise ProblemDefinitionError(f"lower bound {lo[k, j]} > upper bound {hi[k, j]} for component {j}", stage=k, array=name)
        return lo, hi

    # ======================================================================== validation
    def check_array(self, value, shape, function, array, stage=None):
        """Return ``value`` as a float array of ``shape``; ProblemDefinitionError otherwise
        (NonFiniteEvaluationError for a NaN or inf entry). None, complex values, text and object
        arrays are refused by name (:func:`as_real_array`)."""
        if type(shape) is tuple and _plain(value, shape) and _all_finite(value):
            return value                                    # the common case: nothing to convert
        arr = as_real_array(value, function, array, stage)
        if arr.shape != tuple(shape):
            if arr.size == int(np.prod(shape)) and arr.ndim <= 1 and len(shape) <= 1:
                arr = arr.reshape(shape)
            else:
                raise ProblemDefinitionError(f"expected shape {tuple(shape)}, got {arr.shape}", function=function, stage=stage, array=array)
        if not _all_finite(arr):
            bad = np.argwhere(~np.isfinite(arr))[0]
            where = stage
            if stage is None and arr.ndim >= 1 and len(shape) >= 2:
                where = int(bad[0])
            raise NonFiniteEvaluationError(f"non-finite value {arr[tuple(bad)]} at index {tuple(int(b) for b in bad)}",
                                           function=function, stage=where, array=array)
        return arr

    def _check_stacked(self, value, shape, function, array, stage0=0):
        """Validate an all-stages array (leading axis = stage); errors name the stage."""
        if type(shape) is tuple and _plain(value, shape) and _all_finite(value):
            return value                                    # the common case: nothing to convert
        arr = as_real_array(value, function, array, None, stage0=stage0)
        if arr.shape != tuple(shape):
            raise ProblemDefinitionError(f"expected shape {tuple(shape)} (one row per stage), got {arr.shape}", function=function, array=array)
        if not _all_finite(arr):
            finite = np.isfinite(arr)
            bad = np.argwhere(~finite)[0]
            raise NonFiniteEvaluationError(f"non-finite value {arr[tuple(bad)]} at entry {tuple(int(b) for b in bad[1:])}",
                                           function=function, stage=stage0 + int(bad[0]), array=array)
        return arr

    def check_functions(self):
        """Every user function and derivative method is callable with the arguments olado passes
        (:data:`CALL_ARGUMENTS`); ProblemDefinitionError naming the function otherwise. Run by
        the constructor and again at the public entry points (an attribute may be replaced after
        construction); what was accepted is remembered (olado.problems.signatures)."""
        check_signatures(self, CALL_ARGUMENTS, _describe)

    def _overrides(self, name):
        return getattr(type(self), name, None) is not getattr(DOCP, name, None)

    def provides(self, name) -> bool:
        """True when the problem supplies the analytic derivative method ``name``."""
        if name not in _DERIVATIVE_OF:
            raise KeyError(name)
        return self.derivatives == "auto" and self._overrides(name)

    def reset_counters(self):
        self.counters.clear()

    # ======================================================================== raw stage calls
    def _stage_values(self, fname, K, X, U, tail_shape, out_name, count=True):
        """Call a stage function for the stages K with states X (len K, n) and controls U."""
        fn = getattr(self, fname)
        nK = len(K)
        if count:
            self.counters[fname] += 1
        if self.vectorized:
            val = fn(K, X, U)
            shape = (nK,) + tail_shape
            if _plain(val, shape) and _all_finite(val):   # the common case: nothing to convert
                return val
            return self._check_stacked(val, shape, fname, out_name, stage0=int(K[0]) if nK else 0)
        out = np.empty((nK,) + tail_shape)
        for i, k in enumerate(K):
            v = fn(int(k), X[i], U[i])
            out[i] = self.check_array(v, tail_shape, fname, out_name, stage=int(k))
        return out

    def _stage_multi(self, fname, K, X, U, shapes, names):
        """Call a stage method returning a tuple of arrays (analytic derivatives)."""
        fn = getattr(self, fname)
        nK = len(K)
        self.counters[fname] += 1
        if self.vectorized:
            vals = fn(K, X, U)
            stacked = _stacked_shapes(nK, shapes)
            if (type(vals) is tuple and len(vals) == len(stacked)
                    and all(_plain(v, sh) for v, sh in zip(vals, stacked)) and _all_finite_arrays(vals)):
                return vals                                 # the common case: nothing to convert
            if not isinstance(vals, (tuple, list)) or len(vals) != len(shapes):
                raise ProblemDefinitionError(f"must return a tuple of {len(shapes)} arrays", function=fname)
            return tuple(self._check_stacked(v, (nK,) + s, fname, nm, stage0=int(K[0]) if nK else 0)
                         for v, s, nm in zip(vals, shapes, names))
        outs = tuple(np.empty((nK,) + s) for s in shapes)
        for i, k in enumerate(K):
            vals = fn(int(k), X[i], U[i])
            if not isinstance(vals, (tuple, list)) or len(vals) != len(shapes):
                raise ProblemDefinitionError(f"must return a tuple of {len(shapes)} arrays", function=fname, stage=int(k))
            for o, v, s, nm in zip(outs, vals, shapes, names):
                o[i] = self.check_array(v, s, fname, nm, stage=int(k))
        return outs

    def _stacked_values(self, K, X, U, XN):
        """The spot check's values of several points (olado.solvers.certificate): stage costs, dynamics,
        g of their stage rows stacked (checked as by :meth:`_stage_values`, uncounted) and the final
        costs at the rows of XN (:meth:`eval_final_cost`, counted). Overridable as :meth:`eval_values`."""
        cost = self._stage_values("stage_cost", K, X, U, (), "cost", count=False)
        dyn = self._stage_values("dynamics", K, X, U, (self.n,), "x_next", count=False)
        g = self._stage_values("stage_constraints", K, X, U, (self.r,), "g", count=False) if self.r else None
        return cost, dyn, np.zeros((len(K), 0)) if g is None else g, np.array([self.eval_final_cost(x) for x in XN])

    def _split_xu(self, X, U):
        if (type(X) is np.ndarray and type(U) is np.ndarray and X.dtype == np.float64
                and U.dtype == np.float64 and X.shape == (self.N + 1, self.n) and U.shape == (self.N, self.m)):
            return X, U
        X = np.asarray(X, dtype=float)
        U = np.asarray(U, dtype=float)
        if X.shape != (self.N + 1, self.n):
            raise ProblemDefinitionError(f"expected states of shape ({self.N + 1}, {self.n}), got {X.shape}", array="X")
        if U.shape != (self.N, self.m):
            raise ProblemDefinitionError(f"expected controls of shape ({self.N}, {self.m}), got {U.shape}", array="U")
        return X, U

    # ======================================================================== values
    def eval_dynamics(self, X, U):
        """f^k(x^k, u^k) for k = 0..N-1, shape (N, n)."""
        X, U = self._split_xu(X, U)
        return self._stage_values("dynamics", self._K, X[:-1], U, (self.n,), "x_next")

    def eval_stage_costs(self, X, U):
        """f_0^k(x^k, u^k) for k = 0..N-1, shape (N,)."""
        X, U = self._split_xu(X, U)
        return self._stage_values("stage_cost", self._K, X[:-1], U, (), "cost")

    def eval_final_cost(self, xN):
        self.counters["final_cost"] += 1
        value = self.final_cost(xN if type(xN) is np.ndarray and xN.dtype == np.float64 else np.asarray(xN, dtype=float))
        if type(value) is float and math.isfinite(value):   # the common case: nothing to convert
            return value
        return float(self.check_array(value, (), "final_cost", "cost"))

    def eval_stage_constraints(self, X, U):
        """g^k(x^k, u^k) for k = 0..N-1, shape (N, r)."""
        X, U = self._split_xu(X, U)
        if self.r == 0:
            return np.zeros((self.N, 0))
        return self._stage_values("stage_constraints", self._K, X[:-1], U, (self.r,), "g")

    def eval_final_constraints(self, xN):
        if self.rN == 0:
            return np.zeros(0)
        self.counters["final_constraints"] += 1
        return self.check_array(self.final_constraints(np.asarray(xN, dtype=float)), (self.rN,), "final_constraints", "gN")

    def objective(self, X, U):
        """J of eq. (1) at a state/control trajectory pair."""
        X, U = self._split_xu(X, U)
        return float(np.sum(self.eval_stage_costs(X, U)) + self.eval_final_cost(X[-1]))

    # ======================================================================== a point at once
    def eval_values(self, X, U) -> PointValues:
        """J, f, g, gN at (X, U) (:class:`PointValues`): what a solver evaluates at every trial
        point. The default calls :meth:`objective`, :meth:`eval_dynamics`,
        :meth:`eval_stage_constraints` and :meth:`eval_final_constraints` in that order, with their
        validation and counters. A problem may override it with one compiled pass over the stages
        (:class:`olado.problems.zambezi.Zambezi` does); an override returns the same numbers,
        advances the same counters, and for a value the default would refuse raises the default's
        error (simplest: it falls back to this method when its pass finds a NaN or inf)."""
        X, U = self._split_xu(X, U)
        J = self.objective(X, U)
        return PointValues(J, self.eval_dynamics(X, U), self.eval_stage_constraints(X, U),
                           self.eval_final_constraints(X[-1]))

    def eval_first_derivatives(self, X, U) -> FirstDerivatives:
        """The first derivatives at (X, U) (:class:`FirstDerivatives`). The default calls
        :meth:`eval_stage_cost_gradients`, :meth:`eval_final_cost_gradient`,
        :meth:`eval_dynamics_jacobians`, :meth:`eval_stage_constraint_jacobians` and
        :meth:`eval_final_constraint_jacobian` in that order; an override follows the rules of
        :meth:`eval_values`."""
        X, U = self._split_xu(X, U)
        lx, lu = self.eval_stage_cost_gradients(X, U)
        lN = self.eval_final_cost_gradient(X[-1])
        A, B = self.eval_dynamics_jacobians(X, U)
        Cx, Cu = self.eval_stage_constraint_jacobians(X, U)
        return FirstDerivatives(lx, lu, lN, A, B, Cx, Cu, self.eval_final_constraint_jacobian(X[-1]))

    def compiled_evaluations(self):
        """The problem's evaluations as compiled functions, for a solver loop compiled as a whole
        (:class:`olado.problems.compiled.CompiledEvaluations`: :meth:`eval_values`,
        :meth:`eval_first_derivatives`, :meth:`eval_stage_hessians`, :meth:`eval_final_hessian`
        as numba first-class functions with the same numbers), or None: the default, and what a
        problem returns that has no compiled stage functions. Only problems without stage and
        final constraint rows (r = rN = 0) return them for now (Zambezi does)."""
        return None

    def simulate(self, U):
        """States X (N+1, n) from x^0 and the state equation (2) under controls U (N, m)."""
        U = self.check_array(U, (self.N, self.m), "simulate", "u")
        X = np.empty((self.N + 1, self.n))
        X[0] = self.x0
        self.counters["dynamics"] += 1
        for k in range(self.N):
            if self.vectorized:
                v = self.dynamics(self._K[k:k + 1], X[k:k + 1], U[k:k + 1])
                X[k + 1] = self.check_array(np.asarray(v).reshape(-1) if np.size(v) == self.n else v, (self.n,), "dynamics", "x_next", stage=k)
            else:
                X[k + 1] = self.check_array(self.dynamics(k, X[k], U[k]), (self.n,), "dynamics", "x_next", stage=k)
        return X

    def initial_state_guess(self, U):
        """States (N+1, n) to start the simultaneous methods (SQP, IPOPT, ...) from together with
        the initial controls U, or None (default): the states simulated from U. A problem whose
        reference start point fixes the states too (e.g. the CUTEr SIF start of Zambezi) returns
        them here; sequential methods simulate U whatever this returns."""
        return None

    def initial_guess(self):
        """Default controls: midpoint of finite bounds, the finite bound if one-sided, else 0."""
        lo, hi = self.u_lower, self.u_upper
        U = np.zeros((self.N, self.m))
        both = np.isfinite(lo) & np.isfinite(hi)
        U[both] = 0.5 * (lo[both] + hi[both])
        only_lo = np.isfinite(lo) & ~np.isfinite(hi)
        U[only_lo] = np.maximum(lo[only_lo], 0.0)
        only_hi = ~np.isfinite(lo) & np.isfinite(hi)
        U[only_hi] = np.minimum(hi[only_hi], 0.0)
        return U

    # ======================================================================== first derivatives
    def _steps(self, Z, order=1):
        if self.fd_step is not None:
            rel = float(self.fd_step)
        elif order == 2:
            rel = _EPS ** 0.25
        elif self.fd_method == "central":
            rel = _EPS ** (1.0 / 3.0)
        else:
            rel = math.sqrt(_EPS)
        H = rel * np.maximum(1.0, np.abs(Z))
        # make the step exactly representable so that (z + h) - z == h
        return (Z + H) - Z

    def _fd_stage_jacobian(self, fname, X, U, tail, out_name):
        """Finite-difference Jacobian of a stage function w.r.t. (x, u), all stages at once
        (stage functions are separable per stage, so one perturbed call serves every stage)."""
        n, m = self.n, self.m
        Z = np.concatenate([X, U], axis=1)
        H = self._steps(Z)
        f0 = None
        if self.fd_method != "central":
            f0 = self._stage_values(fname, self._K, X, U, tail, out_name)
        J = np.empty((self.N,) + tail + (n + m,))
        for j in range(n + m):
            h = H[:, j]
            if self.fd_method == "central":
                Zp = Z.copy(); Zp[:, j] += h
                Zm = Z.copy(); Zm[:, j] -= h
                fp = self._stage_values(fname, self._K, Zp[:, :n], Zp[:, n:], tail, out_name)
                fm = self._stage_values(fname, self._K, Zm[:, :n], Zm[:, n:], tail, out_name)
                d = (fp - fm) / (2.0 * h).reshape((-1,) + (1,) * len(tail))
            else:
                sgn = 1.0 if self.fd_method == "forward" else -1.0
                Zp = Z.copy(); Zp[:, j] += sgn * h
                fp = self._stage_values(fname, self._K, Zp[:, :n], Zp[:, n:], tail, out_name)
                d = sgn * (fp - f0) / h.reshape((-1,) + (1,) * len(tail))
            J[..., j] = d
        return J[..., :n], J[..., n:]

    def _fd_final_jacobian(self, fname, x, tail, out_name):
        fn = getattr(self, fname)
        H = self._steps(x)

        def call(z):
            self.counters[fname] += 1
            return self.check_array(fn(z), tail, fname, out_name)

        f0 = call(x) if self.fd_method != "central" else None
        J = np.empty(tail + (self.n,))
        for j in range(self.n):
            h = H[j]
            if self.fd_method == "central":
                zp = x.copy(); zp[j] += h
                zm = x.copy(); zm[j] -= h
                J[..., j] = (call(zp) - call(zm)) / (2 * h)
            else:
                sgn = 1.0 if self.fd_method == "forward" else -1.0
                zp = x.copy(); zp[j] += sgn * h
                J[..., j] = sgn * (call(zp) - f0) / h
        return J

    def eval_dynamics_jacobians(self, X, U, source=None):
        """A^k = f_x^k (N, n, n) and B^k = f_u^k (N, n, m)."""
        X, U = self._split_xu(X, U)
        if self._use_analytic("dynamics_jacobian", source):
            return self._stage_multi("dynamics_jacobian", self._K, X[:-1], U, [(self.n, self.n), (self.n, self.m)], ["fx", "fu"])
        return self._fd_stage_jacobian("dynamics", X[:-1], U, (self.n,), "x_next")

    def eval_stage_cost_gradients(self, X, U, source=None):
        """l_x (N, n) and l_u (N, m), gradients of the stage costs."""
        X, U = self._split_xu(X, U)
        if self._use_analytic("stage_cost_gradient", source):
            return self._stage_multi("stage_cost_gradient", self._K, X[:-1], U, [(self.n,), (self.m,)], ["lx", "lu"])
        return self._fd_stage_jacobian("stage_cost", X[:-1], U, (), "cost")

    def eval_final_cost_gradient(self, xN, source=None):
        xN = np.asarray(xN, dtype=float)
        if self._use_analytic("final_cost_gradient", source):
            self.counters["final_cost_gradient"] += 1
            return self.check_array(self.final_cost_gradient(xN), (self.n,), "final_cost_gradient", "gradient")
        return self._fd_final_jacobian("final_cost", xN, (), "cost")

    def eval_stage_constraint_jacobians(self, X, U, source=None):
        """g_x (N, r, n) and g_u (N, r, m)."""
        X, U = self._split_xu(X, U)
        if self.r == 0:
            return np.zeros((self.N, 0, self.n)), np.zeros((self.N, 0, self.m))
        if self._use_analytic("stage_constraints_jacobian", source):
            return self._stage_multi("stage_constraints_jacobian", self._K, X[:-1], U,
                                     [(self.r, self.n), (self.r, self.m)], ["gx", "gu"])
        return self._fd_stage_jacobian("stage_constraints", X[:-1], U, (self.r,), "g")

    def eval_final_constraint_jacobian(self, xN, source=None):
        xN = np.asarray(xN, dtype=float)
        if self.rN == 0:
            return np.zeros((0, self.n))
        if self._use_analytic("final_constraints_jacobian", source):
            self.counters["final_constraints_jacobian"] += 1
            return self.check_array(self.final_constraints_jacobian(xN), (self.rN, self.n), "final_constraints_jacobian", "gN_x")
        return self._fd_final_jacobian("final_constraints", xN, (self.rN,), "gN")

    def _use_analytic(self, method, source):
        if source is None:
            return self.provides(method)
        if source == "fd":
            return False
        if source == "analytic":
            if not self._overrides(method):
                raise ProblemDefinitionError(f"{type(self).__name__} has no analytic {method}", function=method)
            return True
        return self.provides(method)

    # ======================================================================== second derivatives
    def _stage_lagrangian_values(self, X, U, sigma, P, L):
        """phi^k = sigma f_0^k + P[k].f^k + L[k].g^k for all stages (N,)."""
        val = sigma * self._stage_values("stage_cost", self._K, X, U, (), "cost")
        val = val + np.einsum("ki,ki->k", P, self._stage_values("dynamics", self._K, X, U, (self.n,), "x_next"))
        if self.r:
            val = val + np.einsum("ki,ki->k", L, self._stage_values("stage_constraints", self._K, X, U, (self.r,), "g"))
        return val

    def _stage_lagrangian_gradients(self, X, U, sigma, P, L, source):
        XX = np.vstack([X, X[-1:]])  # _split_xu wants N+1 rows; the last row is unused
        lx, lu = self.eval_stage_cost_gradients(XX, U, source=source)
        A, B = self.eval_dynamics_jacobians(XX, U, source=source)
        gx = sigma * lx + np.einsum("ki,kij->kj", P, A)
        gu = sigma * lu + np.einsum("ki,kij->kj", P, B)
        if self.r:
            Cx, Cu = self.eval_stage_constraint_jacobians(XX, U, source=source)
            gx = gx + np.einsum("ki,kij->kj", L, Cx)
            gu = gu + np.einsum("ki,kij->kj", L, Cu)
        return np.concatenate([gx, gu], axis=1)

    def _all_first_analytic(self):
        need = ["dynamics_jacobian", "stage_cost_gradient"] + (["stage_constraints_jacobian"] if self.r else [])
        return all(self.provides(nm) for nm in need)

    def eval_stage_hessians(self, X, U, sigma, P, L=None, source=None):
        """Blocks (H_xx (N,n,n), H_xu (N,n,m), H_uu (N,m,m)) of the second derivatives of
        sigma*f_0^k + P[k].f^k + L[k].g^k -- the stage blocks of the Lagrangian Hessian (12)."""
        X, U = self._split_xu(X, U)
        n, m, N = self.n, self.m, self.N
        P = self.check_array(P, (N, n), "eval_stage_hessians", "P")
        L = np.zeros((N, self.r)) if L is None else self.check_array(L, (N, self.r), "eval_stage_hessians", "L")
        sigma = float(sigma)
        if self._use_analytic("stage_hessian", source):
            fn = self.stage_hessian
            self.counters["stage_hessian"] += 1
            shapes, names = [(n, n), (n, m), (m, m)], ["hxx", "hxu", "huu"]
            if self.vectorized:
                vals = fn(self._K, X[:-1], U, sigma, P, L)
                stacked = _stacked_shapes(N, shapes)
                if (type(vals) is tuple and len(vals) == 3 and all(_plain(v, sh) for v, sh in zip(vals, stacked))
                        and _all_finite_arrays(vals)):
                    return vals                             # the common case: nothing to convert
                return tuple(self._check_stacked(v, (N,) + s, "stage_hessian", nm) for v, s, nm in zip(vals, shapes, names))
            outs = tuple(np.empty((N,) + s) for s in shapes)
            for k in range(N):
                vals = fn(k, X[k], U[k], sigma, P[k], L[k])
                for o, v, s, nm in zip(outs, vals, shapes, names):
                    o[k] = self.check_array(v, s, "stage_hessian", nm, stage=k)
            return outs
        Xs = X[:-1]
        Z = np.concatenate([Xs, U], axis=1)
        nz = n + m
        Hfull = np.empty((N, nz, nz))
        grad_source = None if (source != "fd" and self._all_first_analytic()) else "fd"
        if grad_source is None:
            # central differences of the analytic Lagrangian gradient
            H = (Z + _EPS ** (1 / 3) * np.maximum(1.0, np.abs(Z))) - Z
            for j in range(nz):
                Zp = Z.copy(); Zp[:, j] += H[:, j]
                Zm = Z.copy(); Zm[:, j] -= H[:, j]
                gp = self._stage_lagrangian_gradients(Zp[:, :n], Zp[:, n:], sigma, P, L, None)
                gm = self._stage_lagrangian_gradients(Zm[:, :n], Zm[:, n:], sigma, P, L, None)
                Hfull[:, :, j] = (gp - gm) / (2 * H[:, j:j + 1])
            Hfull = 0.5 * (Hfull + np.transpose(Hfull, (0, 2, 1)))
        else:
            # second central differences of the Lagrangian values
            H = self._steps(Z, order=2)
            for i in range(nz):
                for j in range(i, nz):
                    vals = []
                    for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                        Zp = Z.copy()
                        Zp[:, i] += si * H[:, i]
                        Zp[:, j] += sj * H[:, j]
                        vals.append(self._stage_lagrangian_values(Zp[:, :n], Zp[:, n:], sigma, P, L))
                    hij = (vals[0] - vals[1] - vals[2] + vals[3]) / (4 * H[:, i] * H[:, j])
                    Hfull[:, i, j] = hij
                    Hfull[:, j, i] = hij
        return Hfull[:, :n, :n].copy(), Hfull[:, :n, n:].copy(), Hfull[:, n:, n:].copy()

    def eval_final_hessian(self, xN, sigma, lN=None, source=None):
        """H_xx (n, n) of sigma*F^N + lN.g^N."""
        xN = np.asarray(xN, dtype=float)
        lN = np.zeros(self.rN) if lN is None else self.check_array(lN, (self.rN,), "eval_final_hessian", "lN")
        sigma = float(sigma)
        if self._use_analytic("final_hessian", source):
            self.counters["final_hessian"] += 1
            return self.check_array(self.final_hessian(xN, sigma, lN), (self.n, self.n), "final_hessian", "hxx")
        n = self.n
        H = np.empty((n, n))
        first_analytic = source != "fd" and self.provides("final_cost_gradient") and (self.rN == 0 or self.provides("final_constraints_jacobian"))

        def grad(z):
            g = sigma * self.eval_final_cost_gradient(z)
            if self.rN:
                g = g + lN @ self.eval_final_constraint_jacobian(z)
            return g

        def val(z):
            v = sigma * self.eval_final_cost(z)
            if self.rN:
                v += lN @ self.eval_final_constraints(z)
            return v

        if first_analytic:
            h = (xN + _EPS ** (1 / 3) * np.maximum(1.0, np.abs(xN))) - xN
            for j in range(n):
                zp = xN.copy(); zp[j] += h[j]
                zm = xN.copy(); zm[j] -= h[j]
                H[:, j] = (grad(zp) - grad(zm)) / (2 * h[j])
            return 0.5 * (H + H.T)
        h = self._steps(xN, order=2)
        for i in range(n):
            for j in range(i, n):
                vs = []
                for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                    z = xN.copy(); z[i] += si * h[i]; z[j] += sj * h[j]
                    vs.append(val(z))
                H[i, j] = H[j, i] = (vs[0] - vs[1] - vs[2] + vs[3]) / (4 * h[i] * h[j])
        return H

    # ======================================================================== reporting
    def dimensions(self) -> dict:
        """Dimensions of the problem and of its NLP view (sec. 4.1)."""
        n_var = self.N * (self.n + self.m) + self.n
        return {"n": self.n, "m": self.m, "N": self.N, "r": self.r, "rN": self.rN,
                "variables": n_var, "dynamics_equalities": self.N * self.n,
                "stage_equalities": int(self.stage_equality_mask.sum()) * self.N,
                "final_equalities": int(self.final_equality_mask.sum())}

    def derivative_sources(self) -> dict:
        """Which derivatives are analytic and which come from finite differences."""
        out = {}
        for meth in _DERIVATIVE_OF:
            out[meth] = "analytic" if self.provides(meth) else f"finite differences ({self.fd_method})"
        return out

    def describe(self) -> str:
        d = self.dimensions()
        lines = [f"{self.name}: n={d['n']} states, m={d['m']} controls, N={d['N']} stages, "
                 f"r={d['r']} stage / {d['rN']} final constraints ({'vectorized' if self.vectorized else 'per stage'})"]
        for meth, src in self.derivative_sources().items():
            lines.append(f"  {meth:<28} {src}")
        return "\n".join(lines)


class LagrangeDOCP(DOCP):
    """DOCP in Lagrange form: no final cost, F^N = 0 (paper 001 sec. 3, item 3)."""

    def final_cost(self, x):
        return 0.0

    def final_cost_gradient(self, x):
        return np.zeros(self.n)



class MayerDOCP(DOCP):
    """DOCP in Mayer form: no stage cost, f_0^k = 0 (paper 001 sec. 3, item 3)."""

    def stage_cost(self, k, x, u):
        if self.vectorized:
            return np.zeros(np.size(k))
        return 0.0

    def stage_cost_gradient(self, k, x, u):
        if self.vectorized:
            K = np.size(k)
            return np.zeros((K, self.n)), np.zeros((K, self.m))
        return np.zeros(self.n), np.zeros(self.m)
