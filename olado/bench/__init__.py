"""Benchmarks as part of the package (issue 14; docs/benchmarking.md): ``olado bench`` runs a
suite of problems against several solver configurations, each solve isolated in a worker process
with a time limit and a memory guard, every record appended to a resumable JSON Lines store, on a
local process pool or a Dask cluster; ``olado profile`` draws Dolan-Moré performance profiles
(paper 001 eqs. (48)-(51)), writes tables and compares a run with an earlier one.

    import olado.bench as bench
    report = bench.run("table1", ["configs/sqp-ip.ini", "configs/ipopt.ini"], "table1.jsonl", jobs=2)
    print(report.summary())
    records = bench.read_records("table1.jsonl")
    prof = bench.performance_profile(records, metric="time", where="N >= 120")

The modules by role: ``pool`` (isolated worker processes), ``records`` (one solve and its
record), ``store`` (the JSON Lines store), ``executors`` (process pool, Dask), ``progress``,
``runner`` (``run``), ``where`` (the record filter language), ``profiles`` (profiles, tables,
comparisons). Imported lazily: ``import olado.bench`` loads none of them.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "run": "runner", "RunReport": "runner", "load_bench_configs": "runner", "plan": "runner",
    "Limits": "executors", "LocalExecutor": "executors", "DaskExecutor": "executors",
    "IsolatedPool": "pool", "Failure": "pool",
    "ResultStore": "store", "read_records": "store",
    "BenchConfig": "records", "Task": "records", "config_hash": "records", "solve_case": "records",
    "KEY_FIELDS": "records", "RUN_STATUSES": "records",
    "parse_where": "where", "Where": "where",
    "performance_profile": "profiles", "Profile": "profiles", "profile_table": "profiles",
    "summary_table": "profiles", "compare_runs": "profiles", "plot_profiles": "profiles", "METRICS": "profiles",
}
__all__ = sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
