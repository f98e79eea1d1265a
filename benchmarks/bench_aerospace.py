"""The seeds' aerospace benchmark problems (issue 15 item 4; docs/aerospace.md): olado's result
next to the value the seed reports and the published one.

Each entry of ``ENTRIES`` builds one problem and reads its result in the problem's own terms
(crossrange, final time, radius, range); every entry is solved by every preset of ``CONFIGS``
(configs/<name>.ini). To add a problem, append an :class:`Entry`; to add a column, a
``(heading, function(entry, problem, result) -> str)`` pair to ``COLUMNS``; to add a solver or a
scaled variant, a preset name to ``CONFIGS`` (or ``--configs``). A config name ``preset+word``
is the preset with an override each ``+``: ``sqp-ip+auto`` is configs/sqp-ip.ini with
``scaling=auto`` (a bare word is a scaling method, docs/scaling.md), ``ipopt+tol=1e-10`` any
option of the preset's solver (:func:`config_of`).

    python benchmarks/bench_aerospace.py                       # prints the table
    python benchmarks/bench_aerospace.py --entries shuttle-entry --configs ipopt
    python benchmarks/bench_aerospace.py --entries shuttle-entry-raw --configs sqp-ip sqp-ip+auto ipopt ipopt+auto
    python benchmarks/bench_aerospace.py --write               # and writes the RESULTS.md section

The machine is shared: the times are orders of magnitude; compare iterations and values.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from _common import commit, machine, write_section  # noqa: E402

import olado  # noqa: E402
from olado.problems import PROBLEMS  # noqa: E402

SECTION = "Aerospace benchmark problems of the seeds (issue 15 item 4)"
CONFIGS = ["sqp-ip", "ipopt"]


@dataclass
class Entry:
    """One row group: ``build()`` makes the problem, ``readout(problem, result)`` gives its
    quantities {label: value} (objective aside), ``seed`` what the seed reports (with where),
    ``published`` the literature's value (with where)."""

    name: str
    build: Callable
    readout: Callable
    seed: str
    published: str


def _final_state(names):
    """Readout of a ContinuousDOCP: the named components of the last state (T is the last one
    with a free final time)."""
    def read(problem, result):
        return {label: float(result.x[-1, idx]) for label, idx in names.items()}
    return read


def _shuttle_readout(problem, result, scaled=True):
    from olado.problems.aerospace import entry_result

    e = entry_result(problem, result, scaled=scaled)
    return {"crossrange (deg)": e.crossrange_deg, "t_f (s)": e.tf_s, "max q (BTU/ft^2/s)": e.max_heat_rate}


def _raw_shuttle(heating, heat_limit="linear"):
    """The shuttle in Betts's raw units (ft, ft/s, s: badly scaled on purpose, seed 004's subject)."""
    from olado.problems.aerospace import shuttle_entry

    return shuttle_entry(N=50, heating=heating, scaled=False, heat_limit=heat_limit)


#: the shuttle's reported values: seed 004's and Betts's (docs/aerospace.md)
_SEED_NO_HEAT = "not solved without the heat limit (seed 004 Table 1 has the heat-limited case only)"
_SEED_HEAT = "J = -30.6385 deg (seed 004 Table 1 'SS', 50 Radau nodes, SNOPT and IPOPT)"
_SEED_RAW = "no valid solution without scaling (seed 004 Table 1 'SS', NONE and AUTO rows)"
_BETTS = "crossrange 34.1412 deg, t_f = 2008.59 s (Betts 2010 ex. 6.1)"
_BETTS_HEAT = "crossrange 30.6255 deg, t_f = 2198.67 s (Betts 2010 ex. 6.1, heat-limited)"
ENTRIES = [
    Entry("shuttle-entry", lambda: PROBLEMS["shuttle-entry"](N=200), _shuttle_readout,
          seed=_SEED_NO_HEAT,
          published=_BETTS),
    Entry("shuttle-entry-heating", lambda: PROBLEMS["shuttle-entry-heating"](N=200), _shuttle_readout,
          seed=_SEED_HEAT,
          published=_BETTS_HEAT),
    # the same at N = 50 in Betts's raw units (no manual scaling): for the scaling work (issue 15 item 3)
    Entry("shuttle-entry-raw", lambda: _raw_shuttle(False),
          lambda p, r: _shuttle_readout(p, r, scaled=False),
          seed="-", published=_BETTS),
    Entry("shuttle-entry-heating-raw", lambda: _raw_shuttle(True),
          lambda p, r: _shuttle_readout(p, r, scaled=False),
          seed=_SEED_RAW,
          published=_BETTS_HEAT),
    # the heat limit written 70/q - 1 >= 0 and declared positive: the log / inverse-power
    # transforms of seed 004 sec. 5 apply to it under scaling (olado.problems.aerospace.heat_limit_row)
    Entry("shuttle-entry-heating-ratio-raw", lambda: _raw_shuttle(True, "ratio"),
          lambda p, r: _shuttle_readout(p, r, scaled=False),
          seed=_SEED_RAW,
          published=_BETTS_HEAT),
    # scaled units at N = 100 (the N = 200 rows above are long for sqp-ip)
    Entry("shuttle-entry-100", lambda: PROBLEMS["shuttle-entry"](N=100), _shuttle_readout,
          seed=_SEED_NO_HEAT,
          published=_BETTS),
    Entry("shuttle-entry-heating-100", lambda: PROBLEMS["shuttle-entry-heating"](N=100), _shuttle_readout,
          seed=_SEED_HEAT,
          published=_BETTS_HEAT),
    Entry("rigid-body", lambda: PROBLEMS["rigid-body"](), _final_state({"t_f": -1}),
          seed="J = t_f = 29.990 .. 30.713 (seed 004 Table 1 'AB', with an unstated angular-speed limit)",
          published="t_f = 28.6304077 (Betts 2010)"),
    Entry("hang-glider", lambda: PROBLEMS["hang-glider"](), _final_state({"range x(t_f) (m)": 0, "t_f (s)": -1}),
          seed="J = -1248.032 m (seed 004 Table 1 'HG', every scaling)",
          published="range 1248.03103 m, t_f = 98.436940 s (Betts 2010)"),
    Entry("orbit-raising", lambda: PROBLEMS["orbit-raising"](), _final_state({"r(t_f)": 0}),
          seed="r(t_f) = 1.525 (seed 002 sec. 4.5, 'physical case'; other local minimum 1.504)",
          published="r(t_f) = 1.525 (Bryson and Ho 1975 sec. 2.5)"),
]


def _fmt(v):
    return f"{v:.8g}" if isinstance(v, float) else str(v)


#: (heading, function(entry, problem, result) -> cell)
COLUMNS = [
    ("status", lambda e, p, r: r.status.value),
    ("iterations", lambda e, p, r: str(r.iterations)),
    ("time (s)", lambda e, p, r: f"{r.time_s:.2g}"),
    ("objective", lambda e, p, r: f"{r.objective:.10g}"),
    ("olado's values", lambda e, p, r: ", ".join(f"{k} {_fmt(v)}" for k, v in e.readout(p, r).items())),
]


def _grid(problem):
    """The leading cells of a row: the intervals (N for a plain DOCP) and the scheme."""
    return [str(getattr(problem, "intervals", problem.N)), str(getattr(problem, "method", "-"))]


def config_of(name):
    """The SolverConfig of a config name: ``preset`` or ``preset+override+...`` (module
    docstring); an override without ``=`` is ``scaling=<it>``."""
    from olado.config import load_config

    preset, *extra = name.split("+")
    overrides = [item if "=" in item else f"scaling={item}" for item in extra]
    return load_config(HERE.parent / "configs" / f"{preset}.ini", overrides)


def run(entries, configs):
    """Table rows: one per (entry, config); the problem is built (and its model compiled) once per
    entry, outside the solve times."""
    rows = []
    for e in entries:
        problem = e.build()
        try:                               # compiles the model; the raw shuttle's guess simulates to -inf
            problem.simulate(problem.initial_guess())
        except olado.errors.NonFiniteEvaluationError:
            pass
        for cfg in configs:
            t0 = time.perf_counter()
            r = olado.solve(problem, config=config_of(cfg))
            wall = time.perf_counter() - t0
            cells = [e.name] + _grid(problem) + [cfg] + [f(e, problem, r) for _, f in COLUMNS] + [e.seed, e.published]
            rows.append("| " + " | ".join(cells) + " |")
            print(rows[-1], f"(wall {wall:.1f} s)", flush=True)
    return rows


def table_main(argv, *, entries, section, script, preamble):
    """The command line shared by the seeds' benchmark scripts: ``--entries``, ``--configs``,
    ``--write`` (the section ``section`` of RESULTS.md, headed by ``preamble``)."""
    ap = argparse.ArgumentParser(description=f"{section}: olado next to the seeds' values")
    ap.add_argument("--entries", nargs="+", default=[e.name for e in entries])
    ap.add_argument("--configs", nargs="+", default=CONFIGS)
    ap.add_argument("--write", action="store_true", help=f"write the '{section}' section of RESULTS.md")
    ap.add_argument("--section", default=section, help="the RESULTS.md section --write writes (a subset of "
                    "the entries or configs in a section of its own keeps the full table's section)")
    args = ap.parse_args(argv)
    section = args.section
    chosen = [e for e in entries if e.name in args.entries]
    head = ["problem", "intervals", "scheme", "config"] + [h for h, _ in COLUMNS] + ["seed reports", "published"]
    table = ["| " + " | ".join(head) + " |", "|" + "|".join(":--" for _ in head) + "|"] + run(chosen, args.configs)
    if args.write:
        cmd = f"python benchmarks/{script} --write" + (
            "" if chosen == entries else " --entries " + " ".join(args.entries)) + (
            "" if args.configs == CONFIGS else " --configs " + " ".join(args.configs)) + (
            "" if section == ap.get_default("section") else f" --section '{section}'")
        write_section(section, f"## {section}\n\nCommand: `{cmd}`  \nCommit: {commit()}  \n"
                      f"Date: {time.strftime('%Y-%m-%d')}  \nMachine: {machine()} (shared with other jobs: "
                      f"times are orders of magnitude)\n\n{preamble}\n\n" + "\n".join(table) + "\n")
    return 0


def main(argv=None):
    return table_main(argv, entries=ENTRIES, section=SECTION, script="bench_aerospace.py", preamble=(
        "'intervals' is the number of control intervals (a free final time adds a parameter stage to "
        "the DOCP). Objectives are minimized (a maximized quantity appears with a minus sign; the "
        "shuttle's objective is -theta(t_f) in rad). Formulations, data sources and the differences to "
        "the seeds' values: docs/aerospace.md."))


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
