"""Child process of bench_startup.py: run ``olado.cli.main(argv)`` of the checkout ROOT and print,
as JSON, where the wall time went, each second attributed exclusively to one item:

* phases of the command (``load_config``, ``build_problem``, ``counts_line``, ``make_solver``,
  ``solve``; ``main`` is what the command does outside them: parsing argv, printing, ...);
* within each phase: imports by top-level package (``olado`` modules by name), numba's one-off
  target-context set-up (``numba init``), loading each kernel module's compiled functions from
  numba's cache (``numba load``) and compiling them when the cache is cold (``numba compile``);
  what remains is the phase's own computation.

    python _startup_probe.py ROOT solve zambezi12 --N 24 --config configs/sqp-ip.ini

The last JSON field, ``end_time`` (time.time()), lets the parent measure the interpreter's teardown
after the command. Only olado's command-line phases (``olado.cli.run`` where it exists, else
``main``), the import machinery and numba's caching entry points are wrapped, so the probe runs
unchanged on old and new checkouts. Run it with the working directory ROOT.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import time

ROOT = sys.argv[1]
ARGV = sys.argv[2:]
sys.path.insert(0, ROOT)
T_START = time.perf_counter()

import importlib._bootstrap as bootstrap  # noqa: E402


def _clock():
    return time.perf_counter(), time.process_time()


class Ledger:
    """Exclusive wall and CPU time per (phase, kind, detail): entering a nested region pauses the
    enclosing one, so every second is counted once."""

    def __init__(self):
        self.totals: dict = {}   # key -> [wall, cpu]
        self.counts: dict = {}
        self.stack: list = [["main", "main", _clock()]]

    def enter(self, kind, detail):
        now = _clock()
        self._book_top(now)
        self.stack.append([kind, detail, now])

    def leave(self):
        now = _clock()
        key = self._book_top(now)
        self.counts[key] = self.counts.get(key, 0) + 1
        self.stack.pop()
        self.stack[-1][2] = now

    def _book_top(self, now):
        """Add the time since the innermost region (re)started to its key; return the key."""
        kind, detail, since = self.stack[-1]
        phase = next((d for k, d, _ in reversed(self.stack) if k == "phase"), "main")
        wall_cpu = self.totals.setdefault((phase, kind, detail), [0.0, 0.0])
        wall_cpu[0] += now[0] - since[0]
        wall_cpu[1] += now[1] - since[1]
        return (phase, kind, detail)

    @contextlib.contextmanager
    def region(self, kind, detail):
        self.enter(kind, detail)
        try:
            yield
        finally:
            self.leave()


LEDGER = Ledger()


def _package(name: str) -> str:
    return name if name.startswith("olado") else name.split(".")[0]


_find_and_load = bootstrap._find_and_load


def _timed_find_and_load(name, import_):
    """Every import (``import x`` and importlib.import_module) goes through here."""
    with LEDGER.region("import", _package(name)):
        module = _find_and_load(name, import_)
    if name == "numba":  # numba fully imported: wrap its caching entry points
        _hook_numba()
    return module


bootstrap._find_and_load = _timed_find_and_load


def _wrap(owner, attr, kind, detail_of):
    original = getattr(owner, attr)

    def wrapper(*args, **kwargs):
        with LEDGER.region(kind, detail_of(*args)):
            return original(*args, **kwargs)

    setattr(owner, attr, wrapper)


def _kernel_module(dispatcher_or_cache, *_) -> str:
    func = getattr(dispatcher_or_cache, "py_func", None) or getattr(dispatcher_or_cache, "_py_func", None)
    return getattr(func, "__module__", None) or "?"


_numba_hooked = False


def _hook_numba():
    """Time numba's target-context set-up, cache loads and compilations, per kernel module."""
    global _numba_hooked
    if _numba_hooked:
        return
    _numba_hooked = True
    from numba.core import base, caching, dispatcher

    _wrap(caching.Cache, "load_overload", "numba load", _kernel_module)
    _wrap(dispatcher.Dispatcher, "compile", "numba compile", _kernel_module)
    _wrap(base.BaseContext, "refresh", "numba init", lambda *_: "target context")


def _phase(owner, attr):
    original = getattr(owner, attr)

    def wrapper(*args, **kwargs):
        with LEDGER.region("phase", attr.strip("_").replace("cmd_", "")):
            result = original(*args, **kwargs)
        if attr == "make_solver":
            _wrap_solve(result)
        return result

    setattr(owner, attr, wrapper)


def _wrap_solve(solver):
    original = solver.solve

    def solve(*args, **kwargs):
        with LEDGER.region("phase", "solve"):
            return original(*args, **kwargs)

    solver.solve = solve


def main():
    import olado.cli as cli
    import olado.config as config

    for attr in ("_build_problem", "_counts_line"):
        _phase(cli, attr)
    for attr in ("load_config", "make_solver"):
        _phase(config, attr)
    out = io.StringIO()
    sys.argv = ["olado", *ARGV]
    with contextlib.redirect_stdout(out):
        try:  # the program's own entry point where it has one (it also prepares the exit)
            code = cli.run() if hasattr(cli, "run") else cli.main()
        except SystemExit as exc:
            code = exc.code
    while len(LEDGER.stack) > 1:
        LEDGER.leave()
    LEDGER._book_top(_clock())
    rows = [{"phase": p, "kind": k, "detail": d, "wall": w, "cpu": c, "count": LEDGER.counts.get((p, k, d), 0)}
            for (p, k, d), (w, c) in LEDGER.totals.items()]
    print(json.dumps({"exit": code, "in_process_s": time.perf_counter() - T_START, "rows": rows,
                      "output": out.getvalue()[-2000:], "end_time": time.time()}), flush=True)


main()
