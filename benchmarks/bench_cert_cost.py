"""Per-solve fixed costs of a successful solve: olado's certificate (olado.solvers.certificate.certify,
every call in a solve: the SQP certifies before it stops, Solver.solve certifies the other
families' successes) and Solver.solve outside the solver's own loop (initial point, options,
result fields), in process time per solve, best of the rounds.

    python benchmarks/bench_cert_cost.py --configs ipm sqp-ip --problems zambezi12:24 zambezi:1200 --rounds 7

Prints one JSON line per (config, problem): {"certify_ms", "outside_ms", "solve_ms", "status",
"iterations", "certificates"}. Run it with PYTHONPATH on two trees alternately to compare.
"""

from __future__ import annotations

import argparse
import json
import time

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.solvers import certificate as C


def measure(config, family, N, rounds, reps):
    solver = make_solver(load_config(f"configs/{config}.ini"))
    clock = {"certify": 0.0, "inner": 0.0, "calls": 0}
    certify_inner, solve_inner = C._certify, solver._solve_in_scale

    def timed_certify(*args):
        t0 = time.process_time()
        try:
            return certify_inner(*args)
        finally:
            clock["certify"] += time.process_time() - t0
            clock["calls"] += 1

    def timed_solve(*args):
        t0 = time.process_time()
        try:
            return solve_inner(*args)
        finally:
            clock["inner"] += time.process_time() - t0

    C._certify = timed_certify
    solver._solve_in_scale = timed_solve
    try:
        solver.solve(zambezi_problem(family, N=N, start="balance"))       # warm-up (compile)
        best = None
        for _ in range(rounds):
            problems = [zambezi_problem(family, N=N, start="balance") for _ in range(reps)]
            clock.update(certify=0.0, inner=0.0, calls=0)
            t0 = time.process_time()
            for p in problems:
                r = solver.solve(p)
            total = (time.process_time() - t0) / reps
            cert = clock["certify"] / reps
            # the certificate Solver.solve adds runs outside _solve_in_scale; the SQP's inside it
            outside = total - clock["inner"] / reps - (cert if config != "sqp-ip" else 0.0)
            row = dict(solve_ms=1e3 * total, certify_ms=1e3 * cert, outside_ms=1e3 * outside)
            best = row if best is None else {k: min(best[k], row[k]) for k in row}
        best.update(status=r.status.value, iterations=r.iterations, certificates=clock["calls"] // reps)
        return best
    finally:
        C._certify = certify_inner


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", nargs="+", default=["ipm", "sqp-ip"])
    ap.add_argument("--problems", nargs="+", default=["zambezi12:24", "zambezi:1200"])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--reps", type=int, default=5)
    a = ap.parse_args()
    for c in a.configs:
        for spec in a.problems:
            fam, N = spec.split(":")
            row = measure(c, fam, int(N), a.rounds, a.reps)
            print(json.dumps(dict(config=c, problem=spec, **{k: round(v, 4) if isinstance(v, float) else v
                                                              for k, v in row.items()})), flush=True)


if __name__ == "__main__":
    main()
