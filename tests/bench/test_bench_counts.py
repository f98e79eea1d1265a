"""The counts a bench record carries are the solvers' own: QP iterations of an SQP whose QPs
Clarabel solves (configs/sqp-clarabel.ini) are the sum of Clarabel's own iteration counts over
every QP of the run -- not 0, which qpsolvers' interface used to leave -- in the Result and in
the record ``olado bench`` stores."""

import pytest

from fixtures import CONFIGS
from fixtures.clarabel_spy import spy_on_clarabel
from olado.bench.records import Task, make_record, solve_case
from olado.bench.runner import load_bench_configs, select_entries
from olado.problems.suites import load_suite


def _entry(problem="zambezi12", N=12, start="balance"):
    entries = select_entries(load_suite("zambezi-testset"), f"problem == '{problem}' and N == {N} and "
                                                              f"start == '{start}'")
    assert len(entries) == 1
    return entries[0]


def test_clarabel_qp_iterations_reach_the_result_and_the_record(monkeypatch):
    pytest.importorskip("qpsolvers")
    counts = spy_on_clarabel(monkeypatch)
    config, = load_bench_configs([str(CONFIGS / "sqp-clarabel.ini")], 120.0)
    task = Task(entry=_entry(), config=config, suite="zambezi-testset", warmup=False)
    record = make_record(task, solve_case(task))
    assert record["success"], record["message"]
    assert record["qp_iterations"] > 0 and record["qp_iterations"] == sum(counts)
    # one Clarabel solve per SQP iteration at least (the QP of each step)
    assert len(counts) >= record["sqp_iterations"] and min(counts) > 0
