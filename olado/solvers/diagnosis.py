"""Infeasibility diagnosis: which constraints stay violated, and where, at a point -- for a
result that ends INFEASIBLE the least-infeasible point its solver found (issue 13, item 6;
docs/errors.md, "Infeasibility diagnosis").

The constraints are those of the NLP every olado solver solves (paper 001 sec. 4.1, eq. (6); the
feasibility part [6] of WORHP's optimality test, seed 000 sec. IV.II), recomputed from the
problem's own functions at (X, U) -- nothing is taken from the solver -- and named as the problem
names them (docs/design-core.md):

    dynamics           f^k(x^k, u^k) - x^{k+1} = 0             (N, n)   equality
    stage_constraints  g^k(x^k, u^k) >= 0, or = 0 where flagged  (N, r)
    final_constraints  g^N(x^N) >= 0, or = 0 where flagged       (rN,)
    x0                 x^0 = x0 (the fixed initial state)        (n,)     equality
    x_bounds           x_lower <= x^k <= x_upper, k = 1..N        (N+1, n) (row 0: see x0)
    u_bounds           u_lower <= u^k <= u_upper, k = 0..N-1      (N, m)

The violation of a component is |c| for an equality, max(0, -g) for g >= 0 and the distance to
the bound for a bound; a non-finite residual counts as an infinite violation.
:func:`violation_arrays` computes them once for everyone who needs them (the diagnosis here and
olado's certificate of a success, :mod:`olado.solvers.certificate`); :func:`diagnose` turns them
into the :class:`olado.result.Infeasibility` of a Result: per array the number of components
violated beyond the tolerance, the stages where they are, the largest and the sum, and the
largest violated components over all arrays (at most ``Infeasibility.SHOWN``, largest first), so
that a problem with 10^5 stages is described in a few lines. All of it is O(N): one evaluation of
the constraint functions and a partial sort.

:func:`diagnose_result` attaches the diagnosis to a Result; ``Solver.solve`` calls it for every
result with status INFEASIBLE (every solver family, one place). Other unconverged results (an
iteration or time limit, a numerical error) are not diagnosed automatically: the point where such
a solve stopped is not a stationary point of the violation, so its violated constraints say where
the iteration was, not which constraints conflict; :func:`diagnose` gives the same listing for
any point when it is wanted.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..errors import OladoError
from ..result import Infeasibility, Status, ViolatedArray, Violation

#: the index of a component's kind in olado.result.Violation.KINDS
EQUALITY, INEQUALITY, LOWER, UPPER = range(4)


class ConstraintValues(NamedTuple):
    """The constraint functions at (X, U): dynamics residual h = f - x^+ (N, n), g (N, r),
    gN (rN,). The certificate's and the SQP's points have the same attributes."""

    X: np.ndarray
    U: np.ndarray
    h: np.ndarray
    g: np.ndarray
    gN: np.ndarray

    @classmethod
    def at(cls, problem, X, U):
        """Evaluate the problem's constraint functions at (X, U)."""
        return cls(X, U, problem.eval_dynamics(X, U) - X[1:], problem.eval_stage_constraints(X, U),
                   problem.eval_final_constraints(X[-1]))


class ViolationArray(NamedTuple):
    """The violations of one constraint array (module docstring): ``values`` (K, k) >= 0 (K = 1
    for the arrays without stages), ``kinds`` (K, k) indices into Violation.KINDS, ``staged``:
    the rows are stages."""

    name: str
    values: np.ndarray
    kinds: np.ndarray
    staged: bool


def _rows(values, eq_mask):
    """Violations and kinds of constraint rows: |c| where eq_mask, max(0, -c) elsewhere."""
    v = np.where(eq_mask, np.abs(values), np.maximum(-values, 0.0))
    kinds = np.broadcast_to(np.where(eq_mask, EQUALITY, INEQUALITY), v.shape)
    return v, kinds


def _bounds(y, lo, hi):
    """Violations and kinds of the bounds lo <= y <= hi."""
    with np.errstate(invalid="ignore"):
        below, above = lo - y, y - hi
        v = np.maximum(np.maximum(below, 0.0), np.maximum(above, 0.0))
    return v, np.where(above > below, UPPER, LOWER)


def violation_arrays(problem, pt) -> list[ViolationArray]:
    """The violations at the point ``pt`` (X, U, h, g, gN: a :class:`ConstraintValues`, or the
    certificate's or the SQP's point), one :class:`ViolationArray` per constraint array the
    problem has (module docstring). NaN counts as an infinite violation."""
    p = problem
    X, U = np.asarray(pt.X, dtype=float), np.asarray(pt.U, dtype=float)
    out = [ViolationArray("dynamics", np.abs(pt.h), np.full(pt.h.shape, EQUALITY), True)]
    if p.r:
        out.append(ViolationArray("stage_constraints", *_rows(pt.g, p.stage_equality_mask), True))
    if p.rN:
        v, kinds = _rows(np.reshape(pt.gN, (1, p.rN)), p.final_equality_mask)
        out.append(ViolationArray("final_constraints", v, kinds, False))
    d0 = np.abs(X[0] - p.x0)[None, :]
    out.append(ViolationArray("x0", d0, np.full(d0.shape, EQUALITY), False))
    vx, kx = _bounds(X, p.x_lower, p.x_upper)
    vx[0] = 0.0                                 # x^0 is fixed at x0 (the array x0)
    out.append(ViolationArray("x_bounds", vx, kx, True))
    out.append(ViolationArray("u_bounds", *_bounds(U, p.u_lower, p.u_upper), True))
    return [a._replace(values=np.where(np.isnan(a.values), np.inf, a.values)) if np.isnan(a.values).any() else a
            for a in out]


def _row_values(p, pt):
    """The constraint rows' candidates of :func:`largest_violation_of`: (name, values, staged, kind of an entry)."""
    rows = lambda mask: lambda k, i: EQUALITY if mask[i] else INEQUALITY        # noqa: E731
    out = []
    if p.r:
        mask = p.stage_equality_mask
        out.append(("stage_constraints", _rows(pt.g, mask)[0], True, rows(mask)))
    if p.rN:
        mask = p.final_equality_mask
        out.append(("final_constraints", _rows(np.reshape(pt.gN, (1, p.rN)), mask)[0], False, rows(mask)))
    return out


def _largest_compiled(p, pt):
    """The candidates of :func:`largest_violation_of` in the arrays' order, (name, largest value
    (NaN as inf), stage, component, staged, kind) for the dynamics, x0 and the bounds from
    compiled passes (certificate_kernels.largest_violation: the same maxima and first largest
    entries; |c| as max(max(0 - c, 0), max(c - 0, 0))), the rows' arrays as (name, values,
    staged, kind); None when the arrays do not have the shapes of the problem (the numpy form
    then)."""
    from .certificate_kernels import largest_violation   # noqa: PLC0415 - numba is loaded on the first solve

    c = np.ascontiguousarray
    X, U, h = c(pt.X, dtype=float), c(pt.U, dtype=float), c(pt.h, dtype=float)
    xl, xu, ul, uu = (c(a, dtype=float) for a in (p.x_lower, p.x_upper, p.u_lower, p.u_upper))
    x0 = c(p.x0, dtype=float)
    if not (xl.shape == xu.shape == X.shape and ul.shape == uu.shape == U.shape and h.ndim == 2 and x0.ndim == 1
            and x0.shape[0] == X.shape[1]):
        return None
    out = np.empty((4, 4))
    zeros, zeros0 = np.zeros(h.shape), np.zeros((1, X.shape[1]))
    largest_violation(h, zeros, zeros, 0, out[0])
    largest_violation((X[0] - x0)[None, :], zeros0, zeros0, 0, out[1])
    largest_violation(X, xl, xu, 1, out[2])                 # x^0 is fixed at x0 (the array x0)
    largest_violation(U, ul, uu, 0, out[3])
    kind = lambda a: EQUALITY if a < 2 else (UPPER if out[a, 3] else LOWER)     # noqa: E731
    found = [(name, float(out[a, 0]), int(out[a, 1]), int(out[a, 2]), staged, kind(a))
             for a, (name, staged) in enumerate((("dynamics", True), ("x0", False), ("x_bounds", True),
                                                 ("u_bounds", True)))]
    return found[:1] + _row_values(p, pt) + found[1:]


def largest_violation_of(problem, pt) -> tuple[float, Violation | None]:
    """``largest_violation(violation_arrays(problem, pt))`` -- the same value and Violation --
    with the kind computed for the largest entry only (olado's certificate of a success asks for
    nothing else); the dynamics, x0 and the bounds in one compiled pass."""
    candidates = _largest_compiled(problem, pt)
    if candidates is None:              # arrays not of the problem's shapes: the numpy form
        return largest_violation(violation_arrays(problem, pt))
    best, where = 0.0, None
    for entry in candidates:
        if len(entry) == 6:                     # from the compiled pass: the largest entry found
            name, top, k, i, staged, kind = entry
            if top > best:
                best = top
                where = Violation(array=name, stage=k if staged else None, component=i, value=best,
                                  kind=Violation.KINDS[kind])
            continue
        name, values, staged, kind = entry
        if not values.size:
            continue
        top = float(values.max())
        if top != top:                          # NaN counts as an infinite violation
            values = np.where(np.isnan(values), np.inf, values)
            top = float(values.max())
        if top > best:
            k, i = divmod(int(values.argmax()), values.shape[1])
            best = float(values[k, i])
            where = Violation(array=name, stage=k if staged else None, component=i, value=best,
                              kind=Violation.KINDS[int(kind(k, i))])
    return best, where


def violation_at(array: ViolationArray, flat_index) -> Violation:
    """The :class:`Violation` of ``array``'s entry at ``flat_index`` (of its values, flattened)."""
    k, i = np.unravel_index(int(flat_index), array.values.shape)
    return Violation(array=array.name, stage=int(k) if array.staged else None, component=int(i),
                     value=float(array.values[k, i]), kind=Violation.KINDS[int(array.kinds[k, i])])


def largest_violation(arrays) -> tuple[float, Violation | None]:
    """The max-norm of the violations and its :class:`Violation` (None when nothing is violated)."""
    best, where = 0.0, None
    for a in arrays:
        if a.values.size and float(np.max(a.values)) > best:
            where = violation_at(a, np.argmax(a.values))
            best = where.value
    return best, where


def _summary(a: ViolationArray, tol) -> ViolatedArray | None:
    """The :class:`ViolatedArray` of ``a`` (None when no component exceeds ``tol``)."""
    over = a.values > tol
    count = int(np.count_nonzero(over))
    if not count:
        return None
    stages = np.flatnonzero(over.any(axis=1)) if a.staged else None
    return ViolatedArray(array=a.name, count=count, size=int(a.values.size), largest=float(np.max(a.values)),
                         total=float(np.sum(a.values)),
                         first_stage=None if stages is None else int(stages[0]),
                         last_stage=None if stages is None else int(stages[-1]))


def _largest_components(arrays, tol, count) -> list[Violation]:
    """The ``count`` largest components over ``arrays`` violated beyond ``tol``, largest first
    (ties in the order of the arrays, stages and components)."""
    found = []
    for order, a in enumerate(arrays):
        flat = a.values.ravel()
        idx = np.flatnonzero(flat > tol)
        if idx.size > count:                     # a partial sort: O(size)
            idx = idx[np.argpartition(-flat[idx], count - 1)[:count]]
        found += [(-float(flat[j]), order, int(j)) for j in idx]
    found.sort()
    return [violation_at(arrays[order], j) for _, order, j in found[:count]]


def diagnose(problem, X, U, tolerance=1e-8) -> Infeasibility:
    """The :class:`olado.result.Infeasibility` of the point (X, U): the constraint components
    violated beyond ``tolerance`` (module docstring). The problem's evaluation counters are left
    as they were. A point where the problem cannot be evaluated gives a diagnosis whose ``note``
    says so."""
    t0 = time.perf_counter()
    saved = problem.counters.copy()
    try:
        X, U = np.asarray(X, dtype=float), np.asarray(U, dtype=float)
        arrays = violation_arrays(problem, ConstraintValues.at(problem, X, U))
    except OladoError as exc:
        return Infeasibility(tolerance=float(tolerance), note=f"the problem cannot be evaluated at the returned "
                             f"point ({exc}): no constraint can be named", time_s=time.perf_counter() - t0)
    finally:
        problem.counters.clear()
        problem.counters.update(saved)
    violated = [s for s in (_summary(a, tolerance) for a in arrays) if s is not None]
    violated.sort(key=lambda s: -s.largest)
    largest, _ = largest_violation(arrays)
    return Infeasibility(tolerance=float(tolerance), largest=largest,
                         total=float(sum(np.sum(a.values) for a in arrays)), arrays=violated,
                         violations=_largest_components(arrays, tolerance, Infeasibility.SHOWN),
                         time_s=time.perf_counter() - t0)


def diagnose_result(result, problem, options):
    """Attach the diagnosis of its point to a Result with status INFEASIBLE (tolerance: the
    solver's constr_viol_tol), unless it has one."""
    if result.status is not Status.INFEASIBLE or result.infeasibility is not None:
        return result
    result.infeasibility = diagnose(problem, result.x, result.u, float(getattr(options, "constr_viol_tol", 1e-8)))
    result.time_s += result.infeasibility.time_s
    return result
