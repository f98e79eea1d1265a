"""Very long horizons: the 'zambezi' family (ZAMB2 data, inflow record repeated cyclically past
1965) up to N = 10^6 with one preset, each N in a fresh process: time, iterations, objective,
status, peak resident memory and bytes per stage (issue 16 item 5).

Each N runs in its own subprocess, so its peak RSS (``getrusage(RUSAGE_SELF).ru_maxrss``) is its
own. The worker warms the preset up at N = 12 (compiled kernels), records the RSS there (the
baseline: interpreter, numpy, numba, olado), builds the problem and solves it once.
Bytes per stage = (peak RSS - baseline) / N. N is rounded up to a whole number of years (a
multiple of 12): 10^6 -> 1 000 008.

``--components`` also traces the numpy allocations (tracemalloc, a sampling thread keeps the
snapshot at the largest traced size) and splits that peak by the layer that allocated it:
problem data, derivative arrays, solver state, QP work arrays, Riccati factors, result. Tracing
slows the solve; use it at N <= 10^5.

    python benchmarks/bench_million.py                          # ipm at N = 10^4, 10^5, 10^6; writes RESULTS.md
    python benchmarks/bench_million.py --N 12000 --configs ipm sqp-ip --components --no-write
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import subprocess
import sys
import threading
import time
import tracemalloc

from _common import HERE, commit, machine, write_section

SECTION = "Very long horizons (zambezi, N = 10^4 to 10^6): time and memory"

#: tracemalloc frames -> component: the first olado frame from the innermost one outwards that
#: names a layer; derivative arrays are the problem's eval_*_jacobian/hessian/gradient outputs
LAYERS = (("olado/linalg/", "Riccati factors"), ("olado/qp/", "QP work arrays"), ("olado/result.py", "result"))
DERIVATIVE_WORDS = ("jacobian", "hessian", "gradient")


def years(N):
    """N rounded up to a multiple of 12 (the Zambezi horizon is whole years)."""
    return -(-int(N) // 12) * 12


def rss_mb():
    """Peak resident set size of this process so far (MiB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class PeakSampler(threading.Thread):
    """Keeps the tracemalloc snapshot taken at the largest traced size seen (checked every
    ``interval`` s; a snapshot is taken when the traced size grew by more than ``grow``)."""

    def __init__(self, interval=0.005, grow=1.01):
        super().__init__(daemon=True)
        self.interval, self.grow = interval, grow
        self.best, self.snapshot, self.done = 0, None, threading.Event()

    def run(self):
        while not self.done.wait(self.interval):
            cur, _ = tracemalloc.get_traced_memory()
            if cur > self.best * self.grow:
                self.best, self.snapshot = cur, tracemalloc.take_snapshot()


def breakdown(snapshot, N):
    """Bytes per stage by component at the sampled peak."""
    import linecache

    out = {}
    for stat in snapshot.statistics("traceback"):
        frames = list(stat.traceback)[::-1]
        label = None
        for fr in frames:
            name = fr.filename.replace(os.sep, "/")
            hit = next((lab for key, lab in LAYERS if key in name), None)
            if hit:
                label = hit
                break
        if label is None:
            lines = " ".join(linecache.getline(fr.filename, fr.lineno) for fr in frames).lower()
            files = " ".join(fr.filename.replace(os.sep, "/") for fr in frames)
            if "olado/problems/" in files:
                label = "derivative arrays" if any(w in lines for w in DERIVATIVE_WORDS) else "problem data and values"
            elif "olado/solvers/" in files:
                label = "solver state"
            else:
                label = "other"
        out[label] = out.get(label, 0) + stat.size
    return {k: v / N for k, v in sorted(out.items(), key=lambda kv: -kv[1])}


def worker(config, N, components, max_time):
    """One solve in this process; prints one JSON line."""
    from olado.config import load_config, make_solver
    from olado.problems.zambezi import zambezi_problem

    overrides = {"max_time": max_time} if max_time else None       # the preset's own solver section
    solver = make_solver(load_config(HERE.parent / "configs" / f"{config}.ini", overrides=overrides))
    solver.solve(zambezi_problem("zambezi", N=12))              # warm-up: compiled kernels
    base = rss_mb()
    sampler = None
    if components:
        tracemalloc.start(25)
        sampler = PeakSampler()
        sampler.start()
    t0 = time.perf_counter()
    problem = zambezi_problem("zambezi", N=N)
    build_s, build_rss = time.perf_counter() - t0, rss_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    res = solver.solve(problem)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {"config": config, "N": N, "status": res.status.value, "iterations": res.iterations,
           "qp_iterations": res.qp_iterations, "objective": res.objective, "build_s": build_s, "solve_s": wall,
           "cpu_s": cpu, "baseline_mb": base, "after_build_mb": build_rss, "peak_mb": rss_mb(),
           "callback_share": res.info.get("callback_share")}
    out["bytes_per_stage"] = (out["peak_mb"] - base) * 2 ** 20 / N
    if sampler is not None:
        sampler.done.set()
        sampler.join()
        _, peak = tracemalloc.get_traced_memory()
        out["traced_peak_mb"] = peak / 2 ** 20
        out["components"] = breakdown(sampler.snapshot, N) if sampler.snapshot else {}
        out["sampled_mb"] = sampler.best / 2 ** 20
    print(json.dumps(out), flush=True)


def run_one(config, N, components, max_time, timeout):
    """The worker in a fresh subprocess; its JSON (or a failure record)."""
    cmd = [sys.executable, __file__, "--worker", config, str(N), "--max-time", str(max_time)]
    if components:
        cmd.append("--components")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parent), os.environ.get("PYTHONPATH", "")]))
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {"config": config, "N": N, "status": f"killed after {timeout:g} s"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode or not lines:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"config": config, "N": N, "status": f"worker failed (exit {proc.returncode}): {tail}"}
    return json.loads(lines[-1])


def row(r):
    if "peak_mb" not in r:
        return f"| {r['N']} | {r['config']} | {r['status']} | - | - | - | - | - | - |"
    its = f"{r['iterations']}" + (f" / {r['qp_iterations']}" if r.get("qp_iterations") else "")
    return (f"| {r['N']} | {r['config']} | {r['status']} | {its} | {r['objective']:.10g} | {r['solve_s']:.1f} | "
            f"{r['cpu_s']:.1f} | {r['peak_mb']:.0f} | {r['bytes_per_stage']:.0f} |")


def load():
    """The machine's load averages (1, 5, 15 min), for the heading."""
    try:
        return "load average " + ", ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "load unknown"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=float, nargs="+", default=[1e4, 1e5, 1e6],
                    help="horizons (rounded up to whole years, multiples of 12)")
    ap.add_argument("--configs", nargs="+", default=["ipm"], help="presets (configs/NAME.ini)")
    ap.add_argument("--max-time", type=float, default=600.0, help="the solver's wall-time limit (s)")
    ap.add_argument("--components", action="store_true", help="trace allocations and split the peak by layer (slow)")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--worker", nargs=2, metavar=("CONFIG", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(args.worker[0], int(args.worker[1]), args.components, args.max_time)
        return
    header = ["| N | preset | status | iterations | objective | time (s) | CPU (s) | peak RSS (MiB) | bytes / stage |",
              "|--:|:--|:--|--:|--:|--:|--:|--:|--:|"]
    rows, comps, loads = [], [], []
    print("\n".join(header), flush=True)
    for N in (years(n) for n in args.N):
        for config in args.configs:
            loads.append(load())
            r = run_one(config, N, args.components, args.max_time, timeout=args.max_time * 1.5 + 120)
            rows.append(row(r))
            print(rows[-1], flush=True)
            if r.get("components"):
                parts = ", ".join(f"{k} {v:.0f}" for k, v in r["components"].items())
                comps.append(f"- {config}, N = {N}: traced peak {r['traced_peak_mb']:.0f} MiB "
                             f"({r['traced_peak_mb'] * 2 ** 20 / N:.0f} B / stage); at the sampled peak "
                             f"({r['sampled_mb']:.0f} MiB), bytes per stage: {parts}")
                print(comps[-1], flush=True)
    shown = " ".join(argv if argv is not None else sys.argv[1:])
    text = "\n".join([f"## {SECTION}", "",
                      f"Command: `{f'python benchmarks/bench_million.py {shown}'.strip()}`  ",
                      f"Commit: {commit()}  ", f"Date: {datetime.date.today().isoformat()}  ",
                      f"Machine: {machine(with_ipopt=False)}; {loads[0] if loads else load()} at the start", "",
                      "Family `zambezi`, balance start, each N in a fresh process after a warm-up at N = 12; "
                      f"wall-time limit {args.max_time:g} s. Peak RSS: the process's ru_maxrss (interpreter and "
                      "libraries included); bytes / stage: (peak RSS - RSS after the warm-up) / N. The machine "
                      "is shared: times are orders of magnitude, CPU time is the steadier figure.", "",
                      *header, *rows, *([""] + comps if comps else []), ""])
    if not args.no_write:
        write_section(SECTION, text)
    print(text)


if __name__ == "__main__":
    main()
