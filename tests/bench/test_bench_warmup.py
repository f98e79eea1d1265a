"""The warm-up of ``olado bench`` (docs/benchmarking.md, "Isolation"): a worker solves each
(configuration, problem family) once unmeasured before its first measured solve of that family
-- every family, not only the run's first problem -- on the family's smallest horizon in the
suite (cheap), and every record says whether its solve ran warm."""

import pytest

import olado.bench as bench
from fixtures.bench_helpers import SQP, write_suite
from olado.bench.records import family, warmup_entries
from olado.bench.runner import load_bench_configs, plan, select_entries
from olado.problems.suites import load_suite

DELAY = 1.0
# two families; the first build of once_slow_lq in a process sleeps DELAY s (a compilation)
SUITE = f"""
[[problem]]
problem = "fixtures.bench_problems:once_slow_lq"
name = "once-slow"
N = [3, 5, 7]
settings = {{ delay = {DELAY} }}

[[problem]]
problem = "lq-box"
N = [3, 5, 7]
"""


def test_families_and_their_warm_up_entries_of_the_testing_set():
    entries = load_suite("zambezi-testset")
    warm = warmup_entries(entries)
    fams = ["zambezi", "zambezi10", "zambezi11", "zambezi12", "zambezi8", "zambezi9"]
    assert sorted(f[0] for f in warm) == sorted(fams * 2)                # each from two starts
    assert sorted((e.problem, e.size, e.start_label) for e in warm.values()) == [
        (f, 12, s) for f in fams for s in ("balance", "sif")]
    assert all(family(e) == f for f, e in warm.items())
    # a run of the large horizons only still warms up on N = 12
    configs = load_bench_configs([SQP], 60.0)
    tasks = plan(select_entries(entries, "N >= 216"), configs, "zambezi-testset", entries)
    assert {t.warmup_entry.size for t in tasks} == {12}
    assert {t.warmup_entry.problem for t in tasks} == {t.entry.problem for t in tasks} == {"zambezi", "zambezi8",
                                                                                         "zambezi11", "zambezi12"}
    # another start or another setting is another family; another horizon or a perturbed start is not
    e0 = entries[0]
    assert (e0.problem, e0.size, e0.start_label) == ("zambezi", 12, "balance")
    same = dict(e0.__dict__)
    assert family(type(e0)(**{**same, "settings": {**e0.settings, "N": 420}})) == family(e0)
    assert family(type(e0)(**{**same, "start": "perturbed", "seed": 3})) == family(e0)
    assert family(type(e0)(**{**same, "settings": {**e0.settings, "start": "sif"}})) != family(e0)
    assert family(type(e0)(**{**same, "settings": {**e0.settings, "extend": "cyclic"}})) != family(e0)
    # the robustness set's perturbed starts warm up from the unperturbed entry
    robust = load_suite("robustness")
    assert all(e.start == "problem" for e in warmup_entries(robust).values())


def _run(tmp_path, name, warmup):
    suite = write_suite(tmp_path, SUITE)
    report = bench.run(suite, [SQP], tmp_path / f"{name}.jsonl", jobs=1, where="N >= 5", progress=False,
                       limits=bench.Limits(time_limit=120.0, warmup=warmup))
    return report.records


@pytest.fixture(scope="module")
def warm_and_cold(tmp_path_factory):
    folder = tmp_path_factory.mktemp("warmup")
    return _run(folder, "warm", True), _run(folder, "cold", False)


def test_every_family_is_warmed_up_once_per_worker_on_its_smallest_horizon(warm_and_cold):
    records, _ = warm_and_cold
    assert [(r["problem"], r["N"]) for r in records] == [("once-slow", 5), ("once-slow", 7), ("lq-box", 5),
                                                         ("lq-box", 7)]     # one worker: the plan's order
    assert all(r["success"] for r in records)
    # every measured solve ran warm; the first of each family after a warm-up on N = 3 (not in the run)
    assert [r["warm"] for r in records] == [True] * 4
    assert [r["warmup_N"] for r in records] == [3, None, 3, None]
    assert [r["warmup_s"] is not None for r in records] == [True, False, True, False]
    # the first build's extra cost (the "compilation") fell into the warm-up, not into a measured solve
    assert records[0]["warmup_s"] >= DELAY


def test_without_warm_up_the_record_says_the_first_solve_of_each_family_ran_cold(warm_and_cold):
    _, records = warm_and_cold
    assert [r["warm"] for r in records] == [False, True, False, True]
    assert all(r["warmup_s"] is None and r["warmup_N"] is None for r in records)
    assert records[0]["build_s"] >= DELAY         # the cold first build was measured
