"""Seed 002's Table 4.5 for olado's FQLNK (``fqlnk``, docs/fqlnk.md) on the Earth-to-Mars
maximum-radius transfer (``orbit-raising``): per grid size and Hessian (fd, exact -- the seed's
"AD" --, bfgs) the Newton iterations, the average GMRES iterations per Newton iteration, the
average Hessian-form and KKT-solve times with their shares of the total, the total time and the
speedup over FD, next to sqp-ip and IPOPT (configs/) on the same problem; which local solution
each reaches (r(t_f) against IPOPT's, and a second-order check: the smallest eigenvalue of the
Lagrangian Hessian on the null space of the constraint Jacobian).

The problem is the seed's (sec. 4.1): olado's built-in without its safeguard r >= 0.5 (inactive
at every solution here), i.e. equality constraints only, as the seed solves it; ``--bound`` keeps
the bound (fqlnk then treats it by squared slacks, seed eq. (4.6)). One solve per entry: the
machine is shared, so times are orders of magnitude.

    python benchmarks/bench_fqlnk.py                    # N = 8 .. 128; writes RESULTS.md
    python benchmarks/bench_fqlnk.py --N 8 16 --no-write
    python benchmarks/bench_fqlnk.py --others           # the equality-only built-ins, another section
    python benchmarks/bench_fqlnk.py --backtracking --N 16 32 64    # merit vs full steps, another section
    python benchmarks/bench_fqlnk.py --variants --N 8 16 32 64      # BFGS variants, Earth-to-Mars and the others
    python benchmarks/bench_fqlnk.py --starts --N 8 16 32           # the start: linear thrust-angle ramps
"""

from __future__ import annotations

import argparse
import datetime
import sys

import numpy as np
from _common import HERE, commit, machine, write_section
from scipy.linalg import null_space

from olado.config import load_config, make_solver
from olado.problems import PROBLEMS
from olado.solvers.fqlnk.layout import Layout
from olado.solvers.sqp.state import Point

SECTION = "FQLNK (seed 002) on the Earth-to-Mars transfer: seed 002's Table 4.5"
SECTION_BOUND = SECTION + ", with r >= 0.5 as squared slacks"
SECTION_OTHERS = "FQLNK (seed 002) on olado's equality-only built-ins"
SECTION_BACKTRACKING = "FQLNK (seed 002) on the Earth-to-Mars transfer with and without backtracking (seed's Fig. 4.10)"
SECTION_VARIANTS = "FQLNK (seed 002): BFGS variants on the Earth-to-Mars transfer and the equality-only built-ins"
SECTION_STARTS = "FQLNK (seed 002) on the Earth-to-Mars transfer: the start"
#: --variants: name -> fqlnk options over configs/fqlnk.ini (the first: the defaults, the seed's)
VARIANTS = {
    "seed (Powell 0.2)": {},
    "threshold 0.1": {"bfgs_threshold": 0.1},
    "skip (t = 0.2)": {"bfgs_damping": "skip"},
    "skip (t = 1e-4)": {"bfgs_damping": "skip", "bfgs_threshold": 1e-4},
    "B0 scaled (6.20)": {"bfgs_scaling": "first-step"},
    "B0 = y'y/s'y I": {"bfgs_init": "identity"},
    "full steps": {"line_search": "none"},
}
#: --starts: linear thrust-angle guesses phi(t) = a + (b - a) t / t_f, (a, b) in rad; (0, 0) is olado's
RAMPS = [(0.0, 0.0), (0.0, -0.5), (0.0, -1.0), (0.0, -1.5), (0.5, 0.0), (0.5, -0.5), (0.5, -1.0), (0.5, -1.5),
         (1.0, 0.0), (1.0, -0.5), (1.0, -1.0), (1.0, -1.5)]
#: the built-ins without bounds or inequality rows (their default N)
OTHERS = ("lq", "vanderpol", "rayleigh", "cstr", "hanging-chain", "double-integrator")
#: seed 002's Table 4.5 (MATLAB; trapezoidal subintervals; * an unphysical local minimum):
#: (Hessian, subintervals, Newton its, avg GMRES its, avg Hessian form s (share), avg KKT solve s (share), total s, speedup)
SEED_TABLE = [
    ("FD", "8", 6, 1.2, "0.29 (97.2%)", "0.001 (<1%)", 1.79, "--"),
    ("FD", "16", 8, 1.4, "0.98 (99.1%)", "0.002 (<1%)", 7.91, "--"),
    ("FD", "32", 8, 1.8, "3.62 (99.5%)", "0.003 (<1%)", 29.11, "--"),
    ("FD", "64", 14, 2.0, "13.81 (99.6%)", "0.010 (<1%)", 194.07, "--"),
    ("FD", "128*", 21, 2.1, "52.60 (99.8%)", "0.051 (<1%)", 1107.38, "--"),
    ("AD", "8", 6, 1.2, "0.28 (94.4%)", "0.007 (<1%)", 1.78, "1.0x"),
    ("AD", "16", 8, 1.4, "0.50 (95.7%)", "0.004 (<1%)", 4.13, "1.9x"),
    ("AD", "32", 8, 1.8, "1.20 (98.5%)", "0.005 (<1%)", 9.75, "3.0x"),
    ("AD", "64", 14, 2.0, "3.18 (98.7%)", "0.010 (<1%)", 45.12, "4.3x"),
    ("AD", "128*", 21, 2.1, "18.92 (99.4%)", "0.045 (<1%)", 399.71, "2.8x"),
    ("BFGS", "8", 14, 1.3, "0.03 (76.3%)", "0.003 (7.6%)", 0.55, "3.3x"),
    ("BFGS", "16", 17, 1.8, "0.04 (72.3%)", "0.003 (5.4%)", 0.94, "8.4x"),
    ("BFGS", "32", 16, 2.0, "0.10 (78.4%)", "0.009 (7.1%)", 2.04, "14.3x"),
    ("BFGS", "64", 14, 2.0, "0.27 (77.9%)", "0.043 (12.4%)", 4.85, "40.2x"),
    ("BFGS", "128", 15, 2.1, "1.45 (83.0%)", "0.231 (13.1%)", 26.22, "42.2x"),
    ("BFGS", "256", 25, 3.0, "7.21 (83.2%)", "1.320 (15.2%)", 216.62, "--"),
]


def seed_table() -> str:
    rows = ["| Hessian | subint. | Newton its | avg GMRES its | avg Hessian form (s) | avg KKT solve (s) | total (s) | speedup |",
            "|:--|--:|--:|--:|--:|--:|--:|--:|"]
    rows += [f"| {h} | {n} | {its} | {gm} | {hf} | {kkt} | {tot} | {sp} |" for h, n, its, gm, hf, kkt, tot, sp in SEED_TABLE]
    return "\n".join(rows)
HESSIANS = ("fd", "exact", "bfgs")
PEERS = ("sqp-ip", "ipopt")
#: r(t_f) equal to IPOPT's to this (relative): the same (physical) solution
SAME = 1e-6


def problem(N, bound, method="rk4"):
    p = PROBLEMS["orbit-raising"](N=N, method=method)
    if not bound:
        p.x_bounds = None        # the seed's problem: no r >= 0.5
    return p


def trapezoidal_problem(N, phi):
    """The seed's transcription of its Earth-to-Mars problem (sec. 2.3, 4.1) as an olado OCP: the
    trapezoidal rule with the controls at the N + 1 nodes. Its residuals R_k are implicit in
    s_{k+1}, so the DOCP carries the next node as the control: state z^k = (s_k, phi_k), control
    w^k = (s_{k+1}, phi_{k+1}) - ZREF, z^{k+1} = w^k + ZREF (an explicit Euler step of
    (w + ZREF - z) / h), and R_k = 0 as stage equality rows; phi_0 is a free initial component
    (olado's parameter stage). ``phi`` (N + 1,): the guess at the nodes; the states are integrated
    from it by the same rule (the seed's sec. 4.3). Twice the seed's unknowns (z and w), the extra
    ones fixed by linear rows: exact Newton steps are those of the seed's problem, BFGS's are not
    quite (its matrix lives on both copies)."""
    from olado.problems.autodiff.functions import cos, sin
    from olado.problems.ocp import OCP
    thrust, mdot, tf = 0.1405, 0.0749, 3.32
    h = tf / N

    def f(t, s, ph, c=cos, sn=sin):
        a = thrust / (1.0 - mdot * t)
        return [s[1], s[2] * s[2] / s[0] - 1.0 / (s[0] * s[0]) + a * sn(ph), -s[1] * s[2] / s[0] + a * c(ph)]

    def residuals(t, z, w, p):
        w = [w[i] + ZREF[i] for i in range(4)]
        fz, fw = f(t, z, z[3]), f(t + h, w, w[3])
        return [w[i] - z[i] - 0.5 * h * (fz[i] + fw[i]) for i in range(3)]

    S = np.empty((N + 1, 3))
    S[0] = (1.0, 0.0, 1.0)
    fn = lambda t, s, ph: np.array(f(t, s, ph, np.cos, np.sin))      # noqa: E731
    for k in range(N):                 # the implicit step by fixed-point iteration (h |df/ds| < 1 here)
        nxt = S[k] + h * fn(k * h, S[k], phi[k])
        for _ in range(60):
            nxt = S[k] + 0.5 * h * (fn(k * h, S[k], phi[k]) + fn((k + 1) * h, nxt, phi[k + 1]))
        S[k + 1] = nxt
    Z = np.column_stack([S, phi])
    return OCP(lambda t, z, w, p: [(w[i] + ZREF[i] - z[i]) / h for i in range(4)], [1.0, 0.0, 1.0, float(phi[0])],
               controls=4, N=N, T=tf, final_cost=lambda t, x, p: -x[0], path=residuals, path_equalities=[0, 1, 2],
               terminal=lambda t, x, p: [x[1], x[2] - x[0] ** -0.5], terminal_equalities=[0, 1], method="euler",
               free_x0=[False, False, False, True], u_guess=Z[1:] - ZREF, x_guess=Z, name="earth-to-mars-trapezoidal")


#: trapezoidal_problem's offset of the next node in the control (its stand-in control 0 on the
#: parameter stage then means r = 1, not the singular r = 0)
ZREF = np.array([1.0, 0.0, 1.0, 0.0])


def earth_to_mars(N, method, a, b):
    """(problem, guess) of the seed's problem from the linear thrust-angle guess a -> b."""
    if method == "trapezoidal":
        return trapezoidal_problem(N, a + (b - a) * np.arange(N + 1) / N), None
    return problem(N, False, method), ramp_guess(N, a, b)


def reduced_hessian_min(p, result, bound):
    """Smallest eigenvalue of Z' H Z at the result (H the exact Lagrangian Hessian with the
    result's multipliers, Z a basis of the null space of G, both in fqlnk's full space -- with
    the squared slacks of the bounds when ``bound``): > 0 a strict local minimum, < 0 a saddle."""
    L = Layout(p, slacks=bound)
    b = L.bounds
    y = L.pack(result.x, result.u)[:L.ny]
    s = np.sqrt(np.maximum(b.sign * (y[b.col] - b.value), 0.0))
    v = np.concatenate([y, s])
    pt = Point(p, result.x, result.u)
    m = result.multipliers
    z = {1.0: L.pack(m["bound_lower_x"], m["bound_lower_u"])[:L.ny], -1.0: L.pack(m["bound_upper_x"], m["bound_upper_u"])[:L.ny]}
    mb = np.array([-z[sg][c] for sg, c in zip(b.sign, b.col)])
    lam = np.concatenate([m["dynamics"].ravel(), m["stage_constraints"][:, L.eq].ravel(),
                          m["final_constraints"][L.eqN], mb])
    Z = null_space(L.jacobian(pt, v).toarray())
    H = L.hessian(pt, v, lam).toarray()
    return float(np.linalg.eigvalsh(Z.T @ H @ Z)[0])


def which(r_tf, ref, lowest):
    kind = "" if lowest is None else (", local min" if lowest > 0 else ", saddle")
    if abs(r_tf - ref) <= SAME * abs(ref):
        return f"IPOPT's (physical){kind}"
    return f"other KKT point{kind}"


def fqlnk_row(N, hessian, bound, fd_total):
    s = make_solver(load_config(HERE.parent / "configs" / "fqlnk.ini"))
    s.options.hessian = hessian
    s.options.inequalities = "squared-slacks" if bound else "refuse"
    p = problem(N, bound)
    r = s.solve(p)
    i = r.info
    total = i["solve_time_s"]
    return r, p, dict(its=i["newton_iterations"], gm=i["avg_gmres_iterations"], hf=i["avg_hessian_time_s"],
                      hf_share=i["hessian_time_s"] / total, kkt=i["avg_kkt_time_s"], kkt_share=i["kkt_time_s"] / total,
                      total=total)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--N", type=int, nargs="+", default=[8, 16, 32, 64, 128])
    ap.add_argument("--hessians", nargs="+", default=list(HESSIANS), choices=HESSIANS)
    ap.add_argument("--bound", action="store_true", help="keep olado's r >= 0.5 (squared slacks in fqlnk)")
    ap.add_argument("--others", action="store_true", help="fqlnk (three Hessians) and IPOPT on the equality-only "
                    "built-ins instead")
    ap.add_argument("--backtracking", action="store_true", help="exact and bfgs with the merit's backtracking "
                    "and with full steps (line_search = none) instead")
    ap.add_argument("--variants", action="store_true", help="the BFGS variants (VARIANTS) on Earth-to-Mars at --N and "
                    "on the equality-only built-ins instead")
    ap.add_argument("--starts", action="store_true", help="bfgs and exact from linear thrust-angle guesses (RAMPS) "
                    "instead")
    ap.add_argument("--ramps", nargs="+", type=int, default=None, help="with --starts: indices into RAMPS")
    ap.add_argument("--options", nargs="+", default=[], metavar="KEY=VALUE", help="with --starts: fqlnk options over "
                    "configs/fqlnk.ini (numbers parsed as float), e.g. bfgs_scaling=first-step")
    ap.add_argument("--method", default="rk4", choices=("rk4", "euler", "trapezoidal"), help="with --starts: the "
                    "transcription: the built-in's RK4 or explicit Euler, or the seed's trapezoidal rule "
                    "(trapezoidal_problem)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    if args.variants:
        return variants(args, argv)
    if args.starts:
        return starts(args, argv)
    if args.others:
        return others(args, argv)
    if args.backtracking:
        return backtracking(args, argv)
    head = ["| Hessian | N | status | Newton its | avg GMRES its | avg Hessian form (s) | avg KKT solve (s) | "
            "total (s) | speedup over FD | r(t_f) | solution |",
            "|:--|--:|:--|--:|--:|--:|--:|--:|--:|--:|:--|"]
    rows = []
    peers = {name: make_solver(load_config(HERE.parent / "configs" / f"{name}.ini")) for name in PEERS}
    for s in peers.values():           # warm-up: compiled kernels, imports
        s.solve(problem(min(args.N), args.bound))
    fqlnk_row(min(args.N), "exact", args.bound, None)
    for N in args.N:
        ref_results = {name: s.solve(problem(N, args.bound)) for name, s in peers.items()}
        ref = float(ref_results["ipopt"].x[-1, 0])
        fd_total = None
        for h in args.hessians:
            r, p, f = fqlnk_row(N, h, args.bound, fd_total)
            if h == "fd":
                fd_total = f["total"] if r.status.success else None
            speed = f"{fd_total / f['total']:.1f}x" if fd_total and h != "fd" and r.status.success else "--"
            lowest = reduced_hessian_min(p, r, args.bound) if r.status.success and N <= 128 else None
            r_tf = float(r.x[-1, 0])
            rows.append(f"| {h} | {N} | {r.status.value} | {f['its']} | {f['gm']:.1f} | {f['hf']:.2e} "
                        f"({100 * f['hf_share']:.0f}%) | {f['kkt']:.2e} ({100 * f['kkt_share']:.0f}%) | "
                        f"{f['total']:.2f} | {speed} | {r_tf:.6f} | {which(r_tf, ref, lowest) if r.status.success else r.message[:80]}"
                        f"{'' if lowest is None else f' (min eig {lowest:.1e})'} |")
            print(rows[-1], flush=True)
        for name, r in ref_results.items():
            r_tf = float(r.x[-1, 0])
            rows.append(f"| {name} | {N} | {r.status.value} | {r.iterations} (its) | -- | -- | -- | {r.time_s:.2f} | "
                        f"-- | {r_tf:.6f} | {which(r_tf, ref, None) if r.status.success else r.message[:80]} |")
            print(rows[-1], flush=True)
    shown = " ".join(argv if argv is not None else sys.argv[1:])
    command = f"python benchmarks/bench_fqlnk.py {shown}".strip()
    what = ("olado's built-in with r >= 0.5 as squared slacks" if args.bound
            else "the seed's problem: olado's built-in without its (inactive) bound r >= 0.5, equality constraints only")
    title = SECTION_BOUND if args.bound else SECTION
    text = (f"## {title}\n\n`{command}` at {commit()}, {datetime.date.today()}, {machine()}; one solve per row after a warm-up, "
            f"the machine shared with other jobs (times: orders of magnitude). Problem: {what}; N RK4 intervals "
            "(the seed: N trapezoidal subintervals). configs/fqlnk.ini with hessian = fd / exact / bfgs; "
            "'total' is the solve loop (the in-loop certificates included); sqp-ip and IPOPT: iterations and "
            "Result.time_s. 'solution': r(t_f) equal to IPOPT's to 1e-6 or not, and the smallest eigenvalue of "
            "the Lagrangian Hessian on the null space of the constraint Jacobian (> 0: a strict local minimum).\n\n"
            + "\n".join(head + rows) + "\n\nSeed 002's own Table 4.5 (MATLAB, trapezoidal subintervals, FD Jacobians; "
            "'*': an unphysical local minimum, r(t_f) 1.504 / 1.516 against the physical 1.525; the speedup is over FD):"
            "\n\n" + seed_table() + "\n")
    if not args.no_write:
        write_section(title, text)
    print(text)


def backtracking(args, argv):
    """The seed's Fig. 4.10 as a table: Newton iterations, status and r(t_f) of the exact and BFGS
    variants with Armijo backtracking on the merit and with full steps."""
    rows = ["| N | Hessian | line search | status | Newton its | r(t_f) | stop |", "|--:|:--|:--|:--|--:|--:|:--|"]
    for N in args.N:
        for h in ("exact", "bfgs"):
            for ls in ("merit", "none"):
                s = make_solver(load_config(HERE.parent / "configs" / "fqlnk.ini"))
                s.options.hessian, s.options.line_search = h, ls
                s.options.inequalities = "squared-slacks" if args.bound else "refuse"
                r = s.solve(problem(N, args.bound))
                rows.append(f"| {N} | {h} | {ls} | {r.status.value} | {r.iterations} | {float(r.x[-1, 0]):.6f} | "
                            f"{'' if r.success else r.message[:110]} |")
                print(rows[-1], flush=True)
    command = f"python benchmarks/bench_fqlnk.py {' '.join(argv if argv is not None else sys.argv[1:])}".strip()
    text = (f"## {SECTION_BACKTRACKING}\n\n`{command}` at {commit()}, {datetime.date.today()}, {machine()}. "
            "configs/fqlnk.ini with hessian = exact / bfgs and line_search = merit (Armijo backtracking on the "
            "augmented Lagrangian) / none (full steps); the seed's problem (no r >= 0.5).\n\n" + "\n".join(rows) + "\n")
    if not args.no_write:
        write_section(SECTION_BACKTRACKING, text)
    print(text)


def others(args, argv):
    """Newton iterations, status and objective of fqlnk with each Hessian against IPOPT on the
    built-ins that have neither bounds nor inequality rows."""
    ipopt = make_solver(load_config(HERE.parent / "configs" / "ipopt.ini"))
    rows = ["| problem | N | IPOPT its | IPOPT objective | " + " | ".join(f"{h}: status, its, rel. diff" for h in HESSIANS) + " |",
            "|:--|--:|--:|--:|" + ":--|" * len(HESSIANS)]
    for name in OTHERS:
        ref = ipopt.solve(PROBLEMS[name]())
        cells = []
        for h in HESSIANS:
            s = make_solver(load_config(HERE.parent / "configs" / "fqlnk.ini"))
            s.options.hessian = h
            r = s.solve(PROBLEMS[name]())
            rel = abs(r.objective - ref.objective) / max(1.0, abs(ref.objective))
            cells.append(f"{r.status.value}, {r.iterations}, {rel:.0e}")
        rows.append(f"| {name} | {PROBLEMS[name]().N} | {ref.iterations} | {ref.objective:.10g} | " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    command = f"python benchmarks/bench_fqlnk.py {' '.join(argv if argv is not None else sys.argv[1:])}".strip()
    text = (f"## {SECTION_OTHERS}\n\n`{command}` at {commit()}, {datetime.date.today()}, {machine()}. configs/fqlnk.ini "
            "with hessian = fd / exact / bfgs against configs/ipopt.ini; rel. diff = |J - J_IPOPT| / max(1, |J_IPOPT|).\n\n"
            + "\n".join(rows) + "\n")
    if not args.no_write:
        write_section(SECTION_OTHERS, text)
    print(text)


def fqlnk_solve(p, options, guess=None):
    s = make_solver(load_config(HERE.parent / "configs" / "fqlnk.ini"))
    for k, v in options.items():
        setattr(s.options, k, v)
    return s.solve(p, guess)


def cell(r, ref, what):
    """status mark, iterations, and which solution: '=' IPOPT's (to SAME relative), else the value."""
    value = float(r.x[-1, 0]) if what == "r" else float(r.objective)
    same = abs(value - ref) <= SAME * max(1.0, abs(ref))
    mark = "" if r.status.success else " " + r.status.value
    return f"{r.iterations}{mark}" + ("" if same or not r.status.success else f" ({value:.4g})")


def variants(args, argv):
    """Newton iterations of each BFGS variant (VARIANTS) on Earth-to-Mars at args.N and on the
    equality-only built-ins (OTHERS); '(value)' marks another solution than IPOPT's."""
    ipopt = make_solver(load_config(HERE.parent / "configs" / "ipopt.ini"))
    cases = [(f"Earth-to-Mars N = {N}", lambda N=N: problem(N, False), "r") for N in args.N]
    cases += [(name, lambda name=name: PROBLEMS[name](), "J") for name in OTHERS]
    rows = ["| variant | " + " | ".join(c[0] for c in cases) + " | total |", "|:--" + "|--:" * (len(cases) + 1) + "|"]
    refs = []
    for _, make, what in cases:
        r = ipopt.solve(make())
        refs.append(float(r.x[-1, 0]) if what == "r" else float(r.objective))
    for label, opts in VARIANTS.items():
        cells, total = [], 0
        for (_, make, what), ref in zip(cases, refs):
            r = fqlnk_solve(make(), opts)
            total += r.iterations
            cells.append(cell(r, ref, what))
        rows.append(f"| {label} | " + " | ".join(cells) + f" | {total} |")
        print(rows[-1], flush=True)
    lbfgs = make_solver(load_config(HERE.parent / "configs" / "ipopt.ini"))
    lbfgs.options.hessian = "limited-memory"
    for label, solver in (("IPOPT, exact Hessian", ipopt), ("IPOPT, L-BFGS", lbfgs)):
        cells, total = [], 0
        for (_, make, what), ref in zip(cases, refs):
            r = solver.solve(make())
            total += r.iterations
            cells.append(cell(r, ref, what))
        rows.append(f"| {label} | " + " | ".join(cells) + f" | {total} |")
        print(rows[-1], flush=True)
    command = f"python benchmarks/bench_fqlnk.py {' '.join(argv if argv is not None else sys.argv[1:])}".strip()
    text = (f"## {SECTION_VARIANTS}\n\n`{command}` at {commit()}, {datetime.date.today()}, {machine()}. configs/fqlnk.ini "
            "(hessian = bfgs) with one option changed per row (docs/fqlnk.md, \"Closing the iteration gap\"); Newton "
            "iterations, a status when not success, and in parentheses r(t_f) or J when the point is not IPOPT's "
            "(configs/ipopt.ini, relative 1e-6). Earth-to-Mars: the seed's problem (no r >= 0.5), olado's start "
            "(phi = 0); the others at their default N. The last two rows: IPOPT's iterations with its exact Hessian "
            "and with its own quasi-Newton Hessian (hessian = limited-memory).\n\n" + "\n".join(rows) + "\n")
    if not args.no_write:
        write_section(SECTION_VARIANTS, text)
    print(text)


def _number(text):
    try:
        return float(text)
    except ValueError:
        return text


def ramp_guess(N, a, b):
    t = (np.arange(N) + 0.5) / N
    return (a + (b - a) * t)[:, None]


def starts(args, argv):
    """bfgs and exact from linear thrust-angle guesses phi = a + (b - a) t / t_f (the seed's start is
    'some reasonable control variables', Fig. 4.3, not given in numbers; olado's is phi = 0)."""
    ipopt = make_solver(load_config(HERE.parent / "configs" / "ipopt.ini"))
    refs = {N: float(ipopt.solve(*earth_to_mars(N, args.method, 0.0, 0.0)).x[-1, 0]) for N in args.N}
    ramps = RAMPS if args.ramps is None else [RAMPS[i] for i in args.ramps]
    hessians = [h for h in ("bfgs", "exact") if h in args.hessians]
    extra = {k: _number(v) for k, v in (kv.split("=", 1) for kv in args.options)}
    head = " | ".join(f"{h} N = {N}" for h in hessians for N in args.N)
    rows = [f"| phi(0) .. phi(t_f) (rad) | {head} |", "|:--" + "|--:" * (len(hessians) * len(args.N)) + "|"]
    for a, b in ramps:
        cells = []
        for h in hessians:
            for N in args.N:
                p, guess = earth_to_mars(N, args.method, a, b)
                cells.append(cell(fqlnk_solve(p, {"hessian": h, **extra}, guess), refs[N], "r"))
        rows.append(f"| {a:+.1f} .. {b:+.1f}{' (olado)' if a == b == 0 else ''} | " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    command = f"python benchmarks/bench_fqlnk.py {' '.join(argv if argv is not None else sys.argv[1:])}".strip()
    title = SECTION_STARTS + ("" if args.method == "rk4" else f", {args.method} transcription")
    title += "".join(f", {kv}" for kv in args.options)
    text = (f"## {title}\n\n`{command}` at {commit()}, {datetime.date.today()}, {machine()}. configs/fqlnk.ini "
            "with hessian = bfgs / exact from the guess phi^k = a + (b - a) (k + 1/2) / N (the trapezoidal transcription: "
            "a + (b - a) k / N at the nodes k = 0..N; states simulated, "
            "least-squares multipliers: the seed's sec. 4.3); the seed's problem (no r >= 0.5). Newton iterations, "
            f"a status when not success, and in parentheses r(t_f) when it is not IPOPT's from phi = 0 (relative 1e-6, "
            f"IPOPT on the same {args.method} transcription). The "
            "seed's Table 4.5 (subintervals 8 / 16 / 32 / 64 / 128): BFGS 14 / 17 / 16 / 14 / 15, AD 6 / 8 / 8 / "
            "14 / 21.\n\n" + "\n".join(rows) + "\n")
    if not args.no_write:
        write_section(title, text)
    print(text)


if __name__ == "__main__":
    main()
