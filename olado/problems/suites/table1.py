"""Table 1 of paper 001 as a suite: zambezi12 at N = 12, 24, ..., 252 from the balance start
(46)-(47) (the paper's counts and times: benchmarks/bench_table1.py, ``PAPER``)."""

from __future__ import annotations

HORIZONS = range(12, 253, 12)

ENTRIES = [
    {"name": "zambezi12", "problem": "zambezi12", "settings": {"N": N, "start": "balance"},
     "source": "Błaszczyk, Karbowski, Malinowski (paper 001), Table 1", "group": "table1"}
    for N in HORIZONS
]
