"""Certificate fingerprint: every field of olado's certificate (float.hex, time_s dropped) on the
built-in problems and zambezi12 N = 24 with ipm and sqp-ip -- the solve's own certificate, certify
with the solver's multipliers, with none (least squares), and at a perturbed point (rejected) --
to compare two trees bit for bit (the evaluation counters must be left as they were).

    PYTHONPATH=<tree> python benchmarks/bench_cert_fingerprint.py OUT.json    # then: cmp OLD.json NEW.json
"""
import dataclasses
import json
import sys

import numpy as np
import olado
from olado.config import load_config, make_solver
from olado.problems.testproblems import PROBLEMS as TEST_PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.solvers.certificate import certify, CertificateSettings
out = {}
def fields(c):
    d = dataclasses.asdict(c); d.pop("time_s")
    return {k: (float(v).hex() if isinstance(v, float) else v) for k, v in d.items()}
probs = dict(TEST_PROBLEMS)
probs["zambezi12_24"] = lambda: zambezi_problem("zambezi12", N=24, start="balance")
for cfg in ("ipm", "sqp-ip"):
    s = make_solver(load_config(f"configs/{cfg}.ini"))
    st = CertificateSettings.from_options(s.options)
    for name, fac in probs.items():
        p = fac()
        try:
            r = s.solve(p)
        except Exception as e:
            out[f"{cfg}|{name}"] = repr(e); continue
        key = f"{cfg}|{name}"
        out[key + "|status"] = [str(r.status), r.iterations, float(r.objective).hex(), r.message]
        if r.certificate is not None:
            out[key + "|own"] = fields(r.certificate)
        X, U = np.asarray(r.x, float), np.asarray(r.u, float)
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(U))):
            continue
        c0 = dict(p.counters)
        out[key + "|solver"] = fields(certify(p, X, U, r.multipliers, st))
        out[key + "|lsq"] = fields(certify(p, X, U, None, st))
        rng = np.random.default_rng(1)
        out[key + "|pert"] = fields(certify(p, X + 1e-3 * rng.standard_normal(X.shape), U, r.multipliers, st))
        assert dict(p.counters) == c0
print(olado.__file__, file=sys.stderr)
json.dump(out, open(sys.argv[1], "w"), indent=0, sort_keys=True)
