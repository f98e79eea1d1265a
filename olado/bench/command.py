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
    limits = Limits(time_limit=args.time_limit, grace=args.grace, memory_limit=memory)
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
    report = run(args.suite, configs, store, jobs=args.jobs, dask=args.dask, limits=limits,
                 progress=not args.quiet, stream=sys.stderr, limit=args.limit)
    if not args.quiet:
        print(report.summary(), flush=True)
    return 0
