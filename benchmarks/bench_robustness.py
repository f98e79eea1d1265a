"""The robustness set (issue 13 item 7) for every SQP preset, IPOPT and the penalty methods:
each solve in an isolated worker process with a time limit (a hang or a crash is a recorded
failure), classified against the stored IPOPT reference of its entry
(olado/problems/suites/robustness_refs.json, benchmarks/make_robustness_refs.py):

    solved              converged at IPOPT's objective (relative 1e-6) at a verified feasible point
    other-local-min     converged at a verified feasible point with another objective (its
                        verified KKT residual and objective difference are listed)
    solved-unreferenced converged at a verified feasible point where IPOPT did not
    failed              iteration/time limit, numerical error, exception, crash, timeout
    false-success       reported success at an infeasible point (verified violation > 1e-6),
                        or on a deliberately infeasible problem
    infeasible-correct  reported infeasible on a deliberately infeasible problem
    infeasible-wrong    reported infeasible on a feasible problem

"Verified": the violation and KKT residual of the returned point computed independently of
the solver (olado.problems.suites.verify_point).

    python benchmarks/bench_robustness.py --jobs 1                 # everything (long)
    python benchmarks/bench_robustness.py --configs sqp-ip ipopt --groups built-in cops
    python benchmarks/bench_robustness.py --table-only             # rewrite RESULTS.md from the stored runs

Runs accumulate in benchmarks/robustness_results.json (one record per entry and preset, with
its commit and date; ``--fresh`` starts it over); the RESULTS.md section is written from the
records of the chosen presets and entries.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import signal
import statistics
import sys
from collections import Counter

from _common import HERE, machine, write_section
from _robustness import CLASSES, CONFIGS, OTHER, IsolatedPool, classify, olado_commit

from olado.problems.suites import load_references, load_suite
from olado.result import atomic_write_bytes

SECTION = "Robustness set (issue 13 item 7): SQP presets, IPOPT and the penalty methods"
STORE = HERE / "robustness_results.json"
ORDER = ["solved", "other-local-min", "solved-unreferenced", "failed", "false-success",
         "infeasible-correct", "infeasible-wrong"]


def default_configs():
    sqp = sorted(p.stem for p in CONFIGS.glob("sqp-*.ini"))
    return sqp + ["ipopt", "penalty", "penalty-al"]


def _load_store(fresh):
    if fresh or not STORE.exists():
        return {}
    return json.loads(STORE.read_text(encoding="utf-8"))


def _save_store(store):
    atomic_write_bytes(STORE, (json.dumps(store, indent=0, sort_keys=True) + "\n").encode("utf-8"))


def _key(entry, config):
    return f"{config}|{entry}"


def summarize(entries, configs, store, refs):
    """Per config: class counts, per-group solved counts, other minima and failures."""
    rows = {}
    for c in configs:
        counts, groups, others, fails, times = Counter(), Counter(), [], [], []
        for e in entries:
            rec = store.get(_key(e.name, c))
            if rec is None:
                counts["not run"] += 1
                continue
            cls = classify(rec, refs.get(e.name), e.feasible)
            counts[cls] += 1
            if cls in ("solved", "infeasible-correct"):
                groups[e.group] += 1
            if isinstance(rec.get("time_s"), (int, float)):
                times.append(rec["time_s"])
            if cls == OTHER:
                ref = refs[e.name]["objective"]
                others.append((e.name, (rec["objective"] - ref) / max(abs(ref), 1e-3), rec.get("verified_kkt")))
            elif cls not in ("solved", "infeasible-correct", "solved-unreferenced"):
                fails.append((e.name, cls, rec.get("status")))
        rows[c] = dict(counts=counts, groups=groups, others=others, fails=fails,
                       median_time=statistics.median(times) if times else math.nan)
    return rows


def table(entries, configs, store, refs, args):
    rows = summarize(entries, configs, store, refs)
    n_feas = sum(e.feasible for e in entries)
    group_names = list(dict.fromkeys(e.group for e in entries))
    group_size = Counter(e.group for e in entries)
    recs = [store[_key(e.name, c)] for c in configs for e in entries if _key(e.name, c) in store]
    commits = sorted({r.get("olado_commit", "?") for r in recs})
    dates = sorted({r.get("date", "?") for r in recs})
    ref_meta = load_references("robustness")["meta"]
    lines = [f"## {SECTION}", "",
             f"Command: `python benchmarks/bench_robustness.py {args}`  ",
             f"Date: {', '.join(dates)}; olado commit: {', '.join(commits)}  ",
             f"Machine: {machine()}", "",
             f"{len(entries)} entries of the robustness set (docs/robustness-set.md): {n_feas} feasible, "
             f"{len(entries) - n_feas} deliberately infeasible. Reference: IPOPT (`configs/ipopt.ini`) from each "
             f"entry's start, stored in olado/problems/suites/robustness_refs.json (olado {ref_meta['olado_commit']}, "
             f"{ref_meta['date']}). Every solve ran in an isolated worker process with the preset's `max_time` set to "
             f"the time limit ({store.get('_meta', {}).get('time_limit', '?')} s) and a hard kill 15 s later; "
             "\"verified\" = violation and KKT residual of the returned point computed independently of the solver "
             "(olado.problems.suites.verify_point). Classes:", ""]
    lines += [f"- **{k}**: {v}" for k, v in CLASSES.items() if k in ORDER]
    lines += ["", "| config | " + " | ".join(ORDER) + " | median time (s) |",
              "|:--|" + "---:|" * (len(ORDER) + 1)]
    for c in configs:
        r = rows[c]
        cells = [str(r["counts"].get(k, 0)) for k in ORDER]
        if r["counts"].get("not run"):
            cells[0] += f" ({r['counts']['not run']} not run)"
        lines.append(f"| {c} | " + " | ".join(cells) + f" | {r['median_time']:.2f} |")
    lines += ["", "Solved (or correctly infeasible) per group of entries:", "",
              "| config | " + " | ".join(f"{g} ({group_size[g]})" for g in group_names) + " |",
              "|:--|" + "---:|" * len(group_names)]
    for c in configs:
        lines.append(f"| {c} | " + " | ".join(str(rows[c]["groups"].get(g, 0)) for g in group_names) + " |")
    lines += ["", "Other local minima (entry: relative objective difference to IPOPT, verified KKT residual):", ""]
    any_other = False
    for c in configs:
        if rows[c]["others"]:
            any_other = True
            shown = "; ".join(f"{n} {d:+.1e}, kkt {k:.1e}" if k is not None else f"{n} {d:+.1e}"
                              for n, d, k in rows[c]["others"])
            lines.append(f"- {c}: {shown}")
    if not any_other:
        lines.append("- none")
    lines += certificate_lines(entries, configs, store)
    lines += ["", "Failures (entry: class / status):", ""]
    for c in configs:
        if rows[c]["fails"]:
            by = {}
            for n, cls, st in rows[c]["fails"]:
                by.setdefault(f"{cls} ({st})", []).append(n)
            parts = [f"{k}: {len(v)} ({', '.join(v[:8])}{', ...' if len(v) > 8 else ''})"
                     for k, v in sorted(by.items(), key=lambda kv: -len(kv[1]))]
            lines.append(f"- {c}: " + "; ".join(parts))
    return "\n".join(lines) + "\n"


def certificate_lines(entries, configs, store):
    """Issue 18's check on the robustness set: every success's certificate, and olado's
    independent certificate of the returned point (least-squares multipliers, nothing from the
    solver but the point) against the tolerance of the reported status."""
    lines = ["", "Certificates of the successes (status success or acceptable): the level of the certificate the "
             "result carries, and the successes whose *independently* recomputed scaled KKT residual "
             "(`certify(problem, X, U, None)`) or violation exceeds the tolerance of their status (1e-6 or the "
             "preset's tol, and constr_viol_tol; acceptable: 1e-4, 1e-6); UNCERTIFIED counts the solver "
             "successes the certificate turned down:", "",
             "| config | successes | certificate success | acceptable | uncertified | independent check fails |",
             "|:--|---:|---:|---:|---:|---:|"]
    bad = []
    for c in configs:
        recs = [store.get(_key(e.name, c)) for e in entries]
        recs = [r for r in recs if r is not None]
        succ = [r for r in recs if r.get("status") in ("success", "acceptable")]
        levels = Counter(r.get("certificate", "none") for r in succ)
        fails = [r for r in succ if r.get("independent_holds") is False]
        bad += [(c, r) for r in fails]
        lines.append(f"| {c} | {len(succ)} | {levels.get('success', 0)} | {levels.get('acceptable', 0)} | "
                     f"{sum(r.get('status') == 'uncertified' for r in recs)} | {len(fails)} |")
    for c, r in bad:
        lines.append(f"- {c} {r['entry']}: {r['status']}, independent scaled KKT {r.get('independent_kkt', math.nan):.1e}, "
                     f"violation {r.get('independent_violation', math.nan):.1e}")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="+", default=None, help="presets in configs/ (default: every sqp-*.ini, "
                    "ipopt, penalty, penalty-al)")
    ap.add_argument("--groups", nargs="+", default=None, help="only entries of these groups "
                    "(built-in, cops, literature, infeasible, zambezi)")
    ap.add_argument("--entries", nargs="+", default=None, help="only these entries")
    ap.add_argument("--time-limit", type=float, default=60.0, help="seconds per solve (default 60)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (the machine is shared: default 1)")
    ap.add_argument("--fresh", action="store_true", help="forget the stored runs")
    ap.add_argument("--rerun", action="store_true", help="solve again entries that have a stored run")
    ap.add_argument("--table-only", action="store_true", help="no solves: write the table from the stored runs")
    ap.add_argument("--no-write", action="store_true", help="do not touch RESULTS.md")
    args = ap.parse_args(argv)
    # a SIGTERM unwinds like Ctrl-C, so that the pool's clean-up stops its workers
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    configs = args.configs or default_configs()
    missing = [c for c in configs if not (CONFIGS / f"{c}.ini").exists()]
    if missing:
        raise SystemExit(f"no such presets in configs/: {', '.join(missing)}")
    entries = [e for e in load_suite("robustness")
               if (not args.groups or e.group in args.groups) and (not args.entries or e.name in args.entries)]
    refs = load_references("robustness")["entries"]
    store = _load_store(args.fresh)
    if not args.table_only:
        commit, date = olado_commit(), datetime.date.today().isoformat()
        tasks = [(e.name, c) for c in configs for e in entries if args.rerun or _key(e.name, c) not in store]
        print(f"{len(tasks)} solves ({len(entries)} entries x {len(configs)} presets, stored ones skipped)", flush=True)
        store.setdefault("_meta", {})["time_limit"] = args.time_limit
        feasible = {e.name: e.feasible for e in entries}
        for i, rec in enumerate(IsolatedPool(jobs=args.jobs, time_limit=args.time_limit).run(tasks), 1):
            rec.update(olado_commit=commit, date=date)
            if rec.get("status") != "exception":
                rec.pop("traceback", None)
            store[_key(rec["entry"], rec["config"])] = rec
            cls = classify(rec, refs.get(rec["entry"]), feasible[rec["entry"]])
            obj = rec.get("objective")
            print(f"[{i}/{len(tasks)}] {rec['config']:18s} {rec['entry']:26s} {cls:20s} {rec.get('status')!s:16s} "
                  f"J={obj if obj is None else f'{obj:.10g}'} t={rec.get('wall_s', 0):.2f}s", flush=True)
            if i % 20 == 0:
                _save_store(store)
        _save_store(store)
    shown = [a for a in (argv if argv is not None else sys.argv[1:]) if a not in ("--table-only", "--no-write")]
    text = table(entries, configs, store, refs, " ".join(shown))
    print(text)
    if not args.no_write:
        write_section(SECTION, text)
        print(f"wrote section {SECTION!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
