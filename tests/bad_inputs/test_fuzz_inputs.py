"""Property-based fuzzing of the input layers (hypothesis): the ini parser (olado.config), option
values (olado.options) and Result.load. Whatever comes in, the answer is a value or an olado
error (ConfigError, ResultFileError) -- never a raw Python exception."""

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from olado.config import PROBLEM_KEYS, SolverConfig, config_from_kwargs, load_config
from olado.errors import ConfigError, ResultFileError
from olado.options import option_specs
from olado.result import Infeasibility, Result, Status, ViolatedArray, Violation
from olado.solvers.registry import SOLVERS

FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])

SOLVER_NAMES = sorted(SOLVERS)
OPTION_NAMES = sorted({name for s in SOLVER_NAMES for name in option_specs(SOLVERS[s].Options)})

# ---------------------------------------------------------------------------- ini text
WORDS = st.sampled_from(["", "0", "1", "-1", "1.5", "1e-8", "1e400", "-1e400", "99999999999999999999", "nan",
                         "inf", "-inf", "true", "no", "none", "ipopt", "sqp", "slsqp", "exact", "'quoted'",
                         "\"q\"", "adaptive", "osqp", "[x]", "a=b", "; comment", "%(x)s", "\u00e9t\u00e9"])
SECTIONS = st.sampled_from(["solver", "problem", "DEFAULT", "", "nosuch", *SOLVER_NAMES,
                            *(f"{s}.raw" for s in SOLVER_NAMES)])
KEYS = st.sampled_from(["name", "N", "start", "year", "", "unknown", *PROBLEM_KEYS, *OPTION_NAMES])
VALUES = st.one_of(WORDS, st.text(max_size=12))


@st.composite
def ini_text(draw):
    lines = []
    for _ in range(draw(st.integers(0, 12))):
        kind = draw(st.integers(0, 9))
        if kind == 0:
            lines.append(f"[{draw(SECTIONS)}]")
        elif kind == 1:
            lines.append(draw(st.text(max_size=20)).replace("\x00", ""))
        else:
            sep = draw(st.sampled_from(["=", " = ", ":", " "]))
            lines.append(f"{draw(KEYS)}{sep}{draw(VALUES)}")
    if draw(st.booleans()):
        lines.insert(0, f"[solver]\nname = {draw(st.sampled_from(SOLVER_NAMES))}")
    return "\n".join(lines)


def _load_text(text):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.ini"
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        return load_config(path)


@FUZZ
@given(ini_text())
def test_ini_files_give_a_config_or_a_config_error(text):
    try:
        config = _load_text(text)
    except ConfigError:
        return
    assert isinstance(config, SolverConfig) and config.solver in SOLVERS


@FUZZ
@given(st.binary(max_size=200))
def test_arbitrary_bytes_as_an_ini_file(data):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.ini"
        path.write_bytes(data)
        try:
            load_config(path)
        except ConfigError:
            pass


@FUZZ
@given(st.lists(st.one_of(st.text(max_size=30),
                          st.builds(lambda s, k, v: f"{s}.{k}={v}", SECTIONS, KEYS, VALUES)), max_size=4))
def test_overrides_give_a_config_or_a_config_error(overrides):
    try:
        load_config(None, overrides)
    except ConfigError:
        pass


# ---------------------------------------------------------------------------- option values
JSONISH = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                       lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=3),
                       max_leaves=6)
ANY_VALUE = st.one_of(JSONISH, st.integers(min_value=-2**70, max_value=2**70),
                      st.floats(allow_nan=True, allow_infinity=True), st.complex_numbers(),
                      st.tuples(st.integers(), st.integers()), st.just(print), st.just(object()),
                      st.builds(np.float64, st.floats()), st.builds(np.int64, st.integers(-2**63, 2**63 - 1)),
                      st.just(np.array([1.0, 2.0])))


@FUZZ
@given(st.sampled_from(SOLVER_NAMES), st.data())
def test_keyword_option_values_are_checked(solver, data):
    name = data.draw(st.sampled_from(sorted(option_specs(SOLVERS[solver].Options))))
    value = data.draw(ANY_VALUE)
    try:
        config = config_from_kwargs(solver, **{name: value})
    except ConfigError:
        return
    checked = getattr(config.options, name)
    if isinstance(checked, float):
        assert not math.isnan(checked)


@FUZZ
@given(st.sampled_from(SOLVER_NAMES), st.data())
def test_option_values_from_text_are_checked(solver, data):
    name = data.draw(st.sampled_from(sorted(option_specs(SOLVERS[solver].Options))))
    text = data.draw(VALUES)
    try:
        load_config(None, [f"solver.name={solver}", f"{solver}.{name}={text}"])
    except ConfigError:
        pass


# ---------------------------------------------------------------------------- Result.load
def _good_document(folder):
    N = 3
    result = Result(status=Status.INFEASIBLE, message="m", objective=2.5,
                    x=np.linspace(0, 1, (N + 1) * 2).reshape(N + 1, 2), u=np.ones((N, 1)),
                    multipliers={"dynamics": np.zeros((N, 2))}, kkt_residual=None, N=N,
                    history=[{"iteration": 0}], info={"a": 1},
                    infeasibility=Infeasibility(tolerance=1e-8, largest=0.5, total=0.75, arrays=[
                        ViolatedArray("dynamics", 2, 6, 0.5, 0.75, 0, 2)], violations=[
                        Violation("dynamics", 2, 1, 0.5, "equality"), Violation("dynamics", 0, 0, 0.25, "equality")]))
    path = result.save(Path(folder) / "res.json")
    return path, json.loads(path.read_text())


FIELDS = ["status", "message", "objective", "x", "u", "multipliers", "max_constraint_violation",
          "kkt_residual", "iterations", "qp_iterations", "evaluations", "time_s", "history", "problem",
          "N", "solver", "options", "info", "success", "save_id", "format", "format_version", "extra",
          "certificate", "infeasibility"]


def _load_checked(path):
    try:
        result = Result.load(path)
    except ResultFileError:
        return None
    assert isinstance(result, Result) and isinstance(result.status, Status)
    assert result.x.dtype == float and result.u.dtype == float
    return result


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(FIELDS), st.booleans(), JSONISH), min_size=1, max_size=4),
       st.booleans())
def test_result_files_with_changed_fields(changes, keep_npz):
    with tempfile.TemporaryDirectory() as folder:
        path, doc = _good_document(folder)
        for field, delete, value in changes:
            if delete:
                doc.pop(field, None)
            else:
                doc[field] = value
        path.write_text(json.dumps(doc))
        if not keep_npz:
            path.with_suffix(".npz").unlink()
        _load_checked(path)


@FUZZ
@given(st.sampled_from(["x", "u"]), st.integers(0, 3), st.integers(0, 1), JSONISH)
def test_result_files_with_a_changed_array_entry(field, row, col, value):
    with tempfile.TemporaryDirectory() as folder:
        path, doc = _good_document(folder)
        doc[field][row % len(doc[field])][col % len(doc[field][0])] = value
        path.write_text(json.dumps(doc))
        path.with_suffix(".npz").unlink()
        _load_checked(path)


#: the fields inside a saved infeasibility diagnosis, as paths into its JSON object
DIAGNOSIS_FIELDS = [("tolerance",), ("largest",), ("total",), ("note",), ("time_s",), ("arrays",), ("violations",),
                    ("arrays", 0), ("violations", 1), *(("arrays", 0, k) for k in (
                        "array", "count", "size", "largest", "total", "first_stage", "last_stage")),
                    *(("violations", 0, k) for k in ("array", "stage", "component", "value", "kind"))]


def _has(parent, key) -> bool:
    """parent[key] exists: a key of a dict, or an int index of a list (an earlier change may have
    replaced a dict by a list or the other way round)."""
    if isinstance(parent, dict):
        return key in parent
    return isinstance(parent, list) and isinstance(key, int) and key < len(parent)


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(DIAGNOSIS_FIELDS), st.booleans(), JSONISH), min_size=1, max_size=4))
@example([(("arrays", 0), False, []), (("arrays", 0, "array"), False, None)])   # a dict replaced by a list first
def test_result_files_with_a_changed_diagnosis(changes):
    with tempfile.TemporaryDirectory() as folder:
        path, doc = _good_document(folder)
        for field, delete, value in changes:
            parent = doc["infeasibility"]
            for key in field[:-1]:
                parent = parent[key] if _has(parent, key) else None
            if isinstance(parent, dict) and delete:
                parent.pop(field[-1], None)
            elif isinstance(parent, dict) or _has(parent, field[-1]):
                parent[field[-1]] = value
        path.write_text(json.dumps(doc))
        path.with_suffix(".npz").unlink()
        result = _load_checked(path)
        if result is not None and result.infeasibility is not None:
            result.summary()                # a diagnosis that loads also prints


@FUZZ
@given(st.binary(max_size=300))
def test_arbitrary_bytes_as_a_result_file(data):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "res.json"
        path.write_bytes(data)
        _load_checked(path)


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=8))
def test_result_with_a_damaged_npz(flips):
    with tempfile.TemporaryDirectory() as folder:
        path, _ = _good_document(folder)
        npz = path.with_suffix(".npz")
        data = bytearray(npz.read_bytes())
        for position, byte in flips:
            data[position % len(data)] = byte
        npz.write_bytes(bytes(data))
        _load_checked(path)


@pytest.mark.parametrize("field", FIELDS)
def test_every_field_removed_alone(tmp_path, field):
    path, doc = _good_document(tmp_path)
    doc.pop(field, None)
    path.write_text(json.dumps(doc))
    path.with_suffix(".npz").unlink()
    _load_checked(path)
