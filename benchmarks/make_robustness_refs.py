"""IPOPT references of the robustness suite (issue 13 item 7): every entry of
olado/problems/suites/robustness.py solved by configs/ipopt.ini from the entry's start, each in
an isolated worker process with a time limit; stored in
olado/problems/suites/robustness_refs.json (package data) with the olado commit, date and
machine, and the table of docs/robustness-set.md rewritten from it.

    python benchmarks/make_robustness_refs.py                     # all entries (about 5 min)
    python benchmarks/make_robustness_refs.py --entries goddard dubins   # update these only
    python benchmarks/make_robustness_refs.py --docs-only         # rewrite the docs table

Stored per entry: IPOPT's status, message, objective, its own max violation and KKT residual,
iterations and time, the independently verified violation and KKT residual
(olado.problems.suites.verify_point), the published continuous-time value and the relative
difference (J_ipopt - J_published) / |J_published| (they differ by the discretization).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import re
import sys

from _common import HERE, machine
from _robustness import IsolatedPool, olado_commit

from olado.problems.nlp import nlp_counts
from olado.problems.suites import load_suite, references_path
from olado.result import atomic_write_bytes

DOCS = HERE.parent / "docs" / "robustness-set.md"
TABLE = re.compile(r"<!-- table -->\n.*?<!-- /table -->\n", re.S)
KEYS = ("status", "message", "objective", "violation", "kkt", "iterations", "time_s",
        "verified_violation", "verified_kkt", "verified_kkt_scaled")


def _finite(x):
    return x if isinstance(x, (int, float)) and math.isfinite(x) else None


def reference_record(entry, answer, commit, date):
    rec = {k: answer.get(k) for k in KEYS if k in answer}
    rec["olado_commit"], rec["date"] = commit, date
    for k in ("objective", "violation", "kkt", "verified_violation", "verified_kkt", "verified_kkt_scaled"):
        if k in rec:
            rec[k] = _finite(rec[k])
    rec["published"] = entry.published
    rec["feasible"] = entry.feasible
    obj = rec.get("objective")
    rec["published_rel_diff"] = (None if entry.published is None or obj is None
                                 else (obj - entry.published) / abs(entry.published))
    return rec


def discretization(problem) -> str:
    """How the entry's problem is discretized, in words."""
    text = getattr(problem, "discretization", None)
    if text:
        return text
    if hasattr(problem, "method") and hasattr(problem, "h"):
        scheme = "RK4" if problem.method == "rk4" else "explicit Euler"
        return f"{scheme}, {problem.N} steps of length h = {problem.h:g} on [0, {problem.T:g}]"
    if hasattr(problem, "family"):
        return f"monthly stages from January {problem.start_year} (discrete-time model)"
    return "discrete-time model"


def _fmt(x, digits=8):
    return "-" if x is None else f"{x:.{digits}g}"


def docs_table(entries, refs) -> str:
    lines = ["| entry | source | discretization | n, m, N | variables / eq. / ineq. | published | IPOPT | rel. diff |",
             "|:--|:--|:--|:--|:--|--:|:--|--:|"]
    for e in entries:
        if e.start == "perturbed":
            continue                      # the perturbed starts share their base entry's row
        p = e.make_problem()
        c = nlp_counts(p)
        ref = refs.get(e.name, {})
        ipopt = f"{_fmt(ref.get('objective'), 9)} ({ref.get('status', 'not run')})"
        pub = _fmt(e.published, 10) if e.published is not None else e.published_note
        rel = ref.get("published_rel_diff")
        cells = [e.name, e.source, discretization(p), f"{p.n}, {p.m}, {p.N}",
                 f"{c['variables']} / {c['equalities']} / {c['inequalities']}", pub, ipopt,
                 "-" if rel is None else f"{rel:+.2e}"]
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    perturbed = [e for e in entries if e.start == "perturbed"]
    if perturbed:
        lines += ["", "Perturbed Zambezi starts (IPOPT objective, status):", ""]
        by_base = {}
        for e in perturbed:
            by_base.setdefault(e.name.rsplit("-p", 1)[0], []).append(e)
        for base, group in by_base.items():
            vals = ", ".join(f"p{e.seed}: {_fmt(refs.get(e.name, {}).get('objective'), 9)} "
                             f"({refs.get(e.name, {}).get('status', 'not run')})" for e in group)
            lines.append(f"- {base}: {vals}")
    return "\n".join(lines) + "\n"


def write_docs(entries, data):
    meta = data["meta"]
    head = (f"IPOPT: `configs/ipopt.ini` at olado {meta['olado_commit']}, {meta['date']}, {meta['machine']}; "
            f"command `{meta['command']}`.\n\n")
    block = "<!-- table -->\n" + head + docs_table(entries, data["entries"]) + "<!-- /table -->\n"
    text = DOCS.read_text(encoding="utf-8")
    if not TABLE.search(text):
        raise SystemExit(f"{DOCS} has no <!-- table --> ... <!-- /table --> block")
    atomic_write_bytes(DOCS, TABLE.sub(lambda m: block, text).encode("utf-8"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entries", nargs="*", help="only these entries (the others keep their stored reference)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (the machine is shared: default 1)")
    ap.add_argument("--time-limit", type=float, default=300.0, help="seconds per solve")
    ap.add_argument("--docs-only", action="store_true", help="only rewrite docs/robustness-set.md")
    args = ap.parse_args(argv)
    entries = load_suite("robustness")
    path = references_path("robustness")
    old = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {"meta": {}, "entries": {}}
    if args.docs_only:
        write_docs(entries, old)
        return 0
    chosen = [e for e in entries if not args.entries or e.name in args.entries]
    unknown = set(args.entries or ()) - {e.name for e in entries}
    if unknown:
        raise SystemExit(f"unknown entries: {', '.join(sorted(unknown))}")
    by_name = {e.name: e for e in entries}
    refs = dict(old.get("entries", {}))
    pool = IsolatedPool(jobs=args.jobs, time_limit=args.time_limit)
    commit, date = olado_commit(), datetime.date.today().isoformat()
    for answer in pool.run([(e.name, "ipopt") for e in chosen]):
        e = by_name[answer["entry"]]
        refs[e.name] = reference_record(e, answer, commit, date)
        r = refs[e.name]
        print(f"{e.name:28s} {r.get('status', '?'):16s} J={_fmt(r.get('objective'), 10):>16s} "
              f"viol={_fmt(r.get('verified_violation'), 2)} kkt={_fmt(r.get('verified_kkt'), 2)} "
              f"it={r.get('iterations', '-')} t={_fmt(r.get('time_s'), 3)}s", flush=True)
    data = {"meta": {"suite": "robustness", "config": "configs/ipopt.ini", "olado_commit": commit,
                     "date": date, "machine": machine(),
                     "time_limit_s": args.time_limit,
                     "command": "python benchmarks/make_robustness_refs.py" + (
                         " --entries " + " ".join(args.entries) if args.entries else "")},
            "entries": {e.name: refs[e.name] for e in entries if e.name in refs}}
    atomic_write_bytes(path, (json.dumps(data, indent=1, sort_keys=False) + "\n").encode("utf-8"))
    print(f"wrote {path}")
    write_docs(entries, data)
    print(f"wrote the table of {DOCS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
