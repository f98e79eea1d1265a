"""Old vs new, side by side in one run: the same workloads timed in two checkouts, alternately.

For a change that must not make olado slower (a restructuring, a refactoring of the kernels):
each workload runs in a fresh process per checkout and round, the checkouts alternating (A, B,
A, B, ...), so a slow spell of the shared machine hits both alike; inside a process the workload
is warmed up once (imports, numba caches) and then timed ``--repeats`` times (best and median
kept). The workloads use only what both checkouts have (olado.config, the problem factories, the
KKT back-end factory, the interior-point QP), looked up under their old and new module paths.

    python benchmarks/side_by_side.py OLD_CHECKOUT NEW_CHECKOUT             # print the table
    python benchmarks/side_by_side.py ../base . --rounds 3 --write          # and its RESULTS.md section

Workloads: ``kkt-N`` (Riccati factor + one solve, n = 6, m = 7, random bound terms: bench_kkt's
system), ``qp-N`` (the Mehrotra QP on the convexified first SQP step of Zambezi: bench_qp's
problem), ``table1`` (configs/sqp-ip.ini on zambezi12 N = 12..252, balance start: the sum of the
21 solve times, the SQP-IP column of paper 001 Table 1) and ``large-1200`` (sqp-ip on zambezi N = 1 200).
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import subprocess
import sys
from pathlib import Path

from _common import HERE, commit, machine, write_section

SECTION = "Side by side: before and after a restructuring"
WORKLOADS = ["kkt-1000", "kkt-10000", "kkt-100000", "qp-1200", "qp-12000", "table1", "large-1200"]

# Runs inside the checkout under test (PYTHONPATH=checkout); prints one JSON line.
WORKER = r'''
import importlib, json, statistics, sys, time
import numpy as np
work, repeats = sys.argv[1], int(sys.argv[2])

def first(*paths):
    for mod, name in paths:
        try:
            return getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError):
            pass
    raise ImportError(paths)

def kkt(N, n=6, m=7):
    rng = np.random.default_rng(0)
    def spd(d, count):
        M = rng.standard_normal((count, d, d)); return M @ M.transpose(0, 2, 1) / d + 0.1 * np.eye(d)
    mats = dict(Q=spd(n, N + 1), R=spd(m, N), S=0.1 * rng.standard_normal((N, n, m)),
                A=0.9 * rng.standard_normal((N, n, n)) / np.sqrt(n), B=rng.standard_normal((N, n, m)) / np.sqrt(n))
    diag = dict(Dx=10.0 ** rng.uniform(-4, 4, (N + 1, n)), Du=10.0 ** rng.uniform(-4, 4, (N, m)))
    rhs = (rng.standard_normal((N + 1, n)), rng.standard_normal((N, m)), rng.standard_normal((N, n)), rng.standard_normal(n))
    make = first(("olado.linalg.kkt", "make_kkt_solver"), ("olado.linalg", "make_kkt_solver"))
    def run():
        sol = make("riccati", mats["Q"], mats["S"], mats["R"], mats["A"], mats["B"], **diag).solve(*rhs)
        return {"check": float(np.abs(sol.X).sum())}
    return run

def qp(N):
    from olado.problems.zambezi import zambezi_problem
    step = first(("olado.solvers.sqp.solver", "convex_step_qp"), ("olado.solvers.sqp", "convex_step_qp"),
                 ("olado.solvers.sqp.qp_step", "convex_step_qp"))
    Mehrotra = first(("olado.qp.interior_point", "MehrotraQP"), ("olado.solvers.qp_ip", "MehrotraQP"))
    problem = step(zambezi_problem("zambezi12" if N <= 252 else "zambezi", N=N, extend="cyclic"), shift=1e-4)
    def run():
        res = Mehrotra().solve(problem)
        return {"iterations": int(res.iterations), "objective": float(res.objective)}
    return run

def sqp(family, Ns):
    from pathlib import Path
    from olado.config import load_config, make_solver
    from olado.problems.zambezi import zambezi_problem
    solver = make_solver(load_config(Path("configs") / "sqp-ip.ini"))
    problems = [zambezi_problem(family, N=N) for N in Ns]
    def run():
        its = qits = 0
        for p in problems:
            r = solver.solve(p); its += r.iterations; qits += r.qp_iterations
        return {"iterations": its, "qp_iterations": qits}
    return run

if work.startswith("kkt-"):
    run = kkt(int(work[4:]))
elif work.startswith("qp-"):
    run = qp(int(work[3:]))
elif work == "table1":
    run = sqp("zambezi12", range(12, 253, 12))
elif work.startswith("large-"):
    run = sqp("zambezi", [int(work[6:])])
else:
    raise SystemExit(f"unknown workload {work}")
info = run()                                   # warm-up: imports, numba caches, first-touch memory
times = []
for _ in range(repeats):
    t = time.perf_counter(); info = run(); times.append(time.perf_counter() - t)
print(json.dumps({"best": min(times), "median": statistics.median(times), **info}))
'''


def measure(checkout, work, repeats):
    out = subprocess.run([sys.executable, "-c", WORKER, work, str(repeats)], cwd=checkout, capture_output=True,
                         text=True, env={"PYTHONPATH": str(checkout), "PATH": "/usr/bin:/bin",
                                         "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(f"{work} in {checkout} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="checkout A (before)")
    ap.add_argument("new", type=Path, help="checkout B (after)")
    ap.add_argument("--workloads", nargs="+", default=WORKLOADS)
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (processes) per checkout")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats inside each process")
    ap.add_argument("--write", action="store_true", help=f"replace the section '{SECTION}' in RESULTS.md")
    args = ap.parse_args(argv)
    old, new = args.old.resolve(), args.new.resolve()
    rows = []
    for work in args.workloads:
        got = {old: [], new: []}
        for rnd in range(args.rounds):
            for co in ((old, new) if rnd % 2 == 0 else (new, old)):
                got[co].append(measure(co, work, args.repeats))
        a = statistics.median(r["best"] for r in got[old])
        b = statistics.median(r["best"] for r in got[new])
        same = all({k: v for k, v in r.items() if k not in ("best", "median")}
                   == {k: v for k, v in got[old][0].items() if k not in ("best", "median")} for r in got[old] + got[new])
        extra = {k: v for k, v in got[new][0].items() if k not in ("best", "median", "check")}
        rows.append((work, a, b, b / a, same, extra))
        print(f"{work:12s} old {a:.4f}s  new {b:.4f}s  new/old {b / a:.3f}  same results: {same}  {extra}", flush=True)
    if not args.write:
        return
    lines = [f"## {SECTION}", "",
             f"Command: `python benchmarks/side_by_side.py OLD NEW --rounds {args.rounds} --repeats {args.repeats}`  ",
             f"Date: {datetime.date.today().isoformat()}  ",
             f"Machine: {machine()}  ",
             f"Old: {commit(old, mark_changes=False)}; new: {commit(new, mark_changes=False)}", "",
             "Each figure: the median over the rounds of the best of the timed repeats in one process (after a "
             "warm-up); the checkouts alternate process by process. \"same results\": the iteration counts and "
             "objectives (or a checksum of the solution) are identical in every process of both checkouts.", "",
             "| workload | old (s) | new (s) | new / old | same results | iterations (new) |",
             "|:--|---:|---:|---:|:--|:--|"]
    for work, a, b, ratio, same, extra in rows:
        its = ", ".join(f"{k} {v:.10g}" if isinstance(v, float) else f"{k} {v}" for k, v in extra.items())
        lines.append(f"| {work} | {a:.4f} | {b:.4f} | {ratio:.3f} | {'yes' if same else 'NO'} | {its} |")
    lines.append("")
    write_section(SECTION, "\n".join(lines))
    print(f"wrote section {SECTION!r}")


if __name__ == "__main__":
    main()
