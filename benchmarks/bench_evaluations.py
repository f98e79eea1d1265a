"""Evaluation cost per callback: zambezi12's eval_* methods and the NLP-view callbacks.

For each horizon N the script times (µs per call, median of many calls):

* every ``eval_*`` method of the DOCP layer (validated, counted; what any solver calls), and
* the five callbacks of the NLP view (``StructuredNLP.objective``, ``gradient``,
  ``constraints``, ``jacobian``, ``hessian``; what IPOPT calls), each at a fresh point, and
  one "IPOPT iteration": the five callbacks in IPOPT's order at one new point, per callback.

The points cycle through a set of distinct trajectories, so no call is answered from a cache
holding the previous point: the figures are the cost of a real evaluation.

    python benchmarks/bench_evaluations.py                # N = 12, 252, 12000
    python benchmarks/bench_evaluations.py --N 12 120000
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from olado.problems.nlp import StructuredNLP  # noqa: E402
from olado.problems.zambezi import zambezi_problem  # noqa: E402

N_POINTS = 8


def _median_us(fn, args_list, min_time=0.2, min_calls=20):
    """Median wall time in µs of fn(*args), cycling through args_list."""
    fn(*args_list[0])                                      # warm-up
    times = []
    t_end = time.perf_counter() + min_time
    i = 0
    while i < min_calls or time.perf_counter() < t_end:
        args = args_list[i % len(args_list)]
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
        i += 1
    return 1e6 * statistics.median(times)


def points(problem, count=N_POINTS, seed=0):
    """Distinct (X, U, P) near the balance start: simulated states, perturbed controls."""
    rng = np.random.default_rng(seed)
    U0 = problem.initial_guess()
    out = []
    for _ in range(count):
        U = U0 * (1.0 + 0.01 * rng.standard_normal(U0.shape))
        U = np.clip(U, problem.u_lower, problem.u_upper)
        X = problem.simulate(U)
        P = rng.standard_normal((problem.N, problem.n))
        out.append((X, U, P))
    return out


def bench(N, family="zambezi12"):
    p = zambezi_problem(family, N=N)
    pts = points(p)
    XU = [(X, U) for X, U, _ in pts]
    rows = {}
    rows["eval_dynamics"] = _median_us(p.eval_dynamics, XU)
    rows["eval_stage_costs"] = _median_us(p.eval_stage_costs, XU)
    rows["eval_final_cost"] = _median_us(p.eval_final_cost, [(X[-1],) for X, _ in XU])
    rows["eval_dynamics_jacobians"] = _median_us(p.eval_dynamics_jacobians, XU)
    rows["eval_stage_cost_gradients"] = _median_us(p.eval_stage_cost_gradients, XU)
    rows["eval_final_cost_gradient"] = _median_us(p.eval_final_cost_gradient, [(X[-1],) for X, _ in XU])
    rows["eval_stage_hessians"] = _median_us(p.eval_stage_hessians, [(X, U, 1.0, P) for X, U, P in pts])
    rows["eval_final_hessian"] = _median_us(p.eval_final_hessian, [(X[-1], 1.0) for X, _ in XU])
    rows["objective (DOCP)"] = _median_us(p.objective, XU)

    nlp = StructuredNLP(p)
    rng = np.random.default_rng(1)
    ys = [nlp.pack(X, U) for X, U, _ in pts]
    lams = [rng.standard_normal(nlp.n_cons) for _ in ys]
    rows["nlp.objective"] = _median_us(nlp.objective, [(y,) for y in ys])
    rows["nlp.gradient"] = _median_us(nlp.gradient, [(y,) for y in ys])
    rows["nlp.constraints"] = _median_us(nlp.constraints, [(y,) for y in ys])
    rows["nlp.jacobian"] = _median_us(nlp.jacobian, [(y,) for y in ys])
    rows["nlp.hessian"] = _median_us(nlp.hessian, [(y, lam, 1.0) for y, lam in zip(ys, lams)])

    def iteration(y, lam):
        # IPOPT's order at a new iterate: f, c (line search), then grad f, Jc, Hessian
        nlp.objective(y)
        nlp.constraints(y)
        nlp.gradient(y)
        nlp.jacobian(y)
        nlp.hessian(y, lam, 1.0)

    rows["ipopt iteration / 5"] = _median_us(iteration, list(zip(ys, lams))) / 5.0
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="*", default=[12, 252, 12000])
    ap.add_argument("--family", default="zambezi12")
    args = ap.parse_args(argv)
    results = {N: bench(N, args.family) for N in args.N}
    names = list(next(iter(results.values())))
    head = "| call | " + " | ".join(f"N={N} (µs)" for N in args.N) + " |"
    print(head)
    print("|:--|" + "---:|" * len(args.N))
    for nm in names:
        print(f"| {nm} | " + " | ".join(f"{results[N][nm]:.1f}" for N in args.N) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
