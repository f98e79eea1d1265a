"""Franke's interior-point QP against Mehrotra's in the SQP on paper 001 Table 1 (zambezi12,
N = 12..252): ``configs/sqp-franke.ini`` vs ``configs/sqp-ip.ini`` (identical but for ``qp``),
side by side in one run, best of --repeats solves after a warm-up: SQP iterations, QP
iterations, time, relative objective difference.

    python benchmarks/bench_franke.py                  # all 21 horizons, writes RESULTS.md
    python benchmarks/bench_franke.py --N 12 120 --no-write
"""

from __future__ import annotations

import argparse
import datetime
import os

from _common import HERE, best_of, commit, machine, write_section
from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem

SECTION = "Franke vs Mehrotra (Table 1, zambezi12, SQP-IP)"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="*", default=list(range(12, 253, 12)))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    fr, me = (make_solver(load_config(HERE.parent / "configs" / f"{c}.ini")) for c in ("sqp-franke", "sqp-ip"))
    for s in (fr, me):
        s.solve(zambezi_problem("zambezi12", N=12))
    rows = []
    for N in args.N:
        a, b = best_of(fr, N, args.repeats), best_of(me, N, args.repeats)
        rel = (a.objective - b.objective) / abs(b.objective)
        rows.append((N, a, b, rel))
        print(f"N={N:4d} Franke {a.status.value} {a.iterations}/{a.qp_iterations} {a.time_s:.3f}s | Mehrotra "
              f"{b.status.value} {b.iterations}/{b.qp_iterations} {b.time_s:.3f}s | ratio {a.time_s / b.time_s:.2f} "
              f"| rel.obj {rel:+.1e}", flush=True)
    load1 = os.getloadavg()
    if args.no_write:
        return
    lines = [f"## {SECTION}", "",
             "Command: `python benchmarks/bench_franke.py`  ",
             f"Date: {datetime.date.today().isoformat()}, commit {commit()}  ",
             f"Machine: {machine(with_ipopt=False)}; load average (1 min) {load0[0]:.1f} at the start, "
             f"{load1[0]:.1f} at the end (shared machine: compare within a row)", "",
             "Franke = `configs/sqp-franke.ini` (Franke's QP: one Newton solve per iteration, Franke's barrier rule, "
             "Wright's start, hot start with cold fallback; docs/qp-interior-point.md), Mehrotra = `configs/sqp-ip.ini`; "
             f"otherwise identical. Balance start (46)-(47), best of {args.repeats} solves after a warm-up. "
             "it/qp = SQP iterations / QP iterations; ratio = time Franke / Mehrotra; rel. obj = (J_F - J_M)/|J_M|.", "",
             "| N | Franke it/qp | Franke time (s) | Mehrotra it/qp | Mehrotra time (s) | ratio | rel. obj |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    for N, a, b, rel in rows:
        flag = "" if (a.success and b.success) else f" ({a.status.value}/{b.status.value})"
        lines.append(f"| {N} | {a.iterations}/{a.qp_iterations} | {a.time_s:.3f} | {b.iterations}/{b.qp_iterations} "
                     f"| {b.time_s:.3f} | {a.time_s / b.time_s:.2f}{flag} | {rel:+.1e} |")
    ta, tb = sum(r[1].time_s for r in rows), sum(r[2].time_s for r in rows)
    qa, qb = sum(r[1].qp_iterations for r in rows), sum(r[2].qp_iterations for r in rows)
    ia, ib = sum(r[1].iterations for r in rows), sum(r[2].iterations for r in rows)
    same = sum(abs(r[3]) <= 1e-6 for r in rows)
    lines += ["", f"Totals: Franke {ia} SQP / {qa} QP iterations, {ta:.2f} s; Mehrotra {ib} / {qb}, {tb:.2f} s "
              f"(time ratio {ta / tb:.2f}). Same objective (|rel. obj| <= 1e-6) at {same} of {len(rows)} horizons.", ""]
    write_section(SECTION, "\n".join(lines))


if __name__ == "__main__":
    main()
