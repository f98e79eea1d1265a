"""What the benchmark scripts share: the machine line and the section writer of RESULTS.md."""

from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "RESULTS.md"
sys.path.insert(0, str(HERE.parent))

from olado.result import atomic_write_bytes  # noqa: E402


def commit(checkout: Path = HERE.parent, mark_changes: bool = True) -> str:
    """The checkout's commit (short) for a benchmark's heading, with " (with uncommitted changes)"
    when tracked files changed (``mark_changes``); "unknown" outside a git checkout. The environment
    variable OLADO_COMMIT overrides it (a ``git archive`` copy has no .git)."""
    if os.environ.get("OLADO_COMMIT"):
        return os.environ["OLADO_COMMIT"]
    try:
        run = lambda *a: subprocess.run(["git", *a], cwd=checkout, capture_output=True, text=True,  # noqa: E731
                                        check=True).stdout.strip()
        rev = run("rev-parse", "--short", "HEAD")
        changed = mark_changes and run("status", "--porcelain", "--untracked-files=no")
        return rev + (" (with uncommitted changes)" if changed else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def best_of(solver, N, repeats, family="zambezi12"):
    """The fastest of ``repeats`` solves of the Zambezi ``family`` at horizon N (a fresh problem each
    time, so every solve starts from the same state)."""
    from olado.problems.zambezi import zambezi_problem

    best = None
    for _ in range(repeats):
        r = solver.solve(zambezi_problem(family, N=N))
        if best is None or r.time_s < best.time_s:
            best = r
    return best


def machine(with_ipopt=True) -> str:
    """CPU model and core count (lscpu), Python and, when installed, IPOPT versions."""
    model, cores = platform.processor() or "unknown CPU", os.cpu_count()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        fields = {k.strip(): v.strip() for k, v in (line.split(":", 1) for line in out.splitlines() if ":" in line)}
        model = fields.get("Model name", model)
        cores = fields.get("CPU(s)", cores)
    except (OSError, subprocess.CalledProcessError, ValueError):
        pass
    text = f"{model}, {cores} CPU(s); Python {platform.python_version()}"
    if with_ipopt:
        try:
            import cyipopt

            text += f"; cyipopt {cyipopt.__version__}, IPOPT {'.'.join(map(str, cyipopt.IPOPT_VERSION))} (MUMPS)"
        except Exception:  # pragma: no cover - informative only
            pass
    return text


#: hand-written notes inside a section, kept when a script rewrites the section
NOTES = re.compile(r"^<!-- notes -->\n.*?^<!-- /notes -->\n", re.S | re.M)


def write_section(section: str, text: str, path: Path = RESULTS) -> None:
    """Replace (or append) the '## <section>' part of a markdown file, atomically. Notes written
    by hand between the lines ``<!-- notes -->`` and ``<!-- /notes -->`` in the old section are
    kept, after the new text (they say at which commit and why; the script cannot)."""
    old = path.read_text(encoding="utf-8") if path.exists() else "# olado benchmark results\n\n"
    pattern = re.compile(rf"^## {re.escape(section)}\n.*?(?=^## |\Z)", re.S | re.M)
    m = pattern.search(old)
    if m:
        notes = NOTES.findall(m.group(0))
        body = text.rstrip("\n") + "\n\n" + "".join(n + "\n" for n in notes)
        rest = old[m.end():]
        new = old[:m.start()] + body.rstrip("\n") + ("\n\n" + rest if rest else "\n")
    else:
        new = old.rstrip("\n") + "\n\n" + text.rstrip("\n") + "\n"
    atomic_write_bytes(path, new.encode("utf-8"))
