"""Cost of a problem's compiled evaluations (olado/problems/compiled.py) on zambezi12: per call
through a compiled receiving kernel against the Python entry points, and the cold start the four
compiled entries add.

    python benchmarks/bench_compiled_evaluations.py --N 24          # per call (this tree)
    python benchmarks/bench_compiled_evaluations.py --N 24 --cold   # cold start, twice

Per call: process time, best of 7 repetitions of ``--reps`` calls after a warm-up; (a) a
receiving kernel called from Python that calls ``values`` once, against ``eval_values``; (b) each
of the four inside a compiled loop, through its address and through its dispatcher (numba's
static call), against the bare kernel; (c) ``compiled_evaluations()`` (the data packed again).
``--cold``: a fresh NUMBA_CACHE_DIR per round; a child process times the first calls of the four
Python entry points (their kernels compiled), then ``compiled_evaluations()`` and one call of each
entry (what the entries add), then a second child the same on the warm cache. On a shared machine
the figures are orders of magnitude.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numba as nb
import numpy as np

from _timing import best_per_call


def _best(fn, reps):
    """Microseconds per call (_timing.best_per_call)."""
    return best_per_call(fn, reps) * 1e6


@nb.njit(cache=True)
def _receive(values, data, idata, X, U, f, cost):
    return values(data, idata, X, U, f, cost)


@nb.njit(cache=True)
def _loop_values(fn, d, i, X, U, f, cost, reps):
    s = 0.0
    for _ in range(reps):
        s += fn(d, i, X, U, f, cost)
    return s


@nb.njit(cache=True)
def _loop_derivatives(fn, d, i, X, U, lx, lu, lN, A, B, reps):
    s = 0
    for _ in range(reps):
        s += fn(d, i, X, U, lx, lu, lN, A, B)
    return s


@nb.njit(cache=True)
def _loop_hessians(fn, d, i, X, U, P, hxx, hxu, huu, reps):
    s = 0
    for _ in range(reps):
        s += fn(d, i, X, U, 1.0, P, hxx, hxu, huu)
    return s


@nb.njit(cache=True)
def _loop_final_hessian(fn, d, i, xN, H, reps):
    s = 0
    for _ in range(reps):
        s += fn(d, i, xN, 1.0, H)
    return s


@nb.njit(cache=True)
def _loop_kernel(kernel, k, X, U, inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E, f, cost, reps):
    s = 0.0
    N = U.shape[0]
    for _ in range(reps):
        s += kernel(k, X[:N], U, X[N], inflow, evap, fa, fh, alpha, psi, uref, V_ref, phi, fe, nu_E, f, cost)[0]
    return s


def _problem(N):
    from olado.problems.zambezi import zambezi_problem
    p = zambezi_problem("zambezi12", N=N)
    U = p.initial_guess()
    X, P = p.simulate(U), np.ones((N, 6))
    f, cost = np.empty((N, 6)), np.empty(N)
    lx, lu, lN, A, B = np.empty((N, 6)), np.empty((N, 7)), np.empty(6), np.empty((N, 6, 6)), np.empty((N, 6, 7))
    out = (f, cost, lx, lu, lN, A, B, np.empty((N, 6, 6)), np.empty((N, 6, 7)), np.empty((N, 7, 7)), np.empty((6, 6)))
    return p, X, U, P, out


def _calls(ev, X, U, P, out):
    """One call of each of the four (Python to dispatcher)."""
    f, cost, lx, lu, lN, A, B, hxx, hxu, huu, H = out
    d, i = ev.data, ev.idata
    return (ev.values(d, i, X, U, f, cost), ev.derivatives(d, i, X, U, lx, lu, lN, A, B),
            ev.hessians(d, i, X, U, 1.0, P, hxx, hxu, huu), ev.final_hessian(d, i, X[-1], 1.0, H))


def _cold_child(N):
    p, X, U, P, out = _problem(N)
    t = time.perf_counter()
    p.eval_values(X, U), p.eval_first_derivatives(X, U), p.eval_stage_hessians(X, U, 1.0, P)
    p.eval_final_hessian(X[-1], 1.0)
    t_python = time.perf_counter() - t
    t = time.perf_counter()
    _calls(p.compiled_evaluations(), X, U, P, out)
    print(f"{t_python:.2f} {time.perf_counter() - t:.2f}")


def _timed(fn, *args, reps):
    fn(*args, 10)
    t = time.process_time()
    fn(*args, reps)
    return (time.process_time() - t) / reps * 1e6


def _in_loop(N, reps):
    from olado.problems import zambezi_kernels as zk
    p, X, U, P, out = _problem(N)
    ev = p.compiled_evaluations()
    f, cost, lx, lu, lN, A, B, hxx, hxu, huu, H = out
    d, i = ev.data, ev.idata
    args = {"values": (_loop_values, (X, U, f, cost)), "derivatives": (_loop_derivatives, (X, U, lx, lu, lN, A, B)),
            "hessians": (_loop_hessians, (X, U, P, hxx, hxu, huu)), "final_hessian": (_loop_final_hessian, (X[-1], H))}
    rows = []
    for name, (loop, rest) in args.items():
        fn = getattr(ev, name)
        for label, obj in (("address", fn), ("dispatcher", fn.dispatcher)):
            rows.append(f"{name} ({label}) {_timed(loop, obj, d, i, *rest, reps=reps):.2f}")
    t = _timed(_loop_kernel, zk._values_kernel, p._K, X, U, p.inflow, p.evaporation, p.fa, p.fh, p.alpha, p.psi,
               p.u_ref, p.V_ref, p.phi, p.fe, p.nu_E, f, cost, reps=reps)
    rows.append(f"_values_kernel alone {t:.2f}")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=int, default=24)
    ap.add_argument("--reps", type=int, default=20000)
    ap.add_argument("--cold", action="store_true", help="cold start of the entries (fresh numba caches)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        return _cold_child(a.N)
    if a.cold:
        for r in range(a.rounds):
            with tempfile.TemporaryDirectory() as cache:
                env = dict(os.environ, NUMBA_CACHE_DIR=cache)
                for state in ("cold", "warm"):
                    run = subprocess.run([sys.executable, __file__, "--child", "--N", str(a.N)], env=env,
                                         capture_output=True, text=True, check=True)
                    t_python, t_entries = run.stdout.split()
                    print(f"round {r} {state}: Python entry points' first calls {t_python} s, "
                          f"compiled_evaluations() + one call each {t_entries} s")
        return 0
    p, X, U, P, out = _problem(a.N)
    ev = p.compiled_evaluations()
    f, cost = out[:2]
    print(f"zambezi12 N = {a.N}, us per call")
    receive = _best(lambda: _receive(ev.values, ev.data, ev.idata, X, U, f, cost), a.reps)
    print(f"receiving kernel + values, from Python {receive:.2f}")
    print(f"eval_values {_best(lambda: p.eval_values(X, U), a.reps):.2f}")
    print(f"compiled_evaluations() {_best(p.compiled_evaluations, a.reps):.2f}")
    print("in a compiled loop: " + "; ".join(_in_loop(a.N, a.reps)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
