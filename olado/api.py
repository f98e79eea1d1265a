"""The one entry point: ``olado.solve(problem, ...)`` (in the spirit of scipy.optimize.minimize).

Which solver runs, with which options, is decided in this order (later wins):

1. the default solver, :func:`olado.config.default_solver_name` -- ``ipopt`` when cyipopt is
   installed, else SciPy's ``trust-constr`` (the chosen name is in ``result.solver``);
2. ``config``: an ini file path or a :class:`~olado.config.SolverConfig`;
3. ``solver``: a registry name (``"ipopt"``, ``"slsqp"``, ...; with an ini file the file's section
   for that solver is used) or a ready :class:`~olado.solvers.base.Solver` instance;
4. ``**options``: keyword options of that solver's ``Options`` dataclass, validated.
"""

from __future__ import annotations

from pathlib import Path

from .errors import ConfigError

__all__ = ["solve", "resolve_solver"]


def resolve_solver(config=None, solver=None, **options):
    """The Solver instance that :func:`solve` would use (see the module docstring)."""
    from . import config as cfgmod
    from .solvers.base import Solver

    if isinstance(solver, Solver):
        if config is not None:
            raise ConfigError("give either a Solver instance or a config, not both")
        if not options:
            return solver
        return type(solver)(solver.options, **options)
    if isinstance(solver, type) and issubclass(solver, Solver):
        solver = solver.name
    if solver is not None and not isinstance(solver, str):
        raise ConfigError(f"solver must be a name or a Solver instance, got {type(solver).__name__}")

    if config is None:
        cfg = cfgmod.config_from_kwargs(solver)
    elif isinstance(config, cfgmod.SolverConfig):
        cfg = config
        if solver is not None and solver != cfg.solver:
            raise ConfigError(f"the config is for solver {cfg.solver!r} but solver={solver!r} was given",
                              file=cfg.source, section="solver", key="name")
    elif isinstance(config, (str, Path)):
        cfg = cfgmod.load_config(config, {"solver.name": solver} if solver is not None else None)
    else:
        raise ConfigError("config must be an ini file path, a SolverConfig or None, "
                          f"got {type(config).__name__}")
    if options:
        cfg = cfgmod.with_overrides(cfg, **options)
    return cfgmod.make_solver(cfg)


def solve(problem, config=None, solver=None, guess=None, **options):
    """Solve a discrete-time optimal control problem and return a :class:`~olado.result.Result`.

    Parameters
    ----------
    problem : DOCP
        The problem (an instance of a :class:`olado.problems.DOCP` subclass).
    config : str | Path | SolverConfig | None
        An ini file (see :mod:`olado.config`) or a loaded configuration.
    solver : str | Solver | None
        A registry name (``olado list`` shows them) or a Solver instance; None: the config's
        solver, else the default (``ipopt`` if cyipopt is installed, else ``trust-constr``).
    guess : ndarray | (X, U) | Result | None
        Initial controls U (N, m), a state/control pair, or a previous result (warm start).
    **options
        Options of the chosen solver (``tol=1e-6``, ``max_iter=200``, ``verbose=1`` ...).

    Non-convergence is reported in ``result.status``, never raised. A bad option raises
    :class:`~olado.errors.ConfigError`; a problem that is not a usable DOCP, a bad guess or a user
    function returning something that is not an array of real numbers of the right shape
    :class:`~olado.errors.ProblemDefinitionError`; a missing back-end
    :class:`SolverNotAvailableError` (docs/errors.md). Exceptions raised inside the user's own
    functions pass through unchanged.
    """
    if isinstance(problem, str):
        raise ConfigError(f"problem must be a DOCP instance, not the name {problem!r}; build one "
                          "with olado.problems.PROBLEMS[name](N=...)")
    from .problems.docp import check_problem

    instance = resolve_solver(config, solver, **options)   # the solver's errors first, then the problem's
    check_problem(problem, entry="olado.solve")
    return instance.solve(problem, guess=guess)
