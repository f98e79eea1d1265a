"""benchmarks/paper.py: every experiment of paper 001 (Table 1, Figs. 4-8) resolves -- its suite,
its configuration files, its subset -- and the composition of ``olado bench`` and ``olado profile``
runs end to end on a couple of problems, writing a section with the stored numbers and the
paper's; ``olado bench --where`` selects suite entries."""

import json
import sys

import pytest

from fixtures import REPO

sys.path.insert(0, str(REPO / "benchmarks"))

import paper as P  # noqa: E402

from olado.bench.profiles import METRICS  # noqa: E402
from olado.bench.runner import entry_fields, select_entries  # noqa: E402
from olado.bench.where import Where  # noqa: E402
from olado.config import load_config  # noqa: E402
from olado.errors import ConfigError  # noqa: E402
from olado.problems.suites import load_suite  # noqa: E402


def test_the_paper_experiments_are_all_there():
    assert list(P.EXPERIMENTS) == ["table1", "fig4", "fig5", "fig6", "fig7", "fig8"]


@pytest.mark.parametrize("key", list(P.EXPERIMENTS))
def test_experiment_resolves(key):
    exp = P.EXPERIMENTS[key]
    entries = load_suite(exp.suite)
    assert entries
    for name, path in exp.configs:
        assert (REPO / path).is_file() and load_config(REPO / path).solver in ("sqp", "ipopt")
        assert path == f"configs/{name}.ini"
    assert len(set(exp.names)) == len(exp.names)
    assert all(m in METRICS for m in exp.metrics)
    mapped = {olado for _, olado, _ in exp.mapping if olado}
    assert mapped == set(exp.names)                     # every config is a paper configuration's stand-in
    papers = {paper for paper, _, _ in exp.mapping}
    assert all(c[0] in papers and c[2] in P._QUANTITY and 0 <= c[3] <= 1 for c in exp.claims)
    if exp.where:
        assert select_entries(entries, exp.where)


def test_figure_8_is_the_papers_84_problems_with_n_at_least_216():
    entries = select_entries(load_suite("zambezi-testset"), P.EXPERIMENTS["fig8"].where)
    assert len(entries) == 84 and min(e.size for e in entries) == 216
    assert len(load_suite("zambezi-testset")) == 244


def test_bench_where_selects_entries_and_refuses_nonsense():
    entries = load_suite("zambezi-testset")
    small = select_entries(entries, "N <= 24 and problem == 'zambezi12' and start == 'sif'")
    assert [e.key for e in small] == [("zambezi12", 12, "sif"), ("zambezi12", 24, "sif")]
    assert entry_fields(small[0])["settings"]["extend"] is None
    assert select_entries(entries, None) == entries
    with pytest.raises(ConfigError, match="no record has the field 'n'"):
        select_entries(entries, "n <= 24")
    with pytest.raises(ConfigError, match="no entry of the suite"):
        select_entries(entries, "N < 0")
    with pytest.raises(ConfigError):
        Where("N <=")


def test_combined_where():
    assert P.combined_where(None, None) is None
    assert P.combined_where("N >= 216", None) == "N >= 216"
    assert P.combined_where("N >= 216", "start == 'sif'") == "(N >= 216) and (start == 'sif')"


def _records(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def table1_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("paper")
    results = folder / "RESULTS.md"
    results.write_text("# results\n\n## Another section\n\nkept\n")
    assert P.main(["table1", "--where", "N <= 24", "--store-dir", str(folder), "--results", str(results),
                   "--quiet"]) == 0
    return folder, results


def test_table1_composition_end_to_end(table1_run):
    folder, results = table1_run
    records = _records(folder / "table1.jsonl")
    assert sorted((r["N"], r["config"]) for r in records) == [
        (12, "ipopt"), (12, "sqp-as"), (12, "sqp-ip"), (24, "ipopt"), (24, "sqp-as"), (24, "sqp-ip")]
    assert all(r["success"] for r in records)
    text = results.read_text()
    assert "## Another section\n\nkept" in text
    assert text.count("## Paper 001 Table 1") == 1
    assert "python benchmarks/paper.py table1 --where 'N <= 24'" in text
    assert "measured on a loaded machine" in text
    by = {(r["N"], r["config"]): r for r in records}
    for N, (n, me, m) in ((12, (162, 78, 272)), (24, (318, 150, 536))):
        ip, act = by[N, "sqp-ip"], by[N, "sqp-as"]
        row = (f"| {N} | {n} | {me} | {m} | {ip['sqp_iterations']} / {ip['qp_iterations']} / {ip['solve_s']:.3f} | "
               f"{act['sqp_iterations']} / {act['qp_iterations']} / {act['solve_s']:.3f} | "
               f"{by[N, 'ipopt']['sqp_iterations']} / - / ")
        assert row in text
    assert "| 3 / 65 / 0.06 | 7 / 87 / 0.03 | 19 / 0.15 |" in text       # the paper's N = 12
    assert "| sqp-ip | 2 / 2 |" in text


def test_rewriting_from_the_store_keeps_one_section(table1_run):
    folder, results = table1_run
    before = results.read_text()
    assert P.main(["table1", "--where", "N <= 24", "--store-dir", str(folder), "--results", str(results),
                   "--no-run"]) == 0
    after = results.read_text()
    assert after.count("## Paper 001 Table 1") == 1 and len(after.splitlines()) == len(before.splitlines())


def test_figure_composition_end_to_end(tmp_path):
    results = tmp_path / "RESULTS.md"
    where = "problem == 'zambezi12' and N <= 24 and start == 'balance'"
    assert P.main(["fig4", "--where", where, "--store-dir", str(tmp_path), "--plot-dir", str(tmp_path),
                   "--results", str(results), "--quiet"]) == 0
    records = _records(tmp_path / "zambezi-testset.jsonl")
    assert len(records) == 6 and all(r["success"] for r in records)
    # the KKT back-ends solve the same QPs: the same iterations (paper 001 on Fig. 4)
    its = {(r["N"], r["config"]): (r["sqp_iterations"], r["qp_iterations"]) for r in records}
    assert its[12, "sqp-ip"] == its[12, "sqp-superlu"] == its[12, "sqp-superlu-full"]
    assert (tmp_path / "paper_fig4.png").stat().st_size > 10_000
    text = results.read_text()
    assert "| MA27, MA47 (HSL) | **not in olado** (slot) |" in text
    assert "| LQ-DOCP | sqp-ip | time | phi(0), share of wins | 0.98 |" in text
    assert "profiled: 2 problems (zambezi12; N = 12..24; starts balance)" in text


def test_bench_command_line_where(tmp_path, capsys):
    from olado.cli import main

    code = main(["bench", "table1", "-c", str(REPO / "configs/sqp-ip.ini"), "--store", str(tmp_path / "s.jsonl"),
                 "--where", "N < 0", "--quiet"])
    assert code == 2 and "no entry of the suite for which 'N < 0' holds" in capsys.readouterr().err
    assert not (tmp_path / "s.jsonl").exists() or not (tmp_path / "s.jsonl").read_text()


def test_a_configuration_without_counts_is_left_out_of_that_profile():
    # IPOPT has no QP iterations (0 in its records): floored to 1 it would win every QP profile
    recs = [dict(config=c, problem="p", N=N, start="s", success=True, solve_s=t, sqp_iterations=it, qp_iterations=qp)
            for c, N, t, it, qp in (("a", 1, 1.0, 5, 50), ("b", 1, 2.0, 9, 0), ("a", 2, 3.0, 6, 60), ("b", 2, 1.0, 4, 0))]
    assert P.counted(recs, ["a", "b"], "qp") == ["a"] and P.counted(recs, ["a", "b"], "sqp") == ["a", "b"]
    exp = P.EXPERIMENTS["table1"]
    profiles = [P.bench.performance_profile(recs, m, configs=P.counted(recs, ["a", "b"], m)) for m in ("sqp", "qp")]
    assert P.left_out(dataclasses_replace(exp, ["a", "b"]), profiles) == [
        "Left out of the QP iterations profile: b (no record with a count)."]
    header, rows = P.summary_table(recs, profiles, ["a", "b"])
    assert rows[0][2:8] == ["0.50", "1.00", "1.00", "1.00", "1.00", "1.00"]   # a: sqp wins 1 of 2; qp alone
    assert rows[1][2:8] == ["0.50", "1.00", "1.00", "", "", ""]


def dataclasses_replace(exp, names):
    import dataclasses

    return dataclasses.replace(exp, configs=tuple((n, f"configs/{n}.ini") for n in names))


# ---------------------------------------------------------------------------- parallel efficiency
def test_the_parallel_experiment_is_the_testing_set_with_the_four_fast_configurations():
    assert P.PARALLEL.suite == "zambezi-testset" and P.PARALLEL.names == ["sqp-ip", "sqp-schittkowski", "sqp-gondzio",
                                                                          "ipopt"]
    assert all((REPO / path).is_file() for _, path in P.PARALLEL.configs)
    assert "sqp-as" in P.PARALLEL_WHY_NOT and "parallel" not in P.EXPERIMENTS   # not in "all"


def _fake(config, N, status, objective, iterations=5):
    return dict(problem="zambezi12", N=N, start="sif", config=config, status=status, objective=objective,
                sqp_iterations=iterations)


def test_same_results_counts_and_names_the_differences():
    one = [_fake("a", 12, "success", 1.0), _fake("a", 24, "success", 2.0), _fake("b", 12, "success", 3.0),
           _fake("b", 24, "max_time", None), _fake("b", 36, "success", 1.0)]
    two = [_fake("a", 12, "success", 1.0), _fake("a", 24, "success", 2.0 * (1 + 1e-9), 6),
           _fake("b", 12, "success", 3.1), _fake("b", 24, "success", 4.0)]
    check = P.same_results(one, two)
    assert (check["common"], check["only_one"], check["status"], check["objective"], check["identical"],
            check["iterations"]) == (4, 1, 3, 2, 1, 3)
    assert check["differ"] == ["b on zambezi12 N = 12 sif: success 3.0 against success 3.1",
                               "b on zambezi12 N = 24 sif: max_time None against success 4.0"]


def test_parallel_table_speed_up_and_efficiency():
    runs = [dict(jobs=1, wall_s=10.0, solves=8, solver_s=6.0, warmups=4, warmup_s=1.0, load_start="0.1",
                 load_end="1.0"),
            dict(jobs=2, wall_s=6.25, solves=8, solver_s=7.0, warmups=8, warmup_s=2.0, load_start="1.0",
                 load_end="2.0")]
    rows = P.parallel_table(runs)
    assert rows[2] == "| 1 | 10.0 | 8 | 6.0 | 4, 1.0 | 0.1 / 1.0 | 1.00 | 1.00 |"
    assert rows[3] == "| 2 | 6.2 | 8 | 7.0 | 8, 2.0 | 1.0 / 2.0 | 1.60 | 0.80 |"      # T1 / (2 T2) = 10 / 12.5


@pytest.fixture(scope="module")
def parallel_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("parallel")
    results = folder / "RESULTS.md"
    # a store left by an earlier run: moved aside, not resumed (every solve of the run is timed)
    stale = dict(_fake("sqp-ip", 12, "stale", 0.0), start="balance", schema=1,
                 config_hash=P.bench.load_bench_configs([f"sqp-ip={REPO / 'configs/sqp-ip.ini'}"], 300.0)[0].hash)
    (folder / "parallel-jobs1.jsonl").write_text(json.dumps(stale) + "\n")
    where = "problem == 'zambezi12' and N == 12"
    assert P.main(["parallel", "--where", where, "--store-dir", str(folder), "--plot-dir", str(folder),
                   "--results", str(results), "--quiet"]) == 0
    return folder, results, where


def test_parallel_runs_both_and_writes_the_efficiency(parallel_run):
    folder, results, where = parallel_run
    one, two = _records(folder / "parallel-jobs1.jsonl"), _records(folder / "parallel-jobs2.jsonl")
    assert _records(folder / "parallel-jobs1.jsonl.previous")[0]["status"] == "stale"
    keys = sorted((r["start"], r["config"]) for r in one)
    assert keys == sorted((s, c) for s in ("balance", "sif") for c in P.PARALLEL.names)
    assert sorted((r["start"], r["config"]) for r in two) == keys
    assert all(r["success"] and r["warm"] for r in one + two)
    log = json.loads((folder / "parallel.json").read_text())["runs"]
    assert [r["jobs"] for r in log] == [1, 2] and all(r["wall_s"] > 0 and r["where"] == where for r in log)
    t1, t2 = log[0]["wall_s"], log[1]["wall_s"]
    text = results.read_text()
    assert text.count("## " + P.PARALLEL_SECTION) == 1
    assert "Command: `python benchmarks/paper.py parallel --where" in text
    assert f"| 2 | {t2:.1f} | 8 | " in text and f" | {t1 / t2:.2f} | {t1 / (2 * t2):.2f} |" in text
    assert "of the 8 solves in both runs, 8 have the same status, 8 the same objective" in text
    assert "sqp-as is left out" in text and "Left out of the QP iterations profile: ipopt" in text
    assert (folder / "paper_parallel.png").stat().st_size > 10_000


def test_parallel_section_rewritten_from_the_stores(parallel_run):
    folder, results, _ = parallel_run
    before = results.read_text()
    assert P.main(["parallel", "--store-dir", str(folder), "--plot-dir", str(folder), "--results", str(results),
                   "--no-run", "--no-plot"]) == 0
    after = results.read_text()
    assert after.count("## " + P.PARALLEL_SECTION) == 1 and len(after.splitlines()) == len(before.splitlines())
