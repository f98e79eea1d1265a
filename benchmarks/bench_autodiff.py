"""Automatic differentiation back-ends against the hand-written Zambezi kernels (issue 15 item 1).

Zambezi (zambezi12) is built twice: the hand-written model (olado.problems.zambezi, numba kernels
for every derivative) and the same equations written once for automatic differentiation
(olado.problems.zambezi_ad.ZambeziAD) with each back-end:

* ``casadi``      CasADi SX derivatives, each function's SX algorithm translated to LLVM IR (a
                  loop over the stages) compiled by llvmlite (the default back-end)
* ``casadi-numba`` the same algorithm as Python compiled by numba (disk-cached)
* ``casadi-vm``   the same functions, Function.map over the stages, CasADi's virtual machine
* ``casadi-jit``  Function.map of the functions compiled by the system's C compiler (CasADi's jit)
* ``sympy``       SymPy derivatives + common subexpressions, one numba loop per function

For every horizon N the script times, round robin (every variant called once per round, so a
loaded machine slows them alike), the user-level stage methods of the model (``dynamics``,
``dynamics_jacobian``, ``stage_cost_gradient``, ``stage_hessian``: what the DOCP layer's
``eval_*`` call) and reports the median per call, per stage (ns) and the ratio to the
hand-written kernel. The set-up time is the AD model's trace + differentiation + compilation
(``AutoDiffDOCP.setup_time``, first evaluation); the hand-written kernels load from numba's
disk cache. The second horizon's AD set-up reuses the first one's compiled code (LLVM: in the
process; numba: its disk cache): the stage data are arguments, the code does not depend on N.

A second table does the same for an ODE transcription, where the expression graphs are deeper:
the cart-pole of tests/problems/test_autodiff.py (RK4 with sin, cos and divisions, a path and a
final constraint), ``stage_hessian`` per stage and set-up, for the AD back-ends only (there is no
hand-written version). SymPy is left out of it by default (``--ode-sympy``): its symbolic
Hessian of one RK4 step took 436 s to build here.

A third table (``--solve``) solves zambezi12 with sqp-ip (configs/sqp-ip.ini) through both
models: iterations, objective, the largest difference of the final controls, and as a yardstick
the same difference between two solves of the hand-written model whose start differs by one
part in 10^15 (zambezi12's solution is not unique in some spillages: rounding-level differences
move the final point along that face).

    python benchmarks/bench_autodiff.py                 # N = 252, 12000; prints the tables
    python benchmarks/bench_autodiff.py --write         # and writes the RESULTS.md section
    python benchmarks/bench_autodiff.py --solve-only --write-solve   # only the solve table
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from _common import commit, machine, write_section  # noqa: E402

from olado.problems.zambezi import Zambezi  # noqa: E402
from olado.problems.zambezi_ad import ZambeziAD  # noqa: E402

SECTION = "Automatic differentiation vs hand-written Zambezi kernels"
SOLVE_SECTION = "Zambezi through automatic differentiation: the same SQP iterates"
VARIANTS = {
    "hand-written": lambda N: Zambezi("zambezi12", N=N),
    "casadi": lambda N: ZambeziAD("zambezi12", N=N, backend="casadi"),
    "casadi-numba": lambda N: ZambeziAD("zambezi12", N=N, backend="casadi", backend_options={"mode": "numba"}),
    "casadi-vm": lambda N: ZambeziAD("zambezi12", N=N, backend="casadi", backend_options={"mode": "vm"}),
    "casadi-jit": lambda N: ZambeziAD("zambezi12", N=N, backend="casadi", backend_options={"mode": "jit"}),
    "sympy": lambda N: ZambeziAD("zambezi12", N=N, backend="sympy"),
}
METHODS = ("dynamics", "dynamics_jacobian", "stage_cost_gradient", "stage_hessian")


def _calls(problem, X, U, P):
    K = problem._K
    x = np.ascontiguousarray(X[:-1])
    lam = np.zeros((problem.N, 0))
    return {
        "dynamics": lambda: problem.dynamics(K, x, U),
        "dynamics_jacobian": lambda: problem.dynamics_jacobian(K, x, U),
        "stage_cost_gradient": lambda: problem.stage_cost_gradient(K, x, U),
        "stage_hessian": lambda: problem.stage_hessian(K, x, U, 1.0, P, lam),
    }


def measure(N, variants, rounds, seed=0):
    """Median seconds per call {variant: {method: s}} and set-up seconds {variant: s}."""
    problems, setup = {}, {}
    for name in variants:
        t0 = time.perf_counter()
        p = VARIANTS[name](N)
        if hasattr(p, "ad_functions"):
            p.ad_functions()
            setup[name] = p.setup_time
        else:
            p.stage_hessian(p._K[:1], np.zeros((1, 6)), np.zeros((1, 7)), 1.0, np.zeros((1, 6)), np.zeros((1, 0)))
            setup[name] = time.perf_counter() - t0
        problems[name] = p
    rng = np.random.default_rng(seed)
    ref = problems[variants[0]]
    U = ref.initial_guess() + 0.1 * rng.standard_normal((N, 7))
    X = ref.simulate(U)
    P = rng.standard_normal((N, 6))
    calls = {name: _calls(p, X, U, P) for name, p in problems.items()}
    times = {name: {m: [] for m in METHODS} for name in variants}
    for name in variants:                     # warm-up: first map / first call
        for m in METHODS:
            calls[name][m]()
    for _ in range(rounds):
        for m in METHODS:
            for name in variants:
                t0 = time.perf_counter()
                calls[name][m]()
                times[name][m].append(time.perf_counter() - t0)
    return {name: {m: statistics.median(v) for m, v in d.items()} for name, d in times.items()}, setup


def measure_ode(N, modes, rounds):
    """{variant: (setup s, stage_hessian s per call)} for the RK4 cart-pole."""
    sys.path.insert(0, str(HERE.parent / "tests" / "problems"))
    from test_autodiff import CartPoleRK4   # noqa: PLC0415 - the test suite's model

    problems = {}
    for name in modes:
        backend, _, mode = name.partition("-")
        p = CartPoleRK4(N=N, mode=mode or "llvm")
        if backend == "sympy":
            p.ad_backend, p.ad_options = "sympy", {}
        p.ad_functions()
        problems[name] = p
    rng = np.random.default_rng(0)
    X, U = rng.standard_normal((N + 1, 4)) * 0.3, rng.standard_normal((N, 1))
    P, L = rng.standard_normal((N, 4)), rng.standard_normal((N, 2))
    times = {name: [] for name in modes}
    for _ in range(rounds):
        for name, p in problems.items():
            t0 = time.perf_counter()
            p.stage_hessian(p._K, X[:-1], U, 1.0, P, L)
            times[name].append(time.perf_counter() - t0)
    return {name: (problems[name].setup_time, statistics.median(times[name])) for name in modes}


def ode_table(result, N):
    lines = ["| back-end | set-up (s) | `stage_hessian` (ns per stage) |", "|:--|--:|--:|"]
    for name, (setup, t) in result.items():
        lines.append(f"| {name} | {setup:.2f} | {t / N * 1e9:,.0f} |")
    return "\n".join(lines)


def solve_table(horizons):
    """sqp-ip through the hand-written and the AD model, and the hand-written model from a start
    perturbed by 1e-15 (relative), per horizon."""
    import olado   # noqa: PLC0415

    config = str(HERE.parent / "configs" / "sqp-ip.ini")
    lines = ["| N | model | status | iterations | objective | solve (s) | max abs diff. of U from the hand-written solve |",
             "|--:|:--|:--|--:|--:|--:|--:|"]
    for N in horizons:
        hand = olado.solve(Zambezi("zambezi12", N=N), config=config)
        ad_problem = ZambeziAD("zambezi12", N=N)
        ad = olado.solve(ad_problem, config=config)
        p = Zambezi("zambezi12", N=N)
        moved = olado.solve(p, config=config, guess=p.initial_guess() * (1 + 1e-15))
        for label, r in (("hand-written", hand), (f"AD (set-up {ad_problem.setup_time:.2f} s)", ad),
                         ("hand-written, start x (1 + 1e-15)", moved)):
            diff = "-" if r is hand else f"{np.abs(r.u - hand.u).max():.1e}"
            lines.append(f"| {N} | {label} | {r.status.name} | {r.iterations} | {r.objective:.15g} | "
                         f"{r.time_s:.1f} | {diff} |")
    return "\n".join(lines)


def table(results, horizons, variants):
    lines = ["| N | method | " + " | ".join(variants) + " |",
             "|--:|:--|" + "--:|" * len(variants)]
    for N in horizons:
        med, setup = results[N]
        base = med[variants[0]]
        for m in METHODS:
            cells = []
            for name in variants:
                ns = med[name][m] / N * 1e9
                ratio = med[name][m] / base[m]
                cells.append(f"{ns:,.0f}" + ("" if name == variants[0] else f" ({ratio:.1f}x)"))
            lines.append(f"| {N} | `{m}` | " + " | ".join(cells) + " |")
        lines.append(f"| {N} | set-up (s) | " + " | ".join(f"{setup[name]:.2f}" for name in variants) + " |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=int, nargs="+", default=[252, 12000])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--rounds", type=int, default=0, help="rounds per horizon (default: 400 at N <= 1000, 40 above)")
    ap.add_argument("--ode-sympy", action="store_true", help="include SymPy in the RK4 table (minutes of set-up)")
    ap.add_argument("--write", action="store_true", help=f"write the '{SECTION}' section of RESULTS.md")
    ap.add_argument("--solve-only", action="store_true", help="only the sqp-ip solves (third table)")
    ap.add_argument("--write-solve", action="store_true", help=f"write the solve table as '{SOLVE_SECTION}'")
    args = ap.parse_args(argv)
    if args.solve_only:
        text = solve_table(args.N)
        print(text)
        if args.write_solve:
            write_section(SOLVE_SECTION, f"## {SOLVE_SECTION}\n\nCommand: `python benchmarks/bench_autodiff.py "
                          f"--solve-only --write-solve`  \nCommit: {commit()}  \nDate: {time.strftime('%Y-%m-%d')}  \n"
                          f"Machine: {machine(with_ipopt=False)} (shared with other jobs: solve times are "
                          "orders of magnitude)\n\nzambezi12, sqp-ip (configs/sqp-ip.ini), balance start.\n\n"
                          + text + "\n")
        return
    results = {}
    for N in args.N:
        rounds = args.rounds or (400 if N <= 1000 else 40)
        results[N] = measure(N, args.variants, rounds)
    text = table(results, args.N, args.variants)
    print(text)
    ode_N = 252
    ode = measure_ode(ode_N, ["casadi-llvm", "casadi-numba", "casadi-vm", "casadi-jit"] + (["sympy"] if args.ode_sympy else []), 100)
    ode_text = ode_table(ode, ode_N)
    print(ode_text)
    if args.write:
        cmd = "python benchmarks/bench_autodiff.py --write" + (f" --N {' '.join(map(str, args.N))}" if args.N != [252, 12000] else "")
        write_section(SECTION, f"## {SECTION}\n\nCommand: `{cmd}`  \nCommit: {commit()}  \n"
                      f"Date: {time.strftime('%Y-%m-%d')}  \nMachine: {machine(with_ipopt=False)}\n\n"
                      "Median time per stage (ns) of each user-level stage method on zambezi12, and in "
                      "parentheses its ratio to the hand-written numba kernel, all variants measured "
                      "round robin in one process (the ratios are the figures to read: the machine "
                      "was shared with other jobs). Set-up: trace, differentiation and compilation of "
                      "the AD model (the hand-written kernels: first call, loaded from numba's disk "
                      "cache).\n\n" + text + "\n\n"
                      f"RK4 cart-pole (tests/problems/test_autodiff.py, n = 4, m = 1, r = 2, N = {ode_N}), "
                      "Lagrangian Hessian per stage, same process:\n\n" + ode_text + "\n")


if __name__ == "__main__":
    main()
