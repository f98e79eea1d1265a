"""Large horizons: the 'zambezi' family (ZAMB2 data, inflow record repeated cyclically past 1965)
at N = 1 200, 12 000 and 120 000 with SQP-IP, and IPOPT where it finishes within --ipopt-limit
seconds. Both from the balance start, side by side in one run.

    python benchmarks/bench_large.py                       # writes RESULTS.md
    python benchmarks/bench_large.py --N 1200 --no-write
"""

from __future__ import annotations

import argparse
import datetime
import time

from _common import HERE, machine, write_section

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem

SECTION = "Large horizons (zambezi, N = 1 200 to 120 000)"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="*", default=[1200, 12000, 120000])
    ap.add_argument("--ipopt-limit", type=float, default=600.0, help="wall-time limit of each solve (s), both solvers")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    sqp = make_solver(load_config(HERE.parent / "configs" / "sqp-ip.ini", overrides=[f"sqp.max_time={args.ipopt_limit}"]))
    ipopt = make_solver(load_config(HERE.parent / "configs" / "ipopt.ini", overrides=[f"ipopt.max_time={args.ipopt_limit}"]))
    for s in (sqp, ipopt):
        s.solve(zambezi_problem("zambezi", N=12))   # warm-up
    rows = []
    for N in args.N:
        t = time.perf_counter()
        p = zambezi_problem("zambezi", N=N)
        build = time.perf_counter() - t
        a = sqp.solve(p)
        print(f"N={N}: SQP-IP {a.status.value} it={a.iterations} qp={a.qp_iterations} J={a.objective:.10g} "
              f"{a.time_s:.2f}s", flush=True)
        b = ipopt.solve(zambezi_problem("zambezi", N=N))
        print(f"N={N}: IPOPT  {b.status.value} it={b.iterations} J={b.objective:.10g} {b.time_s:.2f}s", flush=True)
        rows.append((N, p, build, a, b))
    if args.no_write:
        return
    lines = [f"## {SECTION}", "",
             "Command: `python benchmarks/bench_large.py`  ",
             f"Date: {datetime.date.today().isoformat()}  ",
             f"Machine: {machine()}", "",
             "Family `zambezi` (ZAMB2.SIF parameters, from January 1931; past December 1965 the 1930-1965 inflow "
             "record repeats, `extend=\"cyclic\"`), balance start. SQP-IP = configs/sqp-ip.ini, IPOPT = "
             f"configs/ipopt.ini, each with a wall-time limit of {args.ipopt_limit:g} s. One solve each, in one run.", "",
             "| N | variables | SQP-IP status | iter | QP iter | SQP-IP time (s) | IPOPT status | IPOPT iter | IPOPT time (s) "
             "| ratio SQP-IP/IPOPT | rel. obj | problem build (s) |",
             "|---:|---:|:--|---:|---:|---:|:--|---:|---:|---:|---:|---:|"]
    for N, p, build, a, b in rows:
        rel = (a.objective - b.objective) / abs(b.objective) if b.success else float("nan")
        ratio = f"{a.time_s / b.time_s:.2f}" if b.success else "-"
        lines.append(f"| {N} | {N * (p.n + p.m) + p.n} | {a.status.value} | {a.iterations} | {a.qp_iterations} | {a.time_s:.2f} "
                     f"| {b.status.value} | {b.iterations} | {b.time_s:.2f} | {ratio} | {rel:+.1e} | {build:.2f} |")
    lines.append("")
    write_section(SECTION, "\n".join(lines))


if __name__ == "__main__":
    main()
