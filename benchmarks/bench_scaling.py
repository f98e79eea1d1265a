"""Automatic scaling (issue 15 item 3, seed 004): the condition-number ratio of eq. (16) at the
start point and the solves with and without each scaling method, per problem and preset.

    python benchmarks/bench_scaling.py                                    # every entry, sqp-ip and ipopt
    python benchmarks/bench_scaling.py --entries hang-glider lq-box-400 --configs sqp-ip
    python benchmarks/bench_scaling.py --write                            # also rewrite the RESULTS.md section

The machine is shared: compare iterations, objectives, statuses and condition numbers, not times.
To add a problem, add a line to ENTRIES: (label, robustness-suite entry name or None, built-in
problem name, its keyword arguments).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from _common import machine, write_section
from _robustness import CONFIGS, olado_commit

#: (label, entry of the robustness suite (its N and start point) or None, built-in name, its keywords)
ENTRIES = [
    ("hang-glider", "hang-glider", None, None),
    ("goddard", "goddard", None, None),
    ("rigid-body", "rigid-body", None, None),
    ("orbit-raising", "orbit-raising", None, None),
    ("lq-box-400", None, "lq-box", {"N": 400}),
    ("lq-box-800", None, "lq-box", {"N": 800}),
    # the seeds' aerospace problems (docs/aerospace.md) at seed 004's size (50 intervals): the
    # shuttle in scaled units and in Betts's raw units (ft, ft/s, s), the heat limit written
    # 70/q - 1 >= 0 and declared positive (olado.problems.aerospace.heat_limit_row) or 1 - q/70 >= 0
    ("shuttle-entry-50", None, "shuttle-entry", {"N": 50}),
    ("shuttle-entry-raw-50", None, "shuttle-entry", {"N": 50, "scaled": False}),
    ("shuttle-entry-heating-50", None, "shuttle-entry-heating", {"N": 50}),
    ("shuttle-entry-heating-raw-50", None, "shuttle-entry-heating", {"N": 50, "scaled": False}),
    ("shuttle-entry-heating-ratio-50", None, "shuttle-entry-heating", {"N": 50, "heat_limit": "ratio"}),
    ("shuttle-entry-heating-ratio-raw-50", None, "shuttle-entry-heating",
     {"N": 50, "scaled": False, "heat_limit": "ratio"}),
    ("low-thrust-geo-100", None, "low-thrust-geo", {"N": 100}),
    ("hypersonic-landing-200", None, "hypersonic-landing", {"N": 200}),
]
METHODS = ("none", "iso", "jrn", "pjrn", "auto")
#: Jacobians up to this many entries get the dense SVD here (lq-box at N = 400: 1601 x 2400)
DENSE = 4_000_000
SECTION = "Automatic scaling (issue 15 item 3, seed 004)"


def build(label):
    """(problem, guess) of an ENTRIES label."""
    _, entry, name, kwargs = next(e for e in ENTRIES if e[0] == label)
    if entry is not None:
        from olado.problems.suites import load_suite

        return next(e for e in load_suite("robustness") if e.name == entry).build()
    from olado.problems import get_problems

    return get_problems()[name](**kwargs), None


def solve(label, config, method, time_limit):
    from olado.config import load_config, make_solver

    path = CONFIGS / f"{config}.ini"
    solver_name = load_config(path).solver
    cfg = load_config(path, [f"{solver_name}.scaling={method}", f"{solver_name}.max_time={time_limit:g}"])
    problem, guess = build(label)
    t0 = time.perf_counter()
    try:
        res = make_solver(cfg).solve(problem, guess=guess)
    except Exception as exc:  # noqa: BLE001 - a finding, recorded
        return {"status": f"exception {type(exc).__name__}: {str(exc)[:80]}", "objective": math.nan, "iterations": 0,
                "cond": {}, "cert": "-", "time_s": time.perf_counter() - t0}
    cond = res.info.get("scaling", {}).get("condition", {})
    return {"status": res.status.value, "objective": res.objective, "iterations": res.iterations,
            "violation": res.max_constraint_violation, "cond": cond,
            "cert": res.certificate.level if res.certificate else "-", "time_s": time.perf_counter() - t0}


def condition(label, method):
    from olado.problems.scaling import condition_ratio, scale_problem, start_point

    problem, guess = build(label)
    X, U = (guess if isinstance(guess, tuple) else (None, guess))
    X, U = start_point(problem, X, U)
    return condition_ratio(problem, scale_problem(problem, method, X, U), X, U, dense_entries=DENSE)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--entries", nargs="*", default=[e[0] for e in ENTRIES])
    ap.add_argument("--configs", nargs="*", default=["sqp-ip", "ipopt"])
    ap.add_argument("--methods", nargs="*", default=list(METHODS))
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument("--write", action="store_true", help="rewrite the RESULTS.md section")
    args = ap.parse_args(argv)

    lines = ["| problem | method | cond (start) | cond scaled | ratio eq. (16) | " +
             " | ".join(f"{c}: status, iterations, objective" for c in args.configs) + " |",
             "|---|---|---|---|---|" + "---|" * len(args.configs)]
    for label in args.entries:
        for method in args.methods:
            if method == "none":
                cr_text = f"{condition(label, 'iso').original:.3g} | - | -"
            else:
                cr = condition(label, method)
                cr_text = f"{cr.original:.3g} | {cr.scaled:.3g} | {cr.ratio:.3g}"
            cells = []
            for config in args.configs:
                r = solve(label, config, method, args.time_limit)
                cert = "" if r["cert"] in ("-", "success") else f" (certificate {r['cert']})"
                cells.append(f"{r['status']}{cert}, {r['iterations']}, {r['objective']:.8g}")
            line = f"| {label} | {method} | {cr_text} | " + " | ".join(cells) + " |"
            lines.append(line)
            print(line, flush=True)
    command = "python benchmarks/bench_scaling.py " + " ".join(sys.argv[1:])
    text = (f"## {SECTION}\n\n`{command.strip()}` at {olado_commit()}; {machine()} (loaded: 4-5 "
            "processes on 2 cores, so no times). Condition numbers of eq. (2) (objective gradient over the "
            "constraint Jacobian, x^0 columns dropped) at the start point, by dense SVD "
            "(olado.problems.scaling.condition_ratio); eq. (16) is their ratio, higher is better. "
            "The statuses are olado's after its certificate on the original problem.\n\n" + "\n".join(lines) + "\n")
    if args.write:
        write_section(SECTION, text)
    print(text)


if __name__ == "__main__":
    main()
