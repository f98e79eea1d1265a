"""Where the time of an interior-point iteration goes (issue 16 item 2): per QP iteration of the
Riccati interior-point QP inside ``sqp-ip``, and per iteration of ``ipm``, by stage.

sqp-ip: the QPs of one SQP solve are recorded (with their warm starts and tolerances) and solved
again ``--repeats`` times; ipm: the whole solve is repeated. Times are process time (the
machine is shared: wall time would count other jobs), first without timers (the per-iteration
total), then with a timer around every compiled kernel call (olado.linalg.codegen's kernel sets:
the Riccati factorization and solves, the QP's residual and bookkeeping kernels) and a few
Python stages; each stage's time is exclusive (nested timed calls subtracted), the rest of the
iteration is "Python glue". The timers themselves add about a microsecond per call, charged to
the glue: the shares at small N are approximate.

    python benchmarks/bench_qp_profile.py                       # zambezi12 N = 24, zambezi N = 12 000
    python benchmarks/bench_qp_profile.py --cases zambezi12:24 --solvers sqp-ip --no-write
"""

from __future__ import annotations

import argparse
import copy
import datetime
import time
from collections import defaultdict

from _common import HERE, commit, machine, write_section

from olado.config import load_config, make_solver
from olado.linalg import codegen
from olado.problems.zambezi import zambezi_problem
from olado.qp.interior_point import presolve, solver as ip_solver
from olado.solvers.ipm import newton as ipm_newton, solver as ipm_solver

SECTION = "Interior-point iterations: time per stage (issue 16 item 2)"
CASES = ["zambezi12:24", "zambezi:12000"]
RICCATI = ("k:factor", "k:factor_fixed", "k:factor_fixed_loops", "k:factor_plain", "k:solve", "k:solve_fixed",
           "k:solve_plain", "k:newton_solve")


class Timers:
    """Exclusive process-time timers around functions (a stack subtracts nested timed calls)."""

    def __init__(self):
        self.acc, self.calls, self.stack = defaultdict(float), defaultdict(int), []

    def wrap(self, name, f):
        clock, acc, calls, stack = time.process_time, self.acc, self.calls, self.stack

        def timed(*a, **kw):
            t = clock()
            stack.append(0.0)
            try:
                return f(*a, **kw)
            finally:
                dt = clock() - t
                acc[name] += dt - stack.pop()
                calls[name] += 1
                if stack:
                    stack[-1] += dt
        return timed

    def wrap_kernels(self):
        """Every compiled kernel already bound in a kernel set (called once before)."""
        undo = []
        for ks in codegen._KERNEL_SETS.values():
            for name, entry in list(vars(ks).items()):
                if not isinstance(entry, codegen._FirstCall):
                    setattr(ks, name, self.wrap("k:" + name, entry))
                    undo.append((ks, name, entry))
        return undo


def _patch(timers, targets):
    undo = []
    for owner, attr, label in targets:
        f = getattr(owner, attr)
        setattr(owner, attr, timers.wrap(label, f))
        undo.append((owner, attr, f))
    return undo


def _unpatch(undo):
    for owner, attr, f in reversed(undo):
        setattr(owner, attr, f)


def _record_qps(family, N):
    """The QPs of one sqp-ip solve: (QP solver, QP, warm start, options) per QP solve."""
    solver = make_solver(load_config(HERE.parent / "configs" / "sqp-ip.ini"))
    solver.solve(zambezi_problem(family, N=min(N, 24), start="balance"))       # warm-up (compiled kernels)
    calls, orig = [], ip_solver.InteriorPointQP.solve

    def record(self, qp, warm_start=None, limits=None):
        calls.append((self, copy.deepcopy(qp), copy.deepcopy(warm_start), copy.deepcopy(self.options)))
        return orig(self, qp, warm_start, limits)
    ip_solver.InteriorPointQP.solve = record
    try:
        solver.solve(zambezi_problem(family, N=N, start="balance"))
    finally:
        ip_solver.InteriorPointQP.solve = orig
    return calls


def _replay(calls):
    its = 0
    for qp_solver, qp, warm, options in calls:
        qp_solver.options = options
        its += qp_solver.solve(qp, warm_start=warm).iterations
    return its


def profile_sqp_ip(family, N, repeats, stages=True):
    calls = _record_qps(family, N)
    its = _replay(calls)
    best = min(_timed(lambda: _replay(calls)) for _ in range(repeats))
    timers = Timers()
    if not stages:
        return f"sqp-ip, {len(calls)} QPs, {its} QP iterations", best / its, None, 0
    P, S = presolve._Prepared, ip_solver.InteriorPointQP
    undo = timers.wrap_kernels()
    undo += _patch(timers, [(P, "__init__", "QP set-up (_Prepared)"), (S, "_initial_point", "starting point"),
                            (S, "_warm_point", "starting point"), (S, "_finish", "QP result (_finish)"),
                            (S, "solve", "total")])
    try:
        for _ in range(repeats):
            _replay(calls)
    finally:
        _unpatch(undo)
    return f"sqp-ip, {len(calls)} QPs, {its} QP iterations", best / its, timers, repeats * its


def profile_ipm(family, N, repeats, stages=True):
    solver = make_solver(load_config(HERE.parent / "configs" / "ipm.ini"))
    solver.solve(zambezi_problem(family, N=min(N, 24), start="balance"))       # warm-up
    problems = [zambezi_problem(family, N=N, start="balance") for _ in range(2 * repeats + 1)]
    res = solver.solve(problems.pop())
    its = res.iterations
    best = min(_timed(lambda: solver.solve(problems.pop())) for _ in range(repeats))
    timers = Timers()
    if not stages:
        return f"ipm, {its} iterations", best / its, None, 0
    K = ipm_newton.KKTMatrix
    undo = timers.wrap_kernels()
    undo += _patch(timers, [(ipm_solver, "evaluate", "evaluations (functions, Jacobians)"),
                            (ipm_solver, "newton_system", "Newton system set-up (Hessians, Sigma)"),
                            (K, "try_factor", "factorization set-up"), (K, "solve", "Newton solve set-up"),
                            (ipm_solver, "line_search", "line search (barrier, filter, trial points)"),
                            (ipm_solver, "optimality_errors", "optimality errors"),
                            (ipm_solver, "barrier_gradient", "barrier gradient"),
                            (ipm_solver, "take_step", "step (multipliers, safeguard)")])
    top = timers.wrap("total", solver.solve)
    try:
        for _ in range(repeats):
            top(problems.pop())
    finally:
        _unpatch(undo)
    return f"ipm, {its} iterations", best / its, timers, repeats * its


def _timed(f):
    t = time.process_time()
    f()
    return time.process_time() - t


def _rows(label, per_it, timers, n_its):
    total = sum(timers.acc.values())
    riccati = sum(timers.acc[k] for k in RICCATI)
    rows = [f"{label}: {1e6 * per_it:.1f} us per iteration (no timers); with timers {1e6 * total / n_its:.1f} us, "
            f"Riccati factorization + solves {100 * riccati / total:.1f} %", "",
            "| stage | us / iteration | share | calls / iteration |", "|:--|--:|--:|--:|"]
    for name, t in sorted(timers.acc.items(), key=lambda kv: -kv[1]):
        shown = "Python glue (the rest)" if name == "total" else name
        if t / total < 0.002:
            continue
        rows.append(f"| {shown} | {1e6 * t / n_its:.1f} | {100 * t / total:.1f} % | "
                    f"{'' if name == 'total' else f'{timers.calls[name] / n_its:.2f}'} |")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=CASES, help="family:N")
    ap.add_argument("--solvers", nargs="*", default=["sqp-ip", "ipm"], choices=["sqp-ip", "ipm"])
    ap.add_argument("--repeats", type=int, default=None, help="default: 20 below N = 1 000, else 1")
    ap.add_argument("--totals", action="store_true", help="only the time per iteration (no stages; not written)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    out = []
    for case in args.cases:
        family, N = case.split(":")
        N = int(N)
        repeats = args.repeats or (20 if N < 1000 else 1)
        for name in args.solvers:
            run = profile_sqp_ip if name == "sqp-ip" else profile_ipm
            label, per_it, timers, n_its = run(family, N, repeats, stages=not args.totals)
            if args.totals:
                print(f"{family} N = {N}, {label}: {1e6 * per_it:.1f} us per iteration", flush=True)
                continue
            rows = _rows(f"{family} N = {N}, {label}", per_it, timers, n_its)
            print("\n".join(rows) + "\n", flush=True)
            out += rows + [""]
    if args.totals:
        return
    shown = " ".join(argv if argv is not None else __import__("sys").argv[1:])
    text = (f"## {SECTION}\n\n`python benchmarks/bench_qp_profile.py {shown}`".rstrip() +
            f" at {commit()}, {datetime.date.today()}, {machine()}; process time, the machine shared with "
            "other jobs.\n\n" + "\n".join(out))
    if not args.no_write:
        write_section(SECTION, text)
    print(text)


if __name__ == "__main__":
    main()
