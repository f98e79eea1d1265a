"""Start-up time of the olado command: where a small solve's wall time goes.

Measured, each in fresh processes (PYTHONPATH and working directory = the checkout):

* whole-process wall and CPU time (median of --runs) of ``olado solve zambezi12 --N 24 --config
  configs/sqp-ip.ini`` with a warm numba cache, of ``python -c "import olado"``, of ``olado
  list`` and, for reference, of ``python -c pass`` and of the numba floor (``import numba``, the
  first call of one trivial cached kernel and ``gc.freeze()``: what any numba-compiled solve pays
  at least);
* the solve's imports itemised by package (``python -X importtime``, self times, median of
  --probe-runs);
* the solve's time split by phase of the command and, inside each, into imports, numba's one-off
  target-context set-up, numba cache loads (per kernel module, with the number of compiled entry
  points loaded) and the phase's own computation, and the interpreter's teardown after the
  command (``_startup_probe.py``, median of --probe-runs);
* the first-ever run: the same solve with an empty numba cache (``NUMBA_CACHE_DIR`` set to a new
  temporary directory), whole wall time and compile time per kernel module.

With ``--compare DIR`` every measurement is also made on the checkout DIR (e.g. an older commit),
alternating run by run, so old and new are measured side by side under the same load. Python
bytecode caching is on in every child (``PYTHONDONTWRITEBYTECODE`` is dropped; the ``.pyc`` files
go to a temporary ``PYTHONPYCACHEPREFIX``), as for an installed package; one warm-up run of each
command per checkout is not counted.

    python benchmarks/bench_startup.py                            # this checkout; writes RESULTS.md
    git worktree add ../olado-old 45903b1                         # an old commit to compare with
    python benchmarks/bench_startup.py --compare ../olado-old     # old vs this, side by side
    python benchmarks/bench_startup.py --runs 5 --no-compile --no-write
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from _common import HERE, machine, write_section

SECTION = "Start-up time of the olado command (zambezi12, N = 24, sqp-ip)"
SOLVE = ["solve", "zambezi12", "--N", "24", "--config", "configs/sqp-ip.ini"]
FLOOR = "numba floor: import numba, call one cached kernel, gc.freeze()"
#: a module with one cached numba kernel: the start-up any numba-compiled solve pays at least
FLOOR_KERNEL = "import numba\n\n@numba.njit(cache=True)\ndef f(x):\n    return x + 1.0\n"


def commands(floor_dir) -> dict:
    """Command name -> interpreter arguments."""
    return {
        "olado solve zambezi12 --N 24 --config configs/sqp-ip.ini": ["-m", "olado", *SOLVE],
        'python -c "import olado"': ["-c", "import olado"],
        "olado list": ["-m", "olado", "list"],
        "python -c pass (interpreter alone)": ["-c", "pass"],
        FLOOR: ["-c", f"import gc, sys; sys.path.insert(0, {str(floor_dir)!r}); import numba_floor; "
                      "numba_floor.f(1.0); gc.freeze()"],
    }
PROBE = HERE / "_startup_probe.py"
KINDS = ("import", "numba init", "numba load", "numba compile")


# ---------------------------------------------------------------------------- running children
@dataclasses.dataclass
class Checkout:
    """A source tree whose ``olado`` package is measured."""

    label: str
    root: Path

    def describe(self) -> str:
        git = ["git", "-C", str(self.root)]
        try:
            commit = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                    check=True).stdout.strip()
            dirty = subprocess.run([*git, "status", "--porcelain", "--untracked-files=no", "--", ".",
                                    ":!benchmarks/RESULTS.md"], capture_output=True, text=True, check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return f"{self.label}: {self.root}"
        return f"{self.label}: {self.root} at {commit}{' (with uncommitted changes)' if dirty else ''}"


@dataclasses.dataclass
class Run:
    wall: float
    cpu: float
    stdout: str
    stderr: str
    end_time: float  # time.time() when the process had ended


@dataclasses.dataclass
class Runner:
    """Runs ``python ARGS`` in a checkout: PYTHONPATH and working directory = the checkout, bytecode
    cached under ``pycache`` (not in the trees)."""

    pycache: str

    def env(self, checkout: Checkout, extra=None) -> dict:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env.update(PYTHONPATH=str(checkout.root), PYTHONPYCACHEPREFIX=self.pycache, **(extra or {}))
        return env

    def run(self, checkout: Checkout, args, extra_env=None) -> Run:
        """Wall time and the child's user + system CPU time; a failing command raises."""
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, *args], cwd=checkout.root, env=self.env(checkout, extra_env),
                              capture_output=True, text=True)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            raise RuntimeError(f"{checkout.label}: python {' '.join(args)} exited {proc.returncode}:\n"
                               f"{proc.stderr[-2000:]}")
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return Run(wall, cpu, proc.stdout, proc.stderr, time.time())


def alternating(checkouts, count):
    """(i, checkout) pairs, the order of the checkouts reversed every other round (drift cancels)."""
    for i in range(count):
        for c in (checkouts if i % 2 == 0 else checkouts[::-1]):
            yield i, c


# ---------------------------------------------------------------------------- measurements
def whole_process(runner, checkouts, runs) -> dict:
    """{(command, label): [Run]} over ``runs`` alternating rounds, after one warm-up each."""
    floor_dir = Path(runner.pycache) / "floor"
    floor_dir.mkdir()
    (floor_dir / "numba_floor.py").write_text(FLOOR_KERNEL)
    cmds = commands(floor_dir)
    for c in checkouts:
        for args in cmds.values():
            runner.run(c, args)
    out = defaultdict(list)
    for _, c in alternating(checkouts, runs):
        for name, args in cmds.items():
            out[(name, c.label)].append(runner.run(c, args))
    return out


def import_times(runner, checkouts, runs) -> dict:
    """{label: {group: median self-time (s)}} from ``-X importtime`` of the solve."""
    samples = {c.label: defaultdict(list) for c in checkouts}
    for _, c in alternating(checkouts, runs):
        groups = defaultdict(float)
        for line in runner.run(c, ["-X", "importtime", "-m", "olado", *SOLVE]).stderr.splitlines():
            parsed = parse_importtime(line)
            if parsed:
                groups[import_group(parsed[1])] += parsed[0]
        for group, seconds in groups.items():
            samples[c.label][group].append(seconds)
    return {label: {g: statistics.median(v + [0.0] * (runs - len(v))) for g, v in s.items()}
            for label, s in samples.items()}


def parse_importtime(line):
    """(self seconds, module) of one ``-X importtime`` line, else None."""
    if not line.startswith("import time:") or "self [us]" in line:
        return None
    self_us, _, name = line[len("import time:"):].split("|")
    return int(self_us) * 1e-6, name.strip()


def import_group(module: str) -> str:
    top = module.split(".")[0]
    if top == "olado":
        return module
    if top in sys.stdlib_module_names or top.startswith("_"):
        return "(standard library)"
    return top


def probes(runner, checkouts, runs, extra_env=None) -> dict:
    """{label: [probe result]}: ``_startup_probe.py`` runs of the solve."""
    out = defaultdict(list)
    for _, c in alternating(checkouts, runs):
        result = runner.run(c, [str(PROBE), str(c.root), *SOLVE], extra_env)
        data = json.loads(result.stdout.strip().splitlines()[-1])
        out[c.label].append(data | {"wall": result.wall, "teardown": result.end_time - data["end_time"]})
    return out


def first_runs(runner, checkouts) -> dict:
    """{label: (plain run, probe result)} of the solve with an empty numba cache each."""
    out = {}
    for c in checkouts:
        with tempfile.TemporaryDirectory(prefix="olado-numba-") as cold:
            plain = runner.run(c, ["-m", "olado", *SOLVE], {"NUMBA_CACHE_DIR": cold})
        with tempfile.TemporaryDirectory(prefix="olado-numba-") as cold:
            probe = probes(runner, [c], 1, {"NUMBA_CACHE_DIR": cold})[c.label][0]
        out[c.label] = (plain, probe)
    return out


# ---------------------------------------------------------------------------- summarising probes
def split(result, key_of) -> dict:
    """{key: cpu seconds} of one probe result, ``key_of(row)`` choosing the key (None: skip)."""
    out = defaultdict(float)
    for row in result["rows"]:
        key = key_of(row)
        if key is not None:
            out[key] += row["cpu"]
    return out


def median_split(results, key_of) -> dict:
    splits = [split(r, key_of) for r in results]
    keys = {k for s in splits for k in s}
    return {k: statistics.median(s.get(k, 0.0) for s in splits) for k in keys}


def by_phase_and_kind(row):
    kind = row["kind"] if row["kind"] in KINDS else "own computation"
    return row["phase"], kind


def numba_by_module(kind):
    return lambda row: row["detail"] if row["kind"] == kind else None


def entry_points(result, kind) -> dict:
    out = defaultdict(int)
    for row in result["rows"]:
        if row["kind"] == kind:
            out[row["detail"]] += row["count"]
    return out


# ---------------------------------------------------------------------------- report
def ms(seconds) -> str:
    return f"{1000 * seconds:.0f}"


def spread(values) -> str:
    return f"{ms(statistics.median(values))} ({ms(min(values))}-{ms(max(values))})"


def table(header, rows) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|:--|" + "---:|" * (len(header) - 1)]
    lines += ["| " + " | ".join(str(x) for x in row) + " |" for row in rows]
    return lines


def whole_process_table(labels, walls) -> list[str]:
    header = ["command"] + [f"{label}: wall ms, median (min-max)" for label in labels] + \
             [f"{label}: CPU ms" for label in labels]
    if len(labels) == 2:
        header.append(f"wall {labels[1]} / {labels[0]}")
    rows = []
    for name in dict.fromkeys(name for name, _ in walls):
        w = [[r.wall for r in walls[(name, label)]] for label in labels]
        row = [f"`{name}`"] + [spread(x) for x in w]
        row += [ms(statistics.median(r.cpu for r in walls[(name, label)])) for label in labels]
        if len(labels) == 2:
            row.append(f"{statistics.median(w[1]) / statistics.median(w[0]):.2f}")
        rows.append(row)
    return table(header, rows)


def phase_table(label, results) -> list[str]:
    cells = median_split(results, by_phase_and_kind)
    phases = sorted({p for p, _ in cells}, key=lambda p: -sum(v for (q, _), v in cells.items() if q == p))
    kinds = [*KINDS, "own computation"]
    rows = [[p] + [ms(cells.get((p, k), 0.0)) for k in kinds] + [ms(sum(cells.get((p, k), 0.0) for k in kinds))]
            for p in phases]
    rows.append(["**total**"] + [ms(sum(cells.get((p, k), 0.0) for p in phases)) for k in kinds]
                + [ms(sum(cells.values()))])
    return [f"CPU ms in the process of `{label}` (median of {len(results)} probe runs):", ""] + \
        table(["phase"] + [f"{k}" for k in kinds] + ["total"], rows)


def import_table(labels, imports, top=18) -> list[str]:
    groups = {g for label in labels for g in imports[label]}
    totals = {g: max(imports[label].get(g, 0.0) for label in labels) for g in groups}
    shown = sorted(totals, key=lambda g: -totals[g])[:top]
    rows = [[f"`{g}`"] + [ms(imports[label].get(g, 0.0)) for label in labels] for g in shown]
    rows.append(["all other modules"] + [ms(sum(v for g, v in imports[label].items() if g not in shown))
                                          for label in labels])
    rows.append(["**total**"] + [ms(sum(imports[label].values())) for label in labels])
    return table(["package or olado module"] + [f"{label}: self ms" for label in labels], rows)


def numba_table(labels, results, kind) -> list[str]:
    per = {label: median_split(results[label], numba_by_module(kind)) for label in labels}
    counts = {label: entry_points(results[label][0], kind) for label in labels}
    modules = sorted({m for label in labels for m in per[label]}, key=lambda m: -max(per[l].get(m, 0) for l in labels))
    rows = [[f"`{m}`"] + [f"{ms(per[label].get(m, 0.0))} ({counts[label].get(m, 0)})" for label in labels]
            for m in modules]
    rows.append(["**total**"] + [f"{ms(sum(per[label].values()))} ({sum(counts[label].values())})"
                                 for label in labels])
    return table(["kernel module"] + [f"{label}: ms (entry points)" for label in labels], rows)


def teardown_line(labels, results) -> str:
    parts = [f"{label} {ms(statistics.median(r['teardown'] for r in results[label]))} ms" for label in labels]
    return ("Interpreter teardown after the command (wall time from the probe's last output to the end of "
            "the process, median): " + ", ".join(parts) + ".")


def init_line(labels, results) -> str:
    parts = [f"{label} {ms(statistics.median(split(r, numba_by_module('numba init')).get('target context', 0.0) for r in results[label]))} ms"
             for label in labels]
    return "numba's target-context set-up (first call of any compiled function; imports inside it not counted): " + \
        ", ".join(parts) + "."


def report(args, checkouts, walls, imports, probe_results, first, load) -> str:
    labels = [c.label for c in checkouts]
    command = "python benchmarks/bench_startup.py" + (f" --compare {args.compare}" if args.compare else "")
    lines = [f"## {SECTION}", "", f"Command: `{command}`  ", f"Date: {datetime.date.today().isoformat()}  ",
             f"Machine: {machine(with_ipopt=False)}  ",
             f"Load average (1 min) at start and end: {load[0]:.2f}, {load[1]:.2f}", ""]
    lines += [f"- {c.describe()}" for c in checkouts] + [""]
    lines += [f"Whole process, warm numba cache, {args.runs} runs per command and checkout, alternating. "
              f"The last row is a reference independent of olado: `import numba` plus the first call of one "
              "trivial cached kernel (numba's import, its target-context set-up, which imports scipy.linalg "
              "for BLAS, and one cache load), then `gc.freeze()` as the olado program does before it exits.", ""]
    lines += whole_process_table(labels, walls) + [""]
    lines += ["Imports of the solve (`python -X importtime`, self time per package; `olado` modules one by one; "
              f"median of {args.probe_runs}):", ""]
    lines += import_table(labels, imports) + [""]
    lines += ["Where the solve's time goes: each CPU millisecond counted once, in the phase of the command "
              "where it was spent (`_startup_probe.py` wraps olado's command-line phases, every import and "
              "numba's caching entry points; `main` is argument parsing, printing and the rest). Imports "
              "inside a numba set-up or cache load count as imports.", ""]
    for label in labels:
        lines += phase_table(label, probe_results[label]) + [""]
    lines += ["Numba cache loads per kernel module (warm cache: CPU ms, median; in brackets the compiled "
              "entry points loaded):", ""]
    lines += numba_table(labels, probe_results, "numba load") + ["", init_line(labels, probe_results), "",
                                                                 teardown_line(labels, probe_results), ""]
    if first:
        lines += ["First-ever run (empty numba cache): whole-process wall "
                  + ", ".join(f"{label} {first[label][0].wall:.1f} s" for label in labels)
                  + "; compile time per kernel module (CPU ms, one probe run each, entry points compiled "
                  "in brackets):", ""]
        lines += numba_table(labels, {label: [first[label][1]] for label in labels}, "numba compile") + [""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------- main
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", metavar="DIR", help="another checkout measured side by side (e.g. an old commit)")
    ap.add_argument("--runs", type=int, default=15, help="whole-process runs per command and checkout")
    ap.add_argument("--probe-runs", type=int, default=5, help="-X importtime and probe runs per checkout")
    ap.add_argument("--no-compile", action="store_true", help="skip the first-ever (empty numba cache) runs")
    ap.add_argument("--no-write", action="store_true", help="print the section, do not write RESULTS.md")
    args = ap.parse_args(argv)
    checkouts = [Checkout("new", HERE.parent)]
    if args.compare:
        checkouts.insert(0, Checkout("old", Path(args.compare).resolve()))
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="olado-pyc-") as pycache:
        runner = Runner(pycache)
        walls = whole_process(runner, checkouts, args.runs)
        imports = import_times(runner, checkouts, args.probe_runs)
        probe_results = probes(runner, checkouts, args.probe_runs)
        first = None if args.no_compile else first_runs(runner, checkouts)
    load.append(os.getloadavg()[0])
    text = report(args, checkouts, walls, imports, probe_results, first, load)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)


if __name__ == "__main__":
    main()
