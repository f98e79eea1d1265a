"""Timing helper of the benchmark scripts that must not touch sys.path (those that time the
olado of the caller's PYTHONPATH, unlike _common, which puts this checkout first)."""

from __future__ import annotations

import time


def best_per_call(fn, reps):
    """Process time per call of ``fn`` (s): the best of 7 rounds of ``reps`` calls after a warm-up."""
    for _ in range(min(reps, 50)):
        fn()
    best = float("inf")
    for _ in range(7):
        t = time.process_time()
        for _ in range(reps):
            fn()
        best = min(best, (time.process_time() - t) / reps)
    return best
