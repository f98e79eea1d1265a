"""Performance profiles, tables and run comparisons over bench records (``olado profile``;
docs/benchmarking.md, "Profiles").

Dolan and Moré's logarithmic performance profile, paper 001 sec. 6: for problems p and
configurations s with metric t_{p,s} (48) -- solver time, SQP (major) iterations, QP iterations,
function evaluations --

    r_{p,s} = t_{p,s} / min_s t_{p,s}                                  (49)
    phi_s(tau) = card{p : log2 r_{p,s} <= tau} / n_p                   (50)

with r_{p,s} = r_M for a solve that failed (status not success/acceptable, or a run failure such
as a timeout); r_M is taken larger than every finite ratio (``2 * max(r)``, at least 2), so
phi_s(log2 r_M^-) is the share of problems s solved (51) and phi_s(0) the share it won (ties count
for every winner; the paper's text says phi_s(1), but with the log2 scale of (50) winning is
log2 r = 0). A problem no configuration solved has r = r_M for all. Metric values are floored at
:data:`FLOOR` (a solve with 0 QP iterations, a time below the clock's resolution) so ratios stay
finite.
"""

from __future__ import annotations

import collections
import csv
import dataclasses
import io
import math

import numpy as np

from ..errors import ConfigError
from .where import Where

#: metric name -> (record field, label)
METRICS = {"time": ("solve_s", "solver time (s)"), "wall": ("wall_s", "wall time in the worker (s)"),
           "sqp": ("sqp_iterations", "SQP (major) iterations"), "qp": ("qp_iterations", "QP iterations"),
           "evaluations": ("function_evaluations", "function evaluations")}
#: the smallest metric value a ratio is formed with
FLOOR = {"solve_s": 1e-6, "wall_s": 1e-6}
PROBLEM_FIELDS = ("problem", "N", "start")


def _problem(record) -> tuple:
    return tuple(record.get(k) for k in PROBLEM_FIELDS)


def select(records, where=None, configs=None) -> list[dict]:
    """The records for which ``where`` (text or :class:`Where`) holds, of the configurations
    ``configs`` (names; None: all)."""
    if where:
        cond = where if isinstance(where, Where) else Where(where)
        cond.check_fields(records)
        records = [r for r in records if cond(r)]
    if configs:
        known = list(dict.fromkeys(r.get("config") for r in records))
        for name in configs:
            if name not in known:
                raise ConfigError(f"no record of the configuration {name!r}", key="--config",
                                  allowed=", ".join(map(str, known)) or "none")
        records = [r for r in records if r.get("config") in configs]
    return records


def config_names(records) -> list[str]:
    return list(dict.fromkeys(r["config"] for r in records))


@dataclasses.dataclass
class Profile:
    """The performance ratios of one metric: ``ratios`` (n_p, n_s) with ``r_M`` for failures;
    ``problems`` (problem, N, start) and ``configs`` name rows and columns; ``dropped`` counts
    the problems left out because a configuration has no record of them."""

    metric: str
    configs: list
    problems: list
    values: np.ndarray          # t_{p,s}, NaN for a failure
    ratios: np.ndarray          # r_{p,s}, r_M for a failure
    r_M: float
    dropped: int = 0

    @property
    def solved(self) -> np.ndarray:
        return np.isfinite(self.values)

    def phi(self, taus) -> np.ndarray:
        """phi_s(tau) (50) for every configuration (rows) and tau (columns)."""
        taus = np.atleast_1d(np.asarray(taus, dtype=float))
        logr = np.log2(self.ratios)
        return (logr[:, :, None] <= taus[None, None, :]).mean(axis=0)

    def wins(self) -> np.ndarray:
        """phi_s(0): the share of problems on which s was (one of) the best."""
        return self.phi([0.0])[:, 0]

    def solved_share(self) -> np.ndarray:
        """phi_s(log2 r_M^-) (51): the share of problems s solved."""
        return self.solved.mean(axis=0)


def performance_profile(records, metric: str = "time", where=None, configs=None) -> Profile:
    """The :class:`Profile` of ``metric`` (a key of :data:`METRICS`) over ``records`` (those for
    which ``where`` holds, of ``configs``). A problem counts when every configuration has a record
    of it."""
    if metric not in METRICS:
        raise ConfigError(f"unknown metric {metric!r}", key="--metric", allowed=", ".join(METRICS))
    field = METRICS[metric][0]
    records = select(records, where, configs)
    names = list(configs) if configs else config_names(records)
    if not names:
        raise ConfigError("no records to profile" + (f" where {where}" if where else ""), key="--where")
    table = collections.defaultdict(dict)
    for r in records:
        table[_problem(r)][r["config"]] = r
    complete = [p for p in table if all(c in table[p] for c in names)]
    values = np.full((len(complete), len(names)), np.nan)
    for i, p in enumerate(complete):
        for j, c in enumerate(names):
            r = table[p][c]
            v = r.get(field)
            if r.get("success") and v is not None and math.isfinite(v):
                values[i, j] = max(float(v), FLOOR.get(field, 1.0))
    ratios = np.full_like(values, np.inf)
    best = np.nanmin(np.where(np.isfinite(values), values, np.inf), axis=1, initial=np.inf) if values.size else \
        np.zeros(0)
    ok = np.isfinite(values)
    ratios[ok] = (values / best[:, None])[ok]
    finite = ratios[ok]
    r_M = max(2.0, 2.0 * float(finite.max())) if finite.size else 2.0
    ratios[~ok] = r_M
    return Profile(metric, names, complete, values, ratios, r_M, dropped=len(table) - len(complete))


# ---------------------------------------------------------------------------- plots
def plot_profiles(profiles, path, title: str = "") -> None:
    """One panel per profile (metric): phi_s(tau) as steps over tau in [0, log2 r_M); saved
    atomically (olado.result.save_figure, format from the suffix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..result import save_figure

    fig, axes = plt.subplots(1, len(profiles), figsize=(5.2 * len(profiles), 4.2), squeeze=False)
    for ax, prof in zip(axes[0], profiles):
        top = math.log2(prof.r_M)
        finite = np.log2(prof.ratios[prof.solved]) if prof.solved.any() else np.zeros(1)
        taus = np.unique(np.concatenate([[0.0], finite, [top * 0.999]]))
        phi = prof.phi(taus)
        for j, name in enumerate(prof.configs):
            ax.step(taus, phi[j], where="post", label=name)
        ax.set_xlim(0.0, top)
        ax.set_ylim(0.0, 1.02)
        ax.set_xlabel("tau = log2 of the ratio to the best")
        ax.set_ylabel("phi(tau)")
        ax.set_title(f"{METRICS[prof.metric][1]} ({len(prof.problems)} problems)", fontsize=10)
        ax.grid(alpha=0.3)
    axes[0][0].legend(loc="lower right", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


# ---------------------------------------------------------------------------- tables
def _fmt(value, digits=4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def summary_table(records, profiles, configs=None) -> tuple[list, list]:
    """(header, rows): one row per configuration -- solved / problems, for each profile the wins
    phi(0), phi(1), phi(2) (blank for a configuration the profile leaves out), the total solver
    time, and the median SQP and QP iterations of its solved problems."""
    names = list(configs) if configs else (profiles[0].configs if profiles else config_names(records))
    keep = set(profiles[0].problems) if profiles else None
    header = ["config", "solved"]
    for p in profiles:
        header += [f"{p.metric} phi(0)", f"{p.metric} phi(1)", f"{p.metric} phi(2)"]
    header += ["total time (s)", "median SQP iter", "median QP iter"]
    rows = []
    for name in names:
        mine = [r for r in records if r["config"] == name and (keep is None or _problem(r) in keep)]
        ok = [r for r in mine if r.get("success")]
        row = [name, f"{len(ok)} / {len(mine)}"]
        for p in profiles:
            if name not in p.configs:
                row += ["", "", ""]
                continue
            phi = p.phi([0.0, 1.0, 2.0])[p.configs.index(name)]
            row += [f"{v:.2f}" for v in phi]
        row += [f"{sum(r.get('solve_s') or 0.0 for r in mine):.2f}",
                _fmt(float(np.median([r["sqp_iterations"] for r in ok])) if ok else None),
                _fmt(float(np.median([r["qp_iterations"] for r in ok])) if ok else None)]
        rows.append(row)
    return header, rows


def per_problem_table(records, configs=None) -> tuple[list, list]:
    """(header, rows) like paper 001 Table 1: one row per (problem, N, start), per configuration
    its status, SQP and QP iterations, solver time and objective."""
    names = list(configs) if configs else config_names(records)
    table = collections.defaultdict(dict)
    for r in records:
        table[_problem(r)][r["config"]] = r
    header = ["problem", "N", "start"]
    for c in names:
        header += [f"{c} status", f"{c} iter", f"{c} QP iter", f"{c} time (s)", f"{c} objective"]
    rows = []
    for p in sorted(table, key=lambda p: (str(p[0]), p[1] if p[1] is not None else -1, str(p[2]))):
        row = [_fmt(v) for v in p]
        for c in names:
            r = table[p].get(c)
            row += ["", "", "", "", ""] if r is None else [
                r.get("status", ""), _fmt(r.get("sqp_iterations")), _fmt(r.get("qp_iterations")),
                _fmt(r.get("solve_s"), 3), _fmt(r.get("objective"), 10)]
        rows.append(row)
    return header, rows


def format_table(header, rows, fmt: str = "md") -> str:
    """Markdown (``md``) or CSV (``csv``) text of a table."""
    if fmt == "csv":
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(rows)
        return buf.getvalue()
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(":--" if i == 0 else "--:" for i in range(len(header))) + "|"]
    lines += ["| " + " | ".join(map(str, row)) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def profile_table(profile: Profile, taus=(0.0, 1.0, 2.0, 4.0, 8.0)) -> tuple[list, list]:
    """(header, rows): phi_s(tau) at ``taus`` and phi_s(log2 r_M^-) for each configuration."""
    phi = profile.phi(list(taus))
    header = ["config"] + [f"phi({t:g})" for t in taus] + ["solved (51)"]
    rows = [[c] + [f"{v:.3f}" for v in phi[j]] + [f"{profile.solved_share()[j]:.3f}"]
            for j, c in enumerate(profile.configs)]
    return header, rows


# ---------------------------------------------------------------------------- comparisons
@dataclasses.dataclass
class Comparison:
    """A run against an earlier one, matched by (problem, N, start, config name): solves that no
    longer succeed, that now succeed, whose objective moved by more than ``rtol`` (both
    successful), that got slower by more than ``slower`` times (both successful, old time at
    least ``min_time``), and the keys only one run has."""

    regressions: list
    fixed: list
    objective_changes: list
    slower: list
    only_old: int
    only_new: int
    matched: int

    @property
    def has_regressions(self) -> bool:
        return bool(self.regressions or self.objective_changes)

    def text(self) -> str:
        out = [f"{self.matched} solves matched ({self.only_new} only in the new run, {self.only_old} only in the old)"]
        sections = (("status regressions (success before, not now)", self.regressions),
                    ("fixed (success now, not before)", self.fixed),
                    ("objective changes", self.objective_changes), ("slower", self.slower))
        for title, rows in sections:
            out.append(f"{title}: {len(rows)}")
            out += [f"  {line}" for line in rows[:50]]
            if len(rows) > 50:
                out.append(f"  ... and {len(rows) - 50} more")
        return "\n".join(out)


def _cmp_key(r) -> tuple:
    return (*_problem(r), r.get("config"))


def compare_runs(new, old, rtol: float = 1e-6, slower: float = 1.5, min_time: float = 0.05) -> Comparison:
    """Compare the records ``new`` with ``old`` (see :class:`Comparison`)."""
    a = {_cmp_key(r): r for r in old}
    b = {_cmp_key(r): r for r in new}
    both = [k for k in b if k in a]
    regressions, fixed, changes, slow = [], [], [], []
    for k in both:
        o, n = a[k], b[k]
        name = f"{k[3]}: {k[0]} N={k[1]} start {k[2]}"
        if o.get("success") and not n.get("success"):
            regressions.append(f"{name}: {o['status']} -> {n['status']} ({(n.get('message') or '')[:120]})")
        elif n.get("success") and not o.get("success"):
            fixed.append(f"{name}: {o['status']} -> {n['status']}")
        elif o.get("success") and n.get("success"):
            jo, jn = o.get("objective"), n.get("objective")
            if jo is not None and jn is not None and abs(jn - jo) > rtol * max(abs(jo), 1e-3):
                changes.append(f"{name}: objective {jo:.10g} -> {jn:.10g} ({(jn - jo) / max(abs(jo), 1e-3):+.1e})")
            to, tn = o.get("solve_s") or 0.0, n.get("solve_s") or 0.0
            if to >= min_time and tn > slower * to:
                slow.append(f"{name}: {to:.3f} s -> {tn:.3f} s ({tn / to:.2f}x)")
    return Comparison(regressions, fixed, changes, slow, only_old=len(set(a) - set(b)), only_new=len(set(b) - set(a)),
                      matched=len(both))
