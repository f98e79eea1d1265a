"""Where ipm's peak memory sits on a long Zambezi horizon: the resident set sampled every few
milliseconds with the solve's phase marked, and (``--trace``) the numpy arrays alive at the
largest traced size, per allocating line, in bytes per stage.

The phases are marked by wrapping the functions of olado.solvers.ipm.solver (initial_state, its
least_squares_multipliers, iterate's update_barrier / newton_system / line_search / take_step,
the restorations, finish), the Riccati factorization and solve (KKTMatrix.factor, .solve) and the
certificate (certificate.certify_result) -- from here, the library is not edited. A sampling
thread reads the resident set (/proc/self/statm) every ``--interval`` s and keeps, per phase, the
largest value and the time it was seen; the report lists the phases by their largest resident set
(bytes per stage above the RSS after the warm-up at N = 12).

``--trace`` also runs tracemalloc (25 frames): the thread keeps the snapshot at the largest traced
size (a new snapshot once the traced size grew by 1 %) and the report gives the
phase of that snapshot and its allocations grouped by their innermost olado line. tracemalloc
slows the solve about 2-3x; use it at N <= 10^5.

``--patch NAME`` applies a proposed change by monkeypatching (the report of issue 16's memory
work; nothing here is a library change): see PATCHES.

    python benchmarks/bench_memtrace.py --N 1e5                     # phases by peak RSS
    python benchmarks/bench_memtrace.py --N 1e5 --trace --top 25    # + the arrays at the traced peak
    python benchmarks/bench_memtrace.py --N 1e6 --patch step costs finish   # proposed changes, measured
    python benchmarks/bench_memtrace.py --patch step costs finish --behaviour --suites builtin --configs ipm --out F
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import resource
import subprocess
import sys
import threading
import time
import tracemalloc

from _common import HERE

PAGE = os.sysconf("SC_PAGE_SIZE")
#: the phase stack the wrappers maintain (read by the sampling thread)
STACK = ["setup"]


def rss_bytes():
    """The current resident set size (bytes) from /proc/self/statm."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE


def years(N):
    return -(-int(N) // 12) * 12


class Sampler(threading.Thread):
    """Per phase (the wrapper stack joined by '/'): the largest RSS and when; with ``trace`` also
    the tracemalloc snapshot at the largest traced size."""

    def __init__(self, interval, trace=False, grow=1.01):
        super().__init__(daemon=True)
        self.interval, self.trace, self.grow = interval, trace, grow
        self.done = threading.Event()
        self.t0 = time.perf_counter()
        self.phases = {}            # phase -> [max rss, t at max, samples]
        self.timeline = []          # (t, rss, phase) when the phase changes or rss moves by > 1 %
        self.best_traced, self.snapshot, self.snapshot_phase = 0, None, None
        self.phase_traced = {}      # phase -> [max traced, snapshot there or None]
        self.snap_phases = ()       # phases (suffixes) whose own traced maximum gets a snapshot

    def sample(self):
        rss, phase, t = rss_bytes(), "/".join(STACK), time.perf_counter() - self.t0
        rec = self.phases.setdefault(phase, [0, 0.0, 0])
        rec[2] += 1
        if rss > rec[0]:
            rec[0], rec[1] = rss, t
        last = self.timeline[-1] if self.timeline else None
        if last is None or last[2] != phase or abs(rss - last[1]) > 0.01 * last[1]:
            self.timeline.append((t, rss, phase))
        if self.trace:
            cur, _ = tracemalloc.get_traced_memory()
            if cur > self.best_traced * self.grow:
                self.best_traced, self.snapshot_phase = cur, phase
                self.snapshot = tracemalloc.take_snapshot()
            rec = self.phase_traced.setdefault(phase, [0, None])
            if cur > rec[0] * self.grow:
                rec[0] = cur
                if any(phase.endswith(p) for p in self.snap_phases):
                    rec[1] = tracemalloc.take_snapshot()

    def run(self):
        while not self.done.wait(self.interval):
            self.sample()


def marked(name, fn):
    """fn with ``name`` pushed on the phase stack while it runs."""

    @functools.wraps(fn)
    def wrapper(*args, **kw):
        STACK.append(name)
        try:
            return fn(*args, **kw)
        finally:
            STACK.pop()

    return wrapper


def mark_phases():
    """Wrap the ipm solver's phases, the Riccati factor/solve and the certificate."""
    from olado.solvers import certificate
    from olado.solvers.ipm import newton, solver

    for name in ("initial_state", "iterate", "finish", "update_barrier", "newton_system", "line_search",
                 "take_step", "least_squares_multipliers", "restore", "restore_l1", "converged"):
        if hasattr(solver, name):           # (older commits lack some)
            setattr(solver, name, marked(name, getattr(solver, name)))
    for name in ("factor", "solve"):
        setattr(newton.KKTMatrix, name, marked(f"kkt.{name}", getattr(newton.KKTMatrix, name)))
    for name in ("certify_result", "least_squares_multipliers", "spot_check"):
        if hasattr(certificate, name):
            setattr(certificate, name, marked(f"cert.{name}" if name != "certify_result" else name,
                                              getattr(certificate, name)))


# ---------------------------------------------------------------------------- proposed changes
def _released(shape_of):
    from olado.linalg.riccati import _placeholder

    return tuple(_placeholder(a.shape) for a in shape_of)


def patch_step():
    """Before take_step evaluates the accepted point's derivatives: the iteration's Newton matrix
    lets its blocks go (KKTMatrix.release_blocks, as newton_system does one step later) unless the
    watchdog keeps its search, and the iterate's error and complementarity caches -- keyed by the
    old point, recomputed whenever asked again -- are dropped, so the old point's derivatives go
    too (solver.iterate / take_step)."""
    from olado.solvers.ipm import solver

    take_step = solver.take_step

    def take_step_released(setup, st, accepted):
        kkt = setup.last_kkt
        if kkt is not None and (st.watch is None or st.watch.search.kkt is not kkt):
            kkt.release_blocks()
        st.error_cache = st.compl_cache = None
        return take_step(setup, st, accepted)

    solver.take_step = take_step_released


def patch_costs():
    """After a successful factorization whose solve does not read the cost blocks (the Riccati
    back-end's fixed-size plain recursion: RiccatiFactorization.fixed_solve_operands is not None),
    Q, S, R go (in the matrix and its back-end) before the line search (newton.KKTMatrix.factor)."""
    from olado.solvers.ipm import newton

    factor = newton.KKTMatrix.factor

    def factor_released(self, *args, **kw):
        delta = factor(self, *args, **kw)
        k = self.kkt
        if delta is not None and self.plain and k is not None and k.fixed_solve_operands() is not None:
            d = k.data
            d.Q, d.S, d.R = _released((d.Q, d.S, d.R))
            k._costs = None
            self.Q, self.S, self.R = _released((self.Q, self.S, self.R))
        return delta

    newton.KKTMatrix.factor = factor_released


def patch_finish():
    """finish drops the last Newton matrix (Setup.last_kkt: its factors and blocks) before the
    stage KKT figures and the Result are made; the certificate runs after it."""
    from olado.solvers.ipm import solver

    finish = solver.finish

    def finish_released(setup, st):
        setup.last_kkt = None
        return finish(setup, st)

    solver.finish = finish_released


def patch_sigma():
    """KKTMatrix.release_blocks also lets the barrier diagonals Sx, Su go (the next matrix takes the
    back-end over with its own; the old ones are alive through the next factorization otherwise:
    newton_system's ``prev``)."""
    from olado.solvers.ipm import newton

    release = newton.KKTMatrix.release_blocks

    def release_sigma(self, sigma=True):
        # the library's release_blocks takes ``sigma`` since h-mem3 made this change (above
        # REUSE_MAX); the patch applies it at every size
        release(self, sigma=sigma)
        self.Sx, self.Su = _released((self.Sx, self.Su))

    newton.KKTMatrix.release_blocks = release_sigma


def patch_slacks():
    """After take_step, Bounds' per-point cache keeps the new iterate's entry only (the previous
    iterate's slacks served the dual step; a later request -- the watchdog going back -- computes
    them again, the same numbers)."""
    from olado.solvers.ipm import solver

    take_step = solver.take_step

    def take_step_slacks(setup, st, accepted):
        out = take_step(setup, st, accepted)
        b = setup.bounds
        b._points = [e for e in b._points if e.v is st.v]
        return out

    solver.take_step = take_step_slacks


def patch_spotcheck():
    """certificate.spot_check with the directions evaluated one at a time (the stacked shifted
    points, their values and the difference quotients of one direction alive at once instead of
    CHECK_DIRECTIONS'): every formula is elementwise, the largest ratio taken in the same order
    (directions in turn, the first largest kept), so the check's figures are the same numbers."""
    import numpy as np

    from olado.errors import OladoError
    from olado.solvers import certificate as c

    def ratios(p, pt, Vx, Vu, h):
        """The original's arithmetic for the directions (Vx, Vu) stacked: (worst, ratio, d5, an, rel,
        vals.shape[2]) or the _Check when the problem cannot be evaluated."""
        saved = p.counters.copy()
        try:
            vals = c._stacked_shifted_values(p, pt, Vx, Vu, h)
        except OladoError:
            p.counters.clear()
            p.counters.update(saved)
            try:
                vals = c._pointwise_values(p, pt, list(zip(Vx, Vu)), h)
            except OladoError as exc:
                return c._Check(None, False, "spot check skipped: the problem cannot be evaluated near the point "
                                f"({exc})")
        v1, m1, v2, m2 = (vals[:, i] for i in range(len(c._SHIFTS)))
        an, size = c._directional(pt, Vx, Vu)
        d_h = (v1 - m1) / (2 * h)
        d_2h = (v2 - m2) / (4 * h)
        d5 = (4 * d_h - d_2h) / 3
        av = np.abs(vals)
        rounding = c._EPS * (av[:, 0] + av[:, 1] + av[:, 2] + av[:, 3]) / h
        scale = np.maximum(size, np.abs(d5))
        allowed = c.CHECK_RTOL * scale + 10 * (np.abs(d_h - d_2h) + rounding) + 1e-300
        err = np.abs(d5 - an)
        rel = err / np.maximum(scale, 1e-300)
        worst = float(np.where(err > 10 * rounding, rel, 0.0).max())     # NaN kept (the original's max)
        ratio = (err / allowed).ravel()
        j = int(np.argmax(ratio))
        return worst, float(ratio[j]), j, (float(d5.ravel()[j]), float(an.ravel()[j]), float(rel.ravel()[j])), \
            vals.shape[2]

    def spot_check(p, pt, bounds, W, seed=c.CHECK_SEED):
        h = c.CHECK_STEP
        draw = c._uniform_draws(seed, c.CHECK_DIRECTIONS, pt.X.size + pt.U.size)
        Vx, Vu = c._directions(draw, pt, bounds, W, h)
        raw, best = -np.inf, None
        for d in range(Vx.shape[0]):
            out = ratios(p, pt, Vx[d:d + 1], Vu[d:d + 1], h)
            if isinstance(out, c._Check):
                return out
            w, r, j, figs, L = out
            raw = raw if raw != raw else (w if w != w else max(raw, w))    # np.max over all: NaN wins
            # np.argmax over all: the first largest, a NaN counting as the largest
            if best is None or (best[0] == best[0] and (r != r or r > best[0])):
                best = (r, j + d * L, figs, L)
        worst = max(0.0, raw)
        r, j, (d5, an, rel), L = best
        if not r > 1.0:
            return c._Check(worst, False, "")
        name, idx = c._entry_of(c._shapes(p), j % L)
        where = f" at stage {idx[0]}" if name in ("stage_cost", "dynamics", "stage_constraints") else ""
        if len(idx) == 2 or name == "final_constraints":
            where += f", component {idx[-1]}"
        source = p.derivative_sources().get(c._DERIVATIVE_NAMES[name], "")
        return c._Check(worst, True, (f"the derivative of {name}{where} ({source}) disagrees with a five-point "
                                      f"central difference along a random direction: {an:.6g} vs {d5:.6g} "
                                      f"(relative error {rel:.1e})"))

    c.spot_check = spot_check


PATCHES = {"step": patch_step, "costs": patch_costs, "finish": patch_finish, "sigma": patch_sigma,
           "slacks": patch_slacks, "spotcheck": patch_spotcheck}


# ---------------------------------------------------------------------------- the worker
def top_lines(snapshot, N, top):
    """The snapshot's allocations grouped by their innermost olado frame (file:line and the line's
    text), bytes per stage, largest first."""
    import linecache

    groups = {}
    for stat in snapshot.statistics("traceback"):
        frames = list(stat.traceback)      # oldest frame first (Python >= 3.7)
        olado = [fr for fr in frames if "olado" + os.sep in fr.filename]
        fr = olado[-1] if olado else frames[-1]
        key = f"{fr.filename.split('olado' + os.sep, 1)[-1]}:{fr.lineno}"
        text = linecache.getline(fr.filename, fr.lineno).strip()
        caller = ""
        if len(olado) >= 2:
            c = olado[-2]
            caller = f"{c.filename.split('olado' + os.sep, 1)[-1]}:{c.lineno}"
        g = groups.setdefault(key, [0, 0, text, set()])
        g[0] += stat.size
        g[1] += stat.count
        if caller:
            g[3].add(caller)
    rows = sorted(groups.items(), key=lambda kv: -kv[1][0])[:top]
    return [{"line": k, "bytes_per_stage": v[0] / N, "blocks": v[1], "text": v[2][:110],
             "callers": sorted(v[3])[:3]} for k, v in rows]


def worker(config, N, interval, trace, top, patches, snap=()):
    from olado.config import load_config, make_solver
    from olado.problems.zambezi import zambezi_problem

    for p in patches:
        PATCHES[p]()
    mark_phases()
    solver = make_solver(load_config(HERE.parent / "configs" / f"{config}.ini"))
    solver.solve(zambezi_problem("zambezi", N=12))              # warm-up: compiled kernels
    base = rss_bytes()
    if trace:
        tracemalloc.start(25)
    sampler = Sampler(interval, trace)
    sampler.snap_phases = tuple(snap)
    sampler.start()
    STACK[:] = ["build"]
    problem = zambezi_problem("zambezi", N=N)
    STACK[:] = ["solve"]
    t0 = time.perf_counter()
    res = solver.solve(problem)
    wall = time.perf_counter() - t0
    STACK[:] = ["after"]
    sampler.sample()
    sampler.done.set()
    sampler.join()
    out = {"config": config, "N": N, "patches": patches, "status": res.status.value, "iterations": res.iterations,
           "objective": res.objective, "solve_s": wall, "baseline_mb": base / 2 ** 20,
           "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
           "phases": {k: {"rss_mb": v[0] / 2 ** 20, "bytes_per_stage": (v[0] - base) / N, "t": v[1], "samples": v[2]}
                      for k, v in sorted(sampler.phases.items(), key=lambda kv: -kv[1][0])},
           "timeline": [(round(t, 3), round((r - base) / N), ph) for t, r, ph in sampler.timeline]}
    out["bytes_per_stage"] = (out["peak_mb"] * 2 ** 20 - base) / N
    if trace and sampler.snapshot is not None:
        _, peak = tracemalloc.get_traced_memory()
        out["traced_peak_per_stage"] = peak / N
        out["snapshot_per_stage"] = sampler.best_traced / N
        out["snapshot_phase"] = sampler.snapshot_phase
        out["top"] = top_lines(sampler.snapshot, N, top)
        out["phase_traced"] = {k: v[0] / N for k, v in sorted(sampler.phase_traced.items(), key=lambda kv: -kv[1][0])}
        out["phase_top"] = {k: top_lines(v[1], N, top) for k, v in sampler.phase_traced.items() if v[1] is not None}
    print(json.dumps(out), flush=True)


def robustness(groups, config, patches, path, time_limit=120.0):
    """The robustness entries of ``groups`` solved in this process (_robustness.solve_entry) after
    the patches; prints and (``path``) writes {entry: (status, iterations, objective)}."""
    from _robustness import solve_entry

    from olado.problems.suites import load_suite

    for p in patches:
        PATCHES[p]()
    out = {}
    for e in load_suite("robustness"):
        if e.group in groups:
            rec = solve_entry(e.name, config, time_limit)
            out[e.name] = (rec.get("status"), rec.get("iterations"), rec.get("objective"))
            print(e.name, *out[e.name], f"{rec.get('wall_s', 0):.1f} s", flush=True)
    if path:
        with open(path, "w") as f:
            json.dump(out, f)


def report(r, timeline):
    print(f"{r['config']} N = {r['N']} patches {r['patches'] or '-'}: {r['status']}, {r['iterations']} iterations, "
          f"J = {r['objective']:.10g}, {r['solve_s']:.1f} s; peak RSS {r['peak_mb']:.0f} MiB "
          f"({r['bytes_per_stage']:.0f} B / stage above the warm-up's {r['baseline_mb']:.0f} MiB)")
    print("phase (largest RSS first) | B / stage | t (s) | samples")
    for k, v in list(r["phases"].items())[:14]:
        print(f"  {k} | {v['bytes_per_stage']:.0f} | {v['t']:.2f} | {v['samples']}")
    if timeline:
        print("timeline (t, B / stage, phase):")
        for t, b, ph in r["timeline"]:
            print(f"  {t:8.3f} {b:6d} {ph}")
    if "top" in r:
        print(f"traced: peak {r['traced_peak_per_stage']:.0f} B / stage; snapshot {r['snapshot_per_stage']:.0f} "
              f"B / stage in phase {r['snapshot_phase']}")
        for row in r["top"]:
            print(f"  {row['bytes_per_stage']:7.0f}  {row['line']:38s} {row['text']}  <- {', '.join(row['callers'])}")
        print("traced maximum per phase (B / stage):")
        for k, v in list(r["phase_traced"].items())[:16]:
            print(f"  {v:7.0f}  {k}")
        for k, rows in r.get("phase_top", {}).items():
            print(f"at the traced maximum of {k} ({r['phase_traced'][k]:.0f} B / stage):")
            for row in rows:
                print(f"  {row['bytes_per_stage']:7.0f}  {row['line']:38s} {row['text'][:70]}  "
                      f"<- {', '.join(row['callers'])}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=float, default=1e5, help="horizon (rounded up to whole years)")
    ap.add_argument("--config", default="ipm", help="preset (configs/NAME.ini)")
    ap.add_argument("--interval", type=float, default=0.002, help="RSS sampling interval (s)")
    ap.add_argument("--trace", action="store_true", help="tracemalloc: the arrays alive at the traced peak (slow)")
    ap.add_argument("--top", type=int, default=20, help="allocating lines listed with --trace")
    ap.add_argument("--timeline", action="store_true", help="print the RSS timeline with the phases")
    ap.add_argument("--patch", nargs="*", default=[], choices=sorted(PATCHES),
                    help="proposed changes applied by monkeypatching (see the module docstring)")
    ap.add_argument("--snap", nargs="*", default=[], help="with --trace: phases (path suffixes, e.g. finish "
                    "line_search) whose own traced maximum is listed by allocating line")
    ap.add_argument("--json", help="also write the worker's record here")
    ap.add_argument("--behaviour", nargs=argparse.REMAINDER, help="instead of a solve: check_behaviour.py with these "
                    "arguments in this process, after the --patch changes (their iterates against main's fingerprints)")
    ap.add_argument("--robustness", nargs="+", metavar="GROUP", help="instead of a solve: the robustness set's "
                    "entries of these groups solved by --config in this process after the --patch changes (status, "
                    "iterations, objective per entry; compare two --json files of runs with and without patches)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.robustness:
        robustness(args.robustness, args.config, args.patch, args.json)
        return
    if args.behaviour is not None:
        import check_behaviour

        for p in args.patch:
            PATCHES[p]()
        check_behaviour.main(args.behaviour)
        return
    N = years(args.N)
    if args.worker:
        worker(args.config, N, args.interval, args.trace, args.top, args.patch, args.snap)
        return
    cmd = [sys.executable, __file__, "--worker", "--N", str(N), "--config", args.config, "--interval",
           str(args.interval), "--top", str(args.top), *(["--trace"] if args.trace else []),
           *(["--patch", *args.patch] if args.patch else []), *(["--snap", *args.snap] if args.snap else [])]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parent), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode or not lines:
        sys.exit(f"worker failed (exit {proc.returncode}): {proc.stderr[-3000:]}")
    r = json.loads(lines[-1])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(r, f)
    report(r, args.timeline)


if __name__ == "__main__":
    main()
