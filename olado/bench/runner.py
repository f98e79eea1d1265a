"""``olado bench`` / :func:`olado.bench.run`: a suite against several configurations, every
solve isolated, each record appended to the store as it arrives, a killed run resumed where it
stopped (docs/benchmarking.md)."""

from __future__ import annotations

import collections
import dataclasses
import os
from pathlib import Path

from ..errors import ConfigError
from .executors import DaskExecutor, Limits, LocalExecutor
from .progress import Progress
from .records import BenchConfig, Task, config_hash, family, warmup_entries
from .store import ResultStore


def _named_path(item) -> tuple[str, str]:
    """``"NAME=PATH"`` -> (NAME, PATH); ``"PATH"`` -> (the file's stem, PATH)."""
    text = str(item)
    name, sep, path = text.partition("=")
    if sep and name and os.sep not in name and not name.endswith(".ini"):
        return name.strip(), path.strip()
    return Path(text).stem, text


def load_bench_configs(items, time_limit: float) -> list[BenchConfig]:
    """The configurations ``items`` (ini paths, ``NAME=PATH``, or (name, SolverConfig) pairs),
    each with ``max_time = time_limit`` (the bench's per-solve limit) and its hash."""
    from ..config import load_config, with_overrides

    out, names = [], {}
    for item in items:
        if isinstance(item, tuple):
            name, config, source = item[0], item[1], getattr(item[1], "source", "<code>")
        else:
            name, path = _named_path(item)
            config, source = load_config(path), path
        if name in names:
            raise ConfigError(f"two configurations are named {name!r} ({names[name]} and {source}); "
                              "rename one with NAME=PATH", key="--config")
        names[name] = source
        config = with_overrides(config, max_time=float(time_limit))
        out.append(BenchConfig(name=name, config=config, hash=config_hash(config), source=str(source)))
    if not out:
        raise ConfigError("no configuration given (--config FILE.ini, repeatable)", key="--config")
    return out


@dataclasses.dataclass
class RunReport:
    """What a run did: the planned, already stored and newly run solves, the bytes of a cut-short
    record dropped on opening the store, and the records of this run."""

    store: Path
    planned: int
    skipped: int
    records: list
    repaired: int = 0
    rehashed: int = 0       # planned solves whose config name has a record under another hash

    def summary(self) -> str:
        """Per configuration: solved, failed by status, the solver's total time."""
        lines = [f"{len(self.records)} solves run, {self.skipped} already in {self.store} "
                 f"({self.planned} planned)"]
        if self.rehashed:
            lines.append(f"note: {self.rehashed} planned solves have records of the same configuration name with "
                         "another hash (other options or another --time-limit); those records were not reused")
        if self.repaired:
            lines.append(f"dropped an incomplete last record ({self.repaired} bytes) left by a killed run")
        by_config = collections.defaultdict(list)
        for r in self.records:
            by_config[r["config"]].append(r)
        for name, recs in by_config.items():
            solved = sum(bool(r.get("success")) for r in recs)
            fails = collections.Counter(r["status"] for r in recs if not r.get("success"))
            time_s = sum(r.get("solve_s") or 0.0 for r in recs)
            failed = ", ".join(f"{s} {n}" for s, n in fails.most_common()) or "none"
            lines.append(f"  {name}: {solved} solved, {len(recs) - solved} failed ({failed}); solver time {time_s:.1f} s")
        return "\n".join(lines)


def plan(entries, configs, suite: str = "", warmup_from=None) -> list[Task]:
    """Every (entry, configuration) pair, entries outer (a partial run covers whole problems);
    each task names the entry a worker warms up with for its family: the family's smallest
    horizon among ``warmup_from`` (default ``entries``; the whole suite when ``entries`` is a
    subset of it, :func:`olado.bench.records.warmup_entries`)."""
    warm = warmup_entries(list(entries if warmup_from is None else warmup_from) + list(entries))
    return [Task(entry=e, config=c, suite=suite, warmup_entry=warm[family(e)]) for e in entries for c in configs]


def entry_fields(entry) -> dict:
    """The fields of a suite entry that ``--where`` of ``olado bench`` reads: those a record
    will have (problem, N, start, factory, settings) and the entry's group."""
    return {"problem": entry.name, "N": entry.size, "start": entry.start_label, "factory": entry.problem,
            "settings": dict(entry.settings), "group": entry.group}


def select_entries(entries, where) -> list:
    """The entries for which ``where`` (text or :class:`~olado.bench.where.Where`; None: all)
    holds, e.g. ``"N <= 72"`` (a subset of a suite, run with the full suite's keys, so that a
    later run of the whole suite into the same store reuses these solves)."""
    from .where import Where

    entries = list(entries)
    if not where:
        return entries
    cond = where if isinstance(where, Where) else Where(where)
    fields = [entry_fields(e) for e in entries]
    cond.check_fields(fields)
    kept = [e for e, f in zip(entries, fields) if cond(f)]
    if entries and not kept:
        raise ConfigError(f"no entry of the suite for which {cond.text!r} holds", key="--where")
    return kept


def make_executor(jobs: int = 1, dask: str | None = None, limits: Limits = Limits()):
    return DaskExecutor(dask, jobs, limits) if dask else LocalExecutor(jobs, limits)


def run(suite, configs, store, *, jobs: int = 1, dask: str | None = None, limits: Limits = Limits(),
        progress: bool = True, stream=None, limit: int | None = None, where=None) -> RunReport:
    """Run ``suite`` (a suite name, a .toml path or a list of SuiteEntry) against ``configs``
    (see :func:`load_bench_configs`), appending one record per solve to the JSON Lines ``store``;
    solves whose key is already in the store are skipped (resume). ``limit``: run at most this
    many of the remaining solves; ``where``: only the entries for which it holds
    (:func:`select_entries`)."""
    from ..problems.suites import load_suite

    if isinstance(suite, (str, os.PathLike)):
        suite_name, entries = str(suite), load_suite(suite)
    else:
        suite_name, entries = "<entries>", list(suite)
    whole, entries = entries, select_entries(entries, where)
    if not isinstance(configs, list) or not all(isinstance(c, BenchConfig) for c in configs):
        configs = load_bench_configs(list(configs), limits.time_limit)
    executor = make_executor(jobs, dask, limits)
    tasks = [dataclasses.replace(t, warmup=limits.warmup) for t in plan(entries, configs, suite_name, whole)]
    with ResultStore(store) as st:
        done = st.keys()
        todo = [t for t in tasks if t.key not in done]
        if limit is not None:
            todo = todo[:max(0, int(limit))]
        named = {(r.get("problem"), r.get("N"), r.get("start"), r.get("config")) for r in st.records}
        rehashed = sum(t.key not in done and (*t.key[:3], t.config.name) in named for t in tasks)
        report = RunReport(Path(store), len(tasks), sum(t.key in done for t in tasks), [], st.repaired, rehashed)
        bar = Progress(len(todo), stream=stream, enabled=progress)
        try:
            for record in executor.run(todo) if todo else ():
                st.append(record)
                report.records.append(record)
                bar.update(record)
        finally:
            bar.close()
    return report
