"""The abstract root of every olado solver (paper 001 sec. 2.2).

A solver owns one typed options dataclass (``Solver.Options``, a subclass of
:class:`SolverOptions`), validated on construction and when read from an ini file
(:mod:`olado.config`). ``solve(problem, guess)`` always returns a :class:`olado.result.Result`;
non-convergence is a status, never an exception.

Options are declared with :func:`option`, whose metadata (help text, allowed choices, numeric
range) drives validation and the error messages of :mod:`olado.config`.
"""

from __future__ import annotations

import dataclasses
import math
import time
import typing
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..result import Result


def option(default, help="", *, choices=None, min=None, max=None, min_exclusive=False, ini=True, raw=False):
    """Declare a solver option (a dataclass field with validation metadata). ``raw=True`` marks
    the dict option that receives an ini file's ``[<solver>.raw]`` section (olado.config)."""
    meta = {"help": help, "choices": choices, "min": min, "max": max,
            "min_exclusive": min_exclusive, "ini": ini, "raw": raw}
    if isinstance(default, (dict, list)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass
class SolverOptions:
    """Options every solver understands."""

    max_iter: int = option(3000, "maximum number of (major) iterations", min=0)
    tol: float = option(1e-8, "optimality (KKT) tolerance", min=0.0, min_exclusive=True)
    constr_viol_tol: float = option(1e-8, "constraint violation tolerance", min=0.0, min_exclusive=True)
    max_time: float = option(math.inf, "wall-time limit in seconds", min=0.0, min_exclusive=True)
    verbose: int = option(0, "0 silent, 1 summary, 2 iteration log, 3+ solver's own output", min=0, max=12)
    callback: Any = option(None, "callable(info: dict) -> bool|None; True stops the solver", ini=False)


def option_fields(options_cls):
    """The dataclass fields of an options class, in declaration order."""
    return dataclasses.fields(options_cls)


#: options class -> its resolved type hints (typing.get_type_hints is slow; classes do not change)
_TYPE_HINTS: dict = {}


def _field_type(options_cls, f):
    hints = _TYPE_HINTS.get(options_cls)
    if hints is None:
        hints = _TYPE_HINTS[options_cls] = typing.get_type_hints(options_cls)
    return hints.get(f.name, Any)


def validate_value(options_cls, name, value, *, file=None, section=None):
    """Check (and coerce) one option value; raise ConfigError naming where it came from."""
    fields = {f.name: f for f in option_fields(options_cls)}
    if name not in fields:
        raise ConfigError("unknown option", file=file, section=section, key=name,
                          allowed=", ".join(f.name for f in option_fields(options_cls)
                                            if f.metadata.get("ini", True)))
    f = fields[name]
    meta = f.metadata
    typ = _field_type(options_cls, f)
    # optional options (``float | None``): None is their "automatic" value, anything else is
    # checked against the inner type
    union_args = typing.get_args(typ) if (typing.get_origin(typ) is typing.Union
                                          or type(typ).__name__ == "UnionType") else ()
    if type(None) in union_args:
        if value is None:
            return None
        inner = [a for a in union_args if a is not type(None)]
        if len(inner) == 1:
            typ = inner[0]
    origin = typing.get_origin(typ)
    if typ is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise ConfigError(f"expected true/false, got {value!r}", file=file, section=section, key=name)
        value = bool(value)
    elif typ is int:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise ConfigError(f"expected an integer, got {value!r}", file=file, section=section, key=name)
        value = int(value)
    elif typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ConfigError(f"expected a number, got {value!r}", file=file, section=section, key=name)
        value = float(value)
        if math.isnan(value):
            raise ConfigError("NaN is not allowed", file=file, section=section, key=name)
    elif typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"expected a string, got {value!r}", file=file, section=section, key=name)
    elif typ is dict or origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"expected a mapping, got {value!r}", file=file, section=section, key=name)
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"invalid value {value!r}", file=file, section=section, key=name,
                          allowed=", ".join(map(str, choices)))
    lo, hi = meta.get("min"), meta.get("max")
    if lo is not None and (value < lo or (meta.get("min_exclusive") and value == lo)):
        rng = f"{'>' if meta.get('min_exclusive') else '>='} {lo}" + (f" and <= {hi}" if hi is not None else "")
        raise ConfigError(f"value {value!r} out of range", file=file, section=section, key=name, allowed=rng)
    if hi is not None and value > hi:
        raise ConfigError(f"value {value!r} out of range", file=file, section=section, key=name,
                          allowed=f"<= {hi}" + (f" and >= {lo}" if lo is not None else ""))
    return value


def make_options(options_cls, given=None, **overrides):
    """Build a validated options object from an instance/dict plus keyword overrides."""
    if isinstance(given, options_cls):
        values = dataclasses.asdict(given) if given is not None else {}
        values = {f.name: getattr(given, f.name) for f in option_fields(options_cls)}
    elif given is None:
        values = {}
    elif isinstance(given, dict):
        values = dict(given)
    else:
        raise ConfigError(f"options must be a {options_cls.__name__} or a dict, got {type(given).__name__}")
    values.update(overrides)
    checked = {name: validate_value(options_cls, name, value) for name, value in values.items()}
    return options_cls(**checked)


class Solver:
    """Abstract root of all solvers: options, stopping criteria, logging, callbacks, history."""

    name = "solver"
    Options = SolverOptions
    description = ""

    def __init__(self, options=None, **overrides):
        self.options = make_options(self.Options, options, **overrides)

    # -- to implement ---------------------------------------------------------------------
    def _solve(self, problem, X0, U0) -> Result:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- common machinery -----------------------------------------------------------------
    def solve(self, problem, guess=None) -> Result:
        """Solve ``problem`` from ``guess`` (U (N,m), (X, U), a Result, or None for the
        problem's own initial guess) and return a :class:`Result`."""
        X0, U0 = self.initial_point(problem, guess)
        t0 = time.perf_counter()
        problem.reset_counters()
        result = self._solve(problem, X0, U0)
        result.time_s = time.perf_counter() - t0 if not result.time_s else result.time_s
        result.problem = result.problem or getattr(problem, "name", type(problem).__name__)
        result.N = problem.N
        result.solver = result.solver or self.name
        result.options = {k: v for k, v in self.options_dict().items()}
        ev = dict(problem.counters)
        ev.update(result.evaluations)
        result.evaluations = ev
        if self.options.verbose >= 1:
            print(result.summary())
        return result

    def options_dict(self) -> dict:
        out = {}
        for f in option_fields(self.Options):
            if not f.metadata.get("ini", True):
                continue
            out[f.name] = getattr(self.options, f.name)
        return out

    @staticmethod
    def initial_point(problem, guess):
        """Normalise a guess to (X (N+1,n), U (N,m)); X simulated from U when not given (for the
        problem's own guess: its ``initial_state_guess(U)`` when that is not None)."""
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
