"""olado.config: ini files -> typed, validated options; keyword options; olado.solve's choice of solver."""

import dataclasses
import math
from pathlib import Path

import pytest

import olado
from olado.config import (SolverConfig, config_from_kwargs, default_solver_name, load_config,
                          make_solver, parse_overrides, raw_options_field)
from olado.errors import ConfigError
from olado.solvers import registry
from olado.solvers.base import Solver, SolverOptions, option
from fixtures import REPO



# ---------------------------------------------------------------------------- a test solver
@dataclasses.dataclass
class DummyOptions(SolverOptions):
    warm_start: bool = option(False, "a boolean")
    method: str = option("a", "a choice", choices=("a", "b"))
    ratio: float = option(0.5, "in (0, 1]", min=0.0, max=1.0, min_exclusive=True)
    limit: float | None = option(None, "optional number")
    dummy_options: dict = option({}, "raw pass-through")


class DummySolver(Solver):
    name = "dummy"
    Options = DummyOptions


@pytest.fixture
def dummy():
    registry.SOLVERS.add("dummy", DummySolver)
    yield DummySolver
    registry.SOLVERS.remove("dummy")


def write(tmp_path, text, name="conf.ini"):
    path = tmp_path / name
    path.write_text(text)
    return path


def assert_names(exc, *parts):
    text = str(exc.value)
    for part in parts:
        assert str(part) in text, f"{part!r} not in {text!r}"


# ---------------------------------------------------------------------------- reading values
def test_full_file_is_typed(tmp_path, dummy):
    path = write(tmp_path, """
[solver]
name = dummy        ; inline comment
[dummy]
max_iter = 25
tol = 1e-10
max_time = inf
verbose = 2
warm_start = yes
method = b
ratio = 1
limit = none
[dummy.raw]
print_level = 5
mu_init = 1e-3
mu_strategy = adaptive
quoted = "1"
[problem]
name = zambezi12
N = 24
start = sif
year = 1950
""")
    cfg = load_config(path)
    assert isinstance(cfg, SolverConfig)
    assert cfg.solver == "dummy" and cfg.source == str(path)
    o = cfg.options
    assert isinstance(o, DummyOptions)
    assert o.max_iter == 25 and type(o.max_iter) is int
    assert o.tol == 1e-10 and o.max_time == math.inf and o.verbose == 2
    assert o.warm_start is True and o.method == "b" and o.ratio == 1.0 and o.limit is None
    assert o.dummy_options == {"print_level": 5, "mu_init": 1e-3, "mu_strategy": "adaptive", "quoted": "1"}
    assert type(o.dummy_options["print_level"]) is int
    assert cfg.problem == {"name": "zambezi12", "N": 24, "start": "sif", "year": 1950}


@pytest.mark.parametrize("text,value", [("true", True), ("Yes", True), ("on", True), ("1", True),
                                        ("false", False), ("no", False), ("OFF", False), ("0", False)])
def test_booleans(tmp_path, dummy, text, value):
    cfg = load_config(write(tmp_path, f"[solver]\nname = dummy\n[dummy]\nwarm_start = {text}\n"))
    assert cfg.options.warm_start is value


def test_ipopt_file_and_raw_section(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\ntol = 1e-9\nmu_strategy = adaptive\n"
                           "[ipopt.raw]\nlinear_system_scaling = none\nmax_soc = 2\n")
    cfg = load_config(path)
    assert cfg.solver == "ipopt" and cfg.options.tol == 1e-9 and cfg.options.mu_strategy == "adaptive"
    assert cfg.options.ipopt_options == {"linear_system_scaling": "none", "max_soc": 2}
    solver = make_solver(cfg)
    assert solver.name == "ipopt" and solver.options.tol == 1e-9


def test_no_file_gives_defaults():
    cfg = load_config()
    assert cfg.solver == default_solver_name() and cfg.problem == {} and cfg.source == "<defaults>"


def test_shipped_configs_load():
    files = sorted((REPO / "configs").glob("*.ini"))
    checked = 0
    for path in files:
        if "[solver]" not in path.read_text():
            continue  # e.g. a benchmark suite, not a solver preset
        cfg = load_config(path)
        assert cfg.solver in registry.available_solvers()
        checked += 1
    if not checked:
        pytest.skip("no solver presets in configs/ yet")


# ---------------------------------------------------------------------------- errors
def test_missing_file_names_path(tmp_path):
    path = tmp_path / "nope.ini"
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "not found")


def test_unknown_section(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt_typo]\ntol = 1\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "[ipopt_typo]", "unknown section", "[solver]", "[problem]", "[ipopt]",
                 "[ipopt.raw]", "[slsqp]")
    assert exc.value.file == str(path) and exc.value.section == "ipopt_typo"


def test_unknown_key(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\ntoll = 1e-6\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "[ipopt]", "'toll'", "allowed", "tol", "max_iter", "mu_strategy")
    assert exc.value.key == "toll"


def test_unknown_key_in_solver_and_problem_sections(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, "[solver]\nname = ipopt\ntol = 1\n"))
    assert_names(exc, "[solver]", "'tol'", "allowed: name")
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, "[solver]\nname = ipopt\n[problem]\nhorizon = 3\n"))
    assert_names(exc, "[problem]", "'horizon'", "name, N, start, year")


def test_bad_value(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\nmax_iter = many\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "[ipopt]", "'max_iter'", "'many'", "allowed", "integer")


def test_bad_boolean(tmp_path, dummy):
    path = write(tmp_path, "[solver]\nname = dummy\n[dummy]\nwarm_start = maybe\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "[dummy]", "'warm_start'", "maybe", "true, false, yes, no, on, off")


@pytest.mark.parametrize("key,value,allowed", [("tol", "-1e-8", "> 0.0"), ("tol", "0", "> 0.0"),
                                               ("max_iter", "-3", ">= 0"),
                                               ("print_level", "13", "<= 12")])
def test_out_of_range(tmp_path, key, value, allowed):
    path = write(tmp_path, f"[solver]\nname = ipopt\n[ipopt]\n{key} = {value}\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "[ipopt]", f"'{key}'", "out of range", allowed)


def test_bad_choice(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\nmu_strategy = fast\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "'mu_strategy'", "'fast'", "monotone, adaptive")


def test_nan_rejected(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\ntol = nan\n"))
    assert_names(exc, "'tol'", "NaN")


def test_unknown_solver(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt2\n")
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, "[solver]", "'name'", "ipopt2", "allowed: ", "ipopt", "slsqp", "trust-constr")


def test_callback_and_raw_field_not_settable_as_values(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\ncallback = print\n"))
    assert_names(exc, "'callback'", "cannot be set from a file")
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\nipopt_options = x\n"))
    assert_names(exc, "'ipopt_options'", "[ipopt.raw]")


def test_raw_section_for_solver_without_passthrough(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, "[solver]\nname = slsqp\n[slsqp.raw]\nftol = 1\n"))
    assert_names(exc, "[slsqp.raw]", "no pass-through options")


@pytest.mark.parametrize("text,what", [
    ("[solver]\nname = ipopt\n[ipopt]\ntol = 1\ntol = 2\n", "key appears twice"),
    ("[solver]\nname = ipopt\n[solver]\nname = slsqp\n", "section appears twice"),
    ("tol = 1\n", "before any [section]"),
    ("[DEFAULT]\ntol = 1\n", "[DEFAULT]"),
    ("[solver]\nname = ipopt\n[problem]\nN = 0\n", "out of range"),
    ("[solver]\nname = ipopt\n[problem]\nN = twelve\n", "expected an integer"),
])
def test_malformed_files(tmp_path, text, what):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert_names(exc, path, what)


def test_presets_for_other_solvers_are_validated_not_applied(tmp_path):
    text = "[solver]\nname = slsqp\n[slsqp]\nmax_iter = 7\n[ipopt]\ntol = 1e-3\n"
    cfg = load_config(write(tmp_path, text))
    assert cfg.solver == "slsqp" and cfg.options.max_iter == 7
    with pytest.raises(ConfigError) as exc:
        load_config(write(tmp_path, text + "mu_strategy = fast\n"))
    assert_names(exc, "[ipopt]", "'mu_strategy'")


# ---------------------------------------------------------------------------- overrides
def test_parse_overrides_forms():
    assert parse_overrides(["ipopt.tol=1e-3", "max_iter = 5", "ipopt.raw.print_level=3", "problem.N=3"]) == [
        ("ipopt", "tol", "1e-3"), (None, "max_iter", "5"), ("ipopt.raw", "print_level", "3"),
        ("problem", "N", "3")]
    assert parse_overrides({"ipopt.tol": 1e-3, "ipopt": {"max_iter": 4}}) == [
        ("ipopt", "tol", 1e-3), ("ipopt", "max_iter", 4)]
    assert parse_overrides("solver.name=slsqp") == [("solver", "name", "slsqp")]
    assert parse_overrides(None) == []
    assert parse_overrides(["x.y=a=b"]) == [("x", "y", "a=b")]


@pytest.mark.parametrize("bad", ["ipopt.tol", "=3", ""])
def test_malformed_override(bad):
    with pytest.raises(ConfigError) as exc:
        load_config(None, [bad])
    assert_names(exc, "section.key=value")


def test_overrides_win_over_file(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\ntol = 1e-9\nmax_iter = 100\n"
                           "[ipopt.raw]\nprint_level = 0\n[problem]\nname = zambezi12\nN = 24\n")
    cfg = load_config(path, ["ipopt.tol=1e-3", "verbose=1", "ipopt.raw.print_level=3",
                             "ipopt.raw.mu_oracle=probing", "problem.N=12"])
    assert cfg.options.tol == 1e-3 and cfg.options.max_iter == 100 and cfg.options.verbose == 1
    assert cfg.options.ipopt_options == {"print_level": 3, "mu_oracle": "probing"}
    assert cfg.problem == {"name": "zambezi12", "N": 12}


def test_override_switches_solver(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[ipopt]\ntol = 1e-9\n[slsqp]\nmax_iter = 9\n")
    cfg = load_config(path, ["solver.name=slsqp"])
    assert cfg.solver == "slsqp" and cfg.options.max_iter == 9


def test_dict_overrides_may_be_typed():
    cfg = load_config(None, {"solver.name": "ipopt", "ipopt.max_iter": 7, "ipopt": {"tol": 1e-4}})
    assert cfg.options.max_iter == 7 and cfg.options.tol == 1e-4


def test_bad_override_value_names_origin():
    with pytest.raises(ConfigError) as exc:
        load_config(None, ["solver.name=ipopt", "ipopt.max_iter=1.5"])
    assert_names(exc, "<overrides>", "[ipopt]", "'max_iter'", "1.5")
    with pytest.raises(ConfigError) as exc:
        load_config(None, ["solver.name=ipopt", "ipopt.nonsense=1"])
    assert_names(exc, "<overrides>", "'nonsense'", "allowed", "tol")


# ---------------------------------------------------------------------------- from code
def test_config_from_kwargs():
    cfg = config_from_kwargs("slsqp", max_iter=12, tol=1e-5, callback=print)
    assert cfg.solver == "slsqp" and cfg.source == "<kwargs>"
    assert cfg.options.max_iter == 12 and cfg.options.tol == 1e-5 and cfg.options.callback is print
    solver = make_solver(cfg)
    assert solver.options.max_iter == 12
    with pytest.raises(ConfigError) as exc:
        config_from_kwargs("slsqp", tol=-1.0)
    assert_names(exc, "[slsqp]", "'tol'", "out of range")
    with pytest.raises(ConfigError) as exc:
        config_from_kwargs("slsqp", mu_strategy="adaptive")
    assert_names(exc, "'mu_strategy'", "unknown option", "allowed", "max_iter")
    with pytest.raises(ConfigError) as exc:
        config_from_kwargs("nope")
    assert_names(exc, "unknown solver", "ipopt")


def test_raw_options_field_detection():
    @dataclasses.dataclass
    class A(SolverOptions):
        extra: dict = dataclasses.field(default_factory=dict, metadata={"raw": True})

    @dataclasses.dataclass
    class B(SolverOptions):
        raw_options: dict = option({})

    @dataclasses.dataclass
    class C(SolverOptions):
        trust_constr_options: dict = option({})

    assert raw_options_field(A, "a") == "extra"
    assert raw_options_field(B, "b") == "raw_options"
    assert raw_options_field(C, "trust-constr") == "trust_constr_options"
    assert raw_options_field(SolverOptions, "x") is None
    assert raw_options_field(DummyOptions, "dummy") == "dummy_options"


def test_default_solver_falls_back_without_cyipopt(monkeypatch):
    ipopt_cls = registry.get_solver_class("ipopt")
    monkeypatch.setattr(ipopt_cls, "available", classmethod(lambda cls: False))
    assert default_solver_name() == "trust-constr"
    assert load_config().solver == "trust-constr"
    monkeypatch.setattr(ipopt_cls, "available", classmethod(lambda cls: True))
    assert default_solver_name() == "ipopt"


# ---------------------------------------------------------------------------- olado.solve
class TinyLQ(olado.DOCP):
    """x^{k+1} = x^k + u^k, x^0 = 1, -1 <= u <= 1; J = sum 0.5 (x^2 + u^2) + x_N^2."""

    name = "tiny-lq"

    def __init__(self, N=5):
        super().__init__(1, 1, N, [1.0], u_bounds=([-1.0], [1.0]))

    def dynamics(self, k, x, u):
        return x + u

    def stage_cost(self, k, x, u):
        return 0.5 * float(x @ x + u @ u)

    def final_cost(self, x):
        return float(x @ x)


def _tiny_problem():
    return TinyLQ()


def test_solve_validates_keyword_options_before_solving():
    with pytest.raises(ConfigError) as exc:
        olado.solve(_tiny_problem(), solver="slsqp", tol=-1)
    assert_names(exc, "'tol'", "out of range")
    with pytest.raises(ConfigError):
        olado.solve(_tiny_problem(), solver="slsqp", not_an_option=1)
    with pytest.raises(ConfigError) as exc:
        olado.solve("zambezi12")
    assert_names(exc, "PROBLEMS")


def test_solve_with_name_config_and_instance(tmp_path):
    problem = _tiny_problem()
    r1 = olado.solve(problem, solver="slsqp", max_iter=200)
    assert r1.solver == "slsqp" and r1.success
    path = write(tmp_path, "[solver]\nname = slsqp\n[slsqp]\nmax_iter = 200\n")
    r2 = olado.solve(problem, config=path)
    assert r2.solver == "slsqp" and r2.success and r2.options["max_iter"] == 200
    r3 = olado.solve(problem, config=load_config(path), max_iter=150)
    assert r3.options["max_iter"] == 150
    solver = registry.get_solver_class("slsqp")(max_iter=100)
    r4 = olado.solve(problem, solver=solver, guess=r1)
    assert r4.success and r4.iterations <= r1.iterations
    with pytest.raises(ConfigError):
        olado.solve(problem, config=path, solver=solver)
    with pytest.raises(ConfigError):
        olado.solve(problem, config=load_config(path), solver="ipopt")


def test_solve_solver_name_selects_section_of_file(tmp_path):
    path = write(tmp_path, "[solver]\nname = ipopt\n[slsqp]\nmax_iter = 123\n")
    r = olado.solve(_tiny_problem(), config=path, solver="slsqp")
    assert r.solver == "slsqp" and r.options["max_iter"] == 123


def test_import_olado_is_light():
    import subprocess
    import sys

    code = ("import sys, olado; assert 'cyipopt' not in sys.modules and 'scipy' not in sys.modules; "
            "assert olado.Result.__name__ == 'Result' and olado.DOCP.__name__ == 'DOCP'; "
            "assert 'cyipopt' not in sys.modules; print(olado.__version__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == olado.__version__
    for name in ("solve", "Result", "Status", "DOCP", "LagrangeDOCP", "MayerDOCP", "StructuredNLP",
                 "errors", "__version__"):
        assert hasattr(olado, name), name


def test_every_lazy_submodule_of_olado_exists():
    import importlib

    for name in olado._SUBMODULES:
        assert importlib.import_module(f"olado.{name}") is getattr(olado, name), name
    assert "options" in dir(olado)
    assert "bench" in olado._SUBMODULES and callable(olado.bench.run)     # issue 14: olado.bench is real
