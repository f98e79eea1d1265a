"""The ``olado bench`` and ``olado profile`` commands (their arguments are declared in
:mod:`olado.cli`; docs/benchmarking.md)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

from ..errors import ConfigError

_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kmgt]?)i?b?\s*$", re.I)


def parse_memory(text) -> int | None:
    """``"4G"``, ``"512M"``, ``"2.5GiB"``, ``"none"`` -> bytes (None: no limit)."""
    if text is None:
        return None
    if str(text).strip().lower() in ("none", "0", "off", "unlimited"):
        return None
    m = _SIZE.match(str(text))
    if not m:
        raise ConfigError(f"not a memory size: {text!r}", key="--memory-limit", allowed="e.g. 4G, 512M, none")
    scale = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}[m.group(2).lower()]
    value = int(float(m.group(1)) * scale)
    if value < 2**28:
        raise ConfigError(f"{text!r} is below 256M, too little to import olado", key="--memory-limit",
                          allowed=">= 256M or none")
    return value


def default_memory_limit(jobs: int) -> int:
    """Physical memory shared among the jobs, at least 2 GiB (an address-space limit counts
    reserved, not only touched, memory: numba and the BLAS threads reserve several hundred MB)."""
    import os

    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 4 * 2**30
    return max(2 * 2**30, total // max(1, jobs))


def _positive(value, option):
    if not value > 0:
        raise ConfigError(f"{option} must be > 0, got {value:g}", key=option, allowed="> 0")


def cmd_bench(args) -> int:
    from .executors import Limits
    from .runner import load_bench_configs, run

    _positive(args.time_limit, "--time-limit")
    if args.grace < 0:
        raise ConfigError(f"--grace must be >= 0, got {args.grace:g}", key="--grace", allowed=">= 0")
    memory = default_memory_limit(args.jobs) if args.memory_limit is None else parse_memory(args.memory_limit)
    limits = Limits(time_limit=args.time_limit, grace=args.grace, memory_limit=memory, warmup=not args.no_warmup)
    configs = load_bench_configs(args.config or [], args.time_limit)
    store = args.store or f"bench-{Path(args.suite).stem}.jsonl"
    from .runner import make_executor

    executor = make_executor(args.jobs, args.dask, limits)   # checks --jobs / --dask before any work
    if not args.quiet:
        mem = "no memory limit" if memory is None else f"memory limit {memory / 2**30:.1f} GiB"
        print(f"suite {args.suite}, {len(configs)} configuration(s): "
              + ", ".join(f"{c.name} [{c.hash}]" for c in configs), flush=True)
        print(f"store {store}; {executor.describe()}; time limit {args.time_limit:g} s per solve "
              f"(+{args.grace:g} s grace), {mem}", flush=True)
    try:
        report = run(args.suite, configs, store, jobs=args.jobs, dask=args.dask, limits=limits,
                     progress=not args.quiet, stream=sys.stderr, limit=args.limit, where=args.where)
    except KeyboardInterrupt:
        print(f"olado bench: stopped; the records written so far are in {store}, and the same command "
              "resumes the run", file=sys.stderr)
        raise
    if not args.quiet:
        print(report.summary(), flush=True)
    return 0


def _read_stores(paths) -> list[dict]:
    from .store import read_records

    records = []
    for path in paths:
        records.extend(read_records(path))
    return records


def _table_format(path) -> str:
    if path == "-":
        return "md"
    suffix = Path(path).suffix.lower()
    if suffix not in (".md", ".csv"):
        raise ConfigError(f"cannot write a {suffix or 'suffix-less'} table {path!r}", key="--table",
                          allowed=".md, .csv, - (print)")
    return suffix[1:]


def _plot_format(path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    formats = Figure().canvas.get_supported_filetypes()
    if Path(path).suffix.lstrip(".").lower() not in formats:
        raise ConfigError(f"cannot write a {Path(path).suffix or 'suffix-less'} figure {path!r}", key="--plot",
                          allowed=", ".join(f".{f}" for f in sorted(formats)))


def cmd_profile(args) -> int:
    from ..result import atomic_write_bytes
    from .profiles import (compare_runs, format_table, per_problem_table, performance_profile, plot_profiles,
                           select, summary_table)

    if not args.rtol >= 0:
        raise ConfigError(f"--rtol must be >= 0, got {args.rtol:g}", key="--rtol", allowed=">= 0")
    _positive(args.slower, "--slower")
    fmt = _table_format(args.table) if args.table else None
    if args.plot:
        _plot_format(args.plot)
    records = select(_read_stores(args.store), args.where, args.config)
    if not records:
        raise ConfigError("no records" + (f" for which {args.where!r} holds" if args.where else ""), key="--where")
    metrics = list(dict.fromkeys(args.metric or ["time"]))
    profiles = [performance_profile(records, m, configs=args.config) for m in metrics]
    if args.per_problem:
        header, rows = per_problem_table(records, args.config)
    else:
        header, rows = summary_table(records, profiles, args.config)
    text = format_table(header, rows, fmt or "md")
    prof = profiles[0]
    print(f"{len(records)} records, {len(prof.problems)} problems x {len(prof.configs)} configurations"
          + (f" ({prof.dropped} problems left out: not run by every configuration)" if prof.dropped else ""))
    if args.table and args.table != "-":
        atomic_write_bytes(args.table, text.encode("utf-8"))
        print(f"wrote {args.table}")
    else:
        print(text, end="")
    if args.plot:
        plot_profiles(profiles, args.plot, title=", ".join(args.store) + (f" where {args.where}" if args.where else ""))
        print(f"saved {args.plot}")
    if args.compare:
        old = select(_read_stores([args.compare]), args.where, None)
        comparison = compare_runs(records, old, rtol=args.rtol, slower=args.slower)
        print(f"comparison with {args.compare}:")
        print(comparison.text())
        return 1 if comparison.has_regressions else 0
    return 0
