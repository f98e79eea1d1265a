"""Fixed costs per solve at small N (issue 16): olado's certificate (every certify of the solve),
ipm's initial_state (its least-squares multipliers apart) and finish (its stage_kkt apart),
Solver.solve's own work outside the solver and the certificate, and the problem's construction
(outside the timed solve), in process time per solve, best of the rounds after a warm-up.

    python benchmarks/bench_fixed_cost.py --configs ipm sqp-ip --N 24 --rounds 7 --solves 40
    python benchmarks/bench_fixed_cost.py --compare OLD_TREE NEW_TREE --alternations 3

With --compare, runs itself under PYTHONPATH=OLD_TREE and NEW_TREE alternately (one process per
tree and alternation), keeps the best figure of each tree, and checks that status, iterations
and objective (float.hex) agree. Prints one JSON line per (tree, config) and a table.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import time

PIECES = ("solve", "certify", "initial_state", "lsq_multipliers", "finish", "stage_kkt", "outside", "problem")


def measure(config, N, rounds, solves):
    from olado.config import load_config, make_solver
    from olado.problems.zambezi import zambezi_problem
    from olado.solvers import base
    from olado.solvers import certificate as C

    acc = {}

    def wrap(owner, name, key):
        inner = getattr(owner, name)

        @functools.wraps(inner)
        def timed(*args, **kwargs):
            t0 = time.process_time()
            try:
                return inner(*args, **kwargs)
            finally:
                acc[key] = acc.get(key, 0.0) + time.process_time() - t0
        setattr(owner, name, timed)

    wrap(C, "_certify", "certify")
    wrap(base.Solver, "_solve_in_scale", "inner")
    if config == "ipm":
        from olado.solvers.ipm import solver as ipm
        wrap(ipm, "initial_state", "initial_state")
        wrap(ipm, "finish", "finish")
        wrap(ipm, "least_squares_multipliers", "lsq_multipliers")
        wrap(ipm, "stage_kkt", "stage_kkt")
    solver = make_solver(load_config(f"configs/{config}.ini"))
    make = lambda: zambezi_problem("zambezi12", N=N, start="balance")  # noqa: E731
    for _ in range(3):
        r = solver.solve(make())
    best = {}
    for _ in range(rounds):
        acc.clear()
        tp = ts = 0.0
        for _ in range(solves):
            t0 = time.process_time()
            p = make()
            t1 = time.process_time()
            r = solver.solve(p)
            ts += time.process_time() - t1
            tp += t1 - t0
        acc.update(problem=tp, solve=ts)
        acc["outside"] = ts - acc.get("inner", 0.0) - (acc.get("certify", 0.0) if config != "sqp-ip" else 0.0)
        if config == "ipm":     # the parts of the parts, apart
            acc["initial_state"] -= acc.get("lsq_multipliers", 0.0)
            acc["finish"] -= acc.get("stage_kkt", 0.0)
        for k, v in acc.items():
            best[k] = min(best.get(k, float("inf")), v / solves * 1e3)
    return {"config": config, "N": N, "status": str(r.status), "iterations": r.iterations,
            "objective": float(r.objective).hex(), "ms": {k: round(best[k], 4) for k in PIECES if k in best}}


def compare(old, new, args):
    best, fingerprints = {}, {}
    for _ in range(args.alternations):
        for tree in (old, new):
            env = dict(os.environ, PYTHONPATH=tree)
            cmd = [sys.executable, os.path.abspath(__file__), "--configs", *args.configs, "--N", str(args.N),
                   "--rounds", str(args.rounds), "--solves", str(args.solves)]
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True, cwd=args.cwd).stdout
            for line in out.splitlines():
                row = json.loads(line)
                key = (tree, row["config"])
                fingerprints.setdefault(row["config"], set()).add((row["status"], row["iterations"], row["objective"]))
                for k, v in row["ms"].items():
                    best.setdefault(key, {})[k] = min(best.get(key, {}).get(k, float("inf")), v)
    for cfg in args.configs:
        print(f"\n{cfg}, zambezi12 N = {args.N}: {sorted(fingerprints[cfg])}")
        print(f"| ms per solve | {os.path.basename(old.rstrip('/'))} | {os.path.basename(new.rstrip('/'))} |")
        for k in PIECES:
            if k in best.get((old, cfg), {}):
                print(f"| {k} | {best[(old, cfg)][k]:.3f} | {best[(new, cfg)].get(k, float('nan')):.3f} |")
    same = all(len(v) == 1 for v in fingerprints.values())
    print("\nsame status, iterations and objective in every run:", same)
    return 0 if same else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", nargs="+", default=["ipm", "sqp-ip"])
    ap.add_argument("--N", type=int, default=24)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--solves", type=int, default=40)
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"))
    ap.add_argument("--alternations", type=int, default=3)
    ap.add_argument("--cwd", default=os.getcwd(), help="where configs/ is (the preset files)")
    args = ap.parse_args()
    if args.compare:
        return compare(*args.compare, args)
    for cfg in args.configs:
        print(json.dumps(measure(cfg, args.N, args.rounds, args.solves)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
