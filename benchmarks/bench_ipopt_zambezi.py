"""IPOPT on zambezi12 for the horizons of paper 001 Table 1 (N = 12, 24, ..., 252).

Every horizon is solved from the balance start (eqs. (46)-(47)) with IPOPT and the exact
Hessian of the sparse NLP view (configs/ipopt.ini defaults). For each N the table gives the
problem size as counted in Table 1, IPOPT's iteration count, the optimal objective, the wall
time of the solve (best of --repeats runs, after one warm-up solve) and the share of that time
spent inside olado's Python callbacks (objective, gradient, constraints, Jacobian, Hessian).

    python benchmarks/bench_ipopt_zambezi.py                 # print, and update RESULTS.md
    python benchmarks/bench_ipopt_zambezi.py --no-write --N 12 24

The markdown table is written into benchmarks/RESULTS.md under the heading
"IPOPT on zambezi12 (Table 1 horizons)" (that section is replaced, the rest of the file kept).
"""

from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from _common import machine, write_section  # noqa: E402

from olado.problems.zambezi import table1_counts, zambezi_problem  # noqa: E402
from olado.solvers.nlp.ipopt import IpoptSolver  # noqa: E402

SECTION = "IPOPT on zambezi12 (Table 1 horizons)"

#: paper 001 Table 1, IPOPT columns: N -> (iterations, time in s on an Athlon 64 X2 2.2 GHz)
PAPER_IPOPT = {
    12: (19, 0.15), 24: (23, 0.35), 36: (31, 0.71), 48: (33, 1.00), 60: (34, 1.30), 72: (35, 1.61),
    84: (36, 1.95), 96: (41, 2.57), 108: (47, 3.38), 120: (43, 3.41), 132: (47, 4.26),
    144: (44, 4.41), 156: (45, 4.82), 168: (51, 6.17), 180: (50, 6.59), 192: (48, 6.98),
    204: (48, 7.69), 216: (47, 8.25), 228: (51, 9.96), 240: (50, 10.49), 252: (50, 11.43),
}


def run(horizons, repeats, family="zambezi12"):
    """Solve every horizon; return a list of row dicts."""
    solver = IpoptSolver(hessian="exact")
    solver.solve(zambezi_problem(family, N=12, start="balance"))  # warm-up (imports, caches)
    rows = []
    for N in horizons:
        best = None
        for _ in range(repeats):
            res = solver.solve(zambezi_problem(family, N=N, start="balance"))
            if best is None or res.time_s < best.time_s:
                best = res
        counts = table1_counts(zambezi_problem(family, N=N, start="balance"))
        paper_iter, paper_time = PAPER_IPOPT.get(N, (None, None))
        row = {
            "N": N, "variables": counts["variables"], "equalities": counts["equalities"],
            "inequalities": counts["inequalities"], "status": best.status.value,
            "iterations": best.iterations, "objective": best.objective, "time_s": best.time_s,
            "callback_share": best.info["callback_share"],
            "violation": best.max_constraint_violation, "kkt": best.kkt_residual,
            "paper_iter": paper_iter, "paper_time": paper_time,
        }
        rows.append(row)
        print(f"N={N:4d}  vars={row['variables']:5d}  iter={row['iterations']:3d} (paper {paper_iter})  "
              f"J={row['objective']:.10f}  time={row['time_s']:.3f} s  callbacks {100 * row['callback_share']:.0f}%"
              f"  {row['status']}", flush=True)
    return rows


def markdown(rows, command, repeats) -> str:
    lines = [
        f"## {SECTION}",
        "",
        f"Command: `{command}`  ",
        f"Date: {datetime.date.today().isoformat()}  ",
        f"Machine: {machine()}",
        "",
        "IPOPT with the exact Hessian of the sparse NLP view, default options (configs/ipopt.ini: "
        "tol 1e-8, MUMPS, monotone mu), balance start (46)-(47). Size columns are counted as in "
        "Table 1 (equalities include the fixed x^0, inequalities include bounds). Time is the "
        f"wall time of `solve` (best of {repeats}, after a warm-up solve); callback share is the "
        "fraction of the IPOPT call spent in olado's Python evaluation callbacks. KKT residual: "
        "olado's unscaled max-norm of stationarity and complementarity at the returned point "
        "(IPOPT's interior-point complementarity, ~1e-9, dominates it). The last two "
        "columns are the paper's IPOPT figures (Athlon 64 X2 2.2 GHz, C++).",
        "",
        "| N | variables | m_e | m | status | iterations | objective | time (s) | callback share "
        "| max violation | KKT residual | paper iter | paper time (s) |",
        "|---:|---:|---:|---:|:--|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['N']} | {r['variables']} | {r['equalities']} | {r['inequalities']} | {r['status']} "
            f"| {r['iterations']} | {r['objective']:.10f} | {r['time_s']:.3f} | {100 * r['callback_share']:.0f}% "
            f"| {r['violation']:.1e} | {r['kkt']:.1e} | {r['paper_iter'] if r['paper_iter'] is not None else ''} "
            f"| {r['paper_time'] if r['paper_time'] is not None else ''} |")
    total = sum(r["time_s"] for r in rows)
    lines += ["", f"Total solve time over the {len(rows)} horizons: {total:.2f} s.", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="*", default=list(range(12, 253, 12)),
                    help="horizons (default: 12, 24, ..., 252 as in Table 1)")
    ap.add_argument("--repeats", type=int, default=3, help="solves per horizon; the fastest is kept")
    ap.add_argument("--family", default="zambezi12")
    ap.add_argument("--output", type=Path, default=HERE / "RESULTS.md")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)
    rows = run(args.N, max(args.repeats, 1), args.family)
    given = sys.argv[1:] if argv is None else list(argv)
    command = " ".join(["python benchmarks/bench_ipopt_zambezi.py", *given])
    text = markdown(rows, command, max(args.repeats, 1))
    print()
    print(text)
    if not args.no_write:
        write_section(SECTION, text, args.output)
        print(f"written to {args.output}")
    bad = [r["N"] for r in rows if r["status"] not in ("success", "acceptable")]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
