"""The ``olado`` command line.

    olado solve PROBLEM [--N N] [--start sif|balance] [--year Y] [--config INI]
                        [--set section.key=value ...] [--save FILE.json] [--plot FILE.png] [--quiet]
    olado list
    olado bench SUITE --config A.ini [--config B.ini ...] [--store FILE.jsonl] [--jobs N | --dask ADDRESS|local]
                [--where EXPR] [--time-limit S] [--grace S] [--memory-limit SIZE] [--limit K] [--no-warmup] [--quiet]
    olado profile STORE [STORE ...] [--metric time|wall|sqp|qp|evaluations] [--where EXPR] [--config NAME]
                  [--plot FILE.png] [--table FILE.md|.csv|-] [--per-problem] [--compare OLD_STORE]

``solve`` builds a built-in problem (``olado list`` names them), prints its size (the counts of
Table 1 of the paper), solves it and prints the result summary; ``--save`` writes the result
(JSON + npz), ``--plot`` a figure. ``bench`` and ``profile`` are the benchmarks
(:mod:`olado.bench`, docs/benchmarking.md): ``bench`` exits 0 when every planned solve has a
record (failed solves are records too), ``profile`` 0 unless ``--compare`` found a regression (1). Problem settings come from the command line, else from the
config's ``[problem]`` section, else the problem's defaults.

Exit codes: 0 the solver converged (status success or acceptable); 1 it did not; 2 bad input (an
unknown problem, a bad option or config file, a missing back-end): the message is printed to
stderr without a traceback (docs/errors.md lists every case); 130 after SIGINT (Ctrl-C), 143
after SIGTERM (128 + the signal number, as a shell reports a process ended by that signal).
``solve`` stops at the next safe point on the first SIGINT or SIGTERM and still prints and saves
(``--save``) the result, with the status ``interrupted`` and the last accepted iterate; a second
signal aborts at once and saves nothing (docs/interrupts.md).
"""

from __future__ import annotations

import argparse
import gc
import inspect
import re
import signal
import sys

EXIT_SUCCESS, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors raise instead of exiting (so ``main`` returns 2 itself)."""

    def error(self, message):
        raise _UsageError(self, message)


class _UsageError(Exception):
    def __init__(self, parser, message):
        super().__init__(message)
        self.parser = parser


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = _Parser(prog="olado", description="Discrete-time optimal control problems: solve "
                     "built-in problems and list what is available.")
    parser.add_argument("--version", action="version", version=f"olado {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("solve", help="solve a built-in problem",
                       description="Solve a built-in problem and print the result summary.")
    p.add_argument("problem", nargs="?", metavar="PROBLEM",
                   help="problem name (see 'olado list'); default: [problem] name of the config")
    p.add_argument("--N", "-N", dest="N", type=int, metavar="N", help="horizon (number of stages)")
    p.add_argument("--start", metavar="START", help="initial state of the reservoirs, e.g. sif or balance")
    p.add_argument("--year", type=int, metavar="Y", help="hydrological year of the inflow data")
    p.add_argument("--config", "-c", metavar="INI", help="solver configuration file (ini)")
    p.add_argument("--solver", "-s", metavar="NAME", help="solver name (same as --set solver.name=NAME)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one config value, e.g. --set ipopt.tol=1e-6 (repeatable)")
    p.add_argument("--save", metavar="FILE.json", help="save the result (JSON + npz beside it)")
    p.add_argument("--plot", metavar="FILE.png", help="save a plot of the solution")
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")

    sub.add_parser("list", help="list the built-in problems and the solvers",
                   description="List the built-in problems and the solvers.")
    _add_bench_parser(sub)
    _add_profile_parser(sub)
    return parser


def _add_bench_parser(sub) -> None:
    p = sub.add_parser("bench", help="run a suite of problems against solver configurations",
                       description="Run a suite (problems x sizes x starts) against several configurations, each "
                       "solve isolated in a worker process; records are appended to a JSON Lines store, and a "
                       "killed run resumes where it stopped (docs/benchmarking.md).")
    p.add_argument("suite", metavar="SUITE", help="zambezi-testset, table1, robustness, unconstrained, or a "
                   "suite file (.toml)")
    p.add_argument("--config", "-c", action="append", metavar="[NAME=]INI", help="a solver configuration "
                   "(repeatable); NAME defaults to the file's stem")
    p.add_argument("--store", "-o", metavar="FILE.jsonl", help="results store (default bench-SUITE.jsonl)")
    p.add_argument("--jobs", "-j", type=int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--dask", metavar="ADDRESS", help="run on the Dask scheduler at ADDRESS, or on a local "
                   "Dask cluster of --jobs workers with 'local' (needs olado[bench])")
    p.add_argument("--time-limit", type=float, default=600.0, metavar="S",
                   help="seconds per solve, given to the solver as max_time (default 600)")
    p.add_argument("--grace", type=float, default=15.0, metavar="S",
                   help="extra seconds before a worker that did not stop is killed (default 15)")
    p.add_argument("--memory-limit", metavar="SIZE", help="address-space limit per worker, e.g. 4G, or none "
                   "(default: physical memory / jobs, at least 2G)")
    p.add_argument("--limit", type=int, metavar="K", help="run at most K of the remaining solves")
    p.add_argument("--where", "-w", metavar="EXPR", help="only the suite entries for which EXPR holds (fields "
                   "problem, N, start, factory, group, settings.KEY), e.g. \"N <= 72\"")
    p.add_argument("--no-warmup", action="store_true", help="measure every solve, also a worker's first of a "
                   "configuration and problem family (imports, compilation); by default a worker first solves "
                   "each family's smallest horizon unmeasured")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display or summary")


def _add_profile_parser(sub) -> None:
    p = sub.add_parser("profile", help="performance profiles, tables and comparisons of bench records",
                       description="Dolan-More performance profiles (paper 001 eqs. (48)-(51)) of the "
                       "configurations in a results store, tables of the records, and a comparison with an "
                       "earlier run (docs/benchmarking.md).")
    p.add_argument("store", metavar="STORE", nargs="+", help="results store(s) written by 'olado bench'")
    p.add_argument("--metric", "-m", action="append", metavar="METRIC",
                   help="time, wall, sqp, qp or evaluations (repeatable; default time)")
    p.add_argument("--where", "-w", metavar="EXPR", help='keep the records for which EXPR holds, e.g. '
                   '"N >= 216 and problem == \'zambezi12\'"')
    p.add_argument("--config", "-c", action="append", metavar="NAME", help="only these configurations "
                   "(repeatable; default all, in the store's order)")
    p.add_argument("--plot", metavar="FILE.png", help="save the profiles (PNG, SVG, PDF ...)")
    p.add_argument("--table", metavar="FILE.md", help="write the table (.md Markdown or .csv); '-' prints it")
    p.add_argument("--per-problem", action="store_true", help="table of every solve (like paper 001 Table 1) "
                   "instead of one row per configuration")
    p.add_argument("--compare", metavar="OLD_STORE", help="compare with an earlier run: regressions in "
                   "status, objective and time")
    p.add_argument("--rtol", type=float, default=1e-6, help="objective tolerance of --compare (default 1e-6)")
    p.add_argument("--slower", type=float, default=1.5, help="time ratio --compare reports (default 1.5)")


# ---------------------------------------------------------------------------- problems
def _problem_registry() -> dict:
    from . import problems

    registry = getattr(problems, "PROBLEMS", None)
    if registry is None:
        try:  # until olado.problems re-exports them
            from .problems.zambezi import PROBLEMS as registry
        except ImportError:
            registry = {}
    return dict(registry)


def _first_line(obj) -> str:
    """First line of a docstring, with reST roles (:class:`X`) reduced to their text."""
    doc = (inspect.getdoc(obj) or "").strip()
    line = doc.splitlines()[0] if doc else ""
    return re.sub(r":\w+:`~?([^`]+)`", r"\1", line).replace("``", "")


def _build_problem(name, settings):
    from .errors import ConfigError

    registry = _problem_registry()
    if name not in registry:
        raise ConfigError(f"unknown problem {name!r}", allowed=", ".join(sorted(registry)) or "none")
    factory = registry[name]
    kwargs = {k: v for k, v in settings.items() if v is not None}
    named = _named_settings(factory)
    unknown = [k for k in kwargs if k not in named]
    if unknown:  # a setting the factory would only pass on through **kwargs is not one it takes
        raise ConfigError(f"problem {name!r} takes no setting {unknown[0]!r}", key=unknown[0],
                          allowed=", ".join(named) or "none")
    try:
        return factory(**kwargs)
    except ValueError as exc:  # a factory rejecting a bad N, start or year
        from .errors import OladoError

        if isinstance(exc, OladoError):
            raise
        raise ConfigError(f"problem {name!r}: {exc}") from None


def _named_settings(factory) -> list[str]:
    """The command line's problem settings (``--N``, ``--start``, ``--year``) that ``factory``
    names as parameters."""
    from .config import PROBLEM_KEYS

    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return [k for k in PROBLEM_KEYS if k != "name"]
    return [k for k, p in params.items() if k in PROBLEM_KEYS and k != "name"
            and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def _plot_formats() -> list[str]:
    """The file formats matplotlib writes (``--plot out.svg`` ...)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return sorted(Figure().canvas.get_supported_filetypes())


def _check_output(path, option, formats=None) -> None:
    """Before the solve: ``path`` (of ``--save`` or ``--plot``) can be written -- its nearest
    existing folder is a writable folder, and its suffix one of ``formats`` -- so that a solve's
    work is not lost to a typo; ConfigError naming the option otherwise."""
    import os
    from pathlib import Path

    from .errors import ConfigError

    if path is None:
        return
    target = Path(path)
    if formats is not None and target.suffix.lstrip(".").lower() not in formats:
        raise ConfigError(f"cannot write a {target.suffix or 'suffix-less'} file {path!r}",
                          key=option, allowed=", ".join(f".{f}" for f in formats))
    if target.is_dir():
        raise ConfigError(f"{path!r} is a folder; give a file name", key=option)
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"cannot write {path!r}: {str(folder)!r} is not a writable folder", key=option)


def _counts_line(problem) -> str:
    """One line with the sizes of Table 1: variables, equality and inequality constraints."""
    dims = f"n={problem.n}, m={problem.m}, N={problem.N}"
    try:
        from .problems import StructuredNLP

        counts = StructuredNLP(problem).counts()
    except Exception as exc:  # counting is informative only
        return f"problem {getattr(problem, 'name', type(problem).__name__)} ({dims}); counts unavailable: {exc}"
    parts = ", ".join(f"{k} {counts[k]}" for k in ("variables", "equalities", "inequalities")
                      if k in counts)
    return f"problem {getattr(problem, 'name', type(problem).__name__)} ({dims}): {parts}"


# ---------------------------------------------------------------------------- commands
def _cmd_solve(args) -> int:
    from .config import load_config, make_solver
    from .errors import ConfigError

    overrides = list(args.overrides)
    if args.solver:
        overrides.append(f"solver.name={args.solver}")
    config = load_config(args.config, overrides)
    settings = dict(config.problem)
    name = args.problem or settings.pop("name", None)
    settings.pop("name", None)
    if not name:
        raise ConfigError("no problem given: name one (see 'olado list') or set [problem] name",
                          file=config.source if args.config else None)
    for key in ("N", "start", "year"):
        value = getattr(args, key)
        if value is not None:
            settings[key] = value
    if "N" in settings and settings["N"] < 1:
        raise ConfigError(f"N must be >= 1, got {settings['N']}", key="N", allowed=">= 1")
    _check_output(args.save, "--save")
    _check_output(args.plot, "--plot", formats=_plot_formats() if args.plot else None)
    problem = _build_problem(name, settings)
    solver = make_solver(config)
    verbose = getattr(solver.options, "verbose", 0)
    if args.quiet and verbose:
        solver.options.verbose = 0
        verbose = 0
    if not args.quiet:
        print(_counts_line(problem))
        print(f"solver {config.solver} (config: {config.source})", flush=True)
    result = solver.solve(problem)
    if not args.quiet and verbose < 1:  # with verbose >= 1 the solver printed the summary itself
        print(result.summary())
    if args.save:
        path = result.save(args.save)
        if not args.quiet:
            print(f"saved result to {path} (+ {path.with_suffix('.npz').name})")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        fig = result.plot(args.plot, problem=problem)
        try:
            import matplotlib.pyplot as plt

            plt.close(fig)
        except Exception:
            pass
        if not args.quiet:
            print(f"saved plot to {args.plot}")
    return EXIT_SUCCESS if result.success else EXIT_NOT_CONVERGED


def _cmd_list(args) -> int:
    from .solvers.registry import SOLVERS  # a table: no solver module is imported to list them

    problems = _problem_registry()
    print("problems:")
    if not problems:
        print("  (none registered)")
    width = max([len(n) for n in problems] + [8])
    for name in problems:  # registry order (zambezi, zambezi8, ..., zambezi12)
        print(f"  {name:<{width}}  {_first_line(problems[name])}".rstrip())
    print("solvers:")
    width = max([len(n) for n in SOLVERS] + [8])
    for name in sorted(SOLVERS):
        print(f"  {name:<{width}}  {SOLVERS.summary(name)}{_missing_mark(SOLVERS, name)}".rstrip())
    return EXIT_SUCCESS


def _missing_mark(registry, name) -> str:
    """``"  [not installed: <how to install>]"`` when a module the solver needs is missing."""
    if not registry.missing(name):
        return ""
    install = registry.entry(name).install
    return f"  [not installed: {install}]" if install else "  [not installed]"


def main(argv=None) -> int:
    """Run the command line; returns the exit code (0 converged, 1 not converged, 2 bad input)."""
    from .errors import OladoError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        exc.parser.print_usage(sys.stderr)
        print(f"{exc.parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    try:
        if args.command == "bench":
            from .bench.command import cmd_bench

            return cmd_bench(args)
        if args.command == "profile":
            from .bench.command import cmd_profile

            return cmd_profile(args)
        if args.command == "solve":
            from .interrupts import InterruptGuard

            # the first SIGINT / SIGTERM stops the solve at a safe point (the result is still
            # printed and saved); the command then ends with 128 + the signal number
            with InterruptGuard((signal.SIGINT, signal.SIGTERM)) as guard:
                code = _cmd_solve(args)
                received = guard.received
            return 128 + received if received else code
        return _cmd_list(args)
    except OladoError as exc:
        print(f"olado: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:  # output piped into e.g. head, which closed early: stop quietly
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 128 + 13  # as a shell reports death by SIGPIPE
    except OSError as exc:  # e.g. --save/--plot into a folder that cannot be written
        print(f"olado: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:   # before the solve's handler, or a second signal (AbortSolve)
        signum = getattr(exc, "signum", signal.SIGINT)
        print("olado: aborted" if hasattr(exc, "signum") else "olado: interrupted", file=sys.stderr)
        return 128 + int(signum)


def run():
    """The ``olado`` program (the console script and ``python -m olado``): :func:`main` on
    ``sys.argv``, then exit with its code.

    Before the exit every object alive is moved to the garbage collector's permanent generation
    (:func:`gc.freeze`), which the interpreter's final collections skip: after numba has loaded
    or compiled kernels, its object graph makes those collections take about 0.4 s, a quarter of a
    small solve's wall time (benchmarks/RESULTS.md, start-up section). Nothing else changes: output
    is flushed and atexit handlers run as usual. Not for use inside a longer-lived process (the
    frozen objects would never be collected): call :func:`main` there."""
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    run()
