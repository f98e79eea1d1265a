"""Shared machinery of the solvers that work on the NLP view (paper 001 sec. 4.1, eq. (6)).

External NLP solvers (IPOPT, SciPy's SLSQP and trust-constr) see only
:class:`olado.problems.nlp.StructuredNLP`:

    min_y J(y)  s.t.  cl <= c(y) <= cu,  lb <= y <= ub,     y = (x^0, u^0, ..., x^N).     (6)

This module holds what they have in common, written once:

* :class:`TimedNLP` -- counts and times every evaluation a back-end asks for (the share of the
  solve time spent in olado's Python callbacks is reported as ``info["callback_share"]``);
* :class:`FreeVariableNLP` -- the NLP with fixed variables (lb == ub, e.g. x^0) removed, for the
  SciPy methods that do not handle them;
* the KKT quantities at a point and :func:`build_result`, which turns y and multipliers into a
  :class:`~olado.result.Result`. (The SQP, which works on the stage data, computes the same
  quantities stage by stage: :mod:`olado.solvers.sqp.residuals`.)

Multiplier sign convention (the one of IPOPT and of ``StructuredNLP.hessian``): with
``lam`` for the constraints c and ``z_L, z_U >= 0`` for the variable bounds,

    grad J(y) + Jc(y)^T lam - z_L + z_U = 0,                                             (28)

i.e. the Lagrangian is L = J + lam . c - z_L . (y - lb) - z_U . (ub - y). For an active
inequality ``g >= 0`` the multiplier is therefore <= 0; for the dynamics h = f - x^{k+1} = 0 the
multiplier of stage k is the costate p^{k+1} of the discrete maximum principle with that sign.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import ProblemDefinitionError
from ..interrupts import MAX_TIME, Limits
from ..result import Result, Status

#: the evaluation kinds a back-end may ask for, in the order they are reported
EVALUATION_KINDS = ("objective", "gradient", "constraints", "jacobian", "hessian")

MULTIPLIER_CONVENTION = ("grad J + Jc^T lam - z_L + z_U = 0 (IPOPT's sign convention); "
                         "inequality multipliers of active g >= 0 are <= 0, z_L, z_U >= 0")


def make_nlp(problem):
    """The NLP view of ``problem`` (imported late: problems know nothing of solvers)."""
    from ..problems.nlp import StructuredNLP

    return StructuredNLP(problem)


class TimedNLP:
    """Counts and times the evaluations of a StructuredNLP.

    ``counts[kind]`` is the number of calls of each kind in :data:`EVALUATION_KINDS`;
    ``time_s`` the wall time spent inside them (olado's Python side of the solve). With
    ``limits`` (:class:`olado.interrupts.Limits`) every evaluation is followed by its check: a
    solve stops within one evaluation of its time limit or an interrupt."""

    def __init__(self, nlp, limits=None):
        self.nlp = nlp
        self.limits = limits
        self.counts = {k: 0 for k in EVALUATION_KINDS}
        self.time_s = 0.0
        self._jac_structure = None
        self._hess_structure = None

    # the five evaluations, each counted and timed
    def _timed(self, kind, fn, *args):
        t0 = time.perf_counter()
        try:
            value = fn(*args)
        finally:
            self.time_s += time.perf_counter() - t0
            self.counts[kind] += 1
        if self.limits is not None:
            self.limits.check()
        return value

    def objective(self, y):
        return float(self._timed("objective", self.nlp.objective, y))

    def gradient(self, y):
        return self._timed("gradient", self.nlp.gradient, y)

    def constraints(self, y):
        return self._timed("constraints", self.nlp.constraints, y)

    def jacobian(self, y):
        return self._timed("jacobian", self.nlp.jacobian, y)

    def hessian(self, y, lagrange, obj_factor):
        return self._timed("hessian", self.nlp.hessian, y, lagrange, obj_factor)

    # fixed sparsity patterns (computed once; timed, not counted)
    def jacobian_structure(self):
        if self._jac_structure is None:
            t0 = time.perf_counter()
            rows, cols = self.nlp.jacobian_structure()
            self._jac_structure = (np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64))
            self.time_s += time.perf_counter() - t0
        return self._jac_structure

    def hessian_structure(self):
        if self._hess_structure is None:
            t0 = time.perf_counter()
            rows, cols = self.nlp.hessian_structure()
            rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
            if np.any(rows < cols):
                raise ProblemDefinitionError("the NLP Hessian structure must be the lower triangle (row >= col)",
                                             function="hessian_structure")
            self._hess_structure = (rows, cols)
            self.time_s += time.perf_counter() - t0
        return self._hess_structure

    # sparse matrices (CSR; the Hessian full and symmetric), counted as one evaluation each
    def jacobian_matrix(self, y):
        return self._timed("jacobian", self.nlp.jacobian_matrix, y)

    def hessian_matrix(self, y, lagrange, obj_factor):
        return self._timed("hessian", self.nlp.hessian_matrix, y, lagrange, obj_factor)


def jacobian_matrix(nlp, y):
    """Sparse constraint Jacobian of a plain StructuredNLP (not counted)."""
    return nlp.jacobian_matrix(y)


class FreeVariableNLP:
    """The NLP restricted to its free variables: y = y_fixed + P z, where the fixed variables
    (lb == ub, e.g. x^0) are held at their bound. Used by SciPy's methods, for which equal
    bounds are either unsupported (trust-constr's barrier) or wasteful."""

    def __init__(self, timed: TimedNLP):
        self.timed = timed
        self.lb, self.ub = (np.asarray(a, dtype=float) for a in timed.nlp.variable_bounds())
        self.cl, self.cu = (np.asarray(a, dtype=float) for a in timed.nlp.constraint_bounds())
        self.fixed = self.lb == self.ub
        self.free = ~self.fixed
        self.n_free = int(self.free.sum())
        self._template = np.where(self.fixed, self.lb, 0.0)
        self._cache_y = None

    def full(self, z):
        y = self._template.copy()
        y[self.free] = z
        return y

    def reduce(self, y):
        return np.asarray(y, dtype=float)[self.free]

    def bounds(self):
        return self.lb[self.free], self.ub[self.free]

    def objective(self, z):
        return self.timed.objective(self.full(z))

    def gradient(self, z):
        return np.asarray(self.timed.gradient(self.full(z)), dtype=float)[self.free]

    def constraints(self, z):
        return np.asarray(self.timed.constraints(self.full(z)), dtype=float)

    def jacobian(self, z):
        """Sparse (n_cons, n_free) Jacobian."""
        return self.timed.jacobian_matrix(self.full(z))[:, self.free]

    def hessian(self, z, lagrange, obj_factor):
        """Sparse symmetric (n_free, n_free) Lagrangian Hessian."""
        H = self.timed.hessian_matrix(self.full(z), lagrange, obj_factor)
        return H[self.free][:, self.free]


# ---------------------------------------------------------------------------- KKT quantities
def stationarity_residual(grad, jac, lam, zl, zu):
    """grad J + Jc^T lam - z_L + z_U (eq. (28) with bound multipliers)."""
    r = np.asarray(grad, dtype=float).copy()
    if jac.shape[0]:
        r += jac.T @ lam
    return r - zl + zu


def complementarity_residual(nlp, y, c, lam, zl, zu) -> float:
    """Max-norm of the complementarity and multiplier-sign errors at (y, lam, z_L, z_U).

    Bounds: |z_L (y - lb)|, |z_U (ub - y)| on free variables, and negative parts of z_L, z_U.
    Inequality rows cl <= c (cu = inf): |lam (c - cl)| and the positive part of lam (it must be
    <= 0 in the convention of eq. (28)); rows c <= cu symmetrically. Equality rows and fixed
    variables have no complementarity condition."""
    lb, ub = (np.asarray(a, dtype=float) for a in nlp.variable_bounds())
    cl, cu = (np.asarray(a, dtype=float) for a in nlp.constraint_bounds())
    parts = [0.0, *bound_complementarity(y, lb, ub, zl, zu)]
    with np.errstate(invalid="ignore"):
        ineq = cl < cu
        lo = ineq & np.isfinite(cl) & ~np.isfinite(cu)
        hi = ineq & ~np.isfinite(cl) & np.isfinite(cu)
        two = ineq & np.isfinite(cl) & np.isfinite(cu)
        if lo.any():
            parts += [float(np.max(np.abs(lam[lo] * (c[lo] - cl[lo])))), float(np.max(np.maximum(lam[lo], 0.0)))]
        if hi.any():
            parts += [float(np.max(np.abs(lam[hi] * (cu[hi] - c[hi])))), float(np.max(np.maximum(-lam[hi], 0.0)))]
        if two.any():
            gap = np.where(lam[two] <= 0, c[two] - cl[two], cu[two] - c[two])
            parts.append(float(np.max(np.abs(lam[two] * gap))))
    return max(parts)


def einsum_sequential(*sizes):
    """True when ``np.einsum("kij,ki->kj", ...)`` with these output dimensions j sums in the
    sequential order of the compiled contractions (olado.solvers.sqp.kernels._contract,
    olado.solvers.certificate_kernels): every output dimension > 1."""
    return all(s > 1 for s in sizes)


def stage_gradient_terms(p, pt, lam, Lg, LgN, sigma=1.0):
    """sigma grad J + Jc^T lam stage by stage, without bound multipliers: (rx (N+1, n), ru (N, m)).

    ``pt`` holds the derivatives per stage (lx (N, n), lu (N, m), lN (n,), A, B, Cx, Cu, CN, the
    names of the SQP's and the certificate's points); ``lam`` (N, n) is the multiplier of the
    dynamics row h^k = f^k - x^{k+1}, ``Lg`` (N, r) and ``LgN`` (rN,) those of g and g^N;
    ``sigma`` scales the objective (IPOPT's objective scaling; 0: the gradient of the constraint
    terms alone, the objective's derivatives not read)."""
    if sigma == 1.0 and einsum_sequential(p.n, p.m) and p.N:      # the einsums sum in order (certificate_kernels)
        from .certificate_kernels import gradient_terms   # noqa: PLC0415 - numba is loaded on the first solve

        rx, ru = np.empty((p.N + 1, p.n)), np.empty((p.N, p.m))
        c = np.ascontiguousarray
        gradient_terms(c(pt.lx, dtype=float), c(pt.lu, dtype=float), c(pt.lN, dtype=float), c(pt.A, dtype=float),
                       c(pt.B, dtype=float), c(pt.Cx, dtype=float), c(pt.Cu, dtype=float), c(lam, dtype=float),
                       c(Lg, dtype=float), rx, ru)
        if p.rN:
            rx[-1] += pt.CN.T @ LgN
        return rx, ru
    return stage_gradient_terms_reference(p, pt, lam, Lg, LgN, sigma)


def stage_gradient_terms_reference(p, pt, lam, Lg, LgN, sigma=1.0):
    """:func:`stage_gradient_terms` in numpy (its form where the einsums' order is not the
    compiled pass's, and the reference its compiled pass is tested against)."""
    rx = np.empty((p.N + 1, p.n))
    lx, lu, lN = (sigma * pt.lx, sigma * pt.lu, sigma * pt.lN) if sigma else (0.0, 0.0, 0.0)
    rx[:-1] = lx + np.einsum("kij,ki->kj", pt.A, lam)
    rx[1:-1] -= lam[:-1]
    rx[-1] = lN - lam[-1]
    ru = lu + np.einsum("kij,ki->kj", pt.B, lam)
    if p.r:
        rx[:-1] += np.einsum("kij,ki->kj", pt.Cx, Lg)
        ru += np.einsum("kij,ki->kj", pt.Cu, Lg)
    if p.rN:
        rx[-1] += pt.CN.T @ LgN
    return rx, ru


def bound_complementarity(y, lb, ub, zl, zu) -> list:
    """The bound terms of the complementarity residual: |z_L (y - lb)| and |z_U (ub - y)| on the
    free variables (lb < ub) with a finite bound, and the negative parts of z_L, z_U there (as
    max-norms, a list of floats). Any array shape; fixed variables have no condition."""
    free = lb < ub
    parts = []
    with np.errstate(invalid="ignore"):
        for z, gap in ((zl, y - lb), (zu, ub - y)):
            mask = free & np.isfinite(gap)
            if mask.any():
                parts.append(float(np.max(np.abs(z[mask] * gap[mask]))))
            if z[free].size:
                parts.append(float(np.max(np.maximum(-z[free], 0.0))))
    return parts


def bound_multipliers_from_residual(r, y, lb, ub, *, tol, only=None):
    """Bound multipliers that cancel the residual r = grad J + Jc^T lam where a bound is active.

    On a variable at its lower bound z_L = max(r, 0), at its upper bound z_U = max(-r, 0); fixed
    variables (lb == ub) take the whole residual. ``only`` restricts the update to a mask."""
    n = y.size
    zl, zu = np.zeros(n), np.zeros(n)
    scale = 1.0 + np.abs(np.where(np.isfinite(lb), lb, 0.0))
    at_lo = np.isfinite(lb) & (y - lb <= tol * scale)
    scale = 1.0 + np.abs(np.where(np.isfinite(ub), ub, 0.0))
    at_hi = np.isfinite(ub) & (ub - y <= tol * scale)
    if only is not None:
        at_lo &= only
        at_hi &= only
    zl[at_lo] = np.maximum(r[at_lo], 0.0)
    zu[at_hi] = np.maximum(-r[at_hi], 0.0)
    return zl, zu


def fill_fixed_bound_multipliers(nlp, y, lam, zl, zu, grad=None, jac=None):
    """Give the fixed variables (lb == ub) bound multipliers that make eq. (28) hold there.

    A fixed variable's multiplier is free in sign; it is split into z_L (positive part) and z_U.
    Returns new (zl, zu)."""
    lb, ub = (np.asarray(a, dtype=float) for a in nlp.variable_bounds())
    fixed = lb == ub
    zl, zu = np.array(zl, dtype=float), np.array(zu, dtype=float)
    if not fixed.any():
        return zl, zu
    grad = np.asarray(nlp.gradient(y), dtype=float) if grad is None else grad
    jac = jacobian_matrix(nlp, y) if jac is None else jac
    r = stationarity_residual(grad, jac, lam, np.zeros_like(zl), np.zeros_like(zu))
    zl[fixed] = np.maximum(r[fixed], 0.0)
    zu[fixed] = np.maximum(-r[fixed], 0.0)
    return zl, zu


def stage_multipliers(nlp, lam, zl, zu) -> dict:
    """The Result's multipliers dictionary, per stage (sign convention: module docstring).

    ``dynamics`` (N, n), ``stage_constraints`` (N, r), ``final_constraints`` (rN,), and the bound
    multipliers ``bound_lower_x`` / ``bound_upper_x`` (N+1, n), ``bound_lower_u`` /
    ``bound_upper_u`` (N, m) (shaped like X and U; nonnegative)."""
    parts = nlp.multipliers_to_stages(np.asarray(lam, dtype=float))
    out = {
        "dynamics": np.asarray(parts["dynamics"], dtype=float),
        "stage_constraints": np.asarray(parts.get("stage", parts.get("stage_constraints")), dtype=float),
        "final_constraints": np.asarray(parts.get("final", parts.get("final_constraints")), dtype=float),
    }
    Xl, Ul = nlp.unpack(np.asarray(zl, dtype=float))
    Xu, Uu = nlp.unpack(np.asarray(zu, dtype=float))
    out.update(bound_lower_x=np.asarray(Xl), bound_lower_u=np.asarray(Ul),
               bound_upper_x=np.asarray(Xu), bound_upper_u=np.asarray(Uu))
    return out


def build_result(*, nlp, y, lam, zl, zu, status, message, iterations, history, timed,
                 solve_time_s, objective=None, constraints=None, kkt_residual=None,
                 kkt_note="", info=None, fill_fixed=True) -> Result:
    """Assemble the Result of an NLP-view solver at the point y with multipliers (lam, zl, zu).

    The constraint violation is computed here (max norm over c and the variable bounds). The KKT
    residual, unless the caller gives one, is the larger of the unscaled max-norms of eq. (28)
    (stationarity) and of the complementarity conditions at the returned point and multipliers. These after-the-fact evaluations use the plain NLP: they are not part
    of the solver's evaluation counts or callback time."""
    y = np.asarray(y, dtype=float)
    lam = np.asarray(lam, dtype=float).reshape(-1)
    c = np.asarray(nlp.constraints(y) if constraints is None else constraints, dtype=float)
    grad = np.asarray(nlp.gradient(y), dtype=float)
    jac = jacobian_matrix(nlp, y)
    if fill_fixed:
        zl, zu = fill_fixed_bound_multipliers(nlp, y, lam, zl, zu, grad=grad, jac=jac)
    zl, zu = np.asarray(zl, dtype=float), np.asarray(zu, dtype=float)
    residual = stationarity_residual(grad, jac, lam, zl, zu)
    stat = float(np.max(np.abs(residual), initial=0.0))
    compl = complementarity_residual(nlp, y, c, lam, zl, zu)
    if kkt_residual is None:
        kkt_residual = max(stat, compl)
        kkt_note = kkt_note or ("olado's unscaled max-norm, at the returned point and multipliers, of "
                                "stationarity grad J + Jc^T lam - z_L + z_U and of complementarity / "
                                "multiplier signs (primal feasibility: max_constraint_violation)")
    X, U = nlp.unpack(y)
    obj = float(nlp.objective(y)) if objective is None else float(objective)
    counts = timed.counts
    info = dict(info or {})
    info.update(
        callback_time_s=timed.time_s,
        solve_time_s=solve_time_s,
        callback_share=(timed.time_s / solve_time_s) if solve_time_s > 0 else float("nan"),
        kkt_residual_kind=kkt_note,
        stationarity_residual=stat,
        complementarity_residual=compl,
        multiplier_convention=MULTIPLIER_CONVENTION,
    )
    try:
        info["nlp"] = {k: (int(v) if isinstance(v, (int, np.integer)) else v) for k, v in dict(nlp.counts()).items()}
    except Exception:  # pragma: no cover - counts() is informative only
        pass
    return Result(
        status=status,
        message=message,
        objective=obj,
        x=np.asarray(X, dtype=float),
        u=np.asarray(U, dtype=float),
        multipliers=stage_multipliers(nlp, lam, zl, zu),
        max_constraint_violation=float(nlp.max_violation(y, c)),
        kkt_residual=None if kkt_residual is None else float(kkt_residual),
        iterations=int(iterations),
        evaluations={k: int(counts[k]) for k in EVALUATION_KINDS},
        history=list(history),
        info=info,
    )


# ---------------------------------------------------------------------------- stops from outside
#: the former name of :class:`olado.interrupts.Limits` (a wall-clock limit only, then)
Deadline = Limits


class Stoppable:
    """Mixin of a solve's state: :meth:`stop` records how the solve ended (its ``status`` and
    ``message`` fields) and returns True, the iteration loops' "done"."""

    def stop(self, status, message):
        self.status, self.message = status, message
        return True


def run_iterations(limits, start, step, start_again, after):
    """A solve's loop in ``limits.catch()``: ``st = start()``, then ``step(st)`` until it returns
    True. Stopped from outside (time limit, interrupt) during the start's evaluations,
    ``start_again()`` (no clock limit) gives the state to report; stopped at any point, the state
    records :func:`stop_outcome` with ``after(st)`` ("after 12 iterations"). Returns the state."""
    st = None
    with limits.catch() as stop:
        st = start()
        while not step(st):
            pass
    if st is None:
        st = start_again()
    if stop.reason:
        st.stop(*stop_outcome(stop.reason, limits, after(st)))
    return st


def stop_outcome(reason, limits, after="") -> tuple:
    """(Status, message) of a solve ended from outside, ``reason`` "max_time" or "interrupted"
    (:meth:`Limits.reason`, the ``reason`` of its catch block): MAX_TIME, or INTERRUPTED naming
    the signal. ``after`` says how far the solve got, e.g. "after 12 SQP iterations"."""
    where = f" {after}" if after else ""
    if reason == MAX_TIME:
        return Status.MAX_TIME, f"time limit of {limits.max_time:g} s reached{where}"
    source = limits.source() or "interrupt"
    return Status.INTERRUPTED, f"interrupted ({source}){where}; the result holds the last accepted iterate"
