"""One solve of a benchmark and its record (docs/benchmarking.md, "Records").

:func:`solve_case` runs in an isolated worker (:mod:`olado.bench.pool`): it builds the entry's
problem and start, solves it with the configuration and returns the measurements; any exception
becomes status ``exception`` (``memory_limit`` for a MemoryError under the worker's memory guard)
with its message. :func:`make_record` joins the task's identity, the answer (or the pool's
:class:`~olado.bench.pool.Failure`) and where it ran into one flat, JSON-ready record.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import json
import math
import os
import platform
import subprocess
import time
import traceback
from pathlib import Path

#: the record layout's version (a store may hold records of several versions)
SCHEMA = 1
#: the fields that identify a solve: one record per key in a store
KEY_FIELDS = ("problem", "N", "start", "config_hash")
#: statuses a benchmark adds to those of olado.Status
RUN_STATUSES = {"timeout": "killed at the time limit plus grace (the worker did not answer)",
                "crash": "the worker process died (a signal, an abort in compiled code)",
                "exception": "the problem or solver raised an exception",
                "memory_limit": "a MemoryError under the worker's memory guard"}


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """A solver configuration as a benchmark uses it: its name (the ini file's stem or the name
    given with ``NAME=PATH``), the validated config with the bench's time limit as ``max_time``,
    and the hash of that effective configuration (:func:`config_hash`)."""

    name: str
    config: object          # olado.config.SolverConfig
    hash: str
    source: str = ""


@dataclasses.dataclass(frozen=True)
class Task:
    """One solve: a suite entry with one configuration, and the suite's name."""

    entry: object           # olado.problems.suites.SuiteEntry
    config: BenchConfig
    suite: str = ""
    warmup: bool = True     # solve once unmeasured first when the worker has not run this config and family
    warmup_entry: object = None   # the entry that warm-up solves (None: the task's own; see warmup_entries)

    @property
    def key(self) -> tuple:
        return (self.entry.name, self.entry.size, self.entry.start_label, self.config.hash)

    @property
    def warm_key(self) -> tuple:
        """(configuration hash, problem family): what a worker warms up once."""
        return (self.config.hash, family(self.entry))


def family(entry) -> tuple:
    """The problem family of a suite entry: its factory and its settings other than the horizon
    ``N`` -- the entries that run the same code (the problem's kernels, numba's compilations, the
    solver's paths from that start), whatever their size. The start setting is part of it: a
    warm-up from another start left a first solve from this one slower (zambezi N = 48 from the
    SIF start after a warm-up from the balance start: 0.13 s, against 0.07-0.10 s after one
    from the SIF start); a perturbed start (a seed) is not."""
    settings = {k: v for k, v in dict(entry.settings).items() if k != "N"}
    return (entry.problem, json.dumps(_plain(settings), sort_keys=True))


def warmup_entries(entries) -> dict:
    """{family: the entry a worker warms up with}: per :func:`family`, its entry of the smallest
    horizon (the cheapest solve of that code; an entry without ``N`` counts as the largest),
    from the problem's own start where there is one, else the first in suite order."""
    best: dict = {}
    for i, e in enumerate(entries):
        rank = (e.size is None, e.size or 0, e.start != "problem", i)
        fam = family(e)
        if fam not in best or rank < best[fam][0]:
            best[fam] = (rank, e)
    return {fam: e for fam, (_, e) in best.items()}


def _plain(value):
    """JSON-ready: numpy scalars to Python, non-finite floats to None, tuples to lists."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        try:
            value = value.item()
        except (TypeError, ValueError):
            return str(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)


def config_hash(config) -> str:
    """The first 12 hex digits of the SHA-256 of the solver's name and all its options (sorted
    JSON): two configurations with the same hash solve alike, whatever their file names."""
    payload = json.dumps({"solver": config.solver, "options": _plain(config.options_dict())},
                         sort_keys=True, default=str)
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()[:12]


# ---------------------------------------------------------------------------- where it ran
@functools.lru_cache(maxsize=1)
def olado_commit() -> str:
    """The commit of the olado checkout this process imports (short hash, ``+changes`` when
    tracked files differ), the environment variable OLADO_COMMIT when set, "unknown" outside a
    git checkout (an installed package)."""
    if os.environ.get("OLADO_COMMIT"):
        return os.environ["OLADO_COMMIT"]
    checkout = Path(__file__).resolve().parents[2]
    try:
        def git(*args):
            return subprocess.run(["git", *args], cwd=checkout, capture_output=True, text=True, check=True,
                                  timeout=10).stdout.strip()
        if git("rev-parse", "--show-toplevel") != str(checkout):
            return "unknown"
        changed = git("status", "--porcelain", "--untracked-files=no")
        return git("rev-parse", "--short", "HEAD") + ("+changes" if changed else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@functools.lru_cache(maxsize=1)
def machine() -> dict:
    """Host name, CPU model, logical CPUs, Python version and platform of this process."""
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            cpu = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {"host": platform.node(), "cpu": cpu, "cpus": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform(terse=True)}


# ---------------------------------------------------------------------------- the worker side
def _function_evaluations(evaluations: dict) -> int | None:
    """Evaluations of the objective (paper 001 sec. 6: "the number of objective function
    evaluations"); the dynamics' for a solver that counts no objective separately."""
    for key in ("objective", "dynamics"):
        if evaluations.get(key):
            return int(evaluations[key])
    return None


def _measure(result) -> dict:
    cert = getattr(result, "certificate", None)
    evaluations = {k: int(v) for k, v in dict(result.evaluations or {}).items()}
    return {"status": result.status.value, "success": bool(result.status.success),
            "message": (result.message or "")[:500], "objective": result.objective,
            "violation": result.max_constraint_violation, "kkt_residual": result.kkt_residual,
            "certificate": None if cert is None else cert.level,
            "sqp_iterations": int(result.iterations), "qp_iterations": int(result.qp_iterations),
            "function_evaluations": _function_evaluations(evaluations), "evaluations": evaluations,
            "solve_s": float(result.time_s)}


#: (config hash, problem family) pairs this process has solved: warm (imports done, kernels compiled)
_WARM: set = set()


def _warm_up(task: Task) -> dict:
    """The first time this process meets ``task``'s (configuration, problem family): solve the
    family's warm-up entry (``task.warmup_entry``, its smallest horizon; the task's own entry
    when none is given) once, unmeasured, so that imports, numba's compilation or cache loads and
    the problem's own set-up are not counted in the measured solve (the paper's scripts warmed
    up the same way). Returns the record fields ``warmup_s`` (its wall time), ``warmup_N`` (its
    horizon), both None when there was no warm-up, and ``warmup_error`` when the warm-up raised
    (the measured solve then runs cold)."""
    from olado.config import make_solver

    if not task.warmup or task.warm_key in _WARM:
        return {"warmup_s": None, "warmup_N": None}
    from ._worker import reset_clock

    entry = task.warmup_entry or task.entry
    reset_clock("warmup")
    t0 = time.perf_counter()
    out = {"warmup_N": entry.size}
    try:
        problem, guess = entry.build()
        make_solver(task.config.config).solve(problem, guess=guess)
        _WARM.add(task.warm_key)
    except Exception as exc:  # noqa: BLE001 - the measured solve decides the task's status
        out["warmup_error"] = f"{type(exc).__name__}: {exc}"[:300]
    out["warmup_s"] = time.perf_counter() - t0
    reset_clock()  # the time limit of the measured solve starts now
    return out


def solve_case(task: Task) -> dict:
    """Build ``task``'s problem and start, solve it with its configuration; the measurements as
    a dict of plain values, with ``warm``: whether this process had solved the configuration's
    problem family before the measured solve started (by a warm-up or an earlier task), i.e.
    whether its time is free of imports and compilation. Runs in a worker process; never raises
    for a problem's or solver's exception (recorded with status ``exception`` or
    ``memory_limit`` and the message)."""
    from olado.config import make_solver

    t0 = time.perf_counter()
    warm = {"warmup_s": None, "warmup_N": None}
    try:
        warm = _warm_up(task)
        warm["warm"] = task.warm_key in _WARM
        t0 = time.perf_counter()
        problem, guess = task.entry.build()
        build_s = time.perf_counter() - t0
        result = make_solver(task.config.config).solve(problem, guess=guess)
        _WARM.add(task.warm_key)
        out = _measure(result)
    except MemoryError as exc:
        out = {"status": "memory_limit", "success": False, "message": f"MemoryError: {exc}"[:500]}
        build_s = None
    except Exception as exc:  # noqa: BLE001 - recorded, the run goes on
        out = {"status": "exception", "success": False, "message": f"{type(exc).__name__}: {exc}"[:500],
               "traceback": traceback.format_exc()[-1500:]}
        build_s = None
    out.update(wall_s=time.perf_counter() - t0, build_s=build_s, **warm)
    return out


# ---------------------------------------------------------------------------- the record
def identity(task: Task) -> dict:
    """The fields that say which solve a record is: the key fields and their context."""
    entry, cfg = task.entry, task.config
    return {"problem": entry.name, "N": entry.size, "start": entry.start_label, "config": cfg.name,
            "config_hash": cfg.hash, "solver": cfg.config.solver, "factory": entry.problem, "suite": task.suite,
            "settings": _plain(entry.settings)}


def make_record(task: Task, answer) -> dict:
    """One store record: ``task``'s identity, ``answer`` (a :func:`solve_case` dict or a pool
    Failure), the time limit, olado's version and commit, the machine and the time."""
    from olado import __version__

    from .pool import Failure

    if isinstance(answer, Failure):
        answer = {"status": answer.status, "success": False, "message": answer.message, "wall_s": answer.wall_s,
                  **({"traceback": answer.traceback} if answer.traceback else {})}
    record = {"schema": SCHEMA, **identity(task)}
    defaults = dict.fromkeys(("objective", "violation", "kkt_residual", "certificate", "sqp_iterations",
                              "qp_iterations", "function_evaluations", "solve_s", "warm", "warmup_s", "warmup_N"))
    record.update(defaults)
    record.update(answer)
    limit = getattr(task.config.config.options, "max_time", None)
    record.update(time_limit=limit, olado_version=__version__, commit=olado_commit(), machine=machine(),
                  finished=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
    return _plain(record)


def record_key(record: dict) -> tuple:
    return tuple(record.get(k) for k in KEY_FIELDS)
