"""Process time of ipm's solve and of its iterations at small N (issue 16: zambezi12 N = 24).

Per solve (``solver.solve``, the certificate included) and per iteration (the time spent in
``olado.solvers.ipm.solver.iterate`` divided by the iterations: the loop without the start, the
result and the certificate), best of ``--solves`` solves after a warm-up. For a before/after
comparison run it alternately with PYTHONPATH set to each tree:

    PYTHONPATH=<tree> python benchmarks/bench_ipm_iteration.py --N 24 --solves 40

``--paths`` times the compiled common iteration (olado.solvers.ipm.compiled) against the Python
path in one process, in alternating rounds, and checks that both give the same Result:

    python benchmarks/bench_ipm_iteration.py --paths --N 24 120 252 --solves 15 --rounds 2
"""

from __future__ import annotations

import argparse
import time

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="+", default=[24], help="horizons of zambezi12")
    ap.add_argument("--paths", action="store_true", help="compiled iteration against the Python path")
    ap.add_argument("--rounds", type=int, default=2, help="alternating rounds of --paths")
    ap.add_argument("--solves", type=int, default=40, help="timed solves (best reported)")
    ap.add_argument("--config", default="configs/ipm.ini")
    args = ap.parse_args()

    import olado.solvers.ipm.solver as S

    if args.paths:
        return compare_paths(S, args)
    spent = [0.0]
    iterate = S.iterate

    def timed(setup, st):
        t0 = time.process_time()
        try:
            return iterate(setup, st)
        finally:
            spent[0] += time.process_time() - t0

    S.iterate = timed
    solver = make_solver(load_config(args.config))
    N = args.N[0]
    for _ in range(3):
        solver.solve(zambezi_problem("zambezi12", N=N, start="balance"))
    solves, loops = [], []
    for _ in range(args.solves):
        problem = zambezi_problem("zambezi12", N=N, start="balance")
        spent[0] = 0.0
        t0 = time.process_time()
        result = solver.solve(problem)
        solves.append(time.process_time() - t0)
        loops.append(spent[0])
    its = result.iterations
    print(f"N = {N}: {result.status.value}, {its} iterations, objective {result.objective:.12g}; "
          f"per solve best {min(solves) * 1e3:.3f} ms (median {sorted(solves)[len(solves) // 2] * 1e3:.3f}); "
          f"iterations best {min(loops) * 1e3:.3f} ms = {min(loops) / its * 1e6:.1f} us per iteration")


def compare_paths(S, args):
    """Per solve, best of ``--solves``, Python path then compiled path, ``--rounds`` times per N."""
    import numpy as np  # noqa: PLC0415

    compiled = S.plain_path
    solver = make_solver(load_config(args.config))

    def run(plain, N):
        S.plain_path = compiled if plain else (lambda setup: None)
        solver.solve(zambezi_problem("zambezi12", N=N, start="balance"))      # warm-up
        best, result = float("inf"), None
        for _ in range(args.solves):
            problem = zambezi_problem("zambezi12", N=N, start="balance")
            t0 = time.process_time()
            result = solver.solve(problem)
            best = min(best, time.process_time() - t0)
        return best, result

    print("| zambezi12 N | iterations | Python path (ms) | compiled (ms) | ratio | same Result |")
    print("|--:|--:|--:|--:|--:|:--|")
    for N in args.N:
        for _ in range(args.rounds):
            (tp, rp), (tc, rc) = run(False, N), run(True, N)
            same = (rp.iterations == rc.iterations and rp.objective == rc.objective and np.array_equal(rp.x, rc.x)
                    and np.array_equal(rp.u, rc.u) and rp.history == rc.history and rp.evaluations == rc.evaluations)
            print(f"| {N} | {rc.iterations} | {tp * 1e3:.2f} | {tc * 1e3:.2f} | {tc / tp:.2f} | {'yes' if same else 'NO'} |")
    S.plain_path = compiled


if __name__ == "__main__":
    main()
