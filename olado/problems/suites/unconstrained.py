"""The unconstrained set of issue 4 (benchmarks/bench_unconstrained.py): van der Pol, Rayleigh
and the CSTR at N = 1 000 and N = 100 000, the LQ problem at N = 1 000 only (its open-loop
unstable mode, eigenvalue 1.1, overflows the simulated states of any control away from the
optimum at N = 100 000), each from the problem's own initial guess."""

from __future__ import annotations

#: problem -> horizons
HORIZONS = {"vanderpol": (1000, 100000), "rayleigh": (1000, 100000), "cstr": (1000, 100000), "lq": (1000,)}

ENTRIES = [
    {"name": name, "problem": name, "settings": {"N": N}, "source": "olado test problems (issue 4)",
     "group": "unconstrained"}
    for name, horizons in HORIZONS.items() for N in horizons
]
