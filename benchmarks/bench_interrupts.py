"""Interrupt stress test: SIGINT or SIGTERM at random times during ``olado solve zambezi --N 12000
--save`` (docs/interrupts.md).

For each configuration (the default, configs/sqp-ip.ini, configs/ipopt.ini) one uninterrupted
calibration run measures the command's wall time T; then ``--runs`` runs each get SIGINT or
SIGTERM (alternately) at a time drawn uniformly from [0, 1.1 T] after the process started --
during start-up, the problem's construction, the solve, or after it. Every run must leave either
no result file or a complete one that ``Result.load`` reads, with status ``interrupted`` (or the
solver's own status when it had finished first) and finite trajectories of the right shapes; a
file that fails that is counted as corrupt. Reported per configuration: the outcomes, the exit
codes, the time from the signal to the process's exit and to the solver's stop (the interrupted
result's ``info["interrupt_latency_s"]``), median and max.

    python benchmarks/bench_interrupts.py                  # 20 runs per configuration, RESULTS.md
    python benchmarks/bench_interrupts.py --runs 3 --no-write
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import HERE, commit, machine, write_section

from olado.errors import OladoError
from olado.result import Result, Status

REPO = HERE.parent
SECTION = "Interrupts: SIGINT / SIGTERM during olado solve zambezi --N 12000 --save"
CONFIGS = {"default": [], "sqp-ip.ini": ["--config", str(REPO / "configs" / "sqp-ip.ini")],
           "ipopt.ini": ["--config", str(REPO / "configs" / "ipopt.ini")]}
N, n, m = 12000, 6, 7


def command(out, config_args, problem="zambezi", N=N):
    return [sys.executable, "-m", "olado", "solve", problem, "--N", str(N), "--save", str(out), *config_args]


def default_signals():
    """In the child before exec: SIGINT and SIGTERM back to their defaults (a background job of a
    non-interactive shell starts with SIGINT ignored, and the child would inherit that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def run_once(folder, config_args, delay=None, signum=None, problem="zambezi", N=N):
    """One ``olado solve`` run, signalled ``delay`` seconds after its start (None: never).
    Returns a dict: exit code, times, and the outcome of checking what it left in ``folder``."""
    out = Path(folder) / "run.json"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    t0 = time.perf_counter()
    proc = subprocess.Popen(command(out, config_args, problem, N), cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=default_signals)
    sent = None
    if delay is not None:
        try:
            proc.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            proc.send_signal(signum)
            sent = time.perf_counter()
    stdout, stderr = proc.communicate(timeout=3600)
    end = time.perf_counter()
    rec = {"code": proc.returncode, "wall": end - t0, "signal": signal.Signals(signum).name if signum else None,
           "delay": delay, "to_exit": (end - sent) if sent is not None else None}
    rec.update(check(folder, out, sent is not None))
    if rec["outcome"] == "corrupt":
        rec["stderr"] = stderr[-2000:]
    return rec


def check(folder, out, signalled):
    """What the run left: 'interrupted' (a complete interrupted result), 'finished' (a complete
    result with the solver's own status), 'none' (no result file), or 'corrupt'."""
    leftovers = sorted(p.name for p in Path(folder).iterdir() if p.name.startswith("."))
    npz_only = out.with_suffix(".npz").exists() and not out.exists()
    info = {"leftovers": leftovers, "npz_only": npz_only}
    if not out.exists():
        return dict(info, outcome="none")
    try:
        r = Result.load(out)
    except (OladoError, ValueError, KeyError, TypeError, OSError) as exc:
        return dict(info, outcome="corrupt", why=f"{type(exc).__name__}: {exc}"[:300])
    good = (r.x.shape == (N + 1, n) and r.u.shape == (N, m) and np.all(np.isfinite(r.x))
            and np.all(np.isfinite(r.u)) and r.N == N)
    if not good:
        return dict(info, outcome="corrupt", why="shapes or non-finite trajectories")
    if r.status is Status.INTERRUPTED:
        return dict(info, outcome="interrupted", iterations=r.iterations,
                    latency=r.info.get("interrupt_latency_s"))
    return dict(info, outcome="finished", status=r.status.value, iterations=r.iterations)


def stats(values):
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    return f"{statistics.median(values):.3f} / {max(values):.3f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="signalled runs per configuration")
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--no-write", action="store_true", help="print only; do not update RESULTS.md")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    load0 = os.getloadavg()[0]
    rows, failures = [], []
    for name in args.configs:
        with tempfile.TemporaryDirectory() as folder:
            cal = run_once(folder, CONFIGS[name])
        print(f"{name}: calibration {cal['wall']:.1f} s, code {cal['code']}, {cal['outcome']}", flush=True)
        runs = []
        for i in range(args.runs):
            signum = signal.SIGINT if i % 2 == 0 else signal.SIGTERM
            delay = rng.uniform(0.0, 1.1 * cal["wall"])
            with tempfile.TemporaryDirectory() as folder:
                rec = run_once(folder, CONFIGS[name], delay, signum)
            runs.append(rec)
            print(f"  {i + 1:2d} {rec['signal']:7s} at {delay:6.2f} s: code {rec['code']:4d}, {rec['outcome']:11s} "
                  f"exit after {rec['to_exit'] if rec['to_exit'] is not None else float('nan'):.3f} s, "
                  f"stop latency {rec.get('latency') if rec.get('latency') is not None else float('nan'):.3f} s"
                  + (f"  LEFTOVERS {rec['leftovers']}" if rec["leftovers"] else "")
                  + ("  NPZ WITHOUT JSON" if rec["npz_only"] else "")
                  + (f"  CORRUPT: {rec.get('why')}" if rec["outcome"] == "corrupt" else ""), flush=True)
            if rec["outcome"] == "corrupt" or rec["leftovers"]:
                failures.append((name, rec))
        rows.append((name, cal, runs))
    text = report(rows, load0, os.getloadavg()[0], args)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)
    return 1 if failures else 0


def report(rows, load0, load1, args):
    lines = [f"## {SECTION}", "",
             f"Command: `python benchmarks/bench_interrupts.py --runs {args.runs} --seed {args.seed}`  ",
             f"Commit: {commit(REPO)}  ",
             f"Date: {time.strftime('%Y-%m-%d')}  ",
             f"Machine: {machine()}  ",
             f"Load average (1 min) at start and end: {load0:.2f}, {load1:.2f} (a shared machine: times are "
             "indicative)", "",
             "Each run: `olado solve zambezi --N 12000 --save run.json [--config ...]`, SIGINT and SIGTERM "
             "alternately at a time uniform in [0, 1.1 T] after the process started (T: the configuration's "
             "uninterrupted wall time, calibration run); signals before olado's handler is installed (Python's "
             "start-up) end the process the default way. Outcomes: a complete interrupted result, a complete "
             "result with the solver's own status (it had finished), no result file, or a corrupt one (a file "
             "`Result.load` rejects, or wrong shapes / non-finite trajectories). Times in seconds, median / max: "
             "signal to exit (including printing and the atomic save of a 14 MB JSON + npz), and signal to the "
             "solver's stop (`info['interrupt_latency_s']` of the saved interrupted result).", "",
             "| config | T (s) | runs | interrupted, saved | finished first, saved | no file | corrupt | "
             "leftover temp files | exit codes | signal to exit (s) | signal to solver stop (s) |",
             "|:--|--:|--:|--:|--:|--:|--:|--:|:--|--:|--:|"]
    for name, cal, runs in rows:
        count = {k: sum(1 for r in runs if r["outcome"] == k) for k in ("interrupted", "finished", "none", "corrupt")}
        codes = {}
        for r in runs:
            codes[r["code"]] = codes.get(r["code"], 0) + 1
        code_text = ", ".join(f"{c}: {k}" for c, k in sorted(codes.items()))
        lines.append(f"| {name} | {cal['wall']:.1f} | {len(runs)} | {count['interrupted']} | {count['finished']} | "
                     f"{count['none']} | {count['corrupt']} | {sum(1 for r in runs if r['leftovers'])} | {code_text} | "
                     f"{stats([r['to_exit'] for r in runs])} | {stats([r.get('latency') for r in runs])} |")
    lines += ["", "Exit codes: 130 / 143 = 128 + SIGINT / SIGTERM (olado's handler: the result is saved); "
              "0 = converged before the signal; negative = ended by the signal itself (-2, -15: before olado's "
              "handler was installed, during Python's start-up)."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
