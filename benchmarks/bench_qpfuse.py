"""The fused Newton solve of the interior-point QP (issue 16 item 2): time per QP iteration of
the recorded QPs of one ``sqp-ip`` solve, replayed with the fused kernel
(qp.interior_point.kernels._newton_solve_fixed: right-hand side, Riccati sweeps and recovery in
one call) and with the three kernels it replaces (newton_rhs, solve_fixed, recover_step), in
alternating rounds in one process (process time, best of the rounds), and whether both give the
same iterates (iterations, objective and the solution arrays of every QP, bit for bit); then one
Newton solve alone (_StepContext._reduced_solve, both ways in alternating rounds) at every 7th
solve of the first QPs, on the states the replay reaches (median over those samples).

    python benchmarks/bench_qpfuse.py                          # zambezi12 N = 24, zambezi N = 12 000
    python benchmarks/bench_qpfuse.py --cases zambezi:1200 --rounds 3
"""

from __future__ import annotations

import argparse
import time

from _common import commit, machine
from bench_qp_profile import _record_qps

import numpy as np

from olado.qp.interior_point import step

CASES = ["zambezi12:24", "zambezi:12000"]


class _Unfused:
    """Stands for RiccatiFactorization in step.py's test of the fused path: no factorization is
    of this type, so every Newton solve takes the three kernels."""


def _replay(calls, fused):
    """(QP iterations, process time, results) of one replay of the recorded QPs."""
    saved = step.RiccatiFactorization
    if not fused:
        step.RiccatiFactorization = _Unfused
    try:
        its, out = 0, []
        t = time.process_time()
        for qp_solver, qp, warm, options in calls:
            qp_solver.options = options
            res = qp_solver.solve(qp, warm_start=warm)
            its += res.iterations
            out.append(res)
        return its, time.process_time() - t, out
    finally:
        step.RiccatiFactorization = saved


def _solve_times(calls, n_qps=3, every=7):
    """Median process time of one Newton solve, three kernels and fused, at every ``every``-th
    solve of the first ``n_qps`` recorded QPs (each sample: best of 3 alternating rounds)."""
    orig = step._StepContext._reduced_solve
    count, acc = [0], {True: [], False: []}

    def sampled(self, res, rho_l, rho_u, out=None):
        count[0] += 1
        if count[0] % every == 3 and self._fused is not None and out is not None:
            fused, reps = self._fused, 200 if self.P.N < 1000 else 3
            best = {True: np.inf, False: np.inf}
            for _ in range(3):
                for on in (False, True):
                    self._fused = fused if on else None
                    t = time.process_time()
                    for _ in range(reps):
                        orig(self, res, rho_l, rho_u, out)
                    best[on] = min(best[on], (time.process_time() - t) / reps)
            self._fused = fused
            for on in best:
                acc[on].append(best[on])
        return orig(self, res, rho_l, rho_u, out)
    step._StepContext._reduced_solve = sampled
    try:
        for qp_solver, qp, warm, options in calls[:n_qps]:
            qp_solver.options = options
            qp_solver.solve(qp, warm_start=warm)
    finally:
        step._StepContext._reduced_solve = orig
    return len(acc[True]), float(np.median(acc[False])), float(np.median(acc[True]))


def _same(a, b):
    return all(x.iterations == y.iterations and x.objective == y.objective
               and all(np.array_equal(getattr(x, f), getattr(y, f)) for f in ("X", "U", "lam"))
               for x, y in zip(a, b))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=CASES, help="family:N")
    ap.add_argument("--rounds", type=int, default=None, help="alternating rounds (default 20 below N = 1 000, else 3)")
    args = ap.parse_args(argv)
    print(f"commit {commit()}, {machine()}")
    for case in args.cases:
        family, N = case.split(":")
        N = int(N)
        rounds = args.rounds or (20 if N < 1000 else 3)
        calls = _record_qps(family, N)
        best = {True: np.inf, False: np.inf}
        results = {}
        for _ in range(rounds):
            for fused in (False, True):
                its, t, out = _replay(calls, fused)
                best[fused] = min(best[fused], t)
                results[fused] = out
        same = _same(results[True], results[False])
        print(f"{family} N = {N}: {len(calls)} QPs, {its} QP iterations; per QP iteration (best of {rounds}): "
              f"three kernels {1e6 * best[False] / its:.1f} us, fused {1e6 * best[True] / its:.1f} us "
              f"({best[True] / best[False]:.3f}); same iterates and solutions: {same}", flush=True)
        n, three, fused = _solve_times(calls)
        print(f"{family} N = {N}: one Newton solve (median of {n} states): three kernels {1e6 * three:.1f} us, "
              f"fused {1e6 * fused:.1f} us ({fused / three:.3f})", flush=True)


if __name__ == "__main__":
    main()
