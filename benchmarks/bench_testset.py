"""Paper 001 sec. 6 on this machine: the Zambezi testing set (122 problems x 2 starts), every
configured solver against IPOPT, with Dolan-More performance profiles (paper eqs. (48)-(50)).

The set of paper 001 sec. 6: zambezi N = 12:12:420, zambezi8 12:12:216, zambezi9 and zambezi10
12:12:72, zambezi11 12:12:432, zambezi12 12:12:252 (122 problems, the inflow record only, no
cyclic extension), each from two starts: the balance controls (46)-(47) with simulated states,
and the SIF start point (outflow = inflow, every volume at V0; the paper's first start (45) is
the same kind of "outflow = inflow" trajectory). One solve per solver and problem, after a
warm-up, all in one run.

    python benchmarks/bench_testset.py                       # writes RESULTS.md and the plot
    python benchmarks/bench_testset.py --configs ipopt sqp-ip --families zambezi12 --no-write
"""

from __future__ import annotations

import argparse
import datetime
import math

import numpy as np

from _common import HERE, machine, write_section

from olado.config import load_config, make_solver
from olado.problems.suites.zambezi_testset import GRID  # the set as data (also `olado bench zambezi-testset`)
from olado.problems.zambezi import zambezi_problem

SECTION = "Zambezi testing set of paper 001 sec. 6 (244 problems, performance profiles)"
CONFIGS = ["ipopt", "sqp-ip", "sqp-gondzio", "sqp-weighted", "sqp-sr1", "sqp-bfgs"]
#: relative objective difference that counts as "the same objective"
SAME = 1e-6


def profile(metric, solved, taus):
    """Dolan-More profile, paper eqs. (48)-(50): metric (P, S) with solved (P, S) booleans ->
    phi (S, len(taus)), the fraction of problems with log2(metric / best) <= tau; an unsolved
    problem has ratio r_M = inf. Problems no solver solved count against everyone."""
    m = np.where(solved, metric, np.inf)
    best = np.min(m, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        lr = np.where(np.isfinite(m), np.log2(m / best), np.inf)
    return np.array([[float(np.mean(lr[:, s] <= t)) for t in taus] for s in range(m.shape[1])])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="+", default=CONFIGS, help="config files in configs/ (without .ini); "
                    "the first is the reference the objectives are compared with")
    ap.add_argument("--families", nargs="+", default=list(GRID), choices=list(GRID))
    ap.add_argument("--starts", nargs="+", default=["balance", "sif"], choices=["balance", "sif"])
    ap.add_argument("--plot", default=str(HERE / "testset_profile.png"))
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    solvers = {c: make_solver(load_config(HERE.parent / "configs" / f"{c}.ini")) for c in args.configs}
    for s in solvers.values():
        s.solve(zambezi_problem("zambezi12", N=12))          # warm-up: imports, numba caches
    problems = [(f, N, st) for f in args.families for N in GRID[f] for st in args.starts]
    P, S = len(problems), len(args.configs)
    status = np.empty((P, S), dtype=object)
    obj = np.full((P, S), np.nan); tim = np.full((P, S), np.nan); its = np.full((P, S), np.nan)
    for i, (fam, N, st) in enumerate(problems):
        line = f"{fam:9s} N={N:3d} {st:7s}"
        for j, c in enumerate(args.configs):
            try:
                r = solvers[c].solve(zambezi_problem(fam, N=N, start=st, extend=None))
                status[i, j] = r.status.value
                obj[i, j], tim[i, j], its[i, j] = r.objective, r.time_s, r.iterations
            except Exception as exc:               # counted as a failure, and shown
                status[i, j] = f"exception: {type(exc).__name__}: {exc}"[:120]
            line += f" | {c} {str(status[i, j])[:7]:7s} {obj[i, j]:.9g} {tim[i, j]:.3f}s it={its[i, j]:.0f}"
        print(line, flush=True)
    solved = status == "success"
    ref = obj[:, 0]
    best = np.nanmin(np.where(solved, obj, np.nan), axis=1)
    rows = []
    for j, c in enumerate(args.configs):
        ok = solved[:, j]
        both = ok & solved[:, 0]
        rel = (obj[:, j] - ref) / np.abs(ref)
        rel_best = (obj[:, j] - best) / np.abs(best)
        ratios = tim[both, j] / tim[both, 0]
        rows.append(dict(config=c, solved=int(ok.sum()), same=int(np.sum(both & (np.abs(rel) <= SAME))),
                         lower=int(np.sum(both & (rel < -SAME))), higher=int(np.sum(both & (rel > SAME))),
                         best=int(np.sum(ok & (rel_best <= SAME))),
                         median_ratio=float(np.median(ratios)) if ratios.size else math.nan,
                         total=float(np.nansum(np.where(ok, tim[:, j], np.nan))),
                         iters=(int(np.nanmin(its[ok, j])), int(np.nanmedian(its[ok, j])), int(np.nanmax(its[ok, j])))
                         if ok.any() else (0, 0, 0)))
        print(rows[-1], flush=True)
    taus = [0.0, 1.0, 2.0, 4.0, 8.0]
    pt = profile(tim, solved, taus)
    pi = profile(its, solved, taus)
    failures = [(problems[i], args.configs[j], status[i, j]) for i in range(P) for j in range(S) if not solved[i, j]]
    if args.plot and not args.no_write:
        save_plot(args.plot, args.configs, tim, its, solved)
    if args.no_write:
        return
    ref_name = args.configs[0]
    lines = [f"## {SECTION}", "",
             "Command: `python benchmarks/bench_testset.py`  ",
             f"Date: {datetime.date.today().isoformat()}  ",
             f"Machine: {machine()}", "",
             f"{P} problems: {', '.join(f'{f} N = {GRID[f][0]}..{GRID[f][-1]}' for f in args.families)} "
             f"(step 12), starts {' and '.join(args.starts)} (see the script's docstring). One solve per solver and "
             f"problem after a warm-up, all in one run; each solver from its config file in configs/. \"same\": "
             f"objective within {SAME:g} (relative) of {ref_name}'s; \"lower\"/\"higher\": a different local "
             f"minimum, below/above {ref_name}'s; \"best\": within {SAME:g} of the lowest objective any solver "
             f"reached on that problem. Time ratio: against {ref_name} on the problems both solved. Many of "
             "these solves take 10-100 ms, so single times scatter; the totals and medians are the robust "
             "figures.", "",
             f"| config | solved | same as {ref_name} | lower | higher | best | SQP/NLP iterations min / median / max "
             f"| median time ratio vs {ref_name} | total time (s) |",
             "|:--|---:|---:|---:|---:|---:|:--|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['config']} | {r['solved']} / {P} | {r['same']} | {r['lower']} | {r['higher']} | {r['best']} "
                     f"| {r['iters'][0]} / {r['iters'][1]} / {r['iters'][2]} | {r['median_ratio']:.2f} | {r['total']:.1f} |")
    lines += ["", "Performance profiles (paper eq. (50)): phi(tau) = share of the problems a solver solved within "
              "2^tau times the best solver's time (iterations); phi(0) = share of wins, the last column the share "
              "solved.", "",
              "| config | " + " | ".join(f"time phi({t:g})" for t in taus) + " | " + " | ".join(f"iter. phi({t:g})" for t in taus) + " |",
              "|:--|" + "---:|" * (2 * len(taus))]
    for j, c in enumerate(args.configs):
        lines.append(f"| {c} | " + " | ".join(f"{v:.2f}" for v in pt[j]) + " | " + " | ".join(f"{v:.2f}" for v in pi[j]) + " |")
    lines += ["", f"Plot: `benchmarks/{HERE.joinpath(args.plot).name}` (time and iteration profiles).", ""]
    if failures:
        lines.append("Failures (status: count, the first problems):")
        lines.append("")
        for c in args.configs:
            mine = [(prob, s) for prob, cc, s in failures if cc == c]
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
    else:
        lines.append("No failures.")
    write_section(SECTION, "\n".join(lines) + "\n")
    print(f"wrote section {SECTION!r}")


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
