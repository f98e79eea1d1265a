"""QP subproblem: the interior-point Riccati QP against OSQP and Clarabel.

The QP is the Zambezi QP subproblem (14) of the first SQP step at the balance start, built as
tests/qp/test_interior_point.py builds it: A, B from the dynamics Jacobians, the Hessian blocks of the stage
costs (zero multipliers) shifted per stage to be positive definite (most negative eigenvalue +
1e-4), bounds shifted to the step. n = 6, m = 7, two-sided bounds on every control and on 4 of
the 6 states. N = 252 is zambezi12; larger N use the 'zambezi' family (any multiple of 12,
inflows repeated cyclically).

Side by side in one run, on the same QP:

- Mehrotra and Gondzio (olado.qp.interior_point, KKT back-end Riccati, default tol 1e-8);
- OSQP and Clarabel through olado.qp.external.ExternalQP (sparse form; OSQP eps_abs =
  eps_rel = 1e-7 with polishing, Clarabel gap and feasibility tolerances 1e-8 -- the accuracy
  of the default interior-point tolerance, checked by the KKT residuals in the table);

each solve timed as the best of several repeats after a warm-up solve (numba compilation,
imports). Every result's KKT residuals come from olado.qp.stageqp.qp_kkt_residuals
(max-norms of stationarity, primal infeasibility, complementarity), so the accuracy is measured
the same way for all solvers. For a before/after comparison run the script in two checkouts,
alternately (the interior-point QP is a package: one file of an old revision cannot be loaded
next to the current one).

    python benchmarks/bench_qp.py                          # N = 1200, 12000; print the tables
    python benchmarks/bench_qp.py --write                  # and replace the RESULTS.md section
"""

from __future__ import annotations

import argparse
import datetime
import time

import numpy as np
from _common import RESULTS, machine, write_section

from olado.qp.interior_point import GondzioQP, MehrotraQP  # noqa: E402
from olado.qp.external import ExternalQP, available_qp_backends  # noqa: E402

SECTION = "QP subproblem: interior-point Riccati QP vs OSQP and Clarabel"


def zambezi_qp(N, shift=1e-4):
    """The Zambezi step QP at the balance start (olado.solvers.sqp.convex_step_qp)."""
    from olado.problems.zambezi import zambezi_problem
    from olado.solvers.sqp.solver import convex_step_qp

    return convex_step_qp(zambezi_problem("zambezi12" if N <= 252 else "zambezi", N=N, extend="cyclic"), shift=shift)


def timed(solver, qp, repeats, budget=30.0):
    """(best wall time of ``repeats`` solves after a warm-up, last result); fewer repeats (at
    least one) when they would take more than ``budget`` seconds (OSQP at N = 12 000)."""
    t0 = time.perf_counter()
    res = solver.solve(qp)
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(max(1, min(repeats, int(budget // max(first, 1e-9))))):
        t0 = time.perf_counter()
        res = solver.solve(qp)
        best = min(best, time.perf_counter() - t0)
    return best, res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=int, nargs="+", default=[1200, 12000], help="horizons of the solver comparison")
    ap.add_argument("--iteration-N", type=int, nargs="+", default=[252, 1200, 12000],
                    help="horizons of the per-iteration table")
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats per solver at N <= 2000 (3 above; fewer "
                    "for a solver whose solves would take more than 30 s)")
    ap.add_argument("--write", action="store_true", help=f"replace the section in {RESULTS.name}")
    args = ap.parse_args(argv)

    backends = [b for b in ("osqp", "clarabel") if b in available_qp_backends()]
    ip = {"Mehrotra (Riccati)": MehrotraQP(), "Gondzio (Riccati)": GondzioQP()}
    ext = {"OSQP": ExternalQP("osqp", eps_abs=1e-7, eps_rel=1e-7, polish=True),
           "Clarabel": ExternalQP("clarabel", tol_gap_abs=1e-8, tol_gap_rel=1e-8, tol_feas=1e-8)}
    ext = {k: v for k, v in ext.items() if v.backend in backends}

    qps = {N: zambezi_qp(N) for N in sorted(set(args.N) | set(args.iteration_N))}
    reps = lambda N: args.repeats if N <= 2000 else 3  # noqa: E731

    # ---- solver comparison
    rows = []
    for N in args.N:
        qp = qps[N]
        times = {}
        for name, solver in list(ip.items()) + list(ext.items()):
            t, res = timed(solver, qp, reps(N))
            times[name] = t
            rows.append((N, name, res, t))
            print(f"N={N:6d} {name:20s} {res.status.value:10s} it={res.iterations:5d} {t:9.4f} s  "
                  f"obj={res.objective:.10g}  " + "  ".join(f"{k} {v:.1e}" for k, v in res.kkt.items()), flush=True)
        ref = times["Mehrotra (Riccati)"]
        rows[-len(times):] = [(N, name, res, t, t / ref) for (N, name, res, t) in rows[-len(times):]]
    lines = ["| N | solver | status | iterations | time (s) | time / Mehrotra | objective | stationarity | primal | "
             "complementarity |", "|---:|:--|:--|---:|---:|---:|---:|---:|---:|---:|"]
    for N, name, res, t, ratio in rows:
        k = res.kkt
        its = str(res.iterations)   # each method's own count (OSQP's ADMM, Clarabel's interior-point iterations)
        lines.append(f"| {N} | {name} | {res.status.value} | {its} | {t:.4f} | {ratio:.1f}x | "
                     f"{res.objective:.10g} | {k['stationarity']:.1e} | {k['primal']:.1e} | {k['complementarity']:.1e} |")
    table = "\n".join(lines)

    # ---- per-iteration cost of the interior-point methods
    it_lines = ["| N | method | iterations | ms per iteration | µs per stage and iteration |",
                "|---:|:--|---:|---:|---:|"]
    for N in args.iteration_N:
        qp = qps[N]
        for name, cls in (("Mehrotra", MehrotraQP), ("Gondzio", GondzioQP)):
            t, res = timed(cls(), qp, reps(N))
            per = t / res.iterations
            it_lines.append(f"| {N} | {name} | {res.iterations} | {per * 1e3:.3f} | {per / N * 1e6:.2f} |")
            print(it_lines[-1], flush=True)
    it_table = "\n".join(it_lines)
    print(table)
    print(it_table)

    if args.write:
        import numba
        import scipy

        versions = f"numpy {np.__version__}, scipy {scipy.__version__}, numba {numba.__version__}"
        try:
            import clarabel
            import osqp

            versions += f", OSQP {osqp.__version__}, Clarabel {clarabel.__version__}"
        except ImportError:
            pass
        cmd = "python benchmarks/bench_qp.py --write"
        text = f"""## {SECTION}

Command: `{cmd}`  
Date: {datetime.date.today().isoformat()}  
Machine: {machine(with_ipopt=False)}; {versions}

The Zambezi QP subproblem (first SQP step at the balance start, stage Hessians shifted to be
positive definite, as in tests/qp/test_interior_point.py; n = 6, m = 7, 14 control and 8 state bounds per
stage), N = 252 from zambezi12, larger N from the 'zambezi' family (cyclic inflows). Mehrotra and
Gondzio are olado's interior-point QP methods with the Riccati KKT back-end at the default
tol = 1e-8; OSQP (eps 1e-7, polishing) and Clarabel (tolerances 1e-8) solve the sparse form through
`ExternalQP`. KKT residuals are `qp_kkt_residuals` of each result (unscaled max-norms), so the
accuracy is compared on one measure. Times are wall times of `solve` (best of 5 repeats at
N <= 2 000, 3 above -- 1 for OSQP at N = 12 000, whose solves take ~20 s -- after a warm-up
solve, every solver alike), including each method's set-up and result assembly; the external solvers' times
include the conversion of the sparse form to their own (for Clarabel at N = 12 000 about 0.5 s of
its ~3 s). Iterations are each solver's own count (OSQP: ADMM iterations; Clarabel: its
interior-point iterations, from Clarabel itself, which `ExternalQP` calls directly).

{table}

Per interior-point iteration (time of a whole solve divided by its iterations, so the set-up,
starting point and result assembly are included):

{it_table}
"""
        write_section(SECTION, text)
        print(f"wrote section '{SECTION}' of {RESULTS}")


if __name__ == "__main__":
    main()
