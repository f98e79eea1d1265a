"""Where the solves of a benchmark run (docs/benchmarking.md, "Executors"): a local pool of
isolated worker processes (:class:`LocalExecutor`, ``--jobs N``) or a Dask distributed cluster
(:class:`DaskExecutor`, ``--dask ADDRESS`` or ``--dask local``). Both run every solve through
an :class:`~olado.bench.pool.IsolatedPool` (on Dask: one per Dask worker thread, inside the Dask
worker) and build the records with :func:`~olado.bench.records.make_record` on the machine
that ran the solve, so either gives the same records.
"""

from __future__ import annotations

import dataclasses
import threading

from ..errors import ConfigError
from .pool import GRACE, IsolatedPool
from .records import make_record

#: what every worker answers a task with
TARGET = "olado.bench.records:solve_case"


@dataclasses.dataclass(frozen=True)
class Limits:
    """Per-solve limits: the solver's time limit (seconds; also its ``max_time``), the extra
    seconds before a hung worker is killed, the worker's address-space limit in bytes (None:
    none), and whether a worker warms up (an unmeasured solve of each configuration and problem
    family's smallest horizon before its first measured solve of that family,
    :func:`olado.bench.records.solve_case`; the warm-up gets twice the time limit, the measured
    solve the time limit, each plus the grace)."""

    time_limit: float = 600.0
    grace: float = GRACE
    memory_limit: int | None = None
    warmup: bool = True


#: modules a worker imports before it says it is ready (not counted in the first task's time limit)
PRELOAD = ("olado.config", "olado.problems", "olado.solvers.registry")


def _preload(tasks) -> tuple:
    """PRELOAD and the modules of the tasks' solvers."""
    from ..solvers.registry import SOLVERS

    solvers = {t.config.config.solver for t in tasks}
    return PRELOAD + tuple(sorted({SOLVERS.target(s).partition(":")[0] for s in solvers if s in SOLVERS}))


class LocalExecutor:
    """``jobs`` isolated worker processes on this machine."""

    def __init__(self, jobs: int = 1, limits: Limits = Limits()):
        if jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {jobs}", key="--jobs", allowed=">= 1")
        self.jobs, self.limits = jobs, limits

    def describe(self) -> str:
        return f"{self.jobs} local worker process{'es' if self.jobs > 1 else ''}"

    def run(self, tasks):
        """Yield one record per task, in completion order."""
        lim, tasks = self.limits, list(tasks)
        with IsolatedPool(TARGET, jobs=self.jobs, time_limit=lim.time_limit, grace=lim.grace,
                          memory_limit=lim.memory_limit, preload=_preload(tasks)) as pool:
            for task, answer in pool.run(tasks):
                yield make_record(task, answer)


# ---------------------------------------------------------------------------- Dask
_LOCAL = threading.local()


def dask_solve(task, limits: Limits) -> dict:
    """A Dask task: solve ``task`` in this Dask worker thread's own isolated worker process (kept
    from task to task) and return its record."""
    pool = getattr(_LOCAL, "pool", None)
    if pool is None or (pool.time_limit, pool.grace, pool.memory_limit) != (limits.time_limit, limits.grace,
                                                                             limits.memory_limit):
        if pool is not None:
            pool.close()
        pool = _LOCAL.pool = IsolatedPool(TARGET, jobs=1, time_limit=limits.time_limit, grace=limits.grace,
                                          memory_limit=limits.memory_limit, preload=_preload([task]))
    (_, answer), = pool.run([task])
    return make_record(task, answer)


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise ConfigError("--dask needs the optional dependency dask[distributed]", key="--dask",
                          allowed='pip install "olado[bench]"') from None
    return distributed


class DaskExecutor:
    """The solves as tasks of a Dask distributed cluster: ``address`` of a running scheduler, or
    ``"local"`` for a :class:`distributed.LocalCluster` of ``jobs`` worker processes (one thread
    each) started and stopped here."""

    def __init__(self, address: str, jobs: int = 1, limits: Limits = Limits()):
        if not address:
            raise ConfigError("--dask needs a scheduler address or 'local'", key="--dask")
        self.address, self.jobs, self.limits = address, max(1, int(jobs)), limits
        self._distributed = _import_distributed()

    def describe(self) -> str:
        if self.address == "local":
            return f"a local Dask cluster of {self.jobs} worker{'s' if self.jobs > 1 else ''}"
        return f"the Dask scheduler at {self.address}"

    def _client(self):
        d = self._distributed
        if self.address == "local":
            cluster = d.LocalCluster(n_workers=self.jobs, threads_per_worker=1, processes=True,
                                     dashboard_address=None)
            return cluster, d.Client(cluster)
        try:
            return None, d.Client(self.address, timeout=30)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler {self.address!r} ({exc})", key="--dask") from None

    def run(self, tasks):
        """Yield one record per task, in completion order."""
        tasks = list(tasks)
        cluster, client = self._client()
        try:
            futures = [client.submit(dask_solve, task, self.limits, pure=False) for task in tasks]
            for future in self._distributed.as_completed(futures):
                yield future.result()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
