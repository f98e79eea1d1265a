"""Paper 001 sec. 6 on this machine: the Zambezi testing set (122 problems x 2 starts), every
configured solver against a reference, with Dolan-More performance profiles (paper eqs. (48)-(50)).

The set of paper 001 sec. 6: zambezi N = 12:12:420, zambezi8 12:12:216, zambezi9 and zambezi10
12:12:72, zambezi11 12:12:432, zambezi12 12:12:252 (122 problems, the inflow record only, no
cyclic extension), each from two starts: the balance controls (46)-(47) with simulated states,
and the SIF start point (outflow = inflow, every volume at V0; the paper's first start (45) is
the same kind of "outflow = inflow" trajectory). After a warm-up of every solver, each problem
is solved by every configured solver one after the other in the same process (side by side: a
shared machine's load changes between problems, hardly within one), ``--repeats`` times in
turn, the fastest solve kept. The first config is the reference of the objectives and time
ratios; ``--versus`` adds further ones (time ratios only), ``--split`` the horizon that
separates the size classes of the ratios (paper 001 Fig. 8: N < 216 and N >= 216).

    python benchmarks/bench_testset.py                       # writes RESULTS.md and the plot
    python benchmarks/bench_testset.py --configs ipopt sqp-ip --families zambezi12 --no-write
    python benchmarks/bench_testset.py --configs sqp-ip sqp-schittkowski sqp-as sqp-schittkowski-as ipopt \\
        --versus ipopt --section "..." --plot benchmarks/testset_profile_as.png

Another choice of configs than the default writes its own section (``--section``; by default
named after the configs) and plot, never the default's. ``--save-runs`` keeps every solve's
record as JSON, ``--from-runs`` rewrites the section from such a file without solving.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import shlex
import sys
from pathlib import Path

import numpy as np

from _common import HERE, commit, machine, write_section

from olado.problems.suites.zambezi_testset import GRID  # the set as data (also `olado bench zambezi-testset`)

SECTION = "Zambezi testing set of paper 001 sec. 6 (244 problems, performance profiles)"
CONFIGS = ["ipopt", "sqp-ip", "sqp-gondzio", "sqp-weighted", "sqp-sr1", "sqp-bfgs"]
PLOT = HERE / "testset_profile.png"
#: relative objective difference that counts as "the same objective"
SAME = 1e-6
#: the size classes of paper 001 Fig. 8
SPLIT = 216
FIELDS = ("status", "objective", "time_s", "iterations", "qp_iterations")


def profile(metric, solved, taus):
    """Dolan-More profile, paper eqs. (48)-(50): metric (P, S) with solved (P, S) booleans ->
    phi (S, len(taus)), the fraction of problems with log2(metric / best) <= tau; an unsolved
    problem has ratio r_M = inf. Problems no solver solved count against everyone."""
    m = np.where(solved, metric, np.inf)
    best = np.min(m, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        lr = np.where(np.isfinite(m), np.log2(m / best), np.inf)
    return np.array([[float(np.mean(lr[:, s] <= t)) for t in taus] for s in range(m.shape[1])])


# ---------------------------------------------------------------------------- solving
def solve_all(configs, problems, repeats):
    """Every problem by every config, side by side: ``repeats`` rounds over the configs, the
    fastest solve of each kept. -> list of {"problem": (family, N, start), config: record}."""
    from olado.config import load_config, make_solver
    from olado.problems.zambezi import zambezi_problem

    solvers = {c: make_solver(load_config(HERE.parent / "configs" / f"{c}.ini")) for c in configs}
    for s in solvers.values():
        s.solve(zambezi_problem("zambezi12", N=12))          # warm-up: imports, numba caches
    runs = []
    for fam, N, st in problems:
        row = {"problem": [fam, N, st]}
        for _ in range(repeats):
            for c in configs:
                rec = solve_one(solvers[c], lambda: zambezi_problem(fam, N=N, start=st, extend=None))
                if c not in row or rec["time_s"] < row[c]["time_s"]:
                    row[c] = rec
        runs.append(row)
        print(f"{fam:9s} N={N:3d} {st:7s}" + "".join(
            f" | {c} {row[c]['status'][:7]:7s} {row[c]['objective']:.9g} {row[c]['time_s']:.3f}s "
            f"it={row[c]['iterations']}/{row[c]['qp_iterations']}" for c in configs), flush=True)
    return runs


def solve_one(solver, make):
    try:
        r = solver.solve(make())
        return {"status": r.status.value, "objective": float(r.objective), "time_s": float(r.time_s),
                "iterations": int(r.iterations), "qp_iterations": int(r.qp_iterations)}
    except Exception as exc:               # counted as a failure, and shown
        return {"status": f"exception: {type(exc).__name__}: {exc}"[:120], "objective": math.nan,
                "time_s": math.inf, "iterations": -1, "qp_iterations": -1}


# ---------------------------------------------------------------------------- summary
class Table:
    """The runs as arrays (P problems x S configs)."""

    def __init__(self, runs, configs):
        self.configs = list(configs)
        self.problems = [tuple(r["problem"]) for r in runs]
        get = lambda key: np.array([[r[c][key] for c in configs] for r in runs], dtype=float)  # noqa: E731
        self.status = np.array([[r[c]["status"] for c in configs] for r in runs], dtype=object)
        self.obj, self.tim, self.its, self.qps = (get(k) for k in FIELDS[1:])
        self.solved = self.status == "success"
        self.N = np.array([p[1] for p in self.problems])

    def column(self, c):
        return self.configs.index(c)

    def ratios(self, j, ref, mask=None):
        """Time ratios config j / config ref on the problems both solved (within ``mask``)."""
        both = self.solved[:, j] & self.solved[:, ref] & (True if mask is None else mask)
        return self.tim[both, j] / self.tim[both, ref], both

    def rel(self, j, ref):
        return (self.obj[:, j] - self.obj[:, ref]) / np.abs(self.obj[:, ref])


def summary_rows(t):
    """Per config: solved, same / lower / higher (objective vs the reference), best, iterations."""
    best = np.nanmin(np.where(t.solved, t.obj, np.nan), axis=1)
    rows = []
    for j, c in enumerate(t.configs):
        ok = t.solved[:, j]
        both = ok & t.solved[:, 0]
        rel = t.rel(j, 0)
        rel_best = (t.obj[:, j] - best) / np.abs(best)
        ratios, _ = t.ratios(j, 0)
        its, qps = t.its[ok, j], t.qps[ok, j]
        rows.append(dict(config=c, solved=int(ok.sum()), same=int(np.sum(both & (np.abs(rel) <= SAME))),
                         lower=int(np.sum(both & (rel < -SAME))), higher=int(np.sum(both & (rel > SAME))),
                         best=int(np.sum(ok & (rel_best <= SAME))),
                         median_ratio=float(np.median(ratios)) if ratios.size else math.nan,
                         total=float(np.sum(t.tim[ok, j])),
                         iters=(int(its.min()), int(np.median(its)), int(its.max()), int(its.sum())) if ok.any()
                         else (0, 0, 0, 0),
                         qp=(int(np.median(qps)), int(qps.sum())) if ok.any() else (0, 0)))
    return rows


def ratio_rows(t, versus, split):
    """Per config and comparator: median time ratio over all problems both solved, over N < split
    and N >= split, and the ratio of the total times on the problems both solved."""
    rows = []
    for j, c in enumerate(t.configs):
        row = {"config": c}
        for v in versus:
            k = t.column(v)
            cells = []
            for mask in (None, t.N < split, t.N >= split):
                r, both = t.ratios(j, k, mask)
                cells.append((float(np.median(r)) if r.size else math.nan, int(both.sum())))
            _, both = t.ratios(j, k)
            total = float(np.sum(t.tim[both, j]) / np.sum(t.tim[both, k])) if both.any() else math.nan
            row[v] = (cells, total)
        rows.append(row)
    return rows


def other_minima(t, j, ref=0, shown=8):
    """The problems both solved at objectives more than SAME apart: (count lower, count higher,
    text listing the largest differences)."""
    rel = t.rel(j, ref)
    both = t.solved[:, j] & t.solved[:, ref] & (np.abs(rel) > SAME)
    idx = sorted(np.flatnonzero(both), key=lambda i: -abs(rel[i]))
    text = ", ".join(f"{t.problems[i][0]} {t.problems[i][1]} {t.problems[i][2]} {rel[i]:+.1e}" for i in idx[:shown])
    return int(np.sum(rel[both] < 0)), int(np.sum(rel[both] > 0)), text + (", ..." if len(idx) > shown else "")


def failure_lines(t):
    lines = []
    for j, c in enumerate(t.configs):
        mine = [(t.problems[i], t.status[i, j]) for i in np.flatnonzero(~t.solved[:, j])]
        if not mine:
            continue
        by = {}
        for prob, s in mine:
            by.setdefault(str(s).split(":")[0], []).append(prob)
        parts = []
        for s, probs in sorted(by.items(), key=lambda kv: -len(kv[1])):
            shown = ", ".join(f"{f} {N} {st}" for f, N, st in probs[:6]) + (", ..." if len(probs) > 6 else "")
            parts.append(f"{s}: {len(probs)} ({shown})")
        lines.append(f"- {c}: " + "; ".join(parts))
    return lines


def fmt(x, digits=2):
    return "-" if not np.isfinite(x) else f"{x:.{digits}f}"


def report(runs, meta):
    """The section's text from the runs and ``meta`` (section, command, date, machine, families,
    starts, repeats, versus, split, plot)."""
    t = Table(runs, meta["configs"])
    P, ref = len(t.problems), t.configs[0]
    split, versus = meta["split"], [ref] + [v for v in meta["versus"] if v != ref]
    fams = meta["families"]
    lines = [f"## {meta['section']}", "",
             f"Command: `{meta['command']}`  ",
             f"Date: {meta['date']}, commit {meta['commit']}  ",
             f"Machine: {meta['machine']}", "",
             f"{P} problems: {', '.join(f'{f} N = {GRID[f][0]}..{GRID[f][-1]}' for f in fams)} "
             f"(step 12), starts {' and '.join(meta['starts'])} (see the script's docstring). Each problem solved by "
             f"every solver one after the other in one process (side by side), best of {meta['repeats']}, after a "
             f"warm-up; each solver from its config file in configs/. \"same\": objective within {SAME:g} (relative) "
             f"of {ref}'s; \"lower\"/\"higher\": a different local minimum, below/above {ref}'s; \"best\": within "
             f"{SAME:g} of the lowest objective any solver reached on that problem. QP iterations: interior-point "
             "iterations or working-set changes summed over the SQP iterations (IPOPT: none). Many of these "
             "solves take 10-100 ms, so single times scatter; the totals and medians are the robust figures.", "",
             f"| config | solved | same as {ref} | lower | higher | best | SQP/NLP iterations min / median / max "
             f"(total) | QP iterations median (total) | median time ratio vs {ref} | total time (s) |",
             "|:--|---:|---:|---:|---:|---:|:--|:--|---:|---:|"]
    for r in summary_rows(t):
        lines.append(f"| {r['config']} | {r['solved']} / {P} | {r['same']} | {r['lower']} | {r['higher']} | {r['best']} "
                     f"| {r['iters'][0]} / {r['iters'][1]} / {r['iters'][2]} ({r['iters'][3]}) "
                     f"| {r['qp'][0]} ({r['qp'][1]}) | {fmt(r['median_ratio'])} | {r['total']:.1f} |")
    n_small, n_large = int(np.sum(t.N < split)), int(np.sum(t.N >= split))
    lines += ["", f"Time ratios on the problems both solved: median over all, over N < {split} ({n_small} "
              f"problems) and N >= {split} ({n_large}), and the ratio of the total times (below 1: faster than "
              "the comparator).", "",
              "| config | " + " | ".join(f"vs {v}: median | N < {split} | N >= {split} | total" for v in versus) + " |",
              "|:--|" + "---:|" * (4 * len(versus))]
    for r in ratio_rows(t, versus, split):
        cells = []
        for v in versus:
            (a, s, l), total = r[v]
            cells += [fmt(a[0]), fmt(s[0]), fmt(l[0]), fmt(total)]
        lines.append(f"| {r['config']} | " + " | ".join(cells) + " |")
    others = [(c, other_minima(t, j)) for j, c in enumerate(t.configs) if j]
    if any(lo or hi for _, (lo, hi, _) in others):
        lines += ["", f"Other local minima ((J - J_{ref}) / |J_{ref}| beyond {SAME:g}, the largest first):", ""]
        lines += [f"- {c}: {lo} lower, {hi} higher: {text}" for c, (lo, hi, text) in others if lo or hi]
    taus = [0.0, 1.0, 2.0, 4.0, 8.0]
    pt, pi = profile(t.tim, t.solved, taus), profile(t.its, t.solved, taus)
    lines += ["", "Performance profiles (paper eq. (50)): phi(tau) = share of the problems a solver solved within "
              "2^tau times the best solver's time (iterations); phi(0) = share of wins, the last column the share "
              "solved.", "",
              "| config | " + " | ".join(f"time phi({x:g})" for x in taus) + " | "
              + " | ".join(f"iter. phi({x:g})" for x in taus) + " |",
              "|:--|" + "---:|" * (2 * len(taus))]
    for j, c in enumerate(t.configs):
        lines.append(f"| {c} | " + " | ".join(f"{v:.2f}" for v in pt[j]) + " | " + " | ".join(f"{v:.2f}" for v in pi[j]) + " |")
    if meta.get("plot"):
        lines += ["", f"Plot: `benchmarks/{Path(meta['plot']).name}` (time and iteration profiles)."]
    failures = failure_lines(t)
    lines += [""] + (["Failures (status: count, the first problems):", ""] + failures if failures else ["No failures."])
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- command line
def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="+", default=CONFIGS, help="config files in configs/ (without .ini); "
                    "the first is the reference the objectives and times are compared with")
    ap.add_argument("--versus", nargs="*", default=[], help="further configs (among --configs) to give time "
                    "ratios against")
    ap.add_argument("--split", type=int, default=SPLIT, help="horizon separating the size classes of the ratios")
    ap.add_argument("--families", nargs="+", default=list(GRID), choices=list(GRID))
    ap.add_argument("--starts", nargs="+", default=["balance", "sif"], choices=["balance", "sif"])
    ap.add_argument("--repeats", type=int, default=1, help="solves per config and problem, the fastest kept")
    ap.add_argument("--section", default=None, help="RESULTS.md section (default: the testing set's for the "
                    "default configs, otherwise one named after the configs)")
    ap.add_argument("--plot", default=None, help="profile plot (default: testset_profile.png for the default "
                    "configs, otherwise one named after the configs)")
    ap.add_argument("--save-runs", default=None, help="write every solve's record to this JSON file")
    ap.add_argument("--from-runs", default=None, help="report the runs of this JSON file instead of solving")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    unknown = [v for v in args.versus if v not in args.configs]
    if unknown:
        ap.error(f"--versus {' '.join(unknown)}: not among --configs")
    default = args.configs == CONFIGS
    section = args.section or (SECTION if default else f"Zambezi testing set: {', '.join(args.configs)}")
    plot = args.plot or str(PLOT if default else HERE / f"testset_profile_{'_'.join(args.configs)}.png")
    if args.from_runs:
        saved = json.loads(Path(args.from_runs).read_text(encoding="utf-8"))
        meta, runs = saved["meta"], saved["runs"]
        meta.update(section=section, plot=plot)
    else:
        load0, at = os.getloadavg()[0], commit()       # the code measured: before the solves
        problems = [(f, N, st) for f in args.families for N in GRID[f] for st in args.starts]
        runs = solve_all(args.configs, problems, args.repeats)
        load1 = os.getloadavg()[0]
        meta = dict(section=section, plot=plot, configs=args.configs, versus=args.versus, split=args.split,
                    families=args.families, starts=args.starts, repeats=args.repeats,
                    command=" ".join(map(quote, ["python", "benchmarks/bench_testset.py", *command_args(argv)])),
                    date=datetime.date.today().isoformat(), commit=at,
                    machine=f"{machine()}; load average (1 min) {load0:.1f} at the start, {load1:.1f} at the end")
        if args.save_runs:
            Path(args.save_runs).write_text(json.dumps({"meta": meta, "runs": runs}, indent=1), encoding="utf-8")
    text = report(runs, meta)
    print(text)
    if args.no_write:
        return
    t = Table(runs, meta["configs"])
    save_plot(plot, t.configs, t.tim, t.its, t.solved)
    write_section(section, text)
    print(f"wrote section {section!r}")


def quote(arg):
    """A shell word: as it is, in double quotes when it holds an apostrophe (and nothing a
    double-quoted word expands), otherwise as shlex quotes it."""
    if "'" in arg and not any(ch in arg for ch in '"$`\\!'):
        return f'"{arg}"'
    return shlex.quote(arg)


def command_args(argv):
    """The arguments that choose what is measured (not --save-runs, --from-runs, --no-write)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in ("--save-runs", "--from-runs"):
            skip = True
        elif a != "--no-write" and not a.startswith(("--save-runs=", "--from-runs=")):
            out.append(a)
    return out


def save_plot(path, configs, tim, its, solved):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from olado.result import save_figure

    taus = np.linspace(0.0, 8.0, 401)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, metric, title in ((axes[0], tim, "computation time"), (axes[1], its, "iterations (SQP major / IPOPT)")):
        ph = profile(metric, solved, taus)
        for j, c in enumerate(configs):
            ax.step(taus, ph[j], where="post", label=c)
        ax.set_xlabel("tau (log2 of the ratio to the best)")
        ax.set_ylabel("phi(tau)")
        ax.set_title(f"Zambezi testing set: {title}")
        ax.set_ylim(0.0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
