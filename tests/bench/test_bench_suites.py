"""Suites as data: the built-in suites' sizes and keys, suite files (TOML) and their errors,
which name the file, the table and the key."""

import pytest

from olado.errors import ConfigError
from olado.problems.suites import load_suite
from fixtures.bench_helpers import write_suite


@pytest.mark.parametrize("name, count", [("zambezi-testset", 244), ("table1", 21), ("unconstrained", 7),
                                         ("robustness", 101)])
def test_builtin_suites(name, count):
    entries = load_suite(name)
    assert len(entries) == count
    assert len({e.key for e in entries}) == count           # every entry has its own key


def test_testset_is_the_papers():
    entries = load_suite("zambezi-testset")
    horizons = {}
    for e in entries:
        horizons.setdefault(e.name, set()).add(e.size)
        assert e.settings["extend"] is None and e.start_label in ("balance", "sif")
    assert horizons["zambezi"] == set(range(12, 421, 12)) and horizons["zambezi11"] == set(range(12, 433, 12))
    assert sum(len(h) for h in horizons.values()) == 122


def test_suite_file_expands(tmp_path):
    path = write_suite(tmp_path, """
[suite]
description = "two problems"
[[problem]]
problem = "lq-box"
name = "box"
N = [4, 8]
seeds = [1, 2]
settings = { umax = 0.5 }
perturbation = { controls = 0.2 }
[[problem]]
problem = "zambezi8"
N = 24
starts = ["sif", "balance"]
""")
    entries = load_suite(path)
    assert [e.key for e in entries] == [("box", 4, "problem"), ("box", 4, "problem-p1"), ("box", 4, "problem-p2"),
                                        ("box", 8, "problem"), ("box", 8, "problem-p1"), ("box", 8, "problem-p2"),
                                        ("zambezi8", 24, "sif"), ("zambezi8", 24, "balance")]
    assert entries[1].settings == {"umax": 0.5, "N": 4} and entries[1].perturbation == {"controls": 0.2}
    problem, (X, U) = entries[1].build()
    assert problem.N == 4 and abs(U).max() <= 0.5


@pytest.mark.parametrize("text, message", [
    ('[[problem]]\nproblem = "lq"\nsize = 3\n', "section [problem #1], key 'size': unknown key"),
    ('[[problem]]\nproblem = "nosuch"\n', "section [problem #1], key 'problem': suite entry 'nosuch' names the "
                                          "unknown problem 'nosuch'"),
    ('[[problem]]\nproblem = "lq"\n[[problem]]\nproblem = "lq"\nN = "ten"\n',
     "section [problem #2], key 'N': expected int or a list of them, got 'ten'"),
    ('[[problem]]\nproblem = "lq"\nN = [10, 0]\n', "key 'N': value 0 out of range (allowed: >= 1)"),
    ('[[problem]]\nproblem = "rayleigh-mixed"\nsettings = { umax = 1 }\n', "key 'settings.umax': the problem factory takes no "
                                                              "setting 'umax'"),
    ('[[problem]]\nproblem = "rayleigh-mixed"\nstarts = ["sif"]\n', "key 'starts': the problem factory takes no setting 'start'"),
    ('[[problem]]\nproblem = "lq"\nN = 5\n[[problem]]\nproblem = "lq"\nN = [5]\n',
     "section [problem #2], key 'name': problem 'lq' N=5 start 'problem' appears twice (also in [problem #1])"),
    ('[[problem]]\nproblem = "fixtures.nosuch:make"\n', "key 'problem': suite entry 'fixtures.nosuch:make': cannot "
                                                       "import the problem factory"),
    ('[[problem]]\nname = "x"\n', "section [problem #1], key 'problem': missing or empty"),
    ('[[problem]]\nproblem = "lq"\nperturbation = { scale = 1 }\n', "key 'perturbation'"),
    ('[suite]\ntitle = "x"\n[[problem]]\nproblem = "lq"\n', "section [suite], key 'title': unknown key"),
    ('[extra]\n', "section [extra]: unknown table"),
    ('[suite]\n', "no [[problem]] tables"),
    ('[[problem]\nproblem = "lq"\n', "not a valid TOML file"),
])
def test_bad_suite_files_name_file_and_key(tmp_path, text, message):
    path = write_suite(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_suite(path)
    assert str(info.value).startswith(f"file {path}") and message in str(info.value), str(info.value)


def test_missing_suite_file(tmp_path):
    with pytest.raises(ConfigError, match="suite file not found"):
        load_suite(tmp_path / "nothing.toml")
