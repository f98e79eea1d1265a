"""Continuous-time problems written on olado.OCP against their hand-written transcriptions
(issue 15 item 2, docs/continuous-time.md).

Two problems exist both ways:

* ``vanderpol`` -- olado.problems.testproblems.VanDerPol (hand-written (f, L) with analytic first
  and second derivatives, propagated through the RK4 stages in numpy by
  integrators.rk_step_derivatives) and the same problem as an OCP (CasADi SX through the RK4 step,
  compiled by LLVM);
* ``brachistochrone`` -- olado.problems.literature.Brachistochrone (a ContinuousDOCP: free final
  time by its parameter stage, hand-written first derivatives, Hessians by finite differences of
  them) and the same problem as an OCP (T free, ``minimum_time=True``).

Since the built-ins were rewritten on OCP (benchmarks/bench_builtins_ocp.py), VanDerPol and
Brachistochrone are OCPs themselves: this script now compares two OCP constructions, and its
RESULTS.md section stays the record of the hand-written transcriptions (at cae8e17).

For each, the script times round robin (both variants called once per round) the DOCP-level
evaluations the solvers call, ``eval_dynamics_jacobians`` and ``eval_stage_hessians`` (the
Lagrangian's stage blocks), median per stage in ns, at two horizons; the OCP's set-up is its
trace, differentiation and compilation (``setup_time``). Then both are solved by sqp-ip and
IPOPT (configs/sqp-ip.ini, configs/ipopt.ini): iterations and objective.

    python benchmarks/bench_ocp.py            # prints the tables
    python benchmarks/bench_ocp.py --write    # and writes the RESULTS.md section
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

from _common import commit, machine, write_section  # noqa: E402

import olado  # noqa: E402
from olado.problems.autodiff import cos, sin  # noqa: E402
from olado.problems.literature import Brachistochrone  # noqa: E402
from olado.problems.testproblems import VanDerPol  # noqa: E402

SECTION = "Continuous-time problems on OCP vs hand-written transcriptions"


def vanderpol_ocp(N):
    return olado.OCP(lambda t, x, u, p: [(1 - x[1] ** 2) * x[0] - x[1] + u[0], x[0]], [0.0, 1.0], controls=1, N=N,
                     T=5.0, running_cost=lambda t, x, u, p: x[0] ** 2 + x[1] ** 2 + u[0] ** 2)


def brachistochrone_ocp(N):
    return olado.OCP(lambda t, x, u, p: [x[2] * cos(u[0]), x[2] * sin(u[0]), 9.81 * sin(u[0])], [0.0, 0.0, 0.0],
                     controls=1, N=N, T=None, T_bounds=(0.01, 10.0), T_guess=1.0, minimum_time=True,
                     u_bounds=(-np.pi / 2, np.pi / 2), u_guess=np.pi / 4,
                     terminal=lambda t, x, p: [x[0] - 1.0], terminal_equalities=[0])


#: problem -> (hand-written factory, OCP factory), both of the argument "intervals"
PAIRS = {
    "vanderpol": (lambda n: VanDerPol(N=n), vanderpol_ocp),
    "brachistochrone": (lambda n: Brachistochrone(N=n + 1), brachistochrone_ocp),
}


def measure(name, intervals, rounds, seed=0):
    """({variant: {evaluation: median s per call}}, OCP set-up s, N)."""
    hand, ocp = (make(intervals) for make in PAIRS[name])
    rng = np.random.default_rng(seed)
    U = hand.initial_guess() + 0.1 * rng.standard_normal((hand.N, hand.m))
    X = hand.simulate(U)
    P, L = rng.standard_normal((hand.N, hand.n)), np.zeros((hand.N, hand.r))
    calls = {v: {"jacobians": (lambda p=p: p.eval_dynamics_jacobians(X, U)),
                 "hessians": (lambda p=p: p.eval_stage_hessians(X, U, 1.0, P, L))}
             for v, p in (("hand-written", hand), ("OCP", ocp))}
    for d in calls.values():                   # warm-up (and the OCP's compilation)
        for f in d.values():
            f()
    times = {v: {m: [] for m in d} for v, d in calls.items()}
    for _ in range(rounds):
        for m in ("jacobians", "hessians"):
            for v in calls:
                t0 = time.perf_counter()
                calls[v][m]()
                times[v][m].append(time.perf_counter() - t0)
    return {v: {m: statistics.median(s) for m, s in d.items()} for v, d in times.items()}, ocp.setup_time, hand.N


def solves(name, intervals):
    rows = []
    for variant, make in zip(("hand-written", "OCP"), PAIRS[name]):
        for config in ("sqp-ip", "ipopt"):
            r = olado.solve(make(intervals), config=str(HERE.parent / "configs" / f"{config}.ini"))
            rows.append(f"| {name} | {intervals} | {variant} | {config} | {r.status.value} | {r.iterations} | {r.objective:.12g} |")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--intervals", type=int, nargs="+", default=[50, 2000])
    ap.add_argument("--rounds", type=int, default=200)
    ap.add_argument("--write", action="store_true", help=f"write the '{SECTION}' section of RESULTS.md")
    args = ap.parse_args(argv)
    rows = ["| problem | intervals | N | evaluation | hand-written (ns/stage) | OCP (ns/stage) | hand-written / OCP | OCP set-up (s) |",
            "|:--|--:|--:|:--|--:|--:|--:|--:|"]
    for name in PAIRS:
        for n in args.intervals:
            t, setup, N = measure(name, n, args.rounds)
            for m in ("jacobians", "hessians"):
                h, o = t["hand-written"][m] / N * 1e9, t["OCP"][m] / N * 1e9
                rows.append(f"| {name} | {n} | {N} | `eval_stage_{m}` | {h:,.0f} | {o:,.0f} | {h / o:.1f}x | {setup:.2f} |"
                            .replace("eval_stage_jacobians", "eval_dynamics_jacobians"))
    timing = "\n".join(rows)
    print(timing)
    solve_rows = ["| problem | intervals | model | config | status | iterations | objective |",
                  "|:--|--:|:--|:--|:--|--:|--:|"]
    for name in PAIRS:
        solve_rows += solves(name, 50)
    solve_text = "\n".join(solve_rows)
    print(solve_text)
    if args.write:
        write_section(SECTION, f"## {SECTION}\n\nCommand: `python benchmarks/bench_ocp.py --write`  \n"
                      f"Commit: {commit()}  \nDate: {time.strftime('%Y-%m-%d')}  \nMachine: {machine()}\n\n"
                      "Median time per stage (ns) of the DOCP-level evaluations, hand-written transcription "
                      "vs the same problem written on `olado.OCP`, measured round robin in one process "
                      "(the machine was shared with other jobs: read the ratios). VanDerPol: analytic "
                      "(f, L) derivatives propagated through RK4 in numpy; Brachistochrone: a "
                      "ContinuousDOCP with finite-difference Hessians; OCP: CasADi SX through the RK4 "
                      "step, compiled by LLVM.\n\n" + timing + "\n\nThe same problems solved "
                      "(N = 50 intervals):\n\n" + solve_text + "\n")


if __name__ == "__main__":
    main()
