"""Set-up time of the AD problems with and without the disk cache of the LLVM kernels' object
code (olado/problems/autodiff/object_cache.py, docs/autodiff.md).

Every measurement is a fresh Python process that builds one problem at N = 50 and evaluates
every derivative once; it reports the phases of the build: ``trace`` (the user's functions on
symbols, StageModel), ``diff`` (CasADi's Jacobians and Hessians, CSE), ``ir`` (SX -> LLVM IR
translation), ``llvm`` (LLVM optimization and code generation, or loading the cached object code)
and ``setup`` (AutoDiffDOCP.setup_time, all of them). Three runs per problem:

* ``off``   OLADO_KERNEL_CACHE=0: everything compiled, as before the cache;
* ``cold``  an empty cache directory (compiled, then stored);
* ``warm``  the same directory again (the object code loaded; no IR translation either).

The warm run's values and derivatives must equal the cold run's to the bit (a SHA-256 of the
outputs is compared). The process start (imports, numba's first dispatch) is the same in all
three and is reported separately (``process``: the child's wall time; the numba trampoline
of the kernels is imported before the build, so that ``setup`` holds the build only).

    python benchmarks/bench_kernel_cache.py [--problems vanderpol cstr ...] [--repeats 3] [--write]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from _common import HERE, commit, machine, write_section

SECTION = "Set-up time: the LLVM kernels' object-code cache"
PROBLEMS = ["vanderpol", "cstr", "goddard", "shuttle-entry", "ZambeziAD"]

_CHILD = r"""
import hashlib, json, sys, time
t_start = time.perf_counter()
import numpy as np
import olado
from olado.problems.autodiff import casadi_backend as cb, llvm_kernels as lk, model as md
import olado.problems.autodiff.trampoline   # numba's per-process start, the same in every mode
T = dict(trace=0.0, build=0.0, evaluators=0.0, ir=0.0)
def timed(key, f):
    def g(*a, **k):
        t = time.perf_counter(); r = f(*a, **k); T[key] += time.perf_counter() - t; return r
    return g
md.StageModel.__init__ = timed("trace", md.StageModel.__init__)
cb.CasadiBackend.build = timed("build", cb.CasadiBackend.build)
cb.CasadiBackend.evaluators = timed("evaluators", cb.CasadiBackend.evaluators)
lk.sx_llvm_ir = timed("ir", lk.sx_llvm_ir)
name, N = sys.argv[1], 50
if name == "ZambeziAD":
    from olado.problems.zambezi_ad import ZambeziAD
    prob = ZambeziAD()
else:
    prob = olado.problems.get_problems()[name](N=N)
prob.ad_functions()
rng = np.random.default_rng(0)
K = np.arange(prob.N)
x, u = 0.1 * rng.normal(size=(prob.N, prob.n)) + 0.5, 0.1 * rng.normal(size=(prob.N, prob.m)) + 0.5
p, lam = rng.normal(size=(prob.N, prob.n)), rng.normal(size=(prob.N, prob.r))
outs = [prob.dynamics(K, x, u), *prob.dynamics_jacobian(K, x, u), *prob.stage_cost_gradient(K, x, u),
        *prob.stage_hessian(K, x, u, 1.0, p, lam)]
if prob.r:
    outs += list(prob.stage_constraints_jacobian(K, x, u))
digest = hashlib.sha256(b"".join(np.ascontiguousarray(o, dtype=np.float64).tobytes() for o in outs)).hexdigest()
print(json.dumps(dict(trace=T["trace"], diff=T["build"] - T["evaluators"], ir=T["ir"],
                      llvm=T["evaluators"] - T["ir"], setup=prob.setup_time,
                      process=time.perf_counter() - t_start, digest=digest)))
"""


def child(problem, cache_root, enabled):
    env = dict(os.environ, OLADO_CACHE_DIR=cache_root, PYTHONPATH=str(HERE.parent))
    env["OLADO_KERNEL_CACHE"] = "1" if enabled else "0"
    out = subprocess.run([sys.executable, "-c", _CHILD, problem], env=env, capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def measure(problem, repeats):
    """Best of ``repeats`` (smallest setup) per mode; the cold run gets a new directory each time."""
    rows = {}
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as root:
            runs = {"off": child(problem, root, False), "cold": child(problem, root, True),
                    "warm": child(problem, root, True)}
        if runs["warm"]["digest"] != runs["cold"]["digest"] or runs["off"]["digest"] != runs["cold"]["digest"]:
            raise AssertionError(f"{problem}: the cached kernels computed other numbers")
        for mode, r in runs.items():
            if mode not in rows or r["setup"] < rows[mode]["setup"]:
                rows[mode] = r
    return rows


def table(results):
    lines = ["| problem | cache | trace | diff | IR | LLVM | set-up (s) | ratio to off | process (s) |",
             "|:--|:--|--:|--:|--:|--:|--:|--:|--:|"]
    for problem, rows in results.items():
        for mode in ("off", "cold", "warm"):
            r = rows[mode]
            lines.append(f"| {problem} | {mode} | {r['trace']:.3f} | {r['diff']:.3f} | {r['ir']:.3f} | "
                         f"{r['llvm']:.3f} | {r['setup']:.3f} | {r['setup'] / rows['off']['setup']:.2f} | "
                         f"{r['process']:.2f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", nargs="+", default=PROBLEMS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", action="store_true", help="write the RESULTS.md section")
    args = ap.parse_args(argv)
    results = {p: measure(p, args.repeats) for p in args.problems}
    text = table(results)
    print(text)
    if args.write:
        head = [f"## {SECTION}", "",
                f"Command: `python benchmarks/bench_kernel_cache.py --repeats {args.repeats}`  ",
                f"Commit: {commit()}  ", f"Date: {time.strftime('%Y-%m-%d')}  ", f"Machine: {machine(False)}", "",
                "Fresh process per row, N = 50, best of the repeats by set-up; warm values and derivatives "
                "equal the cold ones to the bit (checked).", ""]
        write_section(SECTION, "\n".join(head) + "\n" + text + "\n")


if __name__ == "__main__":
    main()
