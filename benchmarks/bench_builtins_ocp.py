"""The built-in continuous-time problems rewritten on olado.OCP against their implementations
before the rewrite (issue 15 item 2, docs/continuous-time.md).

The modules testproblems, literature, cops and infeasible of an earlier commit (``--before``,
read by ``git show``) are loaded side by side with the current ones, as
``olado.problems._before_<name>``. For every rewritten problem and both schemes (RK4, Euler) the
script checks that the DOCP is the same -- dimensions, x^0, bounds, start point, equality masks,
values and first derivatives to 1e-10 relative (``check_derivatives`` at a perturbed start) -- and
prints the largest Hessian difference (the old finite-difference Hessians against the exact
ones); then it solves both at the default N by sqp-ip and IPOPT (RK4: status, iterations,
objective). ``--timing`` times vanderpol, rayleigh and cstr at N = 12 000: the sequential
simulation, the values, the first derivatives and the stage Hessians (best of 5), and the
sqp-ip solve.

    python benchmarks/bench_builtins_ocp.py --before f8e7f72 [--timing] [--write]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from _common import commit, machine, write_section  # noqa: E402

import olado  # noqa: E402
from olado.problems import check_derivatives  # noqa: E402

SECTION = "Built-in problems on OCP: the same DOCPs as before the rewrite"
MODULES = ("testproblems", "literature", "cops", "infeasible")
#: (module, class) of every rewritten problem
REWRITTEN = [("testproblems", c) for c in ("VanDerPol", "Rayleigh", "CSTR")] + \
    [("variants", "RayleighMixed")] + \
    [("literature", c) for c in ("Brachistochrone", "BrachistochronePoint", "DoubleIntegrator", "BrysonDenham",
                                 "BangBangCart", "MoonLander", "LotkaFishing", "BatchReactor", "AlpRider",
                                 "Dubins", "RigidBody", "Obstacle", "CartPole", "OrbitRaising")] + \
    [("cops", c) for c in ("Goddard", "HangGlider", "RobotArm", "ParticleSteering", "CatalystMixing",
                           "HangingChain")] + \
    [("infeasible", c) for c in ("CartTooShort", "SteeringTooShort", "VanDerPolContradict", "BatchOveryield",
                                 "CatalystOverfull")]
#: problems built with settings: (module, class, keyword arguments)
REWRITTEN_WITH = [("cops", "HangingChain", {"length": 2.0, "name": "chain-too-short"})]
#: problems whose state blows up under a perturbed start (compared at the literature's start)
AT_START = ("Goddard", "HangGlider")


def load_before(rev):
    """The modules of commit ``rev`` as olado.problems._before_<name> (their relative imports of
    each other redirected to the old copies)."""
    root = HERE.parent
    out = {}
    for name in MODULES + ("variants",):
        src = subprocess.run(["git", "show", f"{rev}:olado/problems/{name}.py"], cwd=root, check=True,
                             capture_output=True, text=True).stdout
        for other in MODULES:
            src = src.replace(f"from .{other} import", f"from ._before_{other} import")
        src = src.replace("cache=True", "cache=False")     # numba caches only functions of real files
        full = f"olado.problems._before_{name}"
        spec = importlib.util.spec_from_loader(full, loader=None)
        mod = importlib.util.module_from_spec(spec)
        mod.__package__ = "olado.problems"
        sys.modules[full] = mod
        exec(compile(src, f"{rev}:olado/problems/{name}.py", "exec"), mod.__dict__)
        out[name] = mod
    return out


def same_docp(a, b, method):
    """Assert the structural equalities; (largest relative difference of the values and first
    derivatives, of the Hessian blocks)."""
    assert (a.n, a.m, a.N, a.r, a.rN, a.name) == (b.n, b.m, b.N, b.r, b.rN, b.name)
    for arr in ("x0", "x_lower", "x_upper", "u_lower", "u_upper", "stage_equality_mask", "final_equality_mask"):
        np.testing.assert_array_equal(getattr(a, arr), getattr(b, arr), err_msg=arr)
    U0 = b.initial_guess()
    np.testing.assert_array_equal(a.initial_guess(), U0)
    xa, xb = a.initial_state_guess(U0), b.initial_state_guess(U0)
    assert (xa is None) == (xb is None)
    if xa is not None:
        np.testing.assert_array_equal(xa, xb)
    if type(b).__name__ in AT_START and xb is not None:
        X, U = xb, U0
    else:
        U = U0 + 0.01 * np.random.default_rng(2).standard_normal(U0.shape)
        X = b.simulate(U)
    first = check_derivatives(a, b, X, U, rtol=1e-10, atol=1e-12, hessians=False)
    assert first.ok, str(first)
    full = check_derivatives(a, b, X, U, rtol=1.0, atol=1.0)
    hess = max((c.max_rel_error for c in full.checks if "hessian" in c.name), default=0.0)
    return first.worst.max_rel_error, hess


def compare(before, solve=True):
    import olado.problems.cops as cops           # noqa: PLC0415
    import olado.problems.infeasible as infeasible   # noqa: PLC0415
    import olado.problems.literature as literature   # noqa: PLC0415
    import olado.problems.testproblems as testproblems   # noqa: PLC0415
    import olado.problems.variants as variants   # noqa: PLC0415
    now = {"testproblems": testproblems, "literature": literature, "cops": cops, "infeasible": infeasible,
           "variants": variants}
    rows = []
    for mod, cls, kw in [r + ({},) for r in REWRITTEN] + REWRITTEN_WITH:
        for method in ("rk4", "euler"):
            a, b = getattr(now[mod], cls)(method=method, **kw), getattr(before[mod], cls)(method=method, **kw)
            first, hess = same_docp(a, b, method)
            row = {"problem": a.name, "method": method, "first": first, "hessian": hess}
            if solve and method == "rk4":
                for cfg in ("sqp-ip", "ipopt"):
                    rb, ra = (olado.solve(p, config=HERE.parent / "configs" / f"{cfg}.ini") for p in (b, a))
                    row[cfg] = (rb.status.value, rb.iterations, rb.objective, ra.status.value, ra.iterations, ra.objective)
            rows.append(row)
            print(row, flush=True)
    return rows


def best(f, rounds=5):
    out = []
    for _ in range(rounds):
        t = time.perf_counter()
        f()
        out.append(time.perf_counter() - t)
    return min(out)


def timing(before, N=12_000):
    from olado.problems import get_problems   # noqa: PLC0415
    rows = []
    for name in ("vanderpol", "rayleigh", "cstr"):
        for label, make in (("before", before["testproblems"].PROBLEMS[name]), ("OCP", get_problems()[name])):
            t = time.perf_counter()
            p = make(N=N)
            U = p.initial_guess()
            X = p.simulate(U)
            setup = time.perf_counter() - t
            P = np.random.default_rng(0).standard_normal((N, p.n))
            r = {"problem": name, "model": label, "setup": setup, "simulate": best(lambda: p.simulate(U)),
                 "values": best(lambda: (p.eval_dynamics(X, U), p.eval_stage_costs(X, U))),
                 "jacobians": best(lambda: (p.eval_dynamics_jacobians(X, U), p.eval_stage_cost_gradients(X, U))),
                 "hessians": best(lambda: p.eval_stage_hessians(X, U, 1.0, P))}
            t = time.perf_counter()
            res = olado.solve(p, config=HERE.parent / "configs" / "sqp-ip.ini")
            r["solve"], r["status"], r["iterations"], r["objective"] = time.perf_counter() - t, res.status.value, res.iterations, res.objective
            rows.append(r)
            print(r, flush=True)
    return rows


def markdown(rev, rows, trows):
    lines = [f"## {SECTION}", "", f"Command: `python benchmarks/bench_builtins_ocp.py --before {rev} --timing --write`  ",
             f"Commit: {commit()}  ", f"Date: {time.strftime('%Y-%m-%d')}  ", f"Machine: {machine()}", "",
             f"Every rewritten problem against its implementation at {rev}: the same dimensions, x^0, bounds, start "
             "point (controls and states) and equality masks (asserted), values and first derivatives "
             "(largest relative difference at a perturbed start; goddard and hang-glider at the "
             "literature's start), the stage and final Hessians (the old ones are finite differences for the "
             "ContinuousDOCPs without ExactHessians); sqp-ip and IPOPT at the default N (RK4).", "",
             "| problem | scheme | values, 1st derivatives | Hessians | sqp-ip before | sqp-ip OCP | IPOPT before | IPOPT OCP |",
             "|:--|:--|--:|--:|:--|:--|:--|:--|"]
    fmt = lambda s, i, j: f"{s} {i} {j:.10g}"   # noqa: E731
    for r in rows:
        cells = [r["problem"], r["method"], f"{r['first']:.1e}", f"{r['hessian']:.1e}"]
        for cfg in ("sqp-ip", "ipopt"):
            if cfg in r:
                sb, ib, jb, sa, ia, ja = r[cfg]
                cells += [fmt(sb, ib, jb), fmt(sa, ia, ja)]
            else:
                cells += ["", ""]
        lines.append("| " + " | ".join(cells) + " |")
    if trows:
        lines += ["", "N = 12 000 (best of 5, ms; the solve in s; the machine was shared: orders of magnitude):", "",
                  "| problem | model | set-up (s) | simulate | values | 1st derivatives | Hessians | sqp-ip | iterations | objective |",
                  "|:--|:--|--:|--:|--:|--:|--:|--:|--:|--:|"]
        for r in trows:
            lines.append(f"| {r['problem']} | {r['model']} | {r['setup']:.2f} | {1e3 * r['simulate']:.2f} | "
                         f"{1e3 * r['values']:.2f} | {1e3 * r['jacobians']:.2f} | {1e3 * r['hessians']:.2f} | "
                         f"{r['solve']:.2f} s ({r['status']}) | {r['iterations']} | {r['objective']:.10g} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="the commit before the rewrite (e.g. f8e7f72)")
    ap.add_argument("--timing", action="store_true", help="also time vanderpol, rayleigh, cstr at N = 12 000")
    ap.add_argument("--no-solve", action="store_true", help="compare the DOCPs only")
    ap.add_argument("--write", action="store_true", help="write the RESULTS.md section")
    args = ap.parse_args(argv)
    before = load_before(args.before)
    rows = compare(before, solve=not args.no_solve)
    trows = timing(before) if args.timing else []
    text = markdown(args.before, rows, trows)
    print(text)
    if args.write:
        write_section(SECTION, text)


if __name__ == "__main__":
    main()
