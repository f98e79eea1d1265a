"""What make_robustness_refs.py and bench_robustness.py share: solving one entry of the
robustness suite in an isolated worker process with a time limit, and classifying the outcome.

Isolation: the package's worker pool (:mod:`olado.bench.pool`, the machinery of ``olado bench``):
every solve runs in a worker process; the parent waits for at most the time limit plus a grace
period, then kills the worker and records a timeout; a worker that dies (a crash in compiled
code, an abort) is recorded as a crash. Workers are reused between solves (starting one costs
imports and numba's cache loads); the solver also gets the time limit as its own ``max_time``,
so a solver that honours it stops by itself and returns its last iterate.
"""

from __future__ import annotations

import math
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
#: extra seconds the parent waits beyond the time limit before it kills a worker
GRACE = 15.0
#: a point is feasible when its max-norm violation (verified on the NLP view) is at most this
FEAS_TOL = 1e-6
#: same objective as IPOPT: |J - J_ipopt| <= SAME_RTOL * max(|J_ipopt|, SAME_FLOOR)
SAME_RTOL, SAME_FLOOR = 1e-6, 1e-3
#: a reported success at a point whose verified KKT residual (divided by max(1, |grad J|)) exceeds
#: this is not a minimum (IPOPT's own solutions of the set verify below 1e-4)
KKT_TOL = 1e-3


def olado_commit() -> str:
    """The checkout's commit for the suite's references and runs (benchmarks/_common.commit:
    OLADO_COMMIT overrides it for a ``git archive`` copy)."""
    from _common import commit

    return commit(ROOT)


# ---------------------------------------------------------------------------- the worker side
def _solver(config_name, time_limit):
    from olado.config import load_config, make_solver

    path = CONFIGS / f"{config_name}.ini"
    cfg = load_config(path)
    if math.isfinite(time_limit):
        cfg = load_config(path, [f"{cfg.solver}.max_time={time_limit:g}"])
    return make_solver(cfg)


def solve_entry(entry_name, config_name, time_limit) -> dict:
    """Solve one suite entry with one preset; a dict of plain values (the worker's answer).
    Exceptions are caught and returned as status ``exception`` (a finding in itself: no raw
    exception should reach a user)."""
    from olado.problems.suites import load_suite, verify_point

    entry = next(e for e in load_suite("robustness") if e.name == entry_name)
    out = {"entry": entry_name, "config": config_name}
    t0 = time.perf_counter()
    try:
        problem, guess = entry.build()
        result = _solver(config_name, time_limit).solve(problem, guess=guess)
    except Exception as exc:  # noqa: BLE001 - recorded, not hidden
        out.update(status="exception", message=f"{type(exc).__name__}: {exc}"[:300],
                   traceback=traceback.format_exc()[-1500:], wall_s=time.perf_counter() - t0)
        return out
    out.update(status=result.status.value, message=(result.message or "")[:300], objective=float(result.objective),
               violation=float(result.max_constraint_violation),
               kkt=None if result.kkt_residual is None else float(result.kkt_residual),
               iterations=int(result.iterations), time_s=float(result.time_s), wall_s=time.perf_counter() - t0)
    try:
        check = verify_point(problem, result.x, result.u)
        out.update(verified_objective=check.objective, verified_violation=check.violation,
                   verified_kkt=check.kkt_residual, verified_kkt_scaled=check.kkt_residual_scaled)
    except Exception as exc:  # noqa: BLE001 - e.g. a NaN in the returned point
        out.update(verified_violation=math.inf, verify_error=f"{type(exc).__name__}: {exc}"[:200])
    if result.status.success:
        out.update(_certificate_figures(problem, result))
    return out


def _certificate_figures(problem, result) -> dict:
    """The certificate the result carries and olado's independent one from the point alone
    (least-squares multipliers: ``certify(problem, X, U, None)``), for the certificate table."""
    import numpy as np

    from olado.solvers.certificate import CertificateSettings, certify

    out = {}
    cert = result.certificate
    if cert is not None:
        out.update(certificate=cert.level, certificate_multipliers=cert.multipliers,
                   certificate_kkt=max(cert.stationarity_scaled, cert.complementarity_scaled))
    if not (np.all(np.isfinite(result.x)) and np.all(np.isfinite(result.u))):
        return out
    try:
        settings = CertificateSettings.from_options(_solver_options(result))
        indep = certify(problem, result.x, result.u, None, settings)
    except Exception as exc:  # noqa: BLE001 - recorded, not hidden
        return dict(out, independent_error=f"{type(exc).__name__}: {exc}"[:200])
    tol, viol = ((settings.tol, settings.constr_viol_tol) if result.status.value == "success"
                 else (settings.acceptable_tol, settings.acceptable_constr_viol_tol))
    err = max(indep.stationarity_scaled, indep.complementarity_scaled)
    return dict(out, independent_kkt=float(err), independent_violation=float(indep.violation),
                independent_holds=bool(err <= tol and indep.violation <= viol and not indep.gradient_check_note))


def _solver_options(result):
    """The solve's tolerances as an options object for CertificateSettings.from_options."""
    import types

    opts = result.options or {}
    fields = ("tol", "constr_viol_tol", "certificate_tol", "certificate_acceptable_tol",
              "certificate_acceptable_constr_viol_tol")
    return types.SimpleNamespace(**{k: opts[k] for k in fields if k in opts})


def call_target(task):
    """The package pool's task function: ``task`` = ("module:function", entry, config,
    time_limit) -> ``function(entry, config, time_limit)``."""
    import importlib

    target, *args = task
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)(*args)


# ---------------------------------------------------------------------------- the parent side
class IsolatedPool:
    """``jobs`` worker processes of the package's :class:`olado.bench.pool.IsolatedPool`;
    :meth:`run` yields one answer dict per task (entry, config), in completion order, with
    timeouts, crashes and exceptions recorded instead of raised. A worker answers a task by
    ``target(entry, config, time_limit)`` (default :func:`solve_entry`; a module-level function,
    as the worker imports it by name)."""

    def __init__(self, jobs=1, time_limit=60.0, target=solve_entry, grace=GRACE):
        self.jobs = max(1, int(jobs))
        self.time_limit = float(time_limit)
        self.grace = float(grace)
        self.target = f"{target.__module__}:{target.__name__}"

    def run(self, tasks):
        from olado.bench.pool import Failure, IsolatedPool as Pool

        work = [(self.target, entry, config, self.time_limit) for entry, config in tasks]
        with Pool("_robustness:call_target", jobs=self.jobs, time_limit=self.time_limit, grace=self.grace) as pool:
            for (_, entry, config, _), answer in pool.run(work):
                if isinstance(answer, Failure):
                    answer = {"entry": entry, "config": config, "status": answer.status, "message": answer.message,
                              "wall_s": answer.wall_s}
                yield answer


# ---------------------------------------------------------------------------- classification
SOLVED, OTHER, FAILED, INFEASIBLE_OK, INFEASIBLE_WRONG, FALSE_SUCCESS, UNREFERENCED = (
    "solved", "other-local-min", "failed", "infeasible-correct", "infeasible-wrong", "false-success", "solved-unreferenced")

CLASSES = {
    SOLVED: "converged at IPOPT's objective (relative 1e-6) with a verified feasible point",
    OTHER: "converged at a verified feasible and stationary point (verified KKT residual <= 1e-3, scaled) with "
           "another objective: another local minimum (or a stop close to one)",
    UNREFERENCED: "converged at a verified feasible and stationary point of an entry IPOPT did not solve",
    FAILED: "any other stop: iteration or time limit, numerical error, exception, crash, timeout",
    FALSE_SUCCESS: "reported success at a point that is not a minimum: its verified violation exceeds 1e-6, or its "
                   "verified KKT residual (scaled) exceeds 1e-3 where the objective differs from IPOPT's, or the "
                   "problem is deliberately infeasible",
    INFEASIBLE_OK: "reported infeasible on a deliberately infeasible problem",
    INFEASIBLE_WRONG: "reported infeasible on a feasible problem",
}


def _feasible(rec):
    v = rec.get("verified_violation")
    return v is not None and math.isfinite(v) and v <= FEAS_TOL


def same_objective(objective, reference) -> bool:
    return abs(objective - reference) <= SAME_RTOL * max(abs(reference), SAME_FLOOR)


def classify(rec, ref, feasible_problem) -> str:
    """The class (one of :data:`CLASSES`) of a solve record ``rec`` (from :func:`solve_entry`)
    against the IPOPT reference ``ref`` of its entry."""
    status = rec.get("status")
    success = status in ("success", "acceptable")
    if status == "infeasible":
        return INFEASIBLE_OK if not feasible_problem else INFEASIBLE_WRONG
    if not success:
        return FAILED
    if not feasible_problem or not _feasible(rec):
        return FALSE_SUCCESS
    ref_ok = ref is not None and ref.get("status") in ("success", "acceptable") and _feasible(ref)
    if ref_ok and same_objective(rec["objective"], ref["objective"]):
        return SOLVED
    kkt = rec.get("verified_kkt_scaled")
    if kkt is None or not kkt <= KKT_TOL:
        return FALSE_SUCCESS
    return OTHER if ref_ok else UNREFERENCED
