"""``olado bench`` and ``olado profile`` on the command line: a small run end to end, and bad input
as exit code 2 with a message naming what is wrong (no traceback)."""

import json

import pytest

from olado.cli import main
from fixtures.bench_helpers import IPOPT, SQP, write_suite


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    suite = write_suite(folder, '[[problem]]\nproblem = "lq-box"\nN = [5, 7]\n')
    path = folder / "run.jsonl"
    code = main(["bench", str(suite), "-c", SQP, "-c", f"ip={IPOPT}", "--store", str(path), "--jobs", "2",
                 "--time-limit", "120", "--memory-limit", "none"])
    assert code == 0
    return path


def test_bench_writes_one_record_per_solve(store):
    records = [json.loads(line) for line in store.read_text().splitlines()]
    assert sorted((r["problem"], r["N"], r["config"]) for r in records) == [
        ("lq-box", 5, "ip"), ("lq-box", 5, "sqp-ip"), ("lq-box", 7, "ip"), ("lq-box", 7, "sqp-ip")]
    assert all(r["status"] == "success" for r in records)


def test_rerun_has_nothing_to_do(store, capsys):
    suite = store.parent / "suite.toml"
    code, out, _ = run(capsys, "bench", suite, "-c", SQP, "-c", f"ip={IPOPT}", "--store", store, "--time-limit", 120)
    assert code == 0 and "0 solves run, 4 already in" in out


def test_rerun_with_other_options_is_not_reused(store, capsys, tmp_path):
    """The time limit is the solver's max_time, part of the configuration's hash: another limit is
    another configuration, and the summary says why nothing was reused."""
    import shutil

    copy = tmp_path / "copy.jsonl"
    shutil.copy(store, copy)
    suite = store.parent / "suite.toml"
    code, out, _ = run(capsys, "bench", suite, "-c", SQP, "--store", copy, "--time-limit", 60, "--limit", 0)
    assert code == 0 and "0 solves run, 0 already in" in out
    assert "2 planned solves have records of the same configuration name with another hash" in out


def test_profile_outputs(store, capsys, tmp_path):
    code, out, err = run(capsys, "profile", store, "-m", "time", "-m", "sqp", "--plot", tmp_path / "p.png",
                         "--table", tmp_path / "t.csv", "--where", "N >= 5")
    assert code == 0, err
    assert "4 records, 2 problems x 2 configurations" in out
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert lines[0].startswith("config,solved,time phi(0)") and {l.split(",")[0] for l in lines[1:]} == {"sqp-ip", "ip"}
    code, out, _ = run(capsys, "profile", store, "--per-problem", "--table", "-")
    assert code == 0 and "| lq-box | 5 | problem | success |" in out
    code, out, _ = run(capsys, "profile", store, "--compare", store)
    assert code == 0 and "status regressions (success before, not now): 0" in out


@pytest.mark.parametrize("argv, message", [
    (["profile", "{store}", "--where", "N >"], "key '--where': expected a field"),
    (["profile", "{store}", "--where", "n > 3"], "no record has the field 'n'"),
    (["profile", "{store}", "--where", "N > 1000"], "no records for which 'N > 1000' holds"),
    (["profile", "{store}", "--metric", "speed"], "unknown metric 'speed'"),
    (["profile", "{store}", "--table", "t.txt"], "key '--table': cannot write a .txt table"),
    (["profile", "{store}", "--plot", "p.xyz"], "key '--plot': cannot write a .xyz figure"),
    (["profile", "{store}", "--config", "nosuch"], "no record of the configuration 'nosuch'"),
    (["profile", "nosuch.jsonl"], "nosuch.jsonl: no such results store"),
    (["profile", "{store}", "--compare", "{store}", "--rtol", "-1"], "--rtol must be >= 0"),
    (["bench", "nosuch-suite", "-c", SQP], "unknown suite 'nosuch-suite'"),
    (["bench", "table1"], "no configuration given"),
    (["bench", "table1", "-c", "nosuch.ini"], "configuration file not found"),
    (["bench", "table1", "-c", SQP, "-c", SQP], "two configurations are named 'sqp-ip'"),
    (["bench", "table1", "-c", SQP, "--jobs", "0"], "--jobs must be >= 1"),
    (["bench", "table1", "-c", SQP, "--time-limit", "0"], "--time-limit must be > 0"),
    (["bench", "table1", "-c", SQP, "--memory-limit", "lots"], "not a memory size: 'lots'"),
    (["bench", "{suite}", "-c", SQP], "key 'N': value 0 out of range"),
])
def test_bad_input_is_exit_2(store, capsys, tmp_path, argv, message):
    suite = write_suite(tmp_path, '[[problem]]\nproblem = "lq"\nN = 0\n', name="bad.toml")
    argv = [a.format(store=store, suite=suite) for a in argv]
    code, out, err = run(capsys, *argv)
    assert code == 2 and message in err and "Traceback" not in err, err
