"""The interior-point NLP solver (``configs/ipm.ini``, olado.solvers.ipm) against olado's IPOPT
wrapper (``configs/ipopt.ini``) on zambezi12: iterations, objectives, time (best ``time_s`` of ``--repeats``
after a warm-up; the machine is shared, so times are orders of magnitude).

    python benchmarks/bench_ipm.py                      # N = 24, 120, 252; writes RESULTS.md
    python benchmarks/bench_ipm.py --N 24 --no-write
"""

from __future__ import annotations

import argparse
import datetime
from _common import HERE, best_of, commit, machine, write_section

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem

SECTION = "Interior-point NLP on the Riccati kernel (ipm) against IPOPT"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=int, nargs="+", default=[24, 120, 252])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    solvers = {name: make_solver(load_config(HERE.parent / "configs" / f"{name}.ini")) for name in ("ipm", "ipopt")}
    rows = ["| N | preset | status | iterations | objective | rel. to IPOPT | time (ms) | ms / iteration | factorizations |",
            "|--:|:--|:--|--:|--:|--:|--:|--:|--:|"]
    for N in args.N:
        res = {}
        for name, s in solvers.items():
            s.solve(zambezi_problem(N=N))                      # warm-up
            best = best_of(s, N, args.repeats)
            res[name] = (best, best.time_s)
        ref = res["ipopt"][0].objective
        for name, (r, t) in res.items():
            rel = abs(r.objective - ref) / abs(ref)
            fac = r.info.get("factorizations", "")
            rows.append(f"| {N} | {name} | {r.status.value} | {r.iterations} | {r.objective:.12g} | {rel:.1e} | "
                        f"{1e3 * t:.0f} | {1e3 * t / max(r.iterations, 1):.1f} | {fac} |")
            print(rows[-1], flush=True)
    shown = " ".join(argv if argv is not None else __import__("sys").argv[1:])
    command = f"python benchmarks/bench_ipm.py {shown}".strip()
    text = (f"## {SECTION}\n\n`{command}` at {commit()}, "
            f"{datetime.date.today()}, {machine()}; best of {args.repeats} after a warm-up, the machine shared "
            "with other jobs (times: orders of magnitude).\n\n" + "\n".join(rows) + "\n")
    if not args.no_write:
        write_section(SECTION, text)
    print(text)


if __name__ == "__main__":
    main()
