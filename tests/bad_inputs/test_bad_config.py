"""Bad-input catalogue, part 1: configuration files, overrides and keyword options.

Every case is a ConfigError (docs/errors.md) whose message names the file (or ``<overrides>``),
the section and the key, with the allowed values where they are known."""

import pytest

import olado
from olado.config import SolverConfig, config_from_kwargs, load_config
from olado.errors import ConfigError
from fixtures.bad_problems import Walk, expect

BIG = "99999999999999999999"

# (id, ini text, words the message must contain besides the file name)
INI_CASES = [
    ("unknown-section", "[solver]\nname = ipopt\n[ipopt_typo]\ntol = 1\n",
     ["[ipopt_typo]", "unknown section", "[ipopt]"]),
    ("unknown-key", "[solver]\nname = ipopt\n[ipopt]\ntoll = 1e-6\n", ["[ipopt]", "'toll'", "unknown option", "tol"]),
    ("int-not-a-number", "[solver]\nname = ipopt\n[ipopt]\nmax_iter = many\n", ["'max_iter'", "integer", "'many'"]),
    ("int-overflow", f"[solver]\nname = ipopt\n[ipopt]\nmax_iter = {BIG}\n",
     ["[ipopt]", "'max_iter'", "out of range", "2147483647"]),
    ("int-fraction", "[solver]\nname = ipopt\n[ipopt]\nmax_iter = 1.5\n", ["'max_iter'", "integer"]),
    ("float-text", "[solver]\nname = ipopt\n[ipopt]\ntol = abc\n", ["'tol'", "number", "'abc'"]),
    ("float-nan", "[solver]\nname = ipopt\n[ipopt]\ntol = nan\n", ["'tol'", "NaN"]),
    ("float-negative", "[solver]\nname = ipopt\n[ipopt]\ntol = -1e-8\n", ["'tol'", "out of range", "> 0.0"]),
    ("float-zero-exclusive", "[solver]\nname = ipopt\n[ipopt]\ntol = 0\n", ["'tol'", "out of range"]),
    ("above-max", "[solver]\nname = ipopt\n[ipopt]\nverbose = 99\n", ["'verbose'", "out of range", "<= 12"]),
    ("bad-choice", "[solver]\nname = ipopt\n[ipopt]\nmu_strategy = fast\n", ["'mu_strategy'", "'fast'", "adaptive"]),
    ("bad-bool", "[solver]\nname = sqp\n[sqp]\nwatchdog = maybe\n", ["[sqp]", "'watchdog'", "boolean", "yes"]),
    ("bad-qp-method", "[solver]\nname = sqp\n[sqp]\nqp = nosuch\n", ["[sqp]", "'qp'", "mehrotra"]),
    ("unknown-solver", "[solver]\nname = nope\n", ["[solver]", "'name'", "unknown solver 'nope'", "ipopt"]),
    ("solver-extra-key", "[solver]\nname = ipopt\nspeed = max\n", ["[solver]", "'speed'", "unknown key"]),
    ("duplicate-key", "[solver]\nname = ipopt\n[ipopt]\ntol = 1\ntol = 2\n", ["[ipopt]", "'tol'", "appears twice"]),
    ("duplicate-section", "[solver]\nname = ipopt\n[ipopt]\n[ipopt]\n", ["[ipopt]", "appears twice"]),
    ("key-before-section", "tol = 1\n[solver]\nname = ipopt\n", ["line 1", "before any [section]"]),
    ("default-section", "[DEFAULT]\ntol = 1\n[solver]\nname = ipopt\n", ["[DEFAULT]", "not supported"]),
    ("not-ini", "[solver]\nname = ipopt\njust some words\n", ["not a valid ini file"]),
    ("problem-N-zero", "[solver]\nname = ipopt\n[problem]\nN = 0\n", ["[problem]", "'N'", "out of range", ">= 1"]),
    ("problem-N-text", "[solver]\nname = ipopt\n[problem]\nN = twelve\n", ["[problem]", "'N'", "integer"]),
    ("problem-N-fraction", "[solver]\nname = ipopt\n[problem]\nN = 1.5\n", ["[problem]", "'N'", "integer"]),
    ("problem-unknown-key", "[solver]\nname = ipopt\n[problem]\nhorizon = 12\n",
     ["[problem]", "'horizon'", "unknown key", "name, N, start, year"]),
    ("raw-for-solver-without", "[solver]\nname = slsqp\n[slsqp.raw]\nfoo = 1\n",
     ["[slsqp.raw]", "takes no pass-through options"]),
    ("callable-from-file", "[solver]\nname = ipopt\n[ipopt]\ncallback = print\n", ["'callback'", "cannot be set from a file"]),
    ("mapping-as-value", "[solver]\nname = ipopt\n[ipopt]\nipopt_options = x\n", ["'ipopt_options'", "[ipopt.raw]"]),
    ("other-solvers-section", "[solver]\nname = slsqp\n[slsqp]\nmax_iter = 7\n[ipopt]\nmu_strategy = fast\n",
     ["[ipopt]", "'mu_strategy'"]),
    ("raw-int-overflow-sqp", f"[solver]\nname = sqp\n[sqp]\nqp = osqp\nhessian = sr1\n[sqp.raw]\nmax_iter = {BIG}\n",
     ["[sqp.raw", "'max_iter'", "out of range"]),
]


@pytest.mark.parametrize("case_id,text,names", INI_CASES, ids=[c[0] for c in INI_CASES])
def test_bad_ini_file(tmp_path, case_id, text, names):
    path = tmp_path / f"{case_id}.ini"
    path.write_text(text)
    if case_id == "raw-int-overflow-sqp":
        # the raw section is validated by the QP back-end's options when the SQP is set up
        from fixtures.bad_problems import ConstrainedWalk

        cfg = load_config(path)
        expect(ConfigError, names, olado.solve, ConstrainedWalk(), config=cfg)
        return
    expect(ConfigError, [str(path), *names], load_config, path)


def test_missing_config_file(tmp_path):
    expect(ConfigError, [str(tmp_path / "none.ini"), "not found"], load_config, tmp_path / "none.ini")


@pytest.mark.parametrize("path", [42, ["a.ini"]], ids=["int", "list"])
def test_config_path_of_the_wrong_type(path):
    expect(ConfigError, ["expected a file path", type(path).__name__], load_config, path)


def test_config_path_is_a_folder(tmp_path):
    expect(ConfigError, [str(tmp_path), "directory"], load_config, tmp_path)


def test_config_file_not_text(tmp_path):
    path = tmp_path / "binary.ini"
    path.write_bytes(b"[solver]\nname = \xff\xfe\n")
    expect(ConfigError, [str(path), "cannot read"], load_config, path)


# ---------------------------------------------------------------------------- overrides (--set)
OVERRIDE_CASES = [
    ("no-equals", ["tol"], ["<overrides>", "section.key=value"]),
    ("no-key", ["=3"], ["<overrides>", "has no key"]),
    ("unknown-section", ["nosection.key=1"], ["<overrides>", "[nosection]", "unknown section"]),
    ("int-overflow", [f"ipopt.max_iter={BIG}"], ["<overrides>", "[ipopt]", "'max_iter'", "out of range"]),
    ("bad-type", ["ipopt.max_iter=1.5"], ["<overrides>", "[ipopt]", "'max_iter'", "1.5"]),
    ("unknown-solver", ["solver.name=nope"], ["<overrides>", "[solver]", "unknown solver"]),
    ("not-a-string", [42], ["<overrides>", "42", "section.key=value"]),
]


@pytest.mark.parametrize("case_id,overrides,names", OVERRIDE_CASES, ids=[c[0] for c in OVERRIDE_CASES])
def test_bad_override(case_id, overrides, names):
    expect(ConfigError, names, load_config, None, ["solver.name=ipopt", *overrides])


# ---------------------------------------------------------------------------- keyword options
KWARG_CASES = [
    ("tol-text", "ipopt", {"tol": "abc"}, ["[ipopt]", "'tol'", "expected a number"]),
    ("tol-negative", "ipopt", {"tol": -1.0}, ["'tol'", "out of range"]),
    ("tol-nan", "ipopt", {"tol": float("nan")}, ["'tol'", "NaN"]),
    ("tol-complex", "ipopt", {"tol": 1e-8 + 1j}, ["'tol'", "expected a number"]),
    ("tol-none", "ipopt", {"tol": None}, ["'tol'", "expected a number"]),
    ("max-iter-bool", "ipopt", {"max_iter": True}, ["'max_iter'", "integer"]),
    ("max-iter-fraction", "ipopt", {"max_iter": 2.5}, ["'max_iter'", "integer"]),
    ("max-iter-huge", "ipopt", {"max_iter": 10**20}, ["'max_iter'", "out of range", "2147483647"]),
    ("max-iter-list", "slsqp", {"max_iter": [1]}, ["[slsqp]", "'max_iter'", "integer"]),
    ("callback-not-callable", "slsqp", {"callback": 42}, ["'callback'", "callable", "int"]),
    ("unknown-option", "slsqp", {"foo": 1}, ["[slsqp]", "'foo'", "unknown option", "max_iter"]),
    ("choice-wrong-type", "ipopt", {"mu_strategy": 1}, ["'mu_strategy'", "string"]),
    ("mapping-expected", "ipopt", {"ipopt_options": "print_level=5"}, ["'ipopt_options'", "mapping"]),
    ("verbose-negative", "sqp", {"verbose": -1}, ["[sqp]", "'verbose'", "out of range"]),
]


@pytest.mark.parametrize("case_id,solver,options,names", KWARG_CASES, ids=[c[0] for c in KWARG_CASES])
def test_bad_keyword_option(case_id, solver, options, names):
    expect(ConfigError, names, config_from_kwargs, solver, **options)
    expect(ConfigError, names, olado.solve, Walk(), solver=solver, **options)


SOLVE_ARGUMENT_CASES = [
    ("solver-int", {"solver": 42}, ["solver must be a name or a Solver instance", "int"]),
    ("solver-unknown", {"solver": "nope"}, ["unknown solver 'nope'", "slsqp"]),
    ("config-int", {"config": 42}, ["config must be an ini file path", "int"]),
    ("config-mismatch", {"config": SolverConfig("slsqp", None), "solver": "ipopt"},
     ["the config is for solver 'slsqp'", "'ipopt'"]),
]


@pytest.mark.parametrize("case_id,kwargs,names", SOLVE_ARGUMENT_CASES, ids=[c[0] for c in SOLVE_ARGUMENT_CASES])
def test_bad_solve_argument(case_id, kwargs, names):
    expect(ConfigError, names, olado.solve, Walk(), **kwargs)
