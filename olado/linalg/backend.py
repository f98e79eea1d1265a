"""The KKT back-end interface: the LQ-DOCP KKT system of an interior-point iteration (paper 001
sec. 4.2.3, the reduced system (25), or (24)) as the QP's Newton steps see it, and the one table
of back-ends that implement it.

Every back-end (the block Riccati recursion, :class:`~olado.linalg.riccati.RiccatiFactorization`,
and the sparse ones of :mod:`olado.linalg.kkt`) holds its validated stage arrays in a
:class:`StageData` and implements :class:`KKTBackend`: construction factors, :meth:`refactor`
factors again after new diagonal terms (the next iteration's Newton matrix), :meth:`solve`
checks its arguments and returns an :class:`LQSolution`, :meth:`solve_into` writes the solution
into the caller's arrays without checks (the interior-point QP's work arrays, validated once).

This module imports no back-end: :data:`KKT_BACKENDS` names them (``name -> "module:Class"``)
and loads one on first use.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import Protocol, runtime_checkable

import numpy as np

from .._registry import LazyRegistry
from ..errors import ConfigError, OladoError

#: the KKT back-ends: name -> class (lazy); every one implements KKTBackend
KKT_BACKENDS = LazyRegistry("KKT solver", {
    "riccati": "olado.linalg.riccati:RiccatiFactorization",
    "superlu-full": "olado.linalg.kkt:SuperLUFullKKT",
    "superlu-reduced": "olado.linalg.kkt:SuperLUReducedKKT",
    "minres": "olado.linalg.kkt:MinresKKT",
    "gmres": "olado.linalg.kkt:GmresKKT",
}, key="kkt_solver")
#: their names (an option's ``choices``)
KKT_SOLVERS = tuple(KKT_BACKENDS)
#: the back-ends whose factorization detects a reduced Hessian that is not positive definite
#: (NotPositiveDefiniteError); the sparse ones do not check the inertia (olado.linalg.kkt)
INERTIA_CHECKING = ("riccati",)

#: one right-hand side of the KKT system: q (N+1, n), r (N, m), c (N, n), x0 (n,), e (N, ne_max),
#: eN (neN,) and the constants ci (N, ni_max) of the stage inequality terms
RHS = collections.namedtuple("RHS", "q r c x0 e eN ci")
#: arrays to write a solution into: X (N+1, n), U (N, m), lam (N+1, n), nu (N+1, max(ne_max, neN))
Solution = collections.namedtuple("Solution", "X U lam nu")


class NotPositiveDefiniteError(OladoError, np.linalg.LinAlgError):
    """The reduced Hessian of a stage is not positive definite; ``stage`` says where."""

    def __init__(self, stage, message=None):
        self.stage = int(stage)
        super().__init__(message or f"reduced Hessian Q_uu (projected on the null space of the stage "
                                    f"equality constraints) is not positive definite at stage k={stage}")


@dataclasses.dataclass
class LQSolution:
    """Solution of one right-hand side: states X (N+1, n), controls U (N, m), dynamics
    multipliers lam (N+1, n) (lam[0] belongs to x_0 = xbar_0), equality multipliers nu
    (N+1, ne) (nu[N] for E_N), and ``x0_residual``, the infeasibility of the equality rows
    (max norm): for the Riccati recursion the residual of the rows reaching the fixed x_0 and the
    consistency defects of the dependent rows it dropped (0 up to rounding when the constraint
    set is consistent; with an inconsistent set the other rows are still satisfied)."""

    X: np.ndarray
    U: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    x0_residual: float


@runtime_checkable
class KKTBackend(Protocol):
    """A factorization of the LQ-DOCP KKT matrix (see :mod:`olado.linalg.kkt` for the system and
    the multiplier signs). Constructed by ``cls(Q, S, R, A, B, **stage_kw, **options)`` (which
    factors; ``stage_kw`` are those of :class:`StageData`), usually through
    :func:`make_kkt_solver`. A factorization that finds a stage's reduced Hessian not positive
    definite raises :class:`NotPositiveDefiniteError` (only the Riccati recursion checks the
    inertia); one that fails otherwise raises a ``numpy.linalg.LinAlgError``.

    ``limits`` is the :class:`olado.interrupts.Limits` of the solve the system belongs to (None:
    none; set by :func:`make_kkt_solver`): a back-end whose solve iterates (MINRES, GMRES) checks
    it at every iteration, so a time limit or an interrupt ends a long Krylov solve there
    (``StopRequested``); a direct back-end does a bounded amount of work per call and ignores it."""

    data: StageData
    limits: object

    def refactor(self, Dx=None, Du=None, sigma=None, regularization=None) -> KKTBackend:
        """Factor again after new diagonal terms (arguments as :meth:`StageData.set_diagonal`);
        the matrices Q, S, R, A, B and the equality rows stay (arrays the caller updated in
        place are seen). After a failure the object must be refactored before the next solve."""

    def solve(self, q, r, c, x0, e=None, eN=None, ci=None) -> LQSolution:
        """Solve for one right-hand side (validated; defaults zero)."""

    def solve_into(self, rhs: RHS, out: Solution) -> float:
        """Solve for ``rhs`` and write the solution into ``out`` (every entry of its arrays),
        without checks: all arrays C-contiguous float64 of the right shapes; ``rhs`` and ``out``
        an RHS and a Solution or plain tuples of their fields. Returns the infeasibility of the
        equality rows (``LQSolution.x0_residual``)."""


def make_kkt_solver(name, Q, S, R, A, B, *, limits=None, **kwargs) -> KKTBackend:
    """Factor (or precondition) the LQ-DOCP KKT system with the back-end ``name`` (one of
    :data:`KKT_SOLVERS`); the result's ``solve(q, r, c, x0, e=None, eN=None, ci=None)`` returns an
    :class:`LQSolution` with the multiplier conventions of the Riccati solver.

    ``kwargs`` are those of :class:`StageData` (E, F, n_eq, EN, Dx, Du, Ci, sigma, n_ineq,
    regularization) plus the back-end's options (:mod:`olado.linalg.kkt`); ``limits`` becomes
    the back-end's ``limits`` (:class:`KKTBackend`)."""
    try:
        cls = KKT_BACKENDS[name]
    except TypeError:       # an unhashable name
        raise ConfigError(f"unknown KKT solver {name!r}", key=KKT_BACKENDS.key, allowed=", ".join(KKT_SOLVERS)) from None
    backend = cls(Q, S, R, A, B, **kwargs)
    backend.limits = limits
    return backend


def _f64(a, shape, name):
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.shape != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {arr.shape}")
    return arr


class StageData:
    """Validated stage arrays of an LQ-DOCP KKT system (what every KKT back-end holds):
    defaults for the optional parts, per-stage counts n_eq / n_ineq."""

    def __init__(self, Q, S, R, A, B, E=None, F=None, n_eq=None, EN=None, Dx=None, Du=None, Ci=None,
                 sigma=None, n_ineq=None, regularization=0.0):
        A = np.ascontiguousarray(A, dtype=np.float64)
        if A.ndim != 3 or A.shape[1] != A.shape[2]:
            raise ValueError(f"A: expected shape (N, n, n), got {A.shape}")
        N, n = A.shape[0], A.shape[1]
        B = np.ascontiguousarray(B, dtype=np.float64)
        if B.ndim != 3 or B.shape[:2] != (N, n):
            raise ValueError(f"B: expected shape ({N}, {n}, m), got {B.shape}")
        m = B.shape[2]
        self.N, self.n, self.m = N, n, m
        self.A, self.B = A, B
        self.Q = _f64(Q, (N + 1, n, n), "Q")
        self.S = np.zeros((N, n, m)) if S is None else _f64(S, (N, n, m), "S")
        self.R = _f64(R, (N, m, m), "R")
        if E is None:
            self.ne_max = 0
            self.E, self.F = np.zeros((N, 0, n)), np.zeros((N, 0, m))
            self.ne = np.zeros(N, dtype=np.int64)
        else:
            E = np.asarray(E, dtype=np.float64)
            self.ne_max = E.shape[1]
            self.E = _f64(E, (N, self.ne_max, n), "E")
            self.F = _f64(F, (N, self.ne_max, m), "F")
            self.ne = (np.full(N, self.ne_max, dtype=np.int64) if n_eq is None
                       else _f64(n_eq, (N,), "n_eq").astype(np.int64))
        self.EN = np.zeros((0, n)) if EN is None else np.ascontiguousarray(np.atleast_2d(EN), dtype=np.float64)
        if self.EN.shape[1] != n:
            raise ValueError(f"EN: expected shape (neN, {n}), got {self.EN.shape}")
        self.neN = self.EN.shape[0]
        self.Dx = np.zeros((N + 1, n)) if Dx is None else _f64(Dx, (N + 1, n), "Dx")
        self.Du = np.zeros((N, m)) if Du is None else _f64(Du, (N, m), "Du")
        if Ci is None:
            self.Ci, self.sig = np.zeros((N, 0, n + m)), np.zeros((N, 0))
            self.ni = np.zeros(N, dtype=np.int64)
        else:
            self.Ci = np.ascontiguousarray(Ci, dtype=np.float64)
            if self.Ci.ndim != 3 or self.Ci.shape[0] != N or self.Ci.shape[2] != n + m:
                raise ValueError(f"Ci: expected shape ({N}, nineq, {n + m}), got {self.Ci.shape}")
            self.sig = _f64(sigma, self.Ci.shape[:2], "sigma")
            self.ni = (np.full(N, self.Ci.shape[1], dtype=np.int64) if n_ineq is None
                       else _f64(n_ineq, (N,), "n_ineq").astype(np.int64))
        self.ni_max = self.Ci.shape[1]
        self.regularization = float(regularization)
        # active masks of the padded row slots
        self.eq_mask = np.arange(self.ne_max)[None, :] < self.ne[:, None]                      # (N, ne_max)
        self.ineq_active = np.arange(self.ni_max)[None, :] < self.ni[:, None]                  # (N, ni_max)
        self.ineq_w = np.where(self.ineq_active, self.sig, 0.0)                                 # (N, ni_max)

    @property
    def has_equality_rows(self) -> bool:
        """Whether any stage or final equality row counts."""
        return self.neN > 0 or (self.ne_max > 0 and bool(self.ne.any()))

    def set_diagonal(self, Dx=None, Du=None, sigma=None, regularization=None):
        """New diagonal terms -- the interior-point Newton matrix of the next iteration: Dx
        (N+1, n), Du (N, m), stage-row weights sigma and/or the regularization (None: kept).
        Arrays that are the ones already held (updated in place by the caller) are not
        validated again."""
        N, n, m = self.N, self.n, self.m
        if Dx is not None and Dx is not self.Dx:
            self.Dx = _f64(Dx, (N + 1, n), "Dx")
        if Du is not None and Du is not self.Du:
            self.Du = _f64(Du, (N, m), "Du")
        if sigma is not None:
            if sigma is not self.sig:
                self.sig = _f64(sigma, self.Ci.shape[:2], "sigma")
                self.ineq_w = np.where(self.ineq_active, self.sig, 0.0)
            else:
                np.copyto(self.ineq_w, self.sig, where=self.ineq_active)
        if regularization is not None:
            self.regularization = float(regularization)

    def rhs_arrays(self, q, r, c, x0, e, eN, ci) -> RHS:
        """The right-hand side validated (C-contiguous float64 of the right shapes; e, eN, ci
        None: zero)."""
        N, n, m = self.N, self.n, self.m
        q = _f64(q, (N + 1, n), "q"); r = _f64(r, (N, m), "r"); c = _f64(c, (N, n), "c"); x0 = _f64(x0, (n,), "x0")
        e = np.zeros((N, self.ne_max)) if e is None else _f64(e, (N, self.ne_max), "e")
        eN = np.zeros(self.neN) if eN is None else _f64(eN, (self.neN,), "eN")
        ci = np.zeros(self.sig.shape) if ci is None else _f64(ci, self.sig.shape, "ci")
        return RHS(q, r, c, x0, e, eN, ci)
