"""Behaviour fingerprint: status, iteration counts and objective of every solve of a suite, to
show that a change that should not change the algorithms (a restructuring, a speed-up) does not.

Suites: ``testset`` (the 244-problem Zambezi testing set of paper 001 sec. 6, which contains
Table 1, zambezi12 N = 12..252), ``large`` (zambezi N = 1 200 and 12 000, balance start; sqp-ip and ipm) and
``builtin`` (every built-in problem of olado.problems.testproblems at its default size, with every
preset in configs/ that accepts it). Run it on two commits and compare:

    python benchmarks/check_behaviour.py --out old.json                # on the old commit
    python benchmarks/check_behaviour.py --out new.json                # on the new commit
    python benchmarks/check_behaviour.py --compare old.json new.json   # prints every difference

Only the public API is used (olado.config.load_config/make_solver, the problem factories), so
the script runs unchanged on commits before and after a restructuring. Times are recorded but
never compared (measure speed side by side in one run with the bench_* scripts).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from _common import HERE

from olado.config import load_config, make_solver
from olado.problems.testproblems import PROBLEMS as TEST_PROBLEMS
from olado.problems.zambezi import zambezi_problem

TESTSET = {"zambezi": range(12, 421, 12), "zambezi8": range(12, 217, 12), "zambezi9": range(12, 73, 12),
           "zambezi10": range(12, 73, 12), "zambezi11": range(12, 433, 12), "zambezi12": range(12, 253, 12)}
TESTSET_CONFIGS = ["sqp-ip", "sqp-gondzio", "sqp-weighted", "sqp-sr1", "sqp-bfgs", "ipopt", "ipm"]
LARGE = [1200, 12000]
LARGE_CONFIGS = ["sqp-ip", "ipm"]
#: relative objective difference reported as a change
OBJ_RTOL = 1e-9


def _record(solve):
    t = time.perf_counter()
    try:
        r = solve()
    except Exception as exc:  # a raised exception is behaviour too: record it
        return {"status": f"exception {type(exc).__name__}: {exc}"[:160]}
    return {"status": r.status.value, "iterations": int(r.iterations), "qp_iterations": int(r.qp_iterations),
            "objective": float(r.objective), "time": time.perf_counter() - t}


def run(suites, configs_filter):
    out = {}
    presets = sorted(p.stem for p in (HERE.parent / "configs").glob("*.ini"))
    solvers = {}

    def solver(name):
        if name not in solvers:
            solvers[name] = make_solver(load_config(HERE.parent / "configs" / f"{name}.ini"))
        return solvers[name]

    if "testset" in suites:
        for c in TESTSET_CONFIGS:
            if configs_filter and c not in configs_filter:
                continue
            s = solver(c)
            for fam, grid in TESTSET.items():
                for N in grid:
                    for st in ("balance", "sif"):
                        key = f"testset|{c}|{fam}|{N}|{st}"
                        out[key] = _record(lambda: s.solve(zambezi_problem(fam, N=N, start=st, extend=None)))
                        print(key, out[key], flush=True)
    if "large" in suites:
        for c in LARGE_CONFIGS:
            if configs_filter and c not in configs_filter:
                continue
            for N in LARGE:
                key = f"large|{c}|zambezi|{N}|balance"
                out[key] = _record(lambda: solver(c).solve(zambezi_problem("zambezi", N=N)))
                print(key, out[key], flush=True)
    if "builtin" in suites:
        # olado's original built-ins (testproblems): the literature problems of the robustness set
        # (olado.problems.catalog) are benchmarked by bench_robustness.py, not fingerprinted here
        problems = dict(TEST_PROBLEMS)
        for c in presets:
            if configs_filter and c not in configs_filter:
                continue
            for name, factory in problems.items():
                key = f"builtin|{c}|{name}|default|default"
                out[key] = _record(lambda: solver(c).solve(factory()))
                print(key, out[key], flush=True)
    return out


def compare(old_path, new_path):
    old = json.loads(open(old_path).read())
    new = json.loads(open(new_path).read())
    diffs = 0
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if a is None or b is None:
            print(f"only in {'new' if a is None else 'old'}: {key}")
            diffs += 1
            continue
        notes = []
        for f in ("status", "iterations", "qp_iterations"):
            if a.get(f) != b.get(f):
                notes.append(f"{f} {a.get(f)} -> {b.get(f)}")
        ja, jb = a.get("objective"), b.get("objective")
        if ja is not None and jb is not None and not (math.isnan(ja) and math.isnan(jb)):
            rel = abs(ja - jb) / max(abs(ja), 1e-300)
            if not rel <= OBJ_RTOL:
                notes.append(f"objective {ja:.12g} -> {jb:.12g} (rel {rel:.1e})")
        if notes:
            diffs += 1
            print(f"{key}: " + "; ".join(notes))
    print(f"{diffs} of {len(set(old) | set(new))} solves differ")
    return diffs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suites", nargs="+", default=["builtin", "large", "testset"],
                    choices=["builtin", "large", "testset"])
    ap.add_argument("--configs", nargs="*", default=None, help="restrict to these presets (names in configs/)")
    ap.add_argument("--out", help="write the fingerprint (JSON) here")
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), help="compare two fingerprints")
    args = ap.parse_args(argv)
    if args.compare:
        return 1 if compare(*args.compare) else 0
    out = run(args.suites, args.configs)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(out, fh, indent=0, sort_keys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
