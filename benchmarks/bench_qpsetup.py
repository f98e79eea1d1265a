"""Per-solve and per-QP process time of an SQP preset on Zambezi, for comparing two source trees
(the interior-point QP's fixed cost per QP: preparation, starting point, result).

    python benchmarks/bench_qpsetup.py --trees OLD NEW --cases zambezi12:24 zambezi12:120 zambezi:1200

Each tree runs in its own process (PYTHONPATH=tree), alternately, ``--rounds`` times; a run
warms up (compilation), then times ``--solves`` solves (time.process_time) and reports the best
per-solve time, the QP solver's time per QP and per QP iteration (the time inside
InteriorPointQP.solve, least over the solves) and the least time outside it (solve minus QP).
The figures are the best over the rounds. ``--parts``: the QP's fixed cost per QP instead
(preparation, cold and warm start, result, and whole cold and warm QPs, us per call).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

_CHILD = r"""
import json, sys, time
from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.qp.interior_point.solver import InteriorPointQP
name, N, cfg, solves = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
acc = {"t": 0.0, "n": 0, "it": 0}
orig = InteriorPointQP.solve
def timed(self, qp, warm_start=None, limits=None):
    t = time.process_time()
    r = orig(self, qp, warm_start, limits)
    acc["t"] += time.process_time() - t; acc["n"] += 1; acc["it"] += r.iterations
    return r
InteriorPointQP.solve = timed
solver = make_solver(load_config(cfg))
solver.solve(zambezi_problem(name, N=N, start="balance"))
runs = []
for _ in range(solves):
    acc.update(t=0.0, n=0, it=0)
    p = zambezi_problem(name, N=N, start="balance")
    t = time.process_time()
    r = solver.solve(p)
    t = time.process_time() - t
    runs.append((t, acc["t"], acc["n"], acc["it"], r.iterations, float(r.objective), str(r.status)))
# the best solve, and separately the least QP time and the least time outside the QP of any solve
best = list(min(runs))
best[1] = min(r[1] for r in runs)
best.append(min(r[0] - r[1] for r in runs))
print(json.dumps(best))
"""

# the QP's fixed cost per QP (--parts): preparation, starts and result of the second QP of a
# solve, each the best of 15 x 200 calls (process time); before the refill (a tree without
# InteriorPointQP._prepare) the preparation is _Prepared(qp)
_PARTS = r"""
import json, sys, time, timeit
from olado.config import load_config, make_solver
from olado.problems.zambezi import zambezi_problem
from olado.qp.interior_point import solver as S
from olado.qp.interior_point.presolve import _Prepared
from olado.qp.interior_point.start import initial_point, warm_point
name, N, cfg = sys.argv[1], int(sys.argv[2]), sys.argv[3]
qps = []
orig = S.InteriorPointQP._solve
def spy(self, qp, warm, *a, **k):
    qps.append((self, qp, warm)); return orig(self, qp, warm, *a, **k)
S.InteriorPointQP._solve = spy
make_solver(load_config(cfg)).solve(zambezi_problem(name, N=N, start="balance"))
S.InteriorPointQP._solve = orig
self, qp, _ = qps[1]
ws = [w for _, _, w in qps if w is not None][0]
def t(f, n=200):
    return min(timeit.Timer(f, timer=time.process_time).repeat(number=n, repeat=15)) / n * 1e6
prep = (lambda: self._prepare(qp)) if hasattr(self, "_prepare") else (lambda: _Prepared(qp))
P = prep()
out = {"preparation": t(prep), "cold start": t(lambda: initial_point(P, self.options)),
       "warm start": t(lambda: warm_point(P, self.options, ws))}
it = initial_point(P, self.options)
out["result"] = t(lambda: self._finish(P, it, S.Status.SUCCESS, "", 3, [], 0.0))
out["cold QP (%d it)" % self.solve(qp).iterations] = t(lambda: self.solve(qp), 20)
out["warm QP (%d it)" % self.solve(qp, warm_start=ws).iterations] = t(lambda: self.solve(qp, warm_start=ws), 20)
print(json.dumps(out))
"""


def run(tree, case, cfg, solves):
    name, N = case.split(":")
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", _CHILD, name, N, cfg, str(solves)], env=env, capture_output=True,
                         text=True, check=True, cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])


def parts(tree, case, cfg):
    name, N = case.split(":")
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", _PARTS, name, N, cfg], env=env, capture_output=True, text=True,
                         check=True, cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trees", nargs="+", required=True)
    ap.add_argument("--cases", nargs="+", default=["zambezi12:24", "zambezi12:120", "zambezi:1200"])
    ap.add_argument("--config", default="configs/sqp-ip.ini")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--solves", type=int, default=10)
    ap.add_argument("--parts", action="store_true", help="the QP's fixed cost per QP instead (us per call)")
    a = ap.parse_args()
    if a.parts:
        for case in a.cases:
            best = {}
            for _ in range(a.rounds):
                for tree in a.trees:
                    r = parts(tree, case, a.config)
                    best[tree] = {k: min(v, best.get(tree, {}).get(k, v)) for k, v in r.items()}
            for tree in a.trees:
                print(f"{case:16s} {tree:28s} " + "  ".join(f"{k} {v:.1f} us" for k, v in best[tree].items()),
                      flush=True)
        return
    for case in a.cases:
        best = {}
        for _ in range(a.rounds):
            for tree in a.trees:
                r = run(tree, case, a.config, a.solves)
                old = best.get(tree)
                best[tree] = r if old is None else [min(r[0], old[0]), min(r[1], old[1])] + r[2:7] + [min(r[7], old[7])]
        for tree in a.trees:
            t, tqp, nqp, qit, it, obj, status, rest = best[tree]
            print(f"{case:16s} {tree:28s} solve {1e3 * t:9.3f} ms  QP {1e3 * tqp / nqp:8.3f} ms/QP "
                  f"{1e3 * tqp / max(qit, 1):7.4f} ms/QP-it  outside the QP {1e3 * rest:8.3f} ms  ({nqp} QPs, {qit} "
                  f"QP it, {it} SQP it, {status}, objective {obj:.12g})", flush=True)


if __name__ == "__main__":
    main()
