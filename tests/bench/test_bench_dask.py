"""The same small suite on the local process pool and on a Dask ``distributed.LocalCluster`` with
two workers gives the same statuses and objectives (issue 14, "what it must show"). Skipped when
the optional dependency dask[distributed] is not installed."""

import pytest

import olado.bench as bench
from fixtures.bench_helpers import SQP, by_key, write_suite

distributed = pytest.importorskip("distributed")

SUITE = """
[[problem]]
problem = "lq-box"
N = [6, 9]
seeds = [1]
[[problem]]
problem = "fixtures.bench_problems:raising"
"""


def test_pool_and_dask_give_the_same_records(tmp_path):
    suite = write_suite(tmp_path, SUITE)
    limits = bench.Limits(time_limit=120.0, memory_limit=None)
    pool = bench.run(suite, [SQP], tmp_path / "pool.jsonl", jobs=2, limits=limits, progress=False)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        dask = bench.run(suite, [SQP], tmp_path / "dask.jsonl", dask=cluster.scheduler_address, limits=limits,
                         progress=False)
        workers = {r["machine"]["host"] for r in dask.records}
    finally:
        cluster.close()
    a, b = by_key(pool.records), by_key(dask.records)
    assert len(a) == 5 and set(a) == set(b)
    for key in a:
        assert a[key][0] == b[key][0]
        if a[key][1] is not None:
            assert b[key][1] == pytest.approx(a[key][1], rel=1e-12)
    statuses = sorted(s for s, _ in a.values())
    assert statuses == ["exception"] + ["success"] * 4
    assert workers  # records name the machine that ran them
    assert len(bench.read_records(tmp_path / "dask.jsonl")) == 5


@pytest.mark.slow
def test_dask_local_cluster_by_name(tmp_path):
    suite = write_suite(tmp_path, '[[problem]]\nproblem = "lq"\nN = 5\n')
    report = bench.run(suite, [SQP], tmp_path / "s.jsonl", jobs=2, dask="local",
                       limits=bench.Limits(time_limit=120.0, memory_limit=None), progress=False)
    (rec,) = report.records
    assert rec["status"] == "success"
