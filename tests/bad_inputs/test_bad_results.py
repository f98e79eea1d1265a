"""Bad-input catalogue, part 3: result files. Result.load checks the format version and every
field; a file that is not what Result.save writes is a ResultFileError naming the file and the
field (docs/errors.md)."""

import json
import os

import numpy as np
import pytest

from olado.errors import ResultFileError, ResultFileNotFoundError
from olado.result import FORMAT_VERSION, Infeasibility, Result, Status, ViolatedArray, Violation
from fixtures.bad_problems import expect


def good_result(N=3):
    return Result(status=Status.SUCCESS, message="converged", objective=1.25,
                  x=np.arange((N + 1) * 2, dtype=float).reshape(N + 1, 2), u=np.ones((N, 1)),
                  multipliers={"dynamics": np.zeros((N, 2))}, max_constraint_violation=0.0,
                  kkt_residual=1e-9, iterations=4, problem="toy", N=N, solver="slsqp")


def infeasible_result(N=3):
    r = good_result(N)
    r.status, r.message = Status.INFEASIBLE, "locally infeasible"
    r.infeasibility = Infeasibility(tolerance=1e-8, largest=0.5, total=0.875, arrays=[
        ViolatedArray("dynamics", 2, 6, 0.5, 0.75, 0, 2), ViolatedArray("final_constraints", 1, 1, 0.125, 0.125)],
        violations=[Violation("dynamics", 2, 1, 0.5, "equality"), Violation("dynamics", 0, 0, 0.25, "equality"),
                    Violation("final_constraints", None, 0, 0.125, "inequality")])
    return r


@pytest.fixture
def saved(tmp_path):
    """(JSON path, its document) of a good result saved without its npz (the JSON alone counts)."""
    path = good_result().save(tmp_path / "res.json")
    path.with_suffix(".npz").unlink()
    return path, json.loads(path.read_text())


def _set(doc, key, value):
    doc[key] = value


# (id, change to the JSON document, words the message must contain besides the file name)
FIELD_CASES = [
    ("unknown-status", lambda d: _set(d, "status", "weird"), ["'status'", "unknown status 'weird'", "success"]),
    ("status-number", lambda d: _set(d, "status", 3), ["'status'", "expected a string"]),
    ("missing-status", lambda d: d.pop("status"), ["'status'", "missing"]),
    ("missing-objective", lambda d: d.pop("objective"), ["'objective'", "missing"]),
    ("missing-x", lambda d: d.pop("x"), ["'x'", "missing"]),
    ("missing-u", lambda d: d.pop("u"), ["'u'", "missing"]),
    ("x-text", lambda d: _set(d, "x", [["a", 1.0]] * 4), ["'x[0, 0]'", "expected a number", "'a'"]),
    ("x-null-entry", lambda d: d["x"][2].__setitem__(1, None), ["'x[2, 1]'", "None"]),
    ("x-ragged", lambda d: d["x"][1].append(5.0), ["'x'", "rectangular"]),
    ("x-not-a-list", lambda d: _set(d, "x", {"a": 1}), ["'x'", "expected an array", "object"]),
    ("x-one-dimensional", lambda d: _set(d, "x", [1.0, 2.0]), ["'x'", "table", "1 dimensions"]),
    ("x-rows", lambda d: d["x"].pop(), ["'x'", "3 state rows for 3 control rows"]),
    ("N-mismatch", lambda d: _set(d, "N", 7), ["'N'", "N = 7", "3 rows"]),
    ("N-negative", lambda d: _set(d, "N", -1), ["'N'", "non-negative integer"]),
    ("objective-text", lambda d: _set(d, "objective", "abc"), ["'objective'", "expected a number", "'abc'"]),
    ("objective-bool", lambda d: _set(d, "objective", True), ["'objective'", "expected a number"]),
    ("objective-huge-int", lambda d: _set(d, "objective", 10**400), ["'objective'", "beyond the floating-point range"]),
    ("objective-null", lambda d: _set(d, "objective", None), ["'objective'", "expected a number"]),
    ("kkt-text", lambda d: _set(d, "kkt_residual", "small"), ["'kkt_residual'", "'small'"]),
    ("iterations-fraction", lambda d: _set(d, "iterations", 1.5), ["'iterations'", "non-negative integer"]),
    ("iterations-text", lambda d: _set(d, "iterations", "4"), ["'iterations'", "non-negative integer"]),
    ("qp-iterations-negative", lambda d: _set(d, "qp_iterations", -3), ["'qp_iterations'", "non-negative integer"]),
    ("time-text", lambda d: _set(d, "time_s", "fast"), ["'time_s'", "expected a number"]),
    ("message-number", lambda d: _set(d, "message", 5), ["'message'", "expected a string"]),
    ("solver-list", lambda d: _set(d, "solver", ["slsqp"]), ["'solver'", "expected a string", "array"]),
    ("multipliers-list", lambda d: _set(d, "multipliers", [1, 2]), ["'multipliers'", "JSON object", "array"]),
    ("multiplier-text", lambda d: d["multipliers"].__setitem__("dynamics", [["x"]]),
     ["'multipliers.dynamics[0, 0]'", "'x'"]),
    ("history-object", lambda d: _set(d, "history", {"a": 1}), ["'history'", "JSON array"]),
    ("options-list", lambda d: _set(d, "options", []), ["'options'", "JSON object"]),
    ("evaluations-number", lambda d: _set(d, "evaluations", 3), ["'evaluations'", "JSON object"]),
    ("info-text", lambda d: _set(d, "info", "x"), ["'info'", "JSON object"]),
    ("success-disagrees", lambda d: _set(d, "success", False), ["'success'", "status 'success'"]),
    ("success-not-bool", lambda d: _set(d, "success", "yes"), ["'success'", "true or false"]),
    ("newer-version", lambda d: _set(d, "format_version", FORMAT_VERSION + 1),
     ["'format_version'", "newer olado", f"up to {FORMAT_VERSION}"]),
    ("version-text", lambda d: _set(d, "format_version", "1"), ["'format_version'", "positive integer"]),
    ("other-format", lambda d: _set(d, "format", "something-else"), ["'format'", "'olado-result'"]),
]


@pytest.mark.parametrize("case_id,change,names", FIELD_CASES, ids=[c[0] for c in FIELD_CASES])
def test_bad_result_field(saved, case_id, change, names):
    path, doc = saved
    change(doc)
    path.write_text(json.dumps(doc))
    expect(ResultFileError, [str(path), *names], Result.load, path)


# (id, change to the "infeasibility" object of an infeasible result's JSON, field named, words of the message)
DIAGNOSIS_CASES = [
    ("not-an-object", lambda d: d.__setitem__("infeasibility", [1]), "infeasibility", "object or null"),
    ("tolerance-text", lambda d: d["infeasibility"].__setitem__("tolerance", "tight"), "infeasibility.tolerance",
     "expected a number"),
    ("tolerance-missing", lambda d: d["infeasibility"].pop("tolerance"), "infeasibility.tolerance", "missing"),
    ("stage-text", lambda d: d["infeasibility"]["violations"][1].__setitem__("stage", "one"),
     "infeasibility.violations[1].stage", "non-negative integer"),
    ("unknown-kind", lambda d: d["infeasibility"]["violations"][0].__setitem__("kind", "sideways"),
     "infeasibility.violations[0].kind", "'sideways'"),
    ("negative-value", lambda d: d["infeasibility"]["violations"][2].__setitem__("value", -1.0),
     "infeasibility.violations[2].value", ">= 0"),
    ("nan-value", lambda d: d["infeasibility"]["violations"][2].__setitem__("value", "nan"),
     "infeasibility.violations[2].value", ">= 0"),
    ("array-missing", lambda d: d["infeasibility"]["violations"][1].pop("array"),
     "infeasibility.violations[1].array", "missing"),
    ("violation-not-object", lambda d: d["infeasibility"]["violations"].__setitem__(0, 3),
     "infeasibility.violations[0]", "expected an object"),
    ("count-above-size", lambda d: d["infeasibility"]["arrays"][0].__setitem__("count", 7),
     "infeasibility.arrays[0].count", "7 violated components of 6"),
    ("half-a-range", lambda d: d["infeasibility"]["arrays"][0].__setitem__("last_stage", None),
     "infeasibility.arrays[0].first_stage", "not a range"),
    ("reversed-range", lambda d: d["infeasibility"]["arrays"][0].__setitem__("first_stage", 5),
     "infeasibility.arrays[0].first_stage", "5..2"),
    ("arrays-object", lambda d: d["infeasibility"].__setitem__("arrays", {"a": 1}), "infeasibility.arrays",
     "JSON array"),
]


@pytest.mark.parametrize("case_id,change,field,words", DIAGNOSIS_CASES, ids=[c[0] for c in DIAGNOSIS_CASES])
def test_bad_infeasibility_diagnosis(tmp_path, case_id, change, field, words):
    path = infeasible_result().save(tmp_path / "res.json")
    path.with_suffix(".npz").unlink()
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    err = expect(ResultFileError, [str(path), f"'{field}'", words], Result.load, path)
    assert err.field == field


def test_infeasibility_diagnosis_round_trips(tmp_path):
    r = infeasible_result()
    back = Result.load(r.save(tmp_path / "res.json"))
    assert back.infeasibility == r.infeasibility and back.summary() == r.summary()
    assert "final_constraints[component 0]: 0.125 (inequality)" in back.summary()


WHOLE_FILE_CASES = [
    ("not-json", b"{not json", ["not JSON"]),
    ("empty", b"", ["not JSON"]),
    ("a-list", b"[1, 2]", ["a JSON array", "expected an object"]),
    ("a-string", b'"result"', ["a JSON string"]),
    ("null", b"null", ["a JSON null"]),
    ("not-text", b"\xff\xfe{}", ["not a text file"]),
    ("deeply-nested", b"[" * 100000 + b"]" * 100000, ["not JSON"]),
]


@pytest.mark.parametrize("case_id,data,names", WHOLE_FILE_CASES, ids=[c[0] for c in WHOLE_FILE_CASES])
def test_bad_result_file(tmp_path, case_id, data, names):
    path = tmp_path / "res.json"
    path.write_bytes(data)
    expect(ResultFileError, [str(path), *names], Result.load, path)


def test_missing_result_file_is_also_a_file_not_found_error(tmp_path):
    err = expect(ResultFileNotFoundError, [str(tmp_path / "none.json"), "not found"], Result.load,
                 tmp_path / "none.json")
    assert isinstance(err, FileNotFoundError)


@pytest.mark.parametrize("path", [42, None, ["res.json"]], ids=["int", "none", "list"])
def test_result_path_of_the_wrong_type(path):
    expect(ResultFileError, ["expected a file path", type(path).__name__], Result.load, path)
    expect(ResultFileError, ["expected a file path"], good_result().save, path)


def test_result_path_is_a_folder(tmp_path):
    folder = tmp_path / "res.json"
    folder.mkdir()
    expect(ResultFileError, [str(folder), "cannot read"], Result.load, folder)


# ---------------------------------------------------------------------------- the npz beside it
def _rewrite_npz(path, **arrays):
    np.savez(path.with_suffix(".npz"), **arrays)


def test_corrupt_npz_is_named(tmp_path):
    path = good_result().save(tmp_path / "res.json")
    path.with_suffix(".npz").write_bytes(b"PK\x03\x04 not really a zip file")
    expect(ResultFileError, [str(path.with_suffix(".npz")), "cannot read the arrays"], Result.load, path)


def test_npz_of_the_same_save_with_other_shapes(tmp_path):
    path = good_result().save(tmp_path / "res.json")
    save_id = json.loads(path.read_text())["save_id"]
    _rewrite_npz(path, x=np.zeros((2, 2)), u=np.ones((3, 1)), save_id=np.array(save_id))
    expect(ResultFileError, [str(path.with_suffix(".npz")), "'x'", "shape (2, 2)", "(4, 2)"], Result.load, path)


def test_npz_with_pickled_objects_is_refused_not_executed(tmp_path):
    path = good_result().save(tmp_path / "res.json")
    save_id = json.loads(path.read_text())["save_id"]
    _rewrite_npz(path, x=np.array([{"a": 1}], dtype=object), u=np.ones((3, 1)), save_id=np.array(save_id))
    expect(ResultFileError, [str(path.with_suffix(".npz")), "cannot read the arrays"], Result.load, path)


def test_npz_with_text_arrays(tmp_path):
    path = good_result().save(tmp_path / "res.json")
    save_id = json.loads(path.read_text())["save_id"]
    _rewrite_npz(path, x=np.full((4, 2), "a"), u=np.ones((3, 1)), save_id=np.array(save_id))
    expect(ResultFileError, [str(path.with_suffix(".npz")), "'x'", "dtype"], Result.load, path)


def test_npz_of_another_save_is_ignored(tmp_path):
    """Not an error: the JSON's own (exact) arrays are used."""
    path = good_result().save(tmp_path / "res.json")
    _rewrite_npz(path, x=np.zeros((9, 9)), u=np.zeros((9, 9)), save_id=np.array("another"))
    assert np.array_equal(Result.load(path).x, good_result().x)


# ---------------------------------------------------------------------------- what must still load
def test_file_without_format_fields_still_loads(tmp_path):
    """Files saved before the format was versioned (olado 0.1) have the same fields."""
    path = good_result().save(tmp_path / "res.json")
    doc = json.loads(path.read_text())
    for key in ("format", "format_version"):
        doc.pop(key)
    path.write_text(json.dumps(doc))
    assert Result.load(path).objective == 1.25


def test_non_finite_values_round_trip(tmp_path):
    r = good_result()
    r.x[1, 1] = np.nan
    r.objective, r.max_constraint_violation = np.inf, -np.inf
    path = r.save(tmp_path / "res.json")
    path.with_suffix(".npz").unlink()
    back = Result.load(path)
    assert np.isnan(back.x[1, 1]) and back.objective == np.inf and back.max_constraint_violation == -np.inf


def test_private_file_stays_private_when_saved_over(tmp_path):
    path = good_result().save(tmp_path / "res.json")
    os.chmod(path, 0o600)
    os.chmod(path.with_suffix(".npz"), 0o600)
    good_result(N=5).save(path)
    assert {oct(os.stat(p).st_mode & 0o777) for p in (path, path.with_suffix(".npz"))} == {oct(0o600)}
