"""The runner goes on through a hanging, a raising, a dying and a memory-hungry solve (issue 14,
"what it must show"): the hanging one is killed at its time limit and recorded as a timeout, the
raising one recorded with its message, the dying one as a crash, the hungry one stopped by the
memory guard; the good solve is recorded as usual."""

import pytest

import olado.bench as bench
from fixtures.bench_helpers import SQP, write_suite

SUITE = """
[[problem]]
problem = "lq"
N = 8
[[problem]]
problem = "fixtures.bench_problems:raising"
[[problem]]
problem = "fixtures.bench_problems:hanging"
[[problem]]
problem = "fixtures.bench_problems:dying"
[[problem]]
problem = "fixtures.bench_problems:hungry"
"""


@pytest.fixture(scope="module")
def run_records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("isolation")
    suite = write_suite(folder, SUITE)
    limits = bench.Limits(time_limit=6.0, grace=1.0, memory_limit=3 * 2**30, warmup=False)
    report = bench.run(suite, [SQP], folder / "store.jsonl", jobs=2, limits=limits, progress=False)
    return {r["problem"].rsplit(":", 1)[-1]: r for r in report.records}, report, folder


def test_every_solve_is_recorded(run_records):
    records, report, folder = run_records
    assert sorted(records) == ["dying", "hanging", "hungry", "lq", "raising"]
    assert len(bench.read_records(folder / "store.jsonl")) == 5
    assert "1 solved, 4 failed" in report.summary()


def test_hang_is_killed_at_its_time_limit(run_records):
    rec = run_records[0]["hanging"]
    assert rec["status"] == "timeout" and rec["success"] is False
    assert "time limit 6 s + 1 s grace" in rec["message"]
    assert 7.0 <= rec["wall_s"] < 60.0           # killed after limit + grace, not after the hour it sleeps


def test_exception_is_recorded_with_its_message(run_records):
    rec = run_records[0]["raising"]
    assert rec["status"] == "exception"
    assert rec["message"] == "RuntimeError: boom from the test problem"
    assert "eval_stage_cost_gradients" in rec["traceback"]


def test_dying_worker_is_a_crash(run_records):
    rec = run_records[0]["dying"]
    assert rec["status"] == "crash" and "killed by signal 9" in rec["message"]


def test_memory_guard(run_records):
    """The worker's address space is limited (3 GiB here): an 8 GiB allocation fails in the worker."""
    rec = run_records[0]["hungry"]
    assert rec["status"] == "memory_limit" and rec["message"].startswith("MemoryError")


def test_good_solve_after_the_failures(run_records):
    rec = run_records[0]["lq"]
    assert rec["status"] == "success" and rec["certificate"] == "success"
    assert rec["objective"] == pytest.approx(lq_optimum(8), rel=1e-8)
    assert rec["sqp_iterations"] >= 1 and rec["qp_iterations"] >= 1 and rec["function_evaluations"] >= 1
    for field in ("olado_version", "commit", "machine", "config_hash", "time_limit", "solve_s"):
        assert rec[field] is not None
    assert rec["time_limit"] == 6.0


def lq_optimum(N):
    """The exact optimum of the (unconstrained) LQ test problem: J(U) is quadratic in the controls,
    so its gradient and Hessian from central differences are exact up to rounding, and the minimum
    is one dense linear solve."""
    import numpy as np
    from olado.problems.testproblems import LinearQuadratic

    p = LinearQuadratic(N=N)
    m = p.m

    def cost(U):
        X = p.simulate(U)
        return float(np.sum(p.eval_stage_costs(X, U)) + p.eval_final_cost(X[-1]))
    dim = N * m
    c0 = cost(np.zeros((N, m)))
    H, g = np.zeros((dim, dim)), np.zeros(dim)
    E = np.eye(dim)
    for i in range(dim):
        ei = E[i].reshape(N, m)
        g[i] = (cost(ei) - cost(-ei)) / 2.0
        for j in range(dim):
            ej = E[j].reshape(N, m)
            H[i, j] = (cost(ei + ej) - cost(ei) - cost(ej) + c0)
    u = np.linalg.solve(H, -g)
    return c0 + g @ u + 0.5 * u @ H @ u
