"""olado against the peers a user would pick: CasADi + IPOPT and CasADi + FATROP (``casadi`` wheel,
:mod:`_peers`), side by side in one process on the same Zambezi problems from the same start.

For each case: olado's presets (``--configs``) and both peers are warmed up, then each solves the
problem ``--repeats`` times; the best time counts. The peers' set-up (graph, derivative functions,
FATROP's structure detection) is timed separately and not in the ratio. Every solver must reach
the same objective (``--rtol``, relative to the best peer's); the ratio is olado's best preset
over the faster peer.

    python benchmarks/bench_peers.py                          # issue 16's five cases; writes RESULTS.md
    python benchmarks/bench_peers.py --cases zambezi12:24 --no-write
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
import time
from dataclasses import dataclass

from _common import HERE, commit, machine, write_section
from _peers import PEERS, SETUP_MIN_POWER, CasadiPeer, estimate_setup

from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.problems.zambezi_ad import ZambeziAD

SECTION = "Against the peers: CasADi + IPOPT and CasADi + FATROP"
CASES = ["zambezi12:24", "zambezi12:120", "zambezi12:252", "zambezi:1200", "zambezi:12000"]
#: above this N a peer's set-up is estimated from probes at smaller N when the run has not measured it
PROBE_FROM = 1200


@dataclass
class Row:
    """One solver on one case: the best of the repeats."""

    solver: str
    objective: float
    iterations: str
    status: str
    success: bool
    time_s: float
    setup_s: float = 0.0
    estimated: bool = False     # setup_s is an estimate (the peer was skipped)

    def ms_per_iteration(self) -> str:
        """Time per major iteration (SQP iterations for sqp-ip's "SQP / QP"), or "-"."""
        major = self.iterations.split("/")[0].strip()
        if not major.isdigit() or int(major) == 0 or self.time_s != self.time_s:
            return "-"
        return f"{self.time_s * 1e3 / int(major):.2f}"


def _olado_rows(configs, family, N, repeats):
    rows = []
    for name in configs:
        solver = make_solver(load_config(HERE.parent / "configs" / f"{name}.ini"))
        solver.solve(zambezi_problem(family, N=min(N, 24), start="balance"))     # warm-up (numba caches)
        best = None
        for _ in range(repeats):
            r = solver.solve(zambezi_problem(family, N=N, start="balance"))
            if best is None or r.time_s < best.time_s:
                best = r
        its = f"{best.iterations}" + (f" / {best.qp_iterations}" if best.qp_iterations else "")
        rows.append(Row(name, best.objective, its, best.status.value, best.success, best.time_s))
        print(f"  {name:14s} {best.status.value:12s} it={its:10s} J={best.objective:.12g} {best.time_s * 1e3:9.1f} ms",
              flush=True)
    return rows


def _probe_sizes(N):
    """Smaller horizons to time a peer's set-up at before N when the run has measured none:
    N / 100 and N / 10, whole years, at least 24."""
    return sorted({max(24, 12 * round(N / f / 12)) for f in (100, 10)} - {N})


def _setup_estimate(name, family, N, measured, limit):
    """The estimated set-up of peer ``name`` at N from this run's measurements (``measured``,
    {N: s}, updated), timing probe set-ups at smaller N first when fewer than two are known; a
    probe stops the probing when its own estimate is already above ``limit``."""
    if N > PROBE_FROM and sum(k < N for k in measured) < 2:
        for n in _probe_sizes(N):
            est = estimate_setup(measured, n, SETUP_MIN_POWER[name])
            if n in measured or (est is not None and est > limit):
                continue
            measured[n] = CasadiPeer(ZambeziAD(family=family, N=n, start="balance"), PEERS[name]).setup_s
            print(f"  {name:14s} probe set-up at N = {n}: {measured[n]:.2f} s", flush=True)
    return estimate_setup(measured, N, SETUP_MIN_POWER[name])


def _peer_rows(peers, family, N, repeats, setup_limit, measured=None, max_N=None):
    """The peers on one case. ``measured`` ({peer: {N: set-up s}}) carries the set-up times across
    cases; a peer whose set-up at N is estimated above ``setup_limit`` from them (:func:`estimate_setup`)
    or whose ``max_N`` (per peer) is below N is skipped without building it (FATROP's set-up at
    N = 12 000 took over 5 minutes, and a set-up cannot be stopped once it runs)."""
    rows = []
    measured = {} if measured is None else measured
    max_N = max_N or {}
    for name in peers:
        if N > max_N.get(name, math.inf):
            print(f"  {name:14s} skipped: N > {max_N[name]} (--peer-max-N)", flush=True)
            rows.append(Row(name, float("nan"), "-", f"skipped: N above --peer-max-N {max_N[name]}", False,
                            float("nan")))
            continue
        times = measured.setdefault(name, {})
        est = _setup_estimate(name, family, N, times, setup_limit)
        if est is not None and est > setup_limit:
            print(f"  {name:14s} skipped: set-up estimated at {est:.0f} s > {setup_limit:g} s", flush=True)
            rows.append(Row(name, float("nan"), "-", "skipped: set-up estimated above the limit", False,
                            float("nan"), est, estimated=True))
            continue
        t0 = time.perf_counter()
        peer = CasadiPeer(ZambeziAD(family=family, N=N, start="balance"), PEERS[name])
        setup = times[N] = time.perf_counter() - t0
        if setup > setup_limit:
            print(f"  {name:14s} set-up {setup:.1f} s > {setup_limit:g} s: not solved", flush=True)
            rows.append(Row(name, float("nan"), "-", "set-up too long", False, float("nan"), setup))
            continue
        peer.solve()                                       # warm-up
        best = min((peer.solve() for _ in range(repeats)), key=lambda r: r.time_s)
        rows.append(Row(name, best.objective, str(best.iterations), best.status, best.success, best.time_s, setup))
        print(f"  {name:14s} {best.status:12s} it={best.iterations:<10d} J={best.objective:.12g} "
              f"{best.time_s * 1e3:9.1f} ms (set-up {setup:.2f} s)", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=CASES, help="family:N, e.g. zambezi12:24")
    ap.add_argument("--configs", nargs="*", default=["sqp-ip", "ipm", "ipopt"], help="olado presets (configs/NAME.ini)")
    ap.add_argument("--peers", nargs="*", default=list(PEERS), choices=list(PEERS))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rtol", type=float, default=1e-6, help="objectives must agree to this (relative)")
    ap.add_argument("--setup-limit", type=float, default=600.0,
                    help="a peer whose set-up takes (or is estimated from smaller N to take) longer is skipped (s)")
    ap.add_argument("--peer-max-N", nargs="*", default=[], metavar="PEER=N",
                    help="skip a peer above this N, e.g. casadi-fatrop=1200")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    max_N = {k: int(v) for k, v in (item.split("=") for item in args.peer_max_N)}
    unknown = set(max_N) - set(PEERS)
    if unknown:
        ap.error(f"--peer-max-N: unknown peer(s) {', '.join(sorted(unknown))}; choose from {', '.join(PEERS)}")
    table, measured = [], {}
    for case in args.cases:
        family, N = case.split(":")
        N = int(N)
        print(f"{family} N = {N}", flush=True)
        reps = args.repeats if N <= 1200 else max(1, min(args.repeats, 2))
        olado_rows = _olado_rows(args.configs, family, N, reps)
        peer_rows = _peer_rows(args.peers, family, N, reps, args.setup_limit, measured, max_N)
        table.append((family, N, olado_rows, peer_rows))
    if not args.no_write:
        write_section(SECTION, _section(args, table))


def _section(args, table):
    lines = [f"## {SECTION}", "",
             f"Command: `{' '.join(['python benchmarks/bench_peers.py'] + sys.argv[1:])}`  ",
             f"Commit: {commit()}  ", f"Date: {datetime.date.today().isoformat()}  ", f"Machine: {machine()}", "",
             "Balance start. olado: the presets named, best of the repeats after a warm-up (times from the "
             "result, `time_s`). Peers: Zambezi written once (ZambeziAD: the same data and start) as a stage-ordered "
             "multiple-shooting NLP in CasADi SX (benchmarks/_peers.py), exact Hessians, tolerance 1e-8; best of the "
             "repeats after a warm-up solve; set-up (graph, derivatives, structure detection) apart. "
             f"Ratio: olado's best preset over the faster peer. Objectives agree to {args.rtol:g} where marked ok.", "",
             "| case | solver | status | iterations (SQP / QP) | objective | time (ms) | ms / iteration | peer set-up (s) "
             "| agrees |",
             "|:--|:--|:--|--:|--:|--:|--:|--:|:--|"]
    summary = ["", "| case | olado best (ms) | faster peer (ms) | ratio |", "|:--|--:|--:|--:|"]
    for family, N, olado_rows, peer_rows in table:
        peers_ok = [r for r in peer_rows if r.success]
        ref = min(peers_ok, key=lambda r: r.time_s).objective if peers_ok else None
        for r in olado_rows + peer_rows:
            agrees = "-" if ref is None or not r.success else \
                ("ok" if abs(r.objective - ref) <= args.rtol * max(1.0, abs(ref)) else f"{r.objective - ref:+.1e}")
            setup = "" if r.solver not in PEERS else ("-" if r.setup_s != r.setup_s else
                                                       f"~{r.setup_s:.0f} (estimate)" if r.estimated else f"{r.setup_s:.2f}")
            tms = f"{r.time_s * 1e3:.1f}" if r.time_s == r.time_s else "-"
            obj = f"{r.objective:.10g}" if r.objective == r.objective else "-"
            lines.append(f"| {family} N = {N} | {r.solver} | {r.status} | {r.iterations} | {obj} | {tms} "
                         f"| {r.ms_per_iteration()} | {setup} | {agrees} |")
        ol = [r for r in olado_rows if r.success]
        if ol and peers_ok:
            a, b = min(ol, key=lambda r: r.time_s), min(peers_ok, key=lambda r: r.time_s)
            summary.append(f"| {family} N = {N} | {a.time_s * 1e3:.1f} ({a.solver}) | {b.time_s * 1e3:.1f} ({b.solver}) "
                           f"| {a.time_s / b.time_s:.2f} |")
    return "\n".join(lines + summary + [""])


if __name__ == "__main__":
    main()
