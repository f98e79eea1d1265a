"""benchmarks/_robustness.py: the isolated worker pool (answers, hangs and crashes recorded, the
pool goes on) and the classification of a solve against the IPOPT reference."""

import sys

import pytest

from fixtures import REPO

sys.path.insert(0, str(REPO / "benchmarks"))

import _robustness as R  # noqa: E402
from fixtures import isolated_tasks  # noqa: E402


def test_pool_records_hangs_and_crashes_and_goes_on():
    tasks = [("a", "x"), ("b", "hang"), ("c", "x"), ("d", "crash"), ("e", "x")]
    targets = {"x": isolated_tasks.answer, "hang": isolated_tasks.hang, "crash": isolated_tasks.crash}
    answers = {}
    for config, target in targets.items():
        pool = R.IsolatedPool(jobs=1, time_limit=0.5, target=target, grace=0.5)
        for ans in pool.run([t for t in tasks if t[1] == config]):
            answers[ans["entry"]] = ans
    assert {k: v["status"] for k, v in answers.items()} == {
        "a": "success", "b": "timeout", "c": "success", "d": "crash", "e": "success"}
    assert answers["a"]["time_limit"] == 0.5
    assert "exit code 7" in answers["d"]["message"] and "time limit 0.5 s" in answers["b"]["message"]


def test_pool_replaces_a_dead_worker_and_finishes_the_queue():
    pool = R.IsolatedPool(jobs=2, time_limit=5.0, target=isolated_tasks.crash, grace=1.0)
    answers = list(pool.run([(str(i), "c") for i in range(4)]))
    assert sorted(a["entry"] for a in answers) == ["0", "1", "2", "3"]
    assert all(a["status"] == "crash" for a in answers)


REF = {"status": "success", "objective": 2.0, "verified_violation": 1e-9}


def rec(status="success", objective=2.0, violation=1e-9, kkt=1e-8):
    return {"status": status, "objective": objective, "verified_violation": violation, "verified_kkt_scaled": kkt}


@pytest.mark.parametrize("record,feasible,expected", [
    (rec(objective=2.0 + 1e-7), True, R.SOLVED),
    (rec(status="acceptable", objective=2.0 - 1e-7), True, R.SOLVED),
    (rec(objective=2.1), True, R.OTHER),
    (rec(objective=2.1, kkt=0.5), True, R.FALSE_SUCCESS),          # "success" at a non-stationary point
    (rec(objective=2.0, violation=1e-3), True, R.FALSE_SUCCESS),   # "success" at an infeasible point
    (rec(status="max_iterations"), True, R.FAILED),
    (rec(status="timeout"), True, R.FAILED),
    (rec(status="infeasible"), True, R.INFEASIBLE_WRONG),
    (rec(status="infeasible"), False, R.INFEASIBLE_OK),
    (rec(), False, R.FALSE_SUCCESS),                               # "success" on an infeasible problem
])
def test_classify(record, feasible, expected):
    assert R.classify(record, REF, feasible) == expected


def test_classify_without_a_reference():
    bad_ref = {"status": "max_iterations", "objective": 5.0, "verified_violation": 3.0}
    assert R.classify(rec(), bad_ref, True) == R.UNREFERENCED
    assert R.classify(rec(status="numerical_error"), bad_ref, True) == R.FAILED
    assert R.same_objective(1e-9, 0.0) and not R.same_objective(1e-8, 0.0)   # the 1e-3 floor of the scale
