"""Seed 000's aerospace benchmarks (issue 15 item 4; docs/aerospace-worhp.md): the time-optimal
low-thrust transfer to GEO and the hypersonic emergency landing, at the seed's sizes and by RK4,
olado's result next to what the seed reports (sizes and CPU times only: no optimal values).

``ENTRIES`` are :class:`bench_aerospace.Entry` rows, run by bench_aerospace's table (every
preset of ``CONFIGS``); this script keeps seed 000's entries and its RESULTS.md section apart.

    python benchmarks/bench_worhp.py                       # prints the table
    python benchmarks/bench_worhp.py --entries low-thrust-geo --configs ipopt
    python benchmarks/bench_worhp.py --write               # and writes the RESULTS.md section

The machine is shared: the times are orders of magnitude; compare iterations and values.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from bench_aerospace import Entry, table_main  # noqa: E402

from olado.problems import worhp  # noqa: E402

SECTION = "Seed 000's aerospace benchmarks: low-thrust transfer to GEO, hypersonic emergency landing"


def _geo_readout(problem, result):
    return {"t_f (TU)": problem.solution(result).tf}


def _landing_readout(problem, result):
    """t_f in s, the seed's F, and the great-circle distance from the separation point in km."""
    sol = problem.solution(result)
    la0, th0 = worhp.LANDING_X0[4], worhp.LANDING_X0[5]
    la, th = sol.x[-1, 4], sol.x[-1, 5]
    hav = np.sin((la - la0) / 2) ** 2 + np.cos(la0) * np.cos(la) * np.sin((th - th0) / 2) ** 2
    dist = 2 * worhp.LANDING["r0"] * np.arcsin(np.sqrt(hav)) / 1e3
    return {"F": -result.objective, "t_f (s)": sol.tf * worhp.LANDING_TIME_UNIT, "distance (km)": dist}


def _seed_times(name, n):
    t = worhp.SEED_000[name]["times"][n]
    table = {"low-thrust-geo": 4, "hypersonic-landing": 7}[name]
    return f"no optimal value; n = {n}: WORHP {t['WORHP']} s, IPOPT {t['IPOPT']}" + (
        " s" if isinstance(t["IPOPT"], float) else "") + f" (Table {table})"


_GEO = "none at hand (the seed's source: Kluever 1995)"
_LANDING = "none at hand (the seed's sources: Mayrhofer and Sachs 1996; Buskens and Gerdts 2003)"
ENTRIES = [
    Entry("low-thrust-geo", lambda: worhp.low_thrust_geo(N=100), _geo_readout,
          seed=_seed_times("low-thrust-geo", 101), published=_GEO),
    Entry("low-thrust-geo-n1001", lambda: worhp.low_thrust_geo(N=1000), _geo_readout,
          seed=_seed_times("low-thrust-geo", 1001), published=_GEO),
    Entry("low-thrust-geo-rk4", lambda: worhp.low_thrust_geo(N=400, method="rk4"), _geo_readout,
          seed="-", published=_GEO),
    Entry("hypersonic-landing", lambda: worhp.hypersonic_landing(N=200), _landing_readout,
          seed=_seed_times("hypersonic-landing", 201), published=_LANDING),
    Entry("hypersonic-landing-n2001", lambda: worhp.hypersonic_landing(N=2000), _landing_readout,
          seed=_seed_times("hypersonic-landing", 2001), published=_LANDING),
    Entry("hypersonic-landing-rk4", lambda: worhp.hypersonic_landing(N=400, method="rk4"), _landing_readout,
          seed="-", published=_LANDING),
]


def main(argv=None):
    return table_main(argv, entries=ENTRIES, section=SECTION, script="bench_worhp.py", preamble=(
        "'intervals' is N (the seed's n points: N + 1). Objectives are minimized (the landing's is -F). "
        "The seed reports CPU times only (on an Intel Core2 Quad Q6600), quoted for the same n; "
        "formulations, data and what differs from the seed: docs/aerospace-worhp.md."))


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
