"""The simple-bounds versions of Powell's and Schittkowski's SQP (paper 001 sec. 2.2; presets
``configs/sqp-bounds.ini`` and ``configs/sqp-schittkowski-bounds.ini``, QP method ``qp = bounds``,
olado.qp.bounds) against the same SQPs with the Mehrotra interior-point QP (``sqp-ip.ini``,
``sqp-schittkowski.ini``) on bounds-only problems at several horizons, with IPOPT's objective
(``configs/ipopt.ini``) as the reference.

Per problem and N the four presets run side by side, alternating (the order rotates every
round), each solve the best of --repeats after a warm-up; the machine is shared, so times compare
within a row. For the bounds presets the share of QPs the active-set iteration solved itself
(the rest went to its interior-point fallback) is counted.

    python benchmarks/bench_bounds.py                    # all cases, writes RESULTS.md
    python benchmarks/bench_bounds.py --cases vanderpol-box:100 --repeats 1 --no-write
"""

from __future__ import annotations

import argparse
import datetime
import os

from _common import HERE, commit, machine, write_section

from olado.config import load_config, make_solver
from olado.problems import PROBLEMS
from olado.qp.bounds import PrimalDualActiveSetQP

SECTION = "Simple-bounds SQP (qp = bounds: Powell's and Schittkowski's SQP for bounds-only problems)"
PAIRS = (("sqp-bounds", "sqp-ip"), ("sqp-schittkowski-bounds", "sqp-schittkowski"))
CASES = ["lq-box:50", "lq-box:200", "vanderpol-box:100", "vanderpol-box:1000", "vanderpol-box:10000",
         "rayleigh-box:100", "rayleigh-box:1000", "rayleigh-box:10000", "catalyst-mixing:50", "catalyst-mixing:500",
         "batch-reactor:50", "batch-reactor:500", "lotka-fishing:60", "lotka-fishing:600", "vanderpol-path:100",
         "vanderpol-path:1000", "zambezi12:72", "zambezi12:252"]


class QPCount:
    """Counts the QPs of the simple-bounds method by who solved them (the active-set iteration or
    its fallback) while installed."""

    def __init__(self):
        self.own = self.fallback = 0
        self._real = PrimalDualActiveSetQP.solve

    def __enter__(self):
        real, count = self._real, self

        def solve(self, qp, warm_start=None, limits=None):
            res = real(self, qp, warm_start=warm_start, limits=limits)
            if res.solver == "bounds":
                count.own += 1
            else:
                count.fallback += 1
            return res

        PrimalDualActiveSetQP.solve = solve
        return self

    def __exit__(self, *exc):
        PrimalDualActiveSetQP.solve = self._real


def qp_alone(N, repeats):
    """The QP methods alone on the first SQP QP of zambezi12 at N (convexified per stage block:
    olado.solvers.sqp.solver.convex_step_qp), with its state bounds and without them (control
    bounds only), and warm-started from the solution of the same QP with a 1e-4 relative change of
    the gradient: rows (label, method, status/solver, iterations, best seconds)."""
    import time

    import numpy as np

    from olado.problems.zambezi import zambezi_problem
    from olado.qp import make_qp_solver
    from olado.qp.stageqp import StageQP
    from olado.solvers.sqp.solver import convex_step_qp

    def replace(qp, **kw):
        import dataclasses
        return StageQP(**{**{f.name: getattr(qp, f.name) for f in dataclasses.fields(qp)}, **kw})

    base = convex_step_qp(zambezi_problem("zambezi12", N=N))
    rows = []
    for label, qp in (("state and control bounds", base),
                      ("control bounds only", replace(base, x_lower=None, x_upper=None))):
        near = replace(qp, q=qp.q * (1 + 1e-4), r=qp.r * (1 + 1e-4))
        for method, kw in (("mehrotra", {}), ("bounds", {}), ("bounds", {"state_bounds": "active-set"})):
            s = make_qp_solver(method, tol=1e-9, **kw)
            tag = method + ("" if not kw else " (state_bounds = active-set)")
            for start in ("cold", "warm"):
                best = np.inf
                for _ in range(repeats):
                    warm = s.solve(qp) if start == "warm" else None
                    t = time.perf_counter()
                    r = s.solve(near, warm_start=warm)
                    best = min(best, time.perf_counter() - t)
                rows.append((label, f"{tag}, {start}", f"{r.status.value} ({r.solver})", r.iterations, best))
    return rows


def make(name, N):
    kw = {"N": N}
    if name.startswith("zambezi"):
        kw["start"] = "sif"
    return PROBLEMS[name](**kw)


def run_case(name, N, solvers, repeats):
    """{preset: (best result, (own, fallback) QP counts)} and IPOPT's result."""
    ipopt = solvers["ipopt"].solve(make(name, N))
    presets = [p for pair in PAIRS for p in pair]
    best, counts = {}, {}
    for rnd in range(repeats):
        order = presets[rnd % len(presets):] + presets[:rnd % len(presets)]
        for p in order:
            with QPCount() as c:
                r = solvers[p].solve(make(name, N))
            if p not in best or r.time_s < best[p].time_s:
                best[p] = r
            counts[p] = (c.own, c.fallback)
    return {p: (best[p], counts[p]) for p in presets}, ipopt


def rel(r, ref):
    return (r.objective - ref.objective) / max(1.0, abs(ref.objective))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=CASES, help="problem:N pairs")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--qp-N", type=int, default=1200, help="horizon of the QP-alone comparison (zambezi12's QP)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    names = [p for pair in PAIRS for p in pair] + ["ipopt"]
    solvers = {p: make_solver(load_config(HERE.parent / "configs" / f"{p}.ini")) for p in names}
    for p in names:                                   # warm-up: imports, numba caches
        solvers[p].solve(make("vanderpol-box", 50))
        solvers[p].solve(make("zambezi12", 24))
    qp_rows = qp_alone(args.qp_N, args.repeats)
    for row in qp_rows:
        print("QP alone, N = %d: %s | %s | %s | %d it | %.4f s" % (args.qp_N, *row), flush=True)
    rows = []
    for case in args.cases:
        name, N = case.split(":")
        res, ipopt = run_case(name, int(N), solvers, args.repeats)
        rows.append((name, int(N), res, ipopt))
        line = f"{name} N={N} ipopt {ipopt.status.value} {ipopt.objective:.10g} {ipopt.time_s:.2f}s"
        for p, (r, (own, fb)) in res.items():
            line += (f" | {p} {r.status.value} {r.iterations}/{r.qp_iterations} {r.time_s:.3f}s "
                     f"rel {rel(r, ipopt):+.1e}" + (f" own {own}/{own + fb}" if own + fb else ""))
        print(line, flush=True)
    load1 = os.getloadavg()
    if args.no_write:
        return
    write_section(SECTION, report(rows, qp_rows, args, load0, load1))


def report(rows, qp_rows, args, load0, load1):
    lines = [f"## {SECTION}", "",
             "Command: `python benchmarks/bench_bounds.py`  ",
             f"Date: {datetime.date.today().isoformat()}, commit {commit()}  ",
             f"Machine: {machine()}; load average (1 min) {load0[0]:.1f} at the start, {load1[0]:.1f} at the end "
             "(the machine is shared with other jobs: times compare within a row -- the presets run alternately, "
             f"order rotating, best of {args.repeats} -- not across runs)", "",
             "`qp = bounds` (olado.qp.bounds, docs/structure-exploiting-sqp.md \"Simple bounds only\"): the "
             "primal-dual active-set iteration on the bounds, each iteration one plain Riccati factorization with "
             "the fixed controls eliminated; QPs that bound states (state_bounds = 'interior-point'), general rows "
             "(the elastic QP), a nonconvex working set or a cycle go to Mehrotra's method. `B` = the bounds "
             "preset, `IP` = the same SQP with the Mehrotra QP; it/qp = SQP iterations / QP iterations "
             "(factorizations of the active-set iteration plus its fallback's interior-point iterations; "
             "interior-point iterations for IP); own = QPs the active-set iteration solved itself / all QPs; "
             "rel = (J - J_IPOPT) / max(1, |J_IPOPT|); ratio = time B / time IP (below 1: the bounds preset is "
             "faster). Problems built with their defaults and N (zambezi12 from the SIF start (45)).", ""]
    for (b, ip), label in zip(PAIRS, ("Powell's SQP (l1 merit, watchdog)", "Schittkowski's SQP (augmented "
                                                                            "Lagrangian merit)")):
        lines += [f"**{label}: `{b}.ini` vs `{ip}.ini`**", "",
                  "| problem | N | IPOPT J | IPOPT (s) | B status | B it/qp | B own | B (s) | B rel | IP status "
                  "| IP it/qp | IP (s) | IP rel | ratio |",
                  "|---|---:|---:|---:|---|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
        for name, N, res, ipopt in rows:
            rb, (own, fb) = res[b]
            ri, _ = res[ip]
            lines.append(f"| {name} | {N} | {ipopt.objective:.9g}{'' if ipopt.success else ' (' + ipopt.status.value + ')'}"
                         f" | {ipopt.time_s:.3f} | {rb.status.value} | {rb.iterations}/{rb.qp_iterations} "
                         f"| {own}/{own + fb} | {rb.time_s:.3f} | {rel(rb, ipopt):+.1e} | {ri.status.value} "
                         f"| {ri.iterations}/{ri.qp_iterations} | {ri.time_s:.3f} | {rel(ri, ipopt):+.1e} "
                         f"| {rb.time_s / ri.time_s:.2f} |")
        lines.append("")
    lines += [f"**The QP methods alone** on the first SQP QP of zambezi12 at N = {args.qp_N} (convexified per stage "
              "block: `convex_step_qp`), with its state bounds and with the control bounds only; cold, and warm-started "
              "from the solution of the same QP before a 1e-4 relative change of its gradient (the situation of the "
              f"SQP's later iterations); best of {args.repeats}. Iterations: interior-point iterations (mehrotra), "
              "Riccati factorizations (+ the fallback's iterations) for bounds.", "",
              "| QP | method, start | status (solved by) | iterations | time (s) |", "|---|---|---|---:|---:|"]
    lines += [f"| {a} | {b} | {c} | {d} | {e:.4f} |" for a, b, c, d, e in qp_rows]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
