"""The ipm loop's own time at small N: process time per solve and per iteration of the ipm preset
on Zambezi, and the part outside the problem's evaluations (the loop's own work: the solver's
Python, its compiled passes, the Riccati kernels), in alternating rounds over source trees.

    PYTHONPATH=. python benchmarks/bench_ipm_loop.py --trees /path/to/old/tree . --rounds 3

Every (round, tree, size) runs in a fresh process with PYTHONPATH set to the tree: warm-up solve
(compilation), then ``--solves`` solves, best process time kept (time.process_time). "loop own"
is the time of the iterations minus the problem evaluations made in them (values, derivatives,
Hessians: wrapped and timed); the solve's set-up, Result and certificate are outside the
iterations. Figures: benchmarks/RESULTS.md "ipm loop: compiled passes".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

SIZES = [("zambezi12", 24, 40), ("zambezi12", 120, 20), ("zambezi12", 252, 10), ("zambezi", 1200, 4)]

_CHILD = r"""
import functools, json, sys, time
from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.solvers.sqp import state
import olado.solvers.ipm.solver as S
name, N, solves = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
pc = time.process_time
acc = {}
def wrap(obj, attr, label):
    f = getattr(obj, attr)
    @functools.wraps(f)
    def w(*a, **k):
        t = pc()
        try:
            return f(*a, **k)
        finally:
            acc[label] = acc.get(label, 0.0) + pc() - t
    setattr(obj, attr, w)
wrap(state.Point, "__init__", "eval"); wrap(state.Point, "add_derivatives", "eval"); wrap(S, "iterate", "iterate")
solver = make_solver(load_config("configs/ipm.ini"))
solver.solve(zambezi_problem(name, N=N, start="balance"))
rows = []
for _ in range(solves):
    p = zambezi_problem(name, N=N, start="balance")
    for attr in ("eval_stage_hessians", "eval_final_hessian"):
        f = getattr(p, attr)
        def w(*a, _f=f, **k):
            t = pc(); r = _f(*a, **k); acc["eval"] = acc.get("eval", 0.0) + pc() - t; return r
        setattr(p, attr, w)
    acc.clear()
    t = pc(); r = solver.solve(p); total = pc() - t
    rows.append((total, acc.get("iterate", 0.0) - acc.get("eval", 0.0)))
print(json.dumps({"status": str(r.status), "iterations": r.iterations, "objective": r.objective,
                  "solve_s": min(x[0] for x in rows), "loop_own_s": min(x[1] for x in rows)}))
"""


def run(tree, name, N, solves):
    env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
    out = subprocess.run([sys.executable, "-c", _CHILD, name, str(N), str(solves)], cwd=tree, env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trees", nargs="+", default=["."], help="source trees (each run with PYTHONPATH=tree)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--sizes", nargs="*", type=int, help="only these N")
    a = ap.parse_args()
    best = {}
    for r in range(a.rounds):
        for name, N, solves in SIZES:
            if a.sizes and N not in a.sizes:
                continue
            for tree in a.trees:
                res = run(tree, name, N, solves)
                key = (tree, name, N)
                old = best.get(key)
                if old is not None and (old["iterations"], old["objective"]) != (res["iterations"], res["objective"]):
                    raise SystemExit(f"{key}: the iterates changed between rounds")
                for f in ("solve_s", "loop_own_s"):
                    res[f] = min(res[f], old[f]) if old else res[f]
                best[key] = res
                print(f"round {r + 1} {tree} {name} N={N}: {res['solve_s'] * 1e3:.3f} ms", flush=True)
    print("\n| tree | problem | N | iterations | objective | ms per solve | us per iteration | loop own, us per it |")
    print("|:--|:--|--:|--:|--:|--:|--:|--:|")
    for (tree, name, N), res in best.items():
        it = res["iterations"]
        print(f"| {tree} | {name} | {N} | {it} | {res['objective']:.12g} | {res['solve_s'] * 1e3:.2f} | "
              f"{res['solve_s'] / it * 1e6:.0f} | {res['loop_own_s'] / it * 1e6:.0f} |")


if __name__ == "__main__":
    main()
