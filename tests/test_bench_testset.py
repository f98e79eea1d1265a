"""benchmarks/bench_testset.py: the summary figures from hand-made runs (time ratios per size
class, other local minima, failures) and the section of a non-default choice of configs."""

import sys

import pytest

from fixtures import REPO

sys.path.insert(0, str(REPO / "benchmarks"))

import bench_testset as B  # noqa: E402


def rec(status, objective, time_s, iterations, qp_iterations=0):
    return dict(status=status, objective=objective, time_s=time_s, iterations=iterations, qp_iterations=qp_iterations)


def runs():
    # reference "a", "b" twice a's time below N = 216 and 8 times above, "c" fails once
    return [{"problem": ["zambezi12", 12, "balance"], "a": rec("success", -1.0, 1.0, 4, 40),
             "b": rec("success", -1.0, 2.0, 8, 400), "c": rec("success", -1.0, 0.5, 20)},
            {"problem": ["zambezi12", 24, "sif"], "a": rec("success", -2.0, 2.0, 5, 50),
             "b": rec("success", -2.002, 4.0, 9, 900), "c": rec("max_iterations", -2.0, 9.0, 200)},
            {"problem": ["zambezi", 216, "balance"], "a": rec("success", -3.0, 1.0, 6, 60),
             "b": rec("success", -3.0, 8.0, 12, 1200), "c": rec("success", -3.0, 1.0, 30)},
            {"problem": ["zambezi", 240, "sif"], "a": rec("success", -4.0, 3.0, 7, 70),
             "b": rec("success", -3.992, 24.0, 14, 1400), "c": rec("success", -4.0, 6.0, 40)}]


def test_time_ratios_per_size_class_against_the_reference_and_a_comparator():
    t = B.Table(runs(), ["a", "b", "c"])
    rows = {r["config"]: r for r in B.ratio_rows(t, ["a", "c"], 216)}
    (all_, small, large), total = rows["b"]["a"]
    assert (all_[0], small[0], large[0]) == (5.0, 2.0, 8.0) and (all_[1], small[1], large[1]) == (4, 2, 2)
    assert total == pytest.approx(38.0 / 7.0)
    (all_, small, large), total = rows["b"]["c"]             # c did not solve N = 24
    assert (all_[0], small[0], large[0]) == (4.0, 4.0, 6.0) and all_[1] == 3
    assert total == pytest.approx(34.0 / 7.5)


def test_summary_other_minima_and_failures():
    t = B.Table(runs(), ["a", "b", "c"])
    rows = {r["config"]: r for r in B.summary_rows(t)}
    assert rows["b"]["solved"] == 4 and rows["b"]["same"] == 2 and rows["b"]["lower"] == 1 and rows["b"]["higher"] == 1
    assert rows["b"]["iters"] == (8, 10, 14, 43) and rows["b"]["qp"] == (1050, 3900)
    assert rows["c"]["solved"] == 3 and rows["c"]["total"] == pytest.approx(7.5)
    lower, higher, text = B.other_minima(t, 1)
    assert (lower, higher) == (1, 1)
    assert text == "zambezi 240 sif +2.0e-03, zambezi12 24 sif -1.0e-03"          # the largest first
    assert B.failure_lines(t) == ["- c: max_iterations: 1 (zambezi12 24 sif)"]


def test_report_names_its_section_command_and_classes():
    meta = dict(section="Zambezi testing set: a, b, c", plot="x/testset_profile_a_b_c.png", configs=["a", "b", "c"],
                versus=["c"], split=216, families=["zambezi", "zambezi12"], starts=["balance", "sif"], repeats=1,
                command="python benchmarks/bench_testset.py --configs a b c", date="2026-11-25", commit="abc",
                machine="m")
    text = B.report(runs(), meta)
    assert text.startswith("## Zambezi testing set: a, b, c\n")
    assert "N < 216 (2 problems) and N >= 216 (2)" in text
    assert "| b | 5.00 | 2.00 | 8.00 | 5.43 | 4.00 | 4.00 | 6.00 | 4.53 |" in text
    assert "- c: max_iterations: 1 (zambezi12 24 sif)" in text


def test_the_command_leaves_out_bookkeeping_options_and_quotes_an_apostrophe():
    assert B.command_args(["--configs", "a", "--save-runs", "r.json", "--no-write", "--from-runs=x"]) == ["--configs", "a"]
    assert B.quote("Schittkowski's SQP") == '"Schittkowski\'s SQP"' and B.quote("a b") == "'a b'"
