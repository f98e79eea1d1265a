"""SQP-AS vs SQP-IP on zambezi12, N = 12..252 (paper 001 Table 1 and the trade-off of Figs. 7-8:
the active-set QP is faster for small horizons, the interior-point QP for large ones).

Three comparisons, side by side in one run (each solve the best of --repeats after a warm-up):

1. the presets: ``configs/sqp-as.ini`` (Powell's SQP, active-set QP warm-started from the last
   working set) against ``configs/sqp-ip.ini`` (Mehrotra QP), both with the exact Hessian and
   the inertia correction -- Goldfarb-Idnani refuses the QPs that are not strictly convex on
   their working sets, so SQP-AS follows another path (the shifted Hessian);
2. the same SQP with block SR1 Hessians (positive definite blocks: the paper's recommended
   update, and convex QPs for both methods): ``sqp-as.ini`` with ``hessian = sr1`` against
   ``configs/sqp-sr1.ini``;
3. the QP methods alone on the same QPs: every QP of the block-SR1 SQP-IP run, solved by the
   Mehrotra QP as that run did and by the active-set QP warm-started from its own previous result
   (the chain SQP-AS would take) -- total time, Mehrotra iterations vs working-set changes.

    python benchmarks/bench_sqp_as.py                      # N = 12..252, writes RESULTS.md
    python benchmarks/bench_sqp_as.py --N 12 24 --repeats 1 --no-write
"""

from __future__ import annotations

import argparse
import datetime
import os
import time

from _common import HERE, best_of, commit, machine, write_section

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.qp.active_set import GoldfarbIdnaniQP
from olado.qp.interior_point import MehrotraQP

SECTION = "SQP-AS vs SQP-IP (paper 001 Figs. 7-8, zambezi12)"
PAIRS = {"exact": (("sqp-as", []), ("sqp-ip", [])),
         "sr1": (("sqp-as", ["sqp.hessian=sr1"]), ("sqp-sr1", []))}


def solver(name, overrides):
    return make_solver(load_config(HERE.parent / "configs" / f"{name}.ini", overrides))


def captured_qps(N):
    """The QPs (and warm starts) of the block-SR1 SQP-IP run at N, in order."""
    seen = []
    real = MehrotraQP.solve

    def record(self, qp, warm_start=None):
        res = real(self, qp, warm_start)
        seen.append((qp, warm_start is not None, float(self.options.tol)))
        return res

    MehrotraQP.solve = record
    try:
        solver("sqp-sr1", []).solve(zambezi_problem("zambezi12", N=N))
    finally:
        MehrotraQP.solve = real
    return seen


def qp_chain(N, repeats):
    """(number of QPs, Mehrotra (iterations, seconds), active set (changes, seconds, failures))
    on the QPs of the SR1 SQP-IP run: Mehrotra warm-started where that run did (from its own
    previous result), the active set always from its previous result."""
    qps = captured_qps(N)
    best_ip = best_as = None
    for _ in range(repeats):
        its, t_ip, prev = 0, 0.0, None
        for qp, warm, tol in qps:
            t0 = time.perf_counter()
            r = MehrotraQP(tol=tol, max_iter=200).solve(qp, warm_start=prev if warm else None)
            t_ip += time.perf_counter() - t0
            its, prev = its + r.iterations, r
        changes, t_as, fails, prev = 0, 0.0, 0, None
        for qp, _, tol in qps:
            t0 = time.perf_counter()
            r = GoldfarbIdnaniQP(tol=tol, max_iter=20_000).solve(qp, warm_start=prev)
            t_as += time.perf_counter() - t0
            changes, fails, prev = changes + r.iterations, fails + (not r.success), r
        if best_ip is None or t_ip < best_ip[1]:
            best_ip = (its, t_ip)
        if best_as is None or t_as < best_as[1]:
            best_as = (changes, t_as, fails)
    return len(qps), best_ip, best_as


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="*", default=list(range(12, 253, 12)))
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    solvers = {key: (solver(*a), solver(*b)) for key, (a, b) in PAIRS.items()}
    for pair in solvers.values():
        for s in pair:
            s.solve(zambezi_problem("zambezi12", N=12))      # warm-up: imports, numba caches
    qp_chain(12, 1)
    rows = []
    for N in args.N:
        row = {"N": N}
        for key, (s_as, s_ip) in solvers.items():
            row[key] = (best_of(s_as, N, args.repeats), best_of(s_ip, N, args.repeats))
        row["qp"] = qp_chain(N, args.repeats)
        rows.append(row)
        line = f"N={N:4d}"
        for key in PAIRS:
            a, b = row[key]
            line += (f" | {key}: AS {a.status.value} {a.iterations}/{a.qp_iterations} {a.time_s:.3f}s, IP {b.status.value} "
                     f"{b.iterations}/{b.qp_iterations} {b.time_s:.3f}s, ratio {a.time_s / b.time_s:.2f}")
        nq, (ip_it, ip_t), (as_ch, as_t, fails) = row["qp"]
        line += f" | QPs {nq}: IP {ip_it} it {ip_t:.3f}s, AS {as_ch} ch {as_t:.3f}s ({fails} failed)"
        print(line, flush=True)
    load1 = os.getloadavg()
    if args.no_write:
        return
    lines = [f"## {SECTION}", "",
             "Command: `python benchmarks/bench_sqp_as.py`  ",
             f"Date: {datetime.date.today().isoformat()}, commit {commit()}  ",
             f"Machine: {machine(with_ipopt=False)}; load average (1 min) {load0[0]:.1f} at the start, "
             f"{load1[0]:.1f} at the end (the machine is shared: times are comparable within a row, measured side "
             f"by side, not across runs)", "",
             "SQP-AS = Powell's SQP with the active-set QP (Goldfarb-Idnani's dual method, one O(N) Riccati "
             "factorization per working-set change, warm-started from the last QP's working set; "
             "docs/qp-active-set.md); SQP-IP = the same SQP with the Mehrotra interior-point QP. Balance start "
             f"(46)-(47), best of {args.repeats} solves after a warm-up. it/qp = SQP iterations / QP iterations "
             "(working-set changes for the active set, interior-point iterations for Mehrotra); ratio = time "
             "AS / IP (below 1: the active set is faster). rel. obj = (J_AS - J_IP)/|J_IP|.", "",
             "| N | exact: AS it/qp | AS time (s) | IP it/qp | IP time (s) | ratio | rel. obj | SR1: AS it/qp "
             "| AS time (s) | IP it/qp | IP time (s) | ratio | rel. obj | QPs | Mehrotra it | Mehrotra (s) "
             "| AS changes | AS (s) | QP ratio |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for row in rows:
        cells = [str(row["N"])]
        for key in PAIRS:
            a, b = row[key]
            flag = "" if (a.success and b.success) else f" ({a.status.value}/{b.status.value})"
            cells += [f"{a.iterations}/{a.qp_iterations}", f"{a.time_s:.3f}", f"{b.iterations}/{b.qp_iterations}",
                      f"{b.time_s:.3f}", f"{a.time_s / b.time_s:.2f}{flag}",
                      f"{(a.objective - b.objective) / abs(b.objective):+.1e}"]
        nq, (ip_it, ip_t), (as_ch, as_t, fails) = row["qp"]
        cells += [str(nq), str(ip_it), f"{ip_t:.3f}", f"{as_ch}" + (f" ({fails} failed)" if fails else ""),
                  f"{as_t:.3f}", f"{as_t / ip_t:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for key, label in (("exact", "Presets (exact Hessian)"), ("sr1", "Block SR1")):
        faster = [r["N"] for r in rows if r[key][0].time_s < r[key][1].time_s]
        lines.append(f"{label}: SQP-AS faster at N = {', '.join(map(str, faster)) or 'none'}.")
    faster = [r["N"] for r in rows if r["qp"][2][1] < r["qp"][1][1]]
    lines.append(f"QP methods on the same QPs: the active set faster at N = {', '.join(map(str, faster)) or 'none'}.")
    lines.append("")
    write_section(SECTION, "\n".join(lines))


if __name__ == "__main__":
    main()
