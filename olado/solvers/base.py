"""The abstract root of every olado solver (paper 001 sec. 2.2).

A solver owns one typed options dataclass (``Solver.Options``, a subclass of
:class:`SolverOptions`), validated on construction and when read from an ini file
(:mod:`olado.config`). ``solve(problem, guess)`` always returns a :class:`olado.result.Result`;
non-convergence is a status, never an exception.

``solve`` runs the solve under :class:`olado.interrupts.InterruptGuard` (in the main thread,
Ctrl-C then stops the solve at its next safe point with the status INTERRUPTED and the last
accepted iterate; a second Ctrl-C raises KeyboardInterrupt) and holds the problem instance for
the solve: a second solve of the same instance while the first runs (another thread, a callback)
raises :class:`~olado.errors.ProblemInUseError` (docs/interrupts.md).

Options are declared with :func:`olado.options.option`, whose metadata (help text, allowed
choices, numeric range) drives validation and the error messages; the option helpers are
re-exported here for compatibility, new code imports them from :mod:`olado.options`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import ProblemInUseError
from ..interrupts import AbortSolve, InterruptGuard, StopRequested, interrupt_age, interrupt_source
from ..options import make_options, option, option_fields, validate_value  # noqa: F401 - re-exported
from ..problems.docp import check_problem
from ..result import Result, Status


@dataclasses.dataclass
class SolverOptions:
    """Options every solver understands."""

    max_iter: int = option(3000, "maximum number of (major) iterations", min=0)
    tol: float = option(1e-8, "optimality (KKT) tolerance", min=0.0, min_exclusive=True)
    constr_viol_tol: float = option(1e-8, "constraint violation tolerance", min=0.0, min_exclusive=True)
    max_time: float = option(math.inf, "wall-time limit in seconds", min=0.0, min_exclusive=True)
    verbose: int = option(0, "0 silent, 1 summary, 2 iteration log, 3+ solver's own output", min=0, max=12)
    callback: Callable[[dict], Any] | None = option(None, "callable(info: dict) -> bool|None; True stops the solver", ini=False)
    certify: bool = option(True, "check every success independently: constraint violation, stationarity and "
                           "complementarity recomputed from the problem's own functions with the solver's or "
                           "least-squares multipliers, and a spot check of the derivatives (docs/certificate.md)")
    certificate_tol: float = option(1e-6, "tolerance of the certificate's scaled stationarity and complementarity "
                                    "(relative units of the objective); the solver's tol when that is larger",
                                    min=0.0, min_exclusive=True)
    certificate_acceptable_tol: float = option(1e-4, "a success whose certificate meets only this looser tolerance "
                                               "is reported as acceptable", min=0.0, min_exclusive=True)
    scaling: str = option("none", "automatic scaling of the problem before it is solved (seed 004; docs/scaling.md): "
                          "none, iso (states and controls by their bounds), jrn / pjrn (Jacobian rows normalised, "
                          "projected), auto (isoscaled variables, projected rows, inverse power on positive "
                          "constraints); the result is in the original units",
                          choices=("none", "auto", "iso", "jrn", "pjrn"))
    certificate_acceptable_constr_viol_tol: float = option(1e-6, "constraint violation allowed at the certificate's "
                                                           "acceptable level (constr_viol_tol when that is larger)",
                                                           min=0.0, min_exclusive=True)


class Solver:
    """Abstract root of all solvers: options, stopping criteria, logging, callbacks, history."""

    name = "solver"
    Options = SolverOptions

    def __init__(self, options=None, **overrides):
        self.options = make_options(self.Options, options, **overrides)

    @classmethod
    def available(cls) -> bool:
        """True when this solver can run here; a solver with an optional back-end (IPOPT:
        cyipopt) says whether the back-end imports. The default: nothing optional is needed."""
        return True

    @classmethod
    def summary(cls) -> str:
        """One line on what the solver does: its entry in :data:`olado.solvers.registry.SOLVERS`
        (declared there only), else the first line of the class docstring."""
        from .registry import SOLVERS

        if SOLVERS.get(cls.name) is cls:
            return SOLVERS.summary(cls.name)
        return (cls.__doc__ or "").strip().split("\n", 1)[0]

    # -- to implement ---------------------------------------------------------------------
    def _solve(self, problem, X0, U0) -> Result:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- common machinery -----------------------------------------------------------------
    def solve(self, problem, guess=None) -> Result:
        """Solve ``problem`` from ``guess`` (U (N,m), (X, U), a Result, or None for the
        problem's own initial guess) and return a :class:`Result`. A success is certified
        (olado.solvers.certificate, option ``certify``) unless the solver did so itself; an
        infeasible result gets the diagnosis of its point (olado.solvers.diagnosis: the
        constraints that stay violated, ``result.infeasibility``)."""
        with InterruptGuard(), _exclusive(problem):
            X0 = U0 = None
            t0 = time.perf_counter()
            try:
                X0, U0 = self.initial_point(problem, guess)
                t0 = time.perf_counter()
                problem.reset_counters()
                result = self._solve_in_scale(problem, X0, U0)
            except (StopRequested, KeyboardInterrupt) as exc:
                if isinstance(exc, AbortSolve):
                    raise
                result = _stopped_before_first_iterate(problem, exc, X0, U0)
            age = interrupt_age()
            if result.status is Status.INTERRUPTED and age is not None:
                result.info["interrupt_latency_s"] = age     # from the signal to the solver's stop
            result.time_s = time.perf_counter() - t0 if not result.time_s else result.time_s
            result.problem = result.problem or getattr(problem, "name", type(problem).__name__)
            result.N = problem.N
            result.solver = result.solver or self.name
            result.options = self.options_dict()
            note = getattr(problem, "derivative_note", "")
            if note:     # e.g. an AutoDiffDOCP without CasADi: finite-difference derivatives
                result.info["derivatives"] = note
            ev = dict(problem.counters)
            ev.update(result.evaluations)
            result.evaluations = ev
            if self.options.certify and result.status.success and result.certificate is None:
                from .certificate import certify_result   # noqa: PLC0415 - loaded only for a success

                certify_result(result, problem, self.options)
                result.time_s += result.certificate.time_s
            if result.status is Status.INFEASIBLE and result.infeasibility is None:
                from .diagnosis import diagnose_result  # noqa: PLC0415 - loaded only for an infeasible result

                diagnose_result(result, problem, self.options)
        if self.options.verbose >= 1:
            print(result.summary())
        return result

    def _solve_in_scale(self, problem, X0, U0) -> Result:
        """``_solve`` on the problem, or on its scaled form (option ``scaling``, the one place
        every solver is scaled: olado.solvers.scaled) with the result mapped back."""
        if getattr(self.options, "scaling", "none") == "none":
            return self._solve(problem, X0, U0)
        from .scaled import solve_scaled   # noqa: PLC0415 - loaded only when scaling is on

        return solve_scaled(self, problem, X0, U0)

    def options_dict(self) -> dict:
        """The options that an ini file can hold (those declared ``ini=True``), by name."""
        names = _INI_NAMES.get(self.Options)
        if names is None:
            names = _INI_NAMES[self.Options] = tuple(f.name for f in option_fields(self.Options)
                                                     if f.metadata.get("ini", True))
        o = self.options
        return {name: getattr(o, name) for name in names}

    @staticmethod
    def initial_point(problem, guess):
        """Normalise a guess to (X (N+1,n), U (N,m)); X simulated from U when not given (for the
        problem's own guess: its ``initial_state_guess(U)`` when that is not None)."""
        check_problem(problem, entry="Solver.solve")
        if guess is None:
            U = problem.initial_guess()
            state_guess = getattr(problem, "initial_state_guess", None)
            X = state_guess(problem.check_array(U, (problem.N, problem.m), "guess", "u")) if state_guess else None
        elif isinstance(guess, Result):
            X, U = guess.x, guess.u
        elif isinstance(guess, tuple) and len(guess) == 2:
            X, U = guess
        else:
            X, U = None, guess
        U = problem.check_array(U, (problem.N, problem.m), "guess", "u")
        if X is None:
            X = problem.simulate(U)
        else:
            X = problem.check_array(X, (problem.N + 1, problem.n), "guess", "x")
        return X, U

    def _log(self, level, text):
        if self.options.verbose >= level:
            print(text)

    def _call_callback(self, info: dict) -> bool:
        cb = self.options.callback
        if cb is None:
            return False
        return bool(cb(info))


#: per options class, the names of its options an ini file can hold (Solver.options_dict)
_INI_NAMES: dict = {}


# ---------------------------------------------------------------------------- one solve per problem
_IN_USE_LOCK = threading.Lock()
_IN_USE: dict = {}      # id(problem) -> thread ident of the solve that holds it


@contextlib.contextmanager
def _exclusive(problem):
    """Hold ``problem`` for one solve; a second solve of the same instance meanwhile raises
    ProblemInUseError (the instance's counters are per solve: reset at its start, reported in
    its Result)."""
    key = id(problem)
    with _IN_USE_LOCK:
        holder = _IN_USE.get(key)
        if holder is not None:
            who = ("another thread" if holder != threading.get_ident()
                   else "the solve this one was started from (a callback)")
            raise ProblemInUseError(
                f"problem {getattr(problem, 'name', type(problem).__name__)!r} (this instance) is being solved by "
                f"{who}; a problem instance belongs to one solve at a time (its evaluation counters, "
                "problem.counters, are per solve): give each concurrent solve its own instance, e.g. "
                "copy.deepcopy(problem)")
        _IN_USE[key] = threading.get_ident()
    try:
        yield
    finally:
        with _IN_USE_LOCK:
            _IN_USE.pop(key, None)


def _stopped_before_first_iterate(problem, exc, X0, U0) -> Result:
    """The Result of a solve stopped (time limit, interrupt) outside its solver's loop -- in its
    setup, its first evaluation, or the assembly of its result (a KeyboardInterrupt raised by
    the user's code there): the initial guess, not evaluated. (Inside the loop every solver
    returns its last accepted iterate itself.)"""
    reason = exc.reason if isinstance(exc, StopRequested) else Status.INTERRUPTED.value
    status = Status(reason)
    N, n, m = problem.N, problem.n, problem.m
    X = np.asarray(X0, dtype=float) if X0 is not None else np.full((N + 1, n), np.nan)
    U = np.asarray(U0, dtype=float) if U0 is not None else np.full((N, m), np.nan)
    what = ("time limit reached" if status is Status.MAX_TIME
            else f"interrupted ({interrupt_source() or 'KeyboardInterrupt'})")
    return Result(status=status, message=f"{what} outside the solver's iterations (its setup or the assembly of its "
                  "result): the result holds the initial guess, not the solver's iterate",
                  objective=float("nan"), x=X, u=U)
