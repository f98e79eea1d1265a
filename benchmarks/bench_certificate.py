"""olado's certificate of a success (olado.solvers.certificate, docs/certificate.md) checked on every
built-in problem with every preset in configs/, and its cost on zambezi at large N with sqp-ip.

For each solve: the status, the solver's own KKT residual, the certificate the solve carries (its
level, which multipliers, scaled stationarity and complementarity, violation) and, recomputed here
independently of everything the solver returned but the point, the certificate with olado's
least-squares multipliers only (``certify(problem, X, U, None)``). A success (status success or
acceptable) whose independent scaled KKT residual or violation exceeds the tolerance of its status
is flagged (target: none).

    python benchmarks/bench_certificate.py                     # both parts, writes RESULTS.md
    python benchmarks/bench_certificate.py --part table --no-write
    python benchmarks/bench_certificate.py --part cost --N 1200 12000 120000
"""

from __future__ import annotations

import argparse
import datetime
import math
import time

import numpy as np
from _common import HERE, commit, machine, write_section

from olado.config import load_config, make_solver
from olado.problems import get_problems
from olado.problems.catalog import CATALOG
from olado.problems.zambezi import zambezi_problem
from olado.solvers.certificate import (CertificateSettings, StageBounds, StagePoint, certify, kkt_figures,
                                       least_squares_multipliers, spot_check)

TABLE = "Certificate of every success (built-in problems x presets)"
COST = "Certificate cost (zambezi, sqp-ip)"
ZAMBEZI_N = 12


def header(section, command):
    return [f"## {section}", "", f"Command: `{command}`  ", f"Commit: {commit()}  ",
            f"Date: {datetime.date.today().isoformat()}  ", f"Machine: {machine()}", ""]


def fmt(v, spec=".1e"):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def problems():
    """The built-in problems (Zambezi families at N = ZAMBEZI_N): not the robustness set's
    literature problems (olado.problems.catalog), whose certificates bench_robustness.py tables."""
    out = {}
    for name, factory in get_problems().items():
        if name in CATALOG:
            continue
        out[name] = (lambda f=factory: f(N=ZAMBEZI_N)) if name.startswith("zambezi") else factory
    return out


def run_table(presets_filter=None):
    presets = sorted(p.stem for p in (HERE.parent / "configs").glob("*.ini"))
    if presets_filter:
        presets = [p for p in presets if p in presets_filter]
    rows, flagged = [], []
    for c in presets:
        cfg = load_config(HERE.parent / "configs" / f"{c}.ini")
        solver = make_solver(cfg)
        settings = CertificateSettings.from_options(solver.options)
        for name, factory in problems().items():
            p = factory()
            t = time.perf_counter()
            try:
                r = solver.solve(p)
            except Exception as exc:   # an exception is a result of the table too
                rows.append((name, c, f"exception {type(exc).__name__}", None, None, None, None, ""))
                print(name, c, "exception", exc, flush=True)
                continue
            indep = certify(p, r.x, r.u, None, settings) if np.all(np.isfinite(r.x)) and np.all(np.isfinite(r.u)) else None
            flag = ""
            if r.success and indep is not None:
                tol = settings.tol if r.status.value == "success" else settings.acceptable_tol
                viol = settings.constr_viol_tol if r.status.value == "success" else settings.acceptable_constr_viol_tol
                err = max(indep.stationarity_scaled, indep.complementarity_scaled)
                if not (err <= tol and indep.violation <= viol and not indep.gradient_check_note):
                    flag = "**yes**"
                    flagged.append((name, c))
            rows.append((name, c, r.status.value, r.iterations, r.kkt_residual, r.certificate, indep, flag))
            print(f"{name:15s} {c:18s} {r.status.value:15s} it={r.iterations:5d} kkt={fmt(r.kkt_residual)} "
                  f"cert={r.certificate.summary() if r.certificate else '-'} indep="
                  f"{fmt(max(indep.stationarity_scaled, indep.complementarity_scaled)) if indep else '-'} {flag} "
                  f"({time.perf_counter() - t:.2f}s)", flush=True)
    return rows, flagged, presets


def table_text(rows, flagged, presets):
    successes = [r for r in rows if r[2] in ("success", "acceptable")]
    by_level = {}
    for r in successes:
        level = r[5].level if r[5] is not None else "none"
        by_level[level] = by_level.get(level, 0) + 1
    statuses = {}
    for r in rows:
        statuses[r[2]] = statuses.get(r[2], 0) + 1
    lines = header(TABLE, "python benchmarks/bench_certificate.py --part table")
    lines += [f"Every built-in problem (zambezi families at N = {ZAMBEZI_N}, the others at their default size) with "
              f"every preset in configs/ ({len(presets)}), default start, {len(rows)} solves. Columns: the solver's "
              "own KKT residual (`Result.kkt_residual`, each solver's own measure); the certificate the result "
              "carries (level, multipliers it used: solver's or least-squares, scaled stationarity / "
              "complementarity in relative units of the objective, violation); *independent*: the scaled KKT "
              "residual max(stationarity, complementarity) recomputed by this script from the point alone, with "
              "olado's least-squares multipliers (`certify(problem, X, U, None)`). Tolerances: 1e-6 scaled KKT and "
              "the preset's constr_viol_tol for success, 1e-4 and 1e-6 for acceptable.", "",
              f"Statuses: {', '.join(f'{k} {v}' for k, v in sorted(statuses.items()))}. Successes (success or "
              f"acceptable): {len(successes)}; their certificates: "
              f"{', '.join(f'{k} {v}' for k, v in sorted(by_level.items()))}. "
              f"**Successes whose independently recomputed KKT residual or violation exceeds the tolerance: "
              f"{len(flagged)}**" + (f" ({', '.join(f'{a} / {b}' for a, b in flagged)})" if flagged else "") + ".", "",
              "| problem | preset | status | iter | solver KKT | certificate | multipliers | scaled stat. | scaled compl. "
              "| violation | independent KKT | flagged |",
              "|:--|:--|:--|---:|---:|:--|:--|---:|---:|---:|---:|:--|"]
    for name, c, status, it, kkt, cert, indep, flag in sorted(rows):
        if cert is None:
            cells = ["-", "-", "-", "-", "-"]
        else:
            cells = [cert.level, cert.multipliers or "-", fmt(cert.stationarity_scaled), fmt(cert.complementarity_scaled),
                     fmt(cert.violation)]
        ind = fmt(max(indep.stationarity_scaled, indep.complementarity_scaled)) if indep is not None else "-"
        lines.append(f"| {name} | {c} | {status} | {'-' if it is None else it} | {fmt(kkt)} | " + " | ".join(cells)
                     + f" | {ind} | {flag} |")
    return "\n".join(lines) + "\n"


def run_cost(Ns):
    sqp = make_solver(load_config(HERE.parent / "configs" / "sqp-ip.ini"))
    small = zambezi_problem("zambezi", N=12)
    warm = sqp.solve(small)                        # warm-up: kernels compiled, the least-squares path too
    certify(small, warm.x, warm.u, None)
    rows = []
    for N in Ns:
        p = zambezi_problem("zambezi", N=N)
        r = sqp.solve(p)
        c = r.certificate
        # the certificate's parts, timed one by one at the returned point
        t = time.perf_counter()
        pt = StagePoint(p, r.x, r.u)
        t_eval = time.perf_counter() - t
        bounds = StageBounds.of(p)
        W = (np.maximum(1.0, np.abs(r.x)), np.maximum(1.0, np.abs(r.u)))
        t = time.perf_counter()
        kkt_figures(p, r.x, r.u, r.multipliers)
        t_fig = time.perf_counter() - t
        t = time.perf_counter()
        least_squares_multipliers(p, pt, bounds, W)
        t_ls = time.perf_counter() - t
        t = time.perf_counter()
        spot_check(p, pt, bounds, W)
        t_check = time.perf_counter() - t
        t = time.perf_counter()
        forced = certify(p, r.x, r.u, None)
        t_forced = time.perf_counter() - t
        solve = r.time_s - c.time_s
        rows.append((N, r, c, solve, t_eval, t_fig, t_ls, t_check, forced, t_forced))
        print(f"N={N}: {r.status.value} it={r.iterations} solve {solve:.2f}s certificate {c.time_s:.3f}s "
              f"({100 * c.time_s / solve:.1f}%): eval {t_eval:.3f} figures {t_fig:.3f} spot check {t_check:.3f}; "
              f"least-squares path {t_forced:.3f}s (to convergence {t_ls:.3f}) {forced.summary()}", flush=True)
    lines = header(COST, "python benchmarks/bench_certificate.py --part cost --N " + " ".join(map(str, Ns)))
    lines += ["configs/sqp-ip.ini on `zambezi` (balance start). *solve*: the SQP's time without the certificate; "
              "*certificate*: the check as the solve runs it (values and first derivatives at the point, the SQP's "
              "multipliers, the spot check; the least-squares multipliers only when the solver's fail); its parts "
              "timed again one by one; *least-squares path*: the whole certificate without the solver's "
              "multipliers (`certify(problem, X, U, None)`: the semismooth least-squares steps from a zero start, "
              "each an equality-constrained stage QP solved by olado's interior-point QP, stopped when the "
              "tolerance is met), the cost when a solver's multipliers fail; *to convergence*: the same steps "
              "until the weights repeat. One solve each, after a warm-up.", "",
              "| N | variables | status | iter | solve (s) | certificate (s) | share | evaluation (s) | figures (s) "
              "| spot check (s) | evaluations | least-squares path (s) | its scaled KKT | to convergence (s) |",
              "|---:|---:|:--|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for N, r, c, solve, t_eval, t_fig, t_ls, t_check, forced, t_forced in rows:
        lines.append(f"| {N} | {r.x.size + r.u.size} | {r.status.value} | {r.iterations} "
                     f"| {solve:.2f} | {c.time_s:.3f} | {100 * c.time_s / solve:.1f} % | {t_eval:.3f} | {t_fig:.3f} "
                     f"| {t_check:.3f} | {c.evaluations} | {t_forced:.3f} "
                     f"| {max(forced.stationarity_scaled, forced.complementarity_scaled):.1e} | {t_ls:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=["table", "cost", "both"], default="both")
    ap.add_argument("--N", type=int, nargs="*", default=[1200, 12000])
    ap.add_argument("--presets", nargs="*", default=None, help="restrict the table to these presets")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    if args.part in ("table", "both"):
        text = table_text(*run_table(args.presets))
        if not args.no_write and not args.presets:
            write_section(TABLE, text)
    if args.part in ("cost", "both"):
        text = run_cost(args.N)
        if not args.no_write:
            write_section(COST, text)


if __name__ == "__main__":
    main()
