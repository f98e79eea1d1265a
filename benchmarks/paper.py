"""Paper 001's experiments, one command each: Table 1 and Figs. 4-8 of sec. 5-6 as ``olado bench``
runs and ``olado profile`` profiles (docs/benchmarking.md), each written to its section of
benchmarks/RESULTS.md beside the paper's own numbers.

    python benchmarks/paper.py list                      # the experiments and their configurations
    python benchmarks/paper.py table1                    # zambezi12 N = 12..252: SQP-IP, SQP-AS, IPOPT
    python benchmarks/paper.py fig4 fig5                 # KKT back-ends; Hessian updates (244 problems)
    python benchmarks/paper.py fig6 --where "N <= 72"    # QP methods on a subset of the testing set
    python benchmarks/paper.py fig7 fig8                 # SQP-IP vs SQP-AS vs IPOPT, all / N >= 216
    python benchmarks/paper.py fig4 --no-run             # the section and figure from the stored records
    python benchmarks/paper.py parallel                  # the testing set, 4 configurations, on 1 and 2 workers

An experiment is data (:data:`EXPERIMENTS`): a suite, the configuration files, the profile metrics,
the figure's own subset (Fig. 8: ``N >= 216``) and what the paper reports. Running one is
``olado.bench.run`` (the solves not yet in the store, one isolated worker process each) followed by
``olado.bench`` profiles and tables; the store is shared per suite (benchmarks/paper/SUITE.jsonl,
not in git), so a configuration that several figures compare (sqp-ip) is solved once. ``--where``
runs and profiles a subset of the suite (the same command without it runs the rest: the stored
solves are kept). A paper configuration olado does not have is a row of the experiment's
``mapping`` with no preset: the section says so, and adding a preset there fills the slot.

``parallel`` (issue 14) is not one of the paper's experiments but the bench's own: the testing
set with the four fast configurations (:data:`PARALLEL`), run once on one worker process and once
on two (``--jobs J`` for another count), each from an empty store, with its wall time: speed-up,
parallel efficiency T1 / (J T_J), the load average, the check that both runs give the same
statuses and objectives, and the profiles. ``all`` leaves it out (it solves everything twice).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import json
import shlex
import sys
import time
from pathlib import Path

from _common import HERE, commit, machine, write_section

import olado.bench as bench
from olado.bench.profiles import METRICS, format_table, select, summary_table

ROOT = HERE.parent
STORES = HERE / "paper"
#: relative objective difference that counts as the same local minimum
SAME = 1e-6
TIME_LIMIT = 300.0


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One of the paper's experiments: ``configs`` (olado name, preset path) run on ``suite``;
    ``where`` the figure's subset; ``mapping`` the paper's configurations, each (paper name,
    olado name or None when olado has none, remark); ``claims`` what the paper reports as
    (paper name, metric, quantity, value, its words) with quantity ``wins`` (phi(0)), ``phi1``
    (within 2x of the best) or ``solved`` (51)."""

    key: str
    title: str
    suite: str
    configs: tuple
    metrics: tuple
    compares: str
    mapping: tuple
    claims: tuple = ()
    where: str | None = None

    @property
    def section(self) -> str:
        return f"Paper 001 {self.title}"

    def store(self, folder: Path = STORES) -> Path:
        """The results store (shared by the experiments of one suite)."""
        return Path(folder) / f"{self.suite}.jsonl"

    def plot(self, folder: Path = HERE) -> Path:
        return Path(folder) / f"paper_{self.key}.png"

    @property
    def names(self) -> list:
        return [name for name, _ in self.configs]

    def config_paths(self) -> list:
        return [f"{name}={ROOT / path}" for name, path in self.configs]


def _presets(*names):
    return tuple((n, f"configs/{n}.ini") for n in names)


_SQP_AS_IPOPT = dict(
    suite="zambezi-testset", configs=_presets("sqp-ip", "sqp-schittkowski", "sqp-as", "ipopt"),
    metrics=("time", "sqp", "evaluations"),
    compares="Powell's and Schittkowski's SQP with an interior-point QP, Powell's SQP with an active-set QP, "
             "IPOPT 2.2.1 (Fortran) and IPOPT 3.2.2 (C++); metrics time, iterations, objective evaluations.",
    mapping=(("Powell SQP-IP", "sqp-ip", "the paper's QP was Franke's method, here Mehrotra's (sqp-franke.ini "
              "is Franke's: Fig. 6)"),
             ("Schittkowski SQP-IP", "sqp-schittkowski", ""),
             ("Powell SQP-AS", "sqp-as", "Goldfarb-Idnani's dual active set, one Riccati factorization per change"),
             ("IPOPT 2.2.1 (Fortran)", None, "not in olado (one IPOPT: cyipopt's)"),
             ("IPOPT 3.2.2 (C++)", "ipopt", "IPOPT 3.14 through cyipopt, MUMPS")),
)

EXPERIMENTS = {e.key: e for e in (
    Experiment(
        key="table1", title="Table 1: zambezi12, SQP-IP vs SQP-AS vs IPOPT (olado bench)", suite="table1",
        configs=_presets("sqp-ip", "sqp-as", "ipopt"), metrics=("time", "sqp"),
        compares="zambezi12 at N = 12:12:252 from the balance start (46)-(47): main iterations, cumulative QP "
                 "iterations and CPU time of SQP-IP (Franke's QP), SQP-AS and IPOPT.",
        mapping=(("SQP-IP", "sqp-ip", "Mehrotra's QP (the paper's: Franke's)"),
                 ("SQP-AS", "sqp-as", ""), ("IPOPT", "ipopt", ""))),
    Experiment(
        key="fig4", title="Fig. 4: KKT back-ends of the interior-point QP (olado bench)", suite="zambezi-testset",
        configs=_presets("sqp-ip", "sqp-superlu", "sqp-superlu-full"), metrics=("time", "sqp", "qp"),
        compares="the matrix solver of the interior-point QP: the LQ-DOCP (Riccati) solver against external "
                 "sparse direct solvers on the reduced or full KKT system; metrics time, SQP and QP iterations.",
        mapping=(("LQ-DOCP", "sqp-ip", "block Riccati recursion"),
                 ("a sparse LU, reduced system", "sqp-superlu", "SciPy's SuperLU on (25); stands in for the "
                  "paper's UMFPACK (general sparse LU)"),
                 ("a sparse LU, full system", "sqp-superlu-full", "SuperLU on (24); stands in for WSMP full"),
                 ("MA27, MA47 (HSL)", None, "not in olado"), ("WSMP, PARDISO, BLKFCLT, MUMPS", None, "not in olado "
                  "(MUMPS only inside IPOPT)"),
                 ("iterative (SYMMLQ, MINRES, SQMR)", None, "left out by the paper as well; sqp-minres.ini and "
                  "sqp-gmres.ini exist")),
        claims=(("LQ-DOCP", "time", "wins", 0.98, "the best matrix solver with probability 0.98"),
                ("LQ-DOCP", "sqp", "solved", 1.0, "almost all solvers effective in 100 %"))),
    Experiment(
        key="fig5", title="Fig. 5: Hessian updates (olado bench)", suite="zambezi-testset",
        configs=_presets("sqp-ip", "sqp-sr1", "sqp-bfgs", "sqp-gerschgorin", "sqp-powell-bfgs"),
        metrics=("time", "sqp", "qp"),
        compares="the Lagrangian Hessian of the SQP: block BFGS (Powell's modification), block SR1, exact "
                 "(automatic differentiation), Gerschgorin and the gangster method; metrics time, SQP and QP "
                 "iterations.",
        mapping=(("exact (AD)", "sqp-ip", "exact Hessian with inertia correction (the paper's had none: "
                  "nonconvex QPs)"),
                 ("block SR1", "sqp-sr1", ""), ("block BFGS (Powell)", "sqp-bfgs", "Powell's damping"),
                 ("Gerschgorin", "sqp-gerschgorin", "exact Hessian with modification (13)"),
                 ("Gangster", "sqp-powell-bfgs", "Powell's BFGS on the whole Hessian with the gangster operator")),
        claims=(("exact (AD)", "time", "wins", 0.67, "exact Hessian wins in time"),
                ("exact (AD)", "sqp", "wins", 0.82, "... in major iterations"),
                ("exact (AD)", "qp", "wins", 0.82, "... in QP iterations"),
                ("exact (AD)", "time", "solved", 0.84, "but solves only 84 %"),
                ("block SR1", "time", "wins", 0.20, "fastest of the reliable updates"),
                ("block SR1", "time", "solved", 1.0, "100 %"),
                ("block BFGS (Powell)", "time", "wins", 0.11, ""),
                ("block BFGS (Powell)", "time", "solved", 1.0, "100 %"),
                ("Gangster", "time", "solved", 0.86, "no solution on 14 %"))),
    Experiment(
        key="fig6", title="Fig. 6: QP methods (olado bench)", suite="zambezi-testset",
        configs=_presets("sqp-ip", "sqp-franke", "sqp-gondzio", "sqp-weighted", "sqp-osqp", "sqp-clarabel"),
        metrics=("time", "sqp", "qp"),
        compares="the QP method of the SQP: the structure-exploiting interior-point methods of Franke, Mehrotra "
                 "and Gondzio against external QP solvers (OOQP in Mehrotra's and Gondzio's versions, MOSEK, "
                 "BPMPD, LOQP); metrics time, SQP and QP iterations.",
        mapping=(("Mehrotra (specialized)", "sqp-ip", ""), ("Franke (specialized)", "sqp-franke", ""),
                 ("Gondzio (specialized)", "sqp-gondzio", ""),
                 ("-", "sqp-weighted", "paper 003's weighted correctors: not in paper 001"),
                 ("external QP solvers", "sqp-osqp", "OSQP; with block SR1 and Levenberg shifts (an external QP "
                  "needs a convex QP), so its Hessian differs from the rows above"),
                 ("external QP solvers", "sqp-clarabel", "Clarabel; block SR1 as sqp-osqp"),
                 ("OOQP, MOSEK, BPMPD, LOQP", None, "not in olado")),
        claims=(("Mehrotra (specialized)", "time", "wins", 0.85, "Mehrotra wins in time"),
                ("Mehrotra (specialized)", "qp", "wins", 0.96, "... and in QP iterations"),
                ("Franke (specialized)", "time", "wins", 0.09, "second in time"))),
    Experiment(
        key="fig7", title="Fig. 7: SQP-IP vs SQP-AS vs IPOPT, the whole testing set (olado bench)", **_SQP_AS_IPOPT,
        claims=(("Powell SQP-AS", "time", "wins", 0.39, "fastest"), ("IPOPT 3.2.2 (C++)", "time", "wins", 0.37, ""),
                ("Powell SQP-IP", "time", "wins", 0.18, ""), ("Schittkowski SQP-IP", "time", "wins", 0.08, ""),
                ("Powell SQP-AS", "time", "solved", 1.0, "all solvers solved all problems"))),
    Experiment(
        key="fig8", title="Fig. 8: SQP-IP vs SQP-AS vs IPOPT, N >= 216 (olado bench)", where="N >= 216",
        **_SQP_AS_IPOPT,
        claims=(("Powell SQP-AS", "time", "wins", 0.02, "definitely the weakest"),
                ("IPOPT 3.2.2 (C++)", "time", "wins", 0.54, "fastest on 54 %"),
                ("Powell SQP-AS", "time", "phi1", 0.58, "within 2x of the best on about 58 %"))),
)}


# ---------------------------------------------------------------------------- composition
def combined_where(*parts) -> str | None:
    parts = [p for p in parts if p]
    if len(parts) < 2:
        return parts[0] if parts else None
    return " and ".join(f"({p})" for p in parts)


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def equivalent_commands(exp: Experiment, where: str | None, time_limit: float, store: Path = None,
                        plot: Path = None) -> str:
    """The ``olado bench && olado profile`` command lines the experiment composes."""
    q = shlex.quote
    store = _shown(store or exp.store())
    run = ["olado", "bench", exp.suite, *(a for n, p in exp.configs for a in ("-c", p)), "--store", str(store),
           "--time-limit", f"{time_limit:g}"] + (["--where", where] if where else [])
    prof = ["olado", "profile", str(store), *(a for n in exp.names for a in ("-c", n)),
            *(a for m in exp.metrics for a in ("-m", m))] + (["--where", where] if where else []) + \
        (["--plot", _shown(plot or exp.plot())] if exp.key != "table1" else []) + ["--table", "-"]
    return " ".join(map(q, run)) + " && " + " ".join(map(q, prof))


def load_average() -> str:
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:  # pragma: no cover - not POSIX
        return "?"


def _ours(profiles, names, olado_name, metric, quantity):
    prof = next((p for p in profiles if p.metric == metric), None)
    if prof is None or olado_name not in prof.configs:
        return None
    j = prof.configs.index(olado_name)
    if quantity == "wins":
        return float(prof.wins()[j])
    if quantity == "phi1":
        return float(prof.phi([1.0])[j, 0])
    return float(prof.solved_share()[j])


_QUANTITY = {"wins": "phi(0), share of wins", "phi1": "phi(1), within 2x of the best", "solved": "share solved (51)"}


def claims_table(exp: Experiment, profiles) -> list:
    """Markdown lines: each of the paper's statements next to the same quantity here."""
    olado = {paper: name for paper, name, _ in exp.mapping}
    lines = ["| paper's configuration | olado | metric | quantity | paper | here | the paper's words |",
             "|:--|:--|:--|:--|--:|--:|:--|"]
    for paper, metric, quantity, value, words in exp.claims:
        name = olado.get(paper)
        ours = _ours(profiles, exp.names, name, metric, quantity) if name else None
        lines.append(f"| {paper} | {name or 'not in olado'} | {metric} | {_QUANTITY[quantity]} | {value:.2f} | "
                     f"{'' if ours is None else f'{ours:.2f}'} | {words} |")
    return lines


def other_minima(records, names, rtol=SAME) -> list:
    """Per configuration after the first: the problems both solved whose objective differs from the
    first configuration's by more than ``rtol`` (relative): (name, lower, higher, examples)."""
    by = {}
    for r in records:
        by.setdefault((r["problem"], r["N"], r["start"]), {})[r["config"]] = r
    out = []
    for name in names[1:]:
        diffs = []
        for key, row in by.items():
            a, b = row.get(names[0]), row.get(name)
            if a and b and a.get("success") and b.get("success") and None not in (a["objective"], b["objective"]):
                rel = (b["objective"] - a["objective"]) / max(abs(a["objective"]), 1e-12)
                if abs(rel) > rtol:
                    diffs.append((rel, key))
        diffs.sort(key=lambda d: -abs(d[0]))
        out.append((name, sum(d < 0 for d, _ in diffs), sum(d > 0 for d, _ in diffs),
                    ", ".join(f"{k[0]} {k[1]} {k[2]} {d:+.1e}" for d, k in diffs[:5])))
    return out


def failures(records, names) -> list:
    out = []
    for name in names:
        bad = [r for r in records if r["config"] == name and not r.get("success")]
        if bad:
            by = {}
            for r in bad:
                by.setdefault(r["status"], []).append(f"{r['problem']} {r['N']} {r['start']}")
            out.append(f"- {name}: " + "; ".join(f"{s} {len(v)} ({', '.join(v[:4])}{', ...' if len(v) > 4 else ''})"
                                                  for s, v in by.items()))
    return out


def table1_rows(records, names) -> list:
    """Paper 001 Table 1 with this run's numbers next to the paper's (one row per N)."""
    from olado.problems.suites.table1 import PAPER

    by = {}
    for r in records:
        by.setdefault(r["N"], {})[r["config"]] = r
    head = "| N | n | m_e | m | " + " | ".join(f"{n} iter / QP iter / time (s)" for n in names) + \
        " | paper SQP-IP iter / QP iter / time (U) | paper SQP-AS | paper IPOPT iter / time (U) |"
    lines = [head, "|" + "---:|" * 4 + ":--|" * (len(names) + 3)]
    for N in sorted(by):
        size, ip, act, ipopt = PAPER.get(N, (("", "", ""), ("", "", "", ""), ("", "", "", ""), ("", "")))
        cells = []
        for n in names:
            r = by[N].get(n)
            if r is None:
                cells.append("")
                continue
            flag = "" if r.get("success") else f" ({r['status']})"
            qp = r.get("qp_iterations")
            cells.append(f"{r.get('sqp_iterations')} / {'-' if not qp else qp} / {r.get('solve_s') or 0:.3f}{flag}")
        lines.append(f"| {N} | {size[0]} | {size[1]} | {size[2]} | " + " | ".join(cells) +
                     f" | {ip[0]} / {ip[1]} / {ip[3]} | {act[0]} / {act[1]} / {act[3]} | {ipopt[0]} / {ipopt[1]} |")
    return lines


def counted(records, names, metric) -> list:
    """The configurations with a count of ``metric``: one whose records all have 0 (IPOPT's QP
    iterations: it solves no QPs) is left out of that profile, where the floor of 1 would make it
    win every problem."""
    field = METRICS[metric][0]
    return [n for n in names if any((r.get(field) or 0) > 0 for r in records if r["config"] == n)]


def left_out(exp, profiles) -> list:
    return [f"Left out of the {METRICS[p.metric][1]} profile: {', '.join(n for n in exp.names if n not in p.configs)} "
            "(no record with a count)." for p in profiles if len(p.configs) < len(exp.names)]


def describe_subset(profiles) -> str:
    probs = profiles[0].problems
    if not probs:
        return "no problem"
    fams, Ns, starts = (sorted({p[i] for p in probs}) for i in range(3))
    text = f"{len(probs)} problems ({', '.join(fams)}; N = {Ns[0]}..{Ns[-1]}; starts {', '.join(starts)})"
    if profiles[0].dropped:
        text += f"; {profiles[0].dropped} more in the store were left out (not run by every configuration)"
    return text


def _span(records) -> str:
    stamps = sorted(str(r.get("finished")) for r in records if r.get("finished"))
    return f"{stamps[0][:16]}..{stamps[-1][:16]} UTC" if stamps else "(no date)"


def section_text(exp: Experiment, records, profiles, args, where, load, store: Path, plot: Path) -> str:
    names = exp.names
    commits = sorted({str(r.get("commit")) for r in records})
    command = "python benchmarks/paper.py " + exp.key + (f" --where {shlex.quote(args.where)}" if args.where else "")
    lines = [f"## {exp.section}", "",
             f"Command: `{command}`  ",
             f"The same as: `{equivalent_commands(exp, where, args.time_limit, store, plot)}`  ",
             f"Date: {datetime.date.today().isoformat()}; records made {_span(records)} at commit "
             f"{', '.join(commits)} (section written at {commit()})  ",
             f"Machine: {machine()}; "
             + (f"load average (1 min) {load[0]} at the start, {load[1]} at the end -- " if load else
                "section rewritten from the stored records (--no-run) -- ")
             + "**times measured on a loaded machine** (the machine is shared): compare iterations, solved "
             "shares and objectives; time ratios are orders of magnitude only", "",
             f"The paper compares {exp.compares}", "",
             f"Run: {'the whole suite `' + exp.suite + '`' if not where else f'suite `{exp.suite}` where `{where}`'}"
             f"; profiled: {describe_subset(profiles)}. One solve per problem and configuration in an isolated "
             f"worker after a warm-up, time limit {args.time_limit:g} s. "
             + ("" if not args.where else "The full experiment is the same command without `--where` (stored "
                "solves are kept). "), "",
             "| paper | olado preset | remark |", "|:--|:--|:--|"]
    for paper, name, remark in exp.mapping:
        preset = dict(exp.configs).get(name)
        lines.append(f"| {paper} | {f'`{preset}`' if preset else '**not in olado** (slot)'} | {remark} |")
    lines += ["", "Here (phi(0): share of wins, phi(1): within 2x of the best, phi(2): within 4x; paper eq. (50)):",
              "", format_table(*summary_table(records, profiles, names)).rstrip("\n"), ""]
    notes = left_out(exp, profiles)
    lines += notes + ([""] if notes else [])
    if exp.key == "table1":
        lines += ["Per horizon (this run, then the paper's Table 1):", ""] + table1_rows(records, names) + [""]
    if exp.claims:
        lines += ["The paper's figure against this run:", ""] + claims_table(exp, profiles) + [""]
    minima = other_minima(records, names)
    if minima:
        lines.append(f"Other local minima (objective beyond {SAME:g} relative from {names[0]}'s, both solved):")
        lines.append("")
        lines += [f"- {n}: {lo} lower, {hi} higher" + (f": {ex}" + (", ..." if lo + hi > 5 else "") if ex else "")
                  for n, lo, hi, ex in minima]
        lines.append("")
    fails = failures(records, names)
    lines += (["Failures:", ""] + fails if fails else ["No failures."]) + [""]
    if exp.key != "table1":
        lines += [f"Plot: `{_shown(plot)}` ({', '.join(METRICS[m][1] for m in exp.metrics)}).", ""]
    return "\n".join(lines)


def run_experiment(exp: Experiment, args) -> str:
    """Run (unless --no-run) and profile ``exp``; write its plot and section. -> the section text."""
    where = combined_where(exp.where, args.where)
    store, plot = exp.store(args.store_dir or STORES), exp.plot(args.plot_dir or HERE)
    load = None if args.no_run else [load_average(), None]
    if not args.no_run:
        limits = bench.Limits(time_limit=args.time_limit)
        report = bench.run(exp.suite, exp.config_paths(), store, jobs=args.jobs, limits=limits,
                           progress=not args.quiet, stream=sys.stderr, where=where)
        print(report.summary(), flush=True)
        load[1] = load_average()
    records = select(bench.read_records(store), where, exp.names)
    profiles = [bench.performance_profile(records, m, configs=counted(records, exp.names, m)) for m in exp.metrics]
    keep = set(profiles[0].problems)
    records = [r for r in records if (r["problem"], r["N"], r["start"]) in keep]
    text = section_text(exp, records, profiles, args, where, load, store, plot)
    if exp.key != "table1" and not args.no_plot:
        bench.plot_profiles(profiles, plot, title=f"paper 001 {exp.title.split(':')[0]}"
                            + (f", {where}" if where else ""))
    if not args.no_write:
        write_section(exp.section, text, **({"path": Path(args.results)} if args.results else {}))
    return text


# ---------------------------------------------------------------------------- parallel efficiency
#: the parallel-efficiency experiment: the testing set with the fast configurations (not sqp-as:
#: PARALLEL_WHY_NOT)
PARALLEL = Experiment(
    key="parallel", title="Parallel efficiency: the Zambezi testing set on 1 and 2 workers (olado bench)",
    suite="zambezi-testset", configs=_presets("sqp-ip", "sqp-schittkowski", "sqp-gondzio", "ipopt"),
    metrics=("time", "sqp", "qp"), compares="", mapping=())
PARALLEL_SECTION = "Parallel efficiency: the Zambezi testing set on 1 and 2 workers (olado bench)"
PARALLEL_WHY_NOT = ("sqp-as is left out: on one worker it takes about 28 of the 32 minutes of Fig. 7's run "
                    "(its working-set changes grow with N: 10-30 s per solve at N >= 216), so the experiment "
                    "would measure a handful of long active-set solves -- and how they happen to fall on the "
                    "two workers at the end of the run -- rather than the pool")


def parallel_store(folder: Path, jobs: int) -> Path:
    return Path(folder) / f"parallel-jobs{jobs}.jsonl"


def parallel_log(folder: Path) -> Path:
    """The runs' wall times and load averages (the stores hold per-solve records only)."""
    return Path(folder) / "parallel.json"


def parallel_run(jobs: int, args, where, folder: Path) -> dict:
    """One run of :data:`PARALLEL` on ``jobs`` workers into its own store, emptied first (a
    previous store is kept as ``*.previous``) so that every solve runs: its wall time (from
    the call to the last record, workers' start-up and warm-ups included) and load averages."""
    store = parallel_store(folder, jobs)
    store.parent.mkdir(parents=True, exist_ok=True)
    if store.exists():
        store.replace(Path(f"{store}.previous"))
    load0, started = load_average(), datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    report = bench.run(PARALLEL.suite, PARALLEL.config_paths(), store, jobs=jobs,
                       limits=bench.Limits(time_limit=args.time_limit), progress=not args.quiet, stream=sys.stderr,
                       where=where)
    wall = time.perf_counter() - t0
    if not args.quiet:
        print(f"{jobs} worker(s): {wall:.1f} s wall\n{report.summary()}", flush=True)
    return {"jobs": jobs, "wall_s": wall, "load_start": load0, "load_end": load_average(), "started": started,
            "solves": len(report.records), "where": where, "time_limit": args.time_limit, "commit": commit()}


def same_results(one, other, rtol=SAME) -> dict:
    """The solves of two runs side by side (by problem, N, start, configuration): how many are in
    both, have the same status, the same objective (relative ``rtol``; both null counts as the
    same), the same SQP iterations; and the differing ones (a line each)."""
    def keyed(records):
        return {(r["problem"], r["N"], r["start"], r["config"]): r for r in records}

    a, b = keyed(one), keyed(other)
    common = sorted(set(a) & set(b), key=str)
    out = {"common": len(common), "only_one": len(set(a) ^ set(b)), "status": 0, "objective": 0, "identical": 0,
           "iterations": 0, "differ": []}
    for key in common:
        ra, rb = a[key], b[key]
        fa, fb = ra.get("objective"), rb.get("objective")
        same_obj = (fa is None and fb is None) or (
            fa is not None and fb is not None and abs(fa - fb) <= rtol * max(abs(fa), abs(fb), 1e-12))
        out["status"] += ra["status"] == rb["status"]
        out["objective"] += same_obj
        out["identical"] += fa == fb
        out["iterations"] += ra.get("sqp_iterations") == rb.get("sqp_iterations")
        if ra["status"] != rb["status"] or not same_obj:
            out["differ"].append(f"{key[3]} on {key[0]} N = {key[1]} {key[2]}: {ra['status']} {fa} against "
                                 f"{rb['status']} {fb}")
    return out


def parallel_table(runs) -> list:
    """Markdown lines: per run its wall time, solves, summed solver time, load averages, speed-up
    T1 / T_J and efficiency T1 / (J T_J) against the 1-worker run."""
    t1 = runs[0]["wall_s"]
    lines = ["| workers | wall time (s) | solves | solver time, sum (s) | warm-ups, their time (s) | load average at "
             "start / end | speed-up T1 / T_J | efficiency T1 / (J T_J) |", "|--:|--:|--:|--:|--:|:-:|--:|--:|"]
    for r in runs:
        speed = t1 / r["wall_s"]
        lines.append(f"| {r['jobs']} | {r['wall_s']:.1f} | {r['solves']} | {r['solver_s']:.1f} | {r['warmups']}, "
                     f"{r['warmup_s']:.1f} | {r['load_start']} / {r['load_end']} | {speed:.2f} | {speed / r['jobs']:.2f} |")
    return lines


def parallel_commands(runs, time_limit, plot: Path) -> str:
    q = shlex.quote
    where = runs[0].get("where")
    cmds = []
    for r in runs:
        cmds.append(["olado", "bench", PARALLEL.suite, *(a for n, p in PARALLEL.configs for a in ("-c", p)), "--store",
                     _shown(Path(r["store"])), "--jobs", str(r["jobs"]), "--time-limit", f"{time_limit:g}"]
                    + (["--where", where] if where else []))
    cmds.append(["olado", "profile", _shown(Path(runs[0]["store"])), *(a for n in PARALLEL.names for a in ("-c", n)),
                 *(a for m in PARALLEL.metrics for a in ("-m", m)), "--plot", _shown(plot), "--table", "-"])
    return " && ".join(" ".join(map(q, c)) for c in cmds)


def parallel_section(runs, per_run, profiles, args, plot: Path) -> str:
    """The RESULTS.md section of the parallel experiment (``runs``: the log's entries, 1 worker
    first; ``per_run``: their records; ``profiles``: per run, the profiles of its records)."""
    names, J = PARALLEL.names, runs[-1]["jobs"]
    where = runs[0].get("where")
    check = same_results(per_run[0], per_run[-1])
    records = [r for recs in per_run for r in recs]
    commits = sorted({str(r.get("commit")) for r in records})
    busy = runs[0]["load_start"] != "?" and float(runs[0]["load_start"]) >= 0.5
    command = "python benchmarks/paper.py parallel" + (f" --jobs {J}" if J != 2 else "") + \
        (f" --where {shlex.quote(where)}" if where else "")
    n = check["common"]
    lines = [f"## {PARALLEL_SECTION}", "",
             f"Command: `{command}`  ",
             f"The same as: `{parallel_commands(runs, args.time_limit, plot)}`, each `olado bench` timed  ",
             f"Date: {datetime.date.today().isoformat()}; runs started "
             f"{', '.join(r['started'][:16].replace('T', ' ') for r in runs)} UTC, "
             f"records at commit {', '.join(commits)} (section written at {commit()})  ",
             f"Machine: {machine()}"
             + ("; **the machine was busy** (load average >= 0.5 before the first run): the wall times, and so "
                "the efficiency, are orders of magnitude only" if busy else ""), "",
             f"Run: {'the whole suite `' + PARALLEL.suite + '`' if not where else f'suite `{PARALLEL.suite}` where `{where}`'}"
             f" with {', '.join(names)}, once on one worker process and once on {J} (`--jobs`), each from an empty "
             f"store (every solve runs), time limit {args.time_limit:g} s per solve. {PARALLEL_WHY_NOT}. The wall time "
             "runs from the start of `olado.bench.run` to its last record: it includes the workers' start-up and "
             "their warm-ups (one per worker, configuration and problem family, so the parallel run warms up "
             f"{J} times as often).", "",
             ] + parallel_table(runs) + ["",
             f"Efficiency T1 / ({J} T{J}) = 1 would be a perfect split; the solver-time sum shows how much the solves "
             f"slowed each other down ({J} solves sharing the machine's cores, memory bandwidth and caches). The "
             "load average (1 minute) at the start of the second run still holds the first run's own load (it "
             "decays over minutes); the one before the first run says whether anything else was running.", "",
             f"The same results: of the {n} solves in both runs, {check['status']} have the same status, "
             f"{check['objective']} the same objective (relative {SAME:g}; {check['identical']} identical to the last "
             f"digit) and {check['iterations']} the same iteration count"
             + (f"; {check['only_one']} solves are in one run only" if check["only_one"] else "") + "."]
    if check["differ"]:
        lines += ["", "Differences:", ""] + [f"- {d}" for d in check["differ"][:20]] + \
            ([f"- ... ({len(check['differ']) - 20} more)"] if len(check["differ"]) > 20 else [])
    for run, recs, profs in zip(runs, per_run, profiles):
        lines += ["", f"Profiles of the {run['jobs']}-worker run ({describe_subset(profs)}; phi(0): share of wins, "
                      "phi(1): within 2x of the best, phi(2): within 4x; paper eq. (50)):", "",
                  format_table(*summary_table(recs, profs, names)).rstrip("\n")]
        notes = left_out(PARALLEL, profs)
        lines += [""] + notes if notes else []
    fails = failures(per_run[0], names)
    lines += [""] + (["Failures (1 worker):", ""] + fails if fails else ["No failures (1 worker)."])
    lines += ["", f"Plot: `{_shown(plot)}` (the 1-worker run: {', '.join(METRICS[m][1] for m in PARALLEL.metrics)}).", ""]
    return "\n".join(lines)


def run_parallel(args) -> str:
    """Run (unless --no-run) :data:`PARALLEL` on 1 and J workers (J = --jobs, 2 when it is 1) and
    write its section and plot; -> the section text."""
    folder = Path(args.store_dir or STORES)
    plot = PARALLEL.plot(args.plot_dir or HERE)
    J = args.jobs if args.jobs > 1 else 2
    log = parallel_log(folder)
    if args.no_run:
        if not log.exists():
            raise SystemExit(f"paper.py parallel --no-run: no runs logged in {log}; run without --no-run first")
        runs = json.loads(log.read_text(encoding="utf-8"))["runs"]
    else:
        runs = [parallel_run(jobs, args, args.where, folder) for jobs in (1, J)]
        for r in runs:
            r["store"] = str(parallel_store(folder, r["jobs"]))
        from olado.result import atomic_write_bytes

        atomic_write_bytes(log, json.dumps({"runs": runs}, indent=1).encode("utf-8"))
    per_run = [select(bench.read_records(r["store"]), None, PARALLEL.names) for r in runs]
    for r, recs in zip(runs, per_run):
        r["solver_s"] = sum(x.get("solve_s") or 0.0 for x in recs)
        warm = [x["warmup_s"] for x in recs if x.get("warmup_s") is not None]
        r["warmups"], r["warmup_s"] = len(warm), sum(warm)
    profiles = [[bench.performance_profile(recs, m, configs=counted(recs, PARALLEL.names, m)) for m in PARALLEL.metrics]
                for recs in per_run]
    text = parallel_section(runs, per_run, profiles, args, plot)
    if not args.no_plot:
        bench.plot_profiles(profiles[0], plot, title="Zambezi testing set, 1 worker"
                            + (f", {runs[0]['where']}" if runs[0].get("where") else ""))
    if not args.no_write:
        write_section(PARALLEL_SECTION, text, **({"path": Path(args.results)} if args.results else {}))
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("experiments", nargs="+", metavar="EXPERIMENT",
                    help=f"{', '.join(EXPERIMENTS)}, all (these), parallel, or list")
    ap.add_argument("--where", "-w", help='only the suite entries (and records) for which EXPR holds, e.g. "N <= 72"')
    ap.add_argument("--jobs", "-j", type=int, default=1, help="worker processes (default 1); parallel: the run "
                    "compared with the 1-worker run (default 2)")
    ap.add_argument("--time-limit", type=float, default=TIME_LIMIT, help=f"seconds per solve (default {TIME_LIMIT:g})")
    ap.add_argument("--no-run", action="store_true", help="no solves: the section and plot from the stored records")
    ap.add_argument("--no-write", action="store_true", help="print the section instead of writing RESULTS.md")
    ap.add_argument("--no-plot", action="store_true", help="no figure")
    ap.add_argument("--results", help="the markdown file of the sections (default benchmarks/RESULTS.md)")
    ap.add_argument("--store-dir", help="folder of the results stores (default benchmarks/paper)")
    ap.add_argument("--plot-dir", help="folder of the figures (default benchmarks)")
    ap.add_argument("--quiet", "-q", action="store_true")
    args = ap.parse_args(argv)
    if args.experiments == ["list"]:
        for e in (*EXPERIMENTS.values(), PARALLEL):
            print(f"{e.key:8s} {e.title}\n         suite {e.suite}{', where ' + e.where if e.where else ''}; "
                  f"configs {', '.join(e.names)}; metrics {', '.join(e.metrics)}")
        return 0
    keys = list(EXPERIMENTS) if args.experiments == ["all"] else args.experiments
    unknown = [k for k in keys if k not in EXPERIMENTS and k != PARALLEL.key]
    if unknown:
        ap.error(f"unknown experiment(s) {', '.join(unknown)}; choose from {', '.join(EXPERIMENTS)}, all, "
                 f"{PARALLEL.key}, list")
    if args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    for k in keys:
        text = run_parallel(args) if k == PARALLEL.key else run_experiment(EXPERIMENTS[k], args)
        if args.no_write:
            print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
