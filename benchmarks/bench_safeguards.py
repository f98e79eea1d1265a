"""The SQP's safeguards (docs/structure-exploiting-sqp.md, "Safeguards") on olado's built-in ODE
problems: every SQP preset against IPOPT (configs/ipopt.ini) -- status, objective and its
relative difference from IPOPT's, SQP (QP) iterations, solve time (best of ``--repeats`` after a
warm-up) -- in this checkout. Run it in an old checkout too to get a before / after table:

    python benchmarks/bench_safeguards.py                      # print the table
    python benchmarks/bench_safeguards.py --write              # and its RESULTS.md section
    (cd ../old && PYTHONPATH=. python /path/to/benchmarks/bench_safeguards.py)   # the old code

Only the public API is used (olado.config, the problem factories), so the script runs
unchanged on older commits (a preset missing there is skipped).
"""

from __future__ import annotations

import argparse
import datetime
from pathlib import Path

from _common import HERE, commit, machine, write_section

import olado
from olado.config import load_config, make_solver
from olado.problems import PROBLEMS

SECTION = "SQP safeguards on the built-in ODE problems"
NAMES = ["vanderpol", "rayleigh", "vanderpol-path", "cstr", "vanderpol-box", "rayleigh-box"]
PRESETS = ["sqp-ip", "sqp-schittkowski", "sqp-gondzio", "sqp-sr1", "sqp-bfgs"]


def run(names, presets, repeats, configs: Path):
    rows = []
    for name in names:
        ref = make_solver(load_config(configs / "ipopt.ini")).solve(PROBLEMS[name]())
        for preset in presets:
            path = configs / f"{preset}.ini"
            if not path.exists():
                continue
            solver = make_solver(load_config(path))
            try:
                solver.solve(PROBLEMS[name]())           # warm-up (numba, imports)
                best = None
                for _ in range(repeats):
                    r = solver.solve(PROBLEMS[name]())
                    best = r if best is None or r.time_s < best.time_s else best
                rel = abs(best.objective - ref.objective) / max(abs(ref.objective), 1e-300)
                rows.append(f"| {name} | {preset} | {best.status.value} | {best.objective:.10g} | {ref.objective:.10g} "
                            f"| {rel:.1e} | {best.iterations} ({best.qp_iterations}) | {best.time_s * 1e3:.1f} |")
            except Exception as exc:   # noqa: BLE001 - the old code raised mid-solve: that is the result
                rows.append(f"| {name} | {preset} | exception {type(exc).__name__} | | {ref.objective:.10g} | | | |")
            print(rows[-1], flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", nargs="+", default=NAMES)
    ap.add_argument("--presets", nargs="+", default=PRESETS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--configs", type=Path, default=HERE.parent / "configs")
    ap.add_argument("--write", action="store_true", help="write the RESULTS.md section")
    args = ap.parse_args(argv)
    rows = run(args.problems, args.presets, args.repeats, args.configs)
    if args.write:
        text = "\n".join([
            f"## {SECTION}", "",
            "Command: `python benchmarks/bench_safeguards.py --write`  ",
            f"Date: {datetime.date.today()}  ", f"Machine: {machine()}  ", f"Commit: {commit()} (olado {olado.__version__})", "",
            "Every SQP preset against IPOPT (configs/ipopt.ini) from the problem's initial guess at N = 50: status, "
            "objective, relative difference from IPOPT's, SQP (QP) iterations, solve time in ms (best of "
            f"{args.repeats} after a warm-up).", "",
            "| problem | preset | status | objective | IPOPT | rel. diff | SQP (QP) iterations | time (ms) |",
            "|:--|:--|:--|--:|--:|--:|--:|--:|", *rows])
        write_section(SECTION, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
