"""Test suites as data: named sets of (problem, settings, start) entries that a benchmark can
iterate over, with the reference results stored beside them.

    from olado.problems.suites import load_suite, load_references
    for entry in load_suite("robustness"):
        problem, guess = entry.build()          # guess: (X, U) to pass to solver.solve
        ref = load_references("robustness")["entries"][entry.name]

Suites (:data:`SUITES`): ``robustness`` (issue 13, item 7, :mod:`.robustness`), the Zambezi
testing set of paper 001 sec. 6 (``zambezi-testset``, :mod:`.zambezi_testset`), Table 1
(``table1``, :mod:`.table1`) and the unconstrained set (``unconstrained``, :mod:`.unconstrained`);
a user's suite is a TOML file (:func:`load_suite` with a path, :mod:`.files`). ``olado bench``
runs any of them (docs/benchmarking.md). The robustness set's IPOPT references (objective, status, violation, KKT residual, olado commit and date) are in
``robustness_refs.json`` (written by ``benchmarks/make_robustness_refs.py``).
:func:`verify_point` checks a returned point independently of the solver that produced it.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
from pathlib import Path

import numpy as np

from ...errors import ProblemDefinitionError
from .verify import PointCheck, verify_point

__all__ = ["SuiteEntry", "SUITES", "load_suite", "load_references", "references_path", "perturbed_start",
           "verify_point", "PointCheck"]

HERE = Path(__file__).resolve().parent

#: suite name -> module of this package holding its ENTRIES (and PERTURBATION)
SUITES = {"robustness": "robustness", "zambezi-testset": "zambezi_testset", "table1": "table1",
          "unconstrained": "unconstrained"}


@dataclasses.dataclass(frozen=True)
class SuiteEntry:
    """One entry of a suite: which problem, with which settings, from which start; its source,
    published value (olado's sign convention, None if none is published) and feasibility.

    ``problem`` is a name of :data:`olado.problems.PROBLEMS` or a factory ``"module:function"``
    (a user's problem); ``settings`` are the factory's keyword arguments. ``start`` is
    ``"problem"`` (the problem's own initial guess) or ``"perturbed"`` (that guess perturbed with
    ``seed``). A benchmark identifies an entry by :attr:`key`: (name, size, start label)."""

    name: str
    problem: str
    settings: dict
    start: str = "problem"
    seed: int | None = None
    source: str = ""
    published: float | None = None
    published_note: str = ""
    feasible: bool = True
    group: str = ""
    perturbation: dict = dataclasses.field(default_factory=dict)

    @property
    def size(self) -> int | None:
        """The horizon N of the entry's settings (None: the factory's default)."""
        return self.settings.get("N")

    @property
    def start_label(self) -> str:
        """The start as a benchmark records it: the factory's ``start`` setting (e.g. sif,
        balance) or ``problem``, with ``-p<seed>`` for a perturbed start."""
        base = str(self.settings.get("start", "problem"))
        return f"{base}-p{self.seed}" if self.start == "perturbed" else base

    @property
    def key(self) -> tuple:
        """(name, size, start label): what tells the entries of a suite apart."""
        return (self.name, self.size, self.start_label)

    def factory(self):
        """The callable that builds the problem: :data:`olado.problems.PROBLEMS` [problem], or
        the function named by ``"module:function"``."""
        from .. import PROBLEMS

        if self.problem in PROBLEMS:
            return PROBLEMS[self.problem]
        if ":" in self.problem:
            module, _, name = self.problem.partition(":")
            try:
                return getattr(importlib.import_module(module), name)
            except (ImportError, AttributeError) as exc:
                raise ProblemDefinitionError(f"suite entry {self.name!r}: cannot import the problem factory "
                                             f"{self.problem!r} ({type(exc).__name__}: {exc})",
                                             function="SuiteEntry.factory", array="problem") from None
        raise ProblemDefinitionError(f"suite entry {self.name!r} names the unknown problem {self.problem!r}",
                                     function="SuiteEntry.make_problem", array="problem")

    def make_problem(self):
        """The problem with the entry's settings (see :meth:`factory`)."""
        return self.factory()(**self.settings)

    def start_point(self, problem):
        """(X (N+1, n) or None, U (N, m)): the problem's own start, or that start perturbed
        with the entry's seed (:func:`perturbed_start`)."""
        U = problem.initial_guess()
        X = problem.initial_state_guess(U)
        if self.start == "problem":
            return X, U
        if self.start == "perturbed":
            return perturbed_start(problem, X, U, self.seed, **self.perturbation)
        raise ProblemDefinitionError(f"suite entry {self.name!r}: unknown start {self.start!r}",
                                     function="SuiteEntry.start_point", array="start")

    def build(self):
        """(problem, guess) with guess = (X, U) for ``solver.solve(problem, guess=...)`` (X
        simulated from U where the start has no states)."""
        problem = self.make_problem()
        X, U = self.start_point(problem)
        if X is None:
            X = problem.simulate(U)
        return problem, (X, U)


def load_suite(name: str = "robustness") -> list[SuiteEntry]:
    """The entries of the suite ``name`` (see :data:`SUITES`), or of the suite file ``name``
    (a path ending in .toml: :func:`olado.problems.suites.files.load_suite_file`)."""
    if str(name).endswith(".toml") or isinstance(name, Path):
        from .files import load_suite_file

        return load_suite_file(name)
    if name not in SUITES:
        raise ProblemDefinitionError(f"unknown suite {name!r}; known: {', '.join(SUITES)} or a .toml suite file",
                                     function="load_suite", array="name")
    module = importlib.import_module(f"{__name__}.{SUITES[name]}")
    perturbation = dict(getattr(module, "PERTURBATION", {}))
    return [SuiteEntry(perturbation=perturbation, **row) for row in module.ENTRIES]


def references_path(name: str = "robustness") -> Path:
    return HERE / f"{name}_refs.json"


def load_references(name: str = "robustness") -> dict:
    """The stored reference results of a suite: ``{"meta": {...}, "entries": {name: {...}}}``."""
    path = references_path(name)
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except FileNotFoundError:
        raise ProblemDefinitionError(f"no references stored for suite {name!r} (expected {path.name}; "
                                     "run benchmarks/make_robustness_refs.py)", function="load_references") from None


def _spans(lo, hi, values):
    """Per-entry scale: the bound range where both bounds are finite, else max(1, |value|)."""
    width = hi - lo
    return np.where(np.isfinite(width), width, np.maximum(1.0, np.abs(values)))


def perturbed_start(problem, X, U, seed, controls=0.1, states=0.05):
    """A seeded perturbation of the start (X, U): U + controls * span * xi and, for k >= 1,
    X + states * span * eta (xi, eta standard normal draws of ``numpy.random.default_rng(seed)``,
    U first), span the bound range where both bounds are finite and max(1, |value|) elsewhere,
    clipped to the bounds; x^0 keeps its fixed value. X None: the states simulated from U are
    perturbed."""
    rng = np.random.default_rng(seed)
    U = np.asarray(U, dtype=float)
    X = problem.simulate(U) if X is None else np.asarray(X, dtype=float)
    dU = rng.standard_normal(U.shape) * _spans(problem.u_lower, problem.u_upper, U)
    dX = rng.standard_normal(X.shape) * _spans(problem.x_lower, problem.x_upper, X)
    U2 = np.clip(U + controls * dU, problem.u_lower, problem.u_upper)
    X2 = np.clip(X + states * dX, problem.x_lower, problem.x_upper)
    X2[0] = problem.x0
    return X2, U2
