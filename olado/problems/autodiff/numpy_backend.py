"""The numeric back-end: a model written once evaluated on numpy arrays, vectorized over the
stages, with derivatives from DOCP's finite differences (docs/autodiff.md, "Without CasADi").

The same ``stage(x, u, d)`` and ``final(x)`` that the symbolic back-ends trace are called with
numpy arrays of shape (size, K): row i of ``x`` holds x_i at the K stages being evaluated, so
``x[0]`` is a (K,) array and ``+ - * / **`` and the elementary functions of
:mod:`olado.problems.autodiff` (numpy's on arrays) evaluate every stage at once. Nothing is
differentiated: :class:`~olado.problems.autodiff.AutoDiffDOCP` then provides no derivative method
and DOCP's central differences serve the Jacobians, gradients and Lagrangian Hessians (all
stages per perturbed call). It needs no optional package: it is the fallback when CasADi is not
installed (``ad_backend="auto"``), or chosen by ``ad_backend="numpy"``.
"""

from __future__ import annotations

import numpy as np

from ...errors import ProblemDefinitionError
from .backends import split_final

#: the result note of a problem on this back-end (the solvers copy it to ``result.info``)
FD_NOTE = ("derivatives by central finite differences of the numpy-evaluated model (the 'numpy' "
           "automatic-differentiation back-end); exact ones: pip install olado[ad]")


def entries(value):
    """The scalar entries of a numeric vector: the rows of a 2-D array (size, K), the items of
    a list or tuple, or one entry (a number or a (K,) array)."""
    if isinstance(value, np.ndarray) and value.ndim == 2:
        return list(value)
    if isinstance(value, (list, tuple)):
        return list(value)
    return [value]


def vertcat(*items):
    """A (size, K) array of vectors (2-D arrays) and scalar entries (numbers, (K,) arrays),
    broadcast to the largest K. Each item is copied once, as a block of rows (this runs a few
    times per stage call: its cost per call is what DOCP.simulate's loop pays per stage)."""
    blocks, size, K = [], 0, 1
    for it in items:
        a = it if type(it) is np.ndarray else np.asarray(it, dtype=float)
        rows, k = (a.shape[0], a.shape[1]) if a.ndim == 2 else (1, a.shape[0] if a.ndim else 1)
        if rows:
            blocks.append((size, size + rows, a))
            size += rows
            K = max(K, k)
    if not size:
        return np.zeros((0, 1))
    out = np.empty((size, K))
    for i, j, a in blocks:
        out[i:j] = a
    return out


class NumpyOps:
    """The vector operations :class:`~olado.problems.ocp.OCP` builds its stage from, on numpy
    arrays of shape (size, K) (the CasADi counterpart: :class:`~.casadi_backend.CasadiOps`)."""

    name = "numpy"

    @staticmethod
    def sym(name, size, sample):
        """A stand-in for a symbol: the sample value (size,) at two stages, (size, 2) (so that a
        Python branch on a value fails here, as it does on a symbol)."""
        return np.repeat(np.asarray(sample, dtype=float).reshape(size, 1), 2, axis=1)

    entries = staticmethod(entries)
    vertcat = staticmethod(vertcat)

    @staticmethod
    def empty():
        return np.zeros((0, 1))

    @staticmethod
    def scalar(value):
        return value

    @staticmethod
    def const(values):
        return np.asarray(values, dtype=float).reshape(-1, 1)

    @staticmethod
    def sumsqr(v):
        return np.sum(np.asarray(v) ** 2, axis=0)


class NumpyModel:
    """The evaluators of one problem on this back-end: name -> function of the (K, ...) stage
    arrays returning a tuple of (K, ...) outputs, like the compiled ones of the symbolic
    back-ends (values only; the final function's derivative slots are None).

    ``stage`` computes the next state, cost and constraints together; the last evaluation is
    kept, so that the three DOCP functions at one point (as the finite differences of the
    Lagrangian ask for them) cost one evaluation."""

    def __init__(self, problem):
        self.problem = problem
        self.n, self.m, self.r, self.rN = problem.n, problem.m, problem.r, problem.rN
        self._last = None

    def _rows(self, value, size, K, function, array):
        e = entries(value)
        if len(e) != size:
            raise ProblemDefinitionError(f"returned {len(e)} entries, the problem declares {size}",
                                         function=function, array=array)
        out = np.empty((K, size))
        for i, v in enumerate(e):
            out[:, i] = v
        return out

    def stage(self, X, U, D):
        last = self._last
        if last is not None and all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(last[0], (X, U, D))):
            return last[1]
        K = X.shape[0]
        with np.errstate(all="ignore"):      # a NaN or inf is reported by DOCP's checks, by stage
            out = self.problem.stage(X.T, U.T, D.T)
        if not isinstance(out, (tuple, list)) or len(out) not in (2, 3):
            raise ProblemDefinitionError("must return (x_next, cost) or (x_next, cost, g)", function="stage")
        f = self._rows(out[0], self.n, K, "stage", "x_next")
        cost = self._rows(out[1], 1, K, "stage", "cost")[:, 0]
        g = self._rows(out[2] if len(out) == 3 else (), self.r, K, "stage", "g")
        self._last = ((X.copy(), U.copy(), D.copy()), (f, cost, g))
        return f, cost, g

    def simulate(self, X, U, D):
        """X[k+1] = f(X[k], U[k], D[k]) for k = 0..N-1, in place from X[0]: the sequential
        recursion of eq. (2) as one :meth:`stage` call of the model per stage on (size, 1)
        columns, without DOCP's per-call argument handling, stage-point cache and checks (the
        caller checks X once). Returns X."""
        stage, n = self.problem.stage, self.n
        with np.errstate(all="ignore"):
            for k in range(U.shape[0]):
                out = stage(X[k, :, None], U[k, :, None], D[k, :, None])
                if not isinstance(out, (tuple, list)) or len(out) not in (2, 3):
                    raise ProblemDefinitionError("must return (x_next, cost) or (x_next, cost, g)", function="stage")
                X[k + 1] = self._rows(out[0], n, 1, "stage", "x_next")[0]
        return X

    def final(self, x):
        with np.errstate(all="ignore"):
            fin, gN = split_final(self.problem.final(x.T))
        F = self._rows(fin, 1, x.shape[0], "final", "cost")[:, 0]
        return F, None, self._rows(gN, self.rN, x.shape[0], "final", "gN"), None

    def functions(self):
        return {"dynamics": lambda X, U, D: (self.stage(X, U, D)[0],),
                "stage_cost": lambda X, U, D: (self.stage(X, U, D)[1],),
                "stage_constraints": lambda X, U, D: (self.stage(X, U, D)[2],),
                "final": self.final}
