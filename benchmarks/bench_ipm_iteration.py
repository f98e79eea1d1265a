"""Process time of ipm's solve and of its iterations at small N (issue 16: zambezi12 N = 24).

Per solve (``solver.solve``, the certificate included) and per iteration (the time spent in
``olado.solvers.ipm.solver.iterate`` divided by the iterations: the loop without the start, the
result and the certificate), best of ``--solves`` solves after a warm-up. For a before/after
comparison run it alternately with PYTHONPATH set to each tree:

    PYTHONPATH=<tree> python benchmarks/bench_ipm_iteration.py --N 24 --solves 40
"""

from __future__ import annotations

import argparse
import time

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, default=24, help="horizon of zambezi12")
    ap.add_argument("--solves", type=int, default=40, help="timed solves (best reported)")
    ap.add_argument("--config", default="configs/ipm.ini")
    args = ap.parse_args()

    import olado.solvers.ipm.solver as S

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
    for _ in range(3):
        solver.solve(zambezi_problem("zambezi12", N=args.N, start="balance"))
    solves, loops = [], []
    for _ in range(args.solves):
        problem = zambezi_problem("zambezi12", N=args.N, start="balance")
        spent[0] = 0.0
        t0 = time.process_time()
        result = solver.solve(problem)
        solves.append(time.process_time() - t0)
        loops.append(spent[0])
    its = result.iterations
    print(f"N = {args.N}: {result.status.value}, {its} iterations, objective {result.objective:.12g}; "
          f"per solve best {min(solves) * 1e3:.3f} ms (median {sorted(solves)[len(solves) // 2] * 1e3:.3f}); "
          f"iterations best {min(loops) * 1e3:.3f} ms = {min(loops) / its * 1e6:.1f} us per iteration")


if __name__ == "__main__":
    main()
