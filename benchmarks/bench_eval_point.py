"""Fixed per-evaluation and per-solve costs at small N: a point's values, its first derivatives
and its Hessian blocks (the evaluation a solver does at every trial point and iteration), the
certificate, and whole solves of zambezi12 with the ipm and sqp-ip presets.

    python benchmarks/bench_eval_point.py                        # this tree, one process
    python benchmarks/bench_eval_point.py --compare OLD NEW      # two source trees, alternating

``--compare`` runs this script's worker once per round in each tree (PYTHONPATH=tree), OLD and
NEW alternating, and keeps each figure's best over the rounds: process time (time.process_time),
after a warm-up solve (numba compiles or loads its cache there). The worker uses only what both
trees have (the Point of olado.solvers.sqp.state, the DOCP's eval_* methods, certify), so an old
commit can be measured with the same code. On a shared machine the figures are orders of
magnitude; iteration counts and objectives must agree exactly (the worker prints them).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _best(fn, reps, rounds=5):
    best = float("inf")
    for _ in range(rounds):
        t = time.process_time()
        for _ in range(reps):
            fn()
        best = min(best, (time.process_time() - t) / reps)
    return best


def worker(Ns, presets, solves):
    """Per-call and per-solve figures of the olado on sys.path (JSON on stdout)."""
    import numpy as np

    from olado.config import load_config, make_solver
    from olado.problems.zambezi import zambezi_problem
    from olado.solvers.certificate import CertificateSettings, certify
    from olado.solvers.sqp.state import Point

    out = {}
    for N in Ns:
        p = zambezi_problem("zambezi12", N=N, start="balance")
        solvers = {name: make_solver(load_config(HERE.parent / "configs" / f"{name}.ini")) for name in presets}
        r = solvers[presets[0]].solve(zambezi_problem("zambezi12", N=N, start="balance"))
        X, U = r.x, r.u
        lam = np.random.default_rng(0).standard_normal((N, 6))
        Lg, LgN = np.zeros((N, 0)), np.zeros(0)
        reps = max(1, 4800 // N)
        pt = Point(p, X, U, derivatives=False)

        def derivatives():
            pt.derivs = False
            pt.add_derivatives(p)

        calls = {"point values": lambda: Point(p, X, U, derivatives=False),
                 "point derivatives": derivatives,
                 "hessian blocks": lambda: (p.eval_stage_hessians(X, U, 1.0, lam, Lg), p.eval_final_hessian(X[-1], 1.0, LgN)),
                 "certificate": lambda: certify(p, X, U, r.multipliers, CertificateSettings())}
        for name, fn in calls.items():
            out[f"N={N} {name} [us]"] = _best(fn, max(1, reps // 20) if name == "certificate" else reps) * 1e6
        for name, solver in solvers.items():
            solver.solve(zambezi_problem("zambezi12", N=N, start="balance"))
            times = []
            for _ in range(solves):
                q = zambezi_problem("zambezi12", N=N, start="balance")
                t = time.process_time()
                res = solver.solve(q)
                times.append(time.process_time() - t)
            out[f"N={N} {name} solve [ms]"] = min(times) * 1e3
            out[f"N={N} {name} fingerprint"] = [res.status.value, int(res.iterations), int(res.qp_iterations),
                                                 float(res.objective)]
    json.dump(out, sys.stdout)


def compare(old, new, rounds, args):
    best = {}
    for _ in range(rounds):
        for tag, tree in (("old", old), ("new", new)):
            env = dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--N", *map(str, args.N),
                   "--presets", *args.presets, "--solves", str(args.solves)]
            res = json.loads(subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout)
            for key, val in res.items():
                slot = best.setdefault(key, {})
                if isinstance(val, list):
                    slot[tag] = val
                else:
                    slot[tag] = min(slot.get(tag, float("inf")), val)
    print(f"{'figure':<40} {'old':>12} {'new':>12} {'new/old':>8}")
    for key, slot in best.items():
        o, n = slot.get("old"), slot.get("new")
        if isinstance(o, list):
            print(f"{key:<40} {'same' if o == n else f'DIFFERENT {o} {n}'}")
        else:
            print(f"{key:<40} {o:12.1f} {n:12.1f} {n / o:8.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), help="two source trees, alternating rounds")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--N", type=int, nargs="+", default=[24, 1200])
    ap.add_argument("--presets", nargs="+", default=["ipm", "sqp-ip"])
    ap.add_argument("--solves", type=int, default=7, help="timed solves per preset and N (the best is kept)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args.N, args.presets, args.solves)
    elif args.compare:
        compare(*args.compare, args.rounds, args)
    else:
        worker(args.N, args.presets, args.solves)
        print()


if __name__ == "__main__":
    main()
