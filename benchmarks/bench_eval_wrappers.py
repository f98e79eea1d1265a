"""Per-call cost of the evaluation layer every solver calls per iteration, against its compiled
kernels: zambezi12's ``eval_values``, ``eval_first_derivatives``, ``eval_stage_hessians``,
``eval_final_hessian``, the solvers' ``Point`` (values; values and first derivatives) and the
bare kernel calls they wrap (the kernels' argument lists as the entry points pass them).

    python benchmarks/bench_eval_wrappers.py --N 24                   # this tree
    python benchmarks/bench_eval_wrappers.py --compare OLD NEW --N 24  # two trees, alternating

``--compare`` runs the worker once per round in each tree (PYTHONPATH=tree), OLD and NEW
alternating, and keeps each figure's best: process time per call (time.process_time) over
``--reps`` calls, best of 7 repetitions, after a warm-up. On a shared machine the figures are
orders of magnitude. At long horizons a fresh output array of several MB is page-faulted on
every call until malloc's mmap threshold has risen (after the first large frees, as in a solve):
the entry points then look several ms dearer than their kernels here, not inside a solve
(bench_eval_point.py measures after a solve). Compare the trees at the same N.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from _timing import best_per_call


def worker(N, reps):
    """Per-call figures (us) of the olado on sys.path, JSON on stdout."""
    import numpy as np

    from olado.problems import zambezi as z
    from olado.solvers.sqp.state import Clock, Point

    p = z.zambezi_problem("zambezi12", N=N)
    U = p.initial_guess()
    X = p.simulate(U)
    P = np.random.default_rng(0).standard_normal((N, 6))
    L, LN = np.zeros((N, 0)), np.zeros(0)
    clock = Clock()
    x, xN = X[:-1], X[-1]
    f, cost = np.empty((N, 6)), np.empty(N)
    gx, gu, fx, fu, gN = np.empty((N, 6)), np.empty((N, 7)), np.empty((N, 6, 6)), np.empty((N, 6, 7)), np.zeros(6)
    hxx, hxu, huu, sig, H = np.empty((N, 6, 6)), np.empty((N, 6, 7)), np.empty((N, 7, 7)), np.ones(N), np.zeros((6, 6))
    data = (p.inflow, p.evaporation, p.fa, p.fh, p.alpha, p.psi)
    tail = (p.u_ref, p.V_ref, p.phi, p.fe, p.nu_E)
    calls = {
        "eval_values": lambda: p.eval_values(X, U),
        "  _values_kernel": lambda: z._values_kernel(p._K, x, U, xN, *data, *tail, f, cost),
        "eval_first_derivatives": lambda: p.eval_first_derivatives(X, U),
        "  _derivatives_kernel": lambda: z._derivatives_kernel(p._K, x, U, xN, *data, *tail, z._LX, z._LU,
                                                               gx, gu, fx, fu, gN),
        "eval_stage_hessians": lambda: p.eval_stage_hessians(X, U, 1.0, P, L),
        "  _stage_hessian_kernel": lambda: z._stage_hessian_kernel(p._K, x, U, *data, sig, P, z._LX, z._LU, z._JCOLS,
                                                                   hxx, hxu, huu),
        "eval_final_hessian": lambda: p.eval_final_hessian(xN, 1.0, LN),
        "  _final_hessian_kernel": lambda: z._final_hessian_kernel(1.0, p.phi, p.fe, p.nu_E, H),
        "Point (values)": lambda: Point(p, X, U, derivatives=False, clock=clock),
        "Point (values, derivatives)": lambda: Point(p, X, U, derivatives=True, clock=clock),
    }
    json.dump({name: best_per_call(fn, reps) * 1e6 for name, fn in calls.items()}, sys.stdout)


def compare(old, new, rounds, N, reps):
    best = {}
    for _ in range(rounds):
        for tag, tree in (("old", old), ("new", new)):
            env = dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--N", str(N), "--reps", str(reps)]
            res = json.loads(subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout)
            for key, val in res.items():
                slot = best.setdefault(key, {})
                slot[tag] = min(slot.get(tag, float("inf")), val)
    print(f"N = {N}: us per call, best of {rounds} rounds")
    print(f"{'call':<30} {'old':>9} {'new':>9} {'new/old':>8}")
    for key, slot in best.items():
        print(f"{key:<30} {slot['old']:9.2f} {slot['new']:9.2f} {slot['new'] / slot['old']:8.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), help="two source trees, alternating rounds")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--N", type=int, default=24)
    ap.add_argument("--reps", type=int, default=0, help="calls per repetition (default 48000 // N, at least 5)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    reps = args.reps or max(5, 48000 // args.N)
    if args.compare:
        compare(*args.compare, args.rounds, args.N, reps)
    else:
        worker(args.N, reps)
        print()


if __name__ == "__main__":
    main()
