"""benchmarks/bench_million.py: each N solved in a fresh process that reports its own peak RSS,
and the traced peak split by the layer that allocated it."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_million  # noqa: E402


def test_horizons_are_whole_years():
    assert [bench_million.years(n) for n in (1e4, 1e5, 1e6, 12, 13, 24)] == \
        [10008, 100008, 1000008, 12, 24, 24]


def test_a_worker_reports_its_solve_and_its_memory():
    r = bench_million.run_one("ipm", 24, components=True, max_time=60, timeout=300)
    assert r["status"] == "success" and r["iterations"] > 0
    assert r["peak_mb"] >= r["after_build_mb"] >= r["baseline_mb"] > 0
    assert r["bytes_per_stage"] == (r["peak_mb"] - r["baseline_mb"]) * 2 ** 20 / 24
    comps = r["components"]
    assert set(comps) <= {"solver state", "derivative arrays", "Riccati factors", "QP work arrays", "result",
                          "problem data and values", "other"}
    # every allocation of the sampled snapshot is in some layer: the parts add up to its size
    # (taken right after the size was read; the solve's thread may allocate in between)
    assert abs(sum(comps.values()) * 24 / 2 ** 20 - r["sampled_mb"]) <= 0.05 * r["sampled_mb"]
    assert comps["solver state"] > 0 and comps["derivative arrays"] > 0


def test_a_failing_worker_is_a_row_not_a_crash():
    r = bench_million.run_one("no-such-preset", 24, components=False, max_time=10, timeout=120)
    assert r["status"].startswith("worker failed") and "peak_mb" not in r
    assert bench_million.row(r).startswith("| 24 | no-such-preset | worker failed")
