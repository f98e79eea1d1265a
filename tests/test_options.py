"""olado.options: declaring options, parsing ini strings and validating values, in one engine."""

import dataclasses
import math
import subprocess
import sys
import typing

import numpy as np
import pytest

import olado.config
import olado.solvers.base
from olado.errors import ConfigError
from olado.options import (make_options, option, option_specs, parse_scalar, parse_value, read_value,
                           split_optional, validate_value)
from fixtures import REPO


@dataclasses.dataclass
class Opts:
    flag: bool = option(False, "a boolean")
    count: int = option(3, "an integer >= 0", min=0)
    ratio: float = option(0.5, "in (0, 1]", min=0.0, max=1.0, min_exclusive=True)
    name: str = option("a", "a choice", choices=("a", "b"))
    text: str = option("x", "any string")
    limit: float | None = option(None, "optional number")
    old_style: typing.Optional[int] = option(None, "Optional[...] spelling", min=1)
    either: int | str = option(1, "a union without None: not type-checked")
    maybe: int | str | None = option(None, "a union with None: None or anything")
    table: dict = option({}, "a mapping")
    typed_table: dict[str, int] = option({}, "a parametrised mapping")
    anything: typing.Any = option(None, "not checked", ini=False)


def where(exc, *parts):
    text = str(exc.value)
    for part in parts:
        assert part in text, f"{part!r} not in {text!r}"


# ---------------------------------------------------------------------------- declaration
def test_option_metadata_and_fresh_mutable_defaults():
    f = {f.name: f for f in dataclasses.fields(Opts)}
    assert f["ratio"].metadata["min"] == 0.0 and f["ratio"].metadata["min_exclusive"] is True
    assert f["name"].metadata["choices"] == ("a", "b") and f["anything"].metadata["ini"] is False
    a, b = Opts(), Opts()
    a.table["k"] = 1
    assert b.table == {} and a.table is not b.table


def test_specs_resolve_hints_once_per_class():
    specs = option_specs(Opts)
    assert option_specs(Opts) is specs  # the one cache
    assert list(specs) == [f.name for f in dataclasses.fields(Opts)]
    assert (specs["limit"].kind, specs["limit"].optional) == (float, True)
    assert (specs["old_style"].kind, specs["old_style"].optional) == (int, True)
    assert (specs["either"].kind, specs["either"].optional) == (typing.Any, False)
    assert (specs["maybe"].kind, specs["maybe"].optional) == (typing.Any, True)
    assert (specs["count"].kind, specs["count"].optional) == (int, False)
    assert not specs["anything"].settable_from_file and specs["flag"].settable_from_file


def test_split_optional():
    assert split_optional(float | None) == (float, True)
    assert split_optional(typing.Optional[str]) == (str, True)
    assert split_optional(int | str) == (typing.Any, False)
    assert split_optional(int | str | None) == (typing.Any, True)
    assert split_optional(int) == (int, False)


def test_unresolvable_annotation_leaves_the_value_unchecked():
    ns = {}
    exec("import dataclasses\nfrom olado.options import option\n"
         "@dataclasses.dataclass\nclass Late:\n    x: 'NotDefinedAnywhere' = option(1, 'x')\n", ns)
    assert validate_value(ns["Late"], "x", "anything") == "anything"


def test_the_old_entry_points_are_this_engine():
    assert olado.solvers.base.validate_value is validate_value
    assert olado.solvers.base.make_options is make_options and olado.solvers.base.option is option
    assert olado.config.raw_options_field is olado.options.raw_options_field


def test_leaf_module_imports_only_errors():
    code = "import sys, olado.options; print(sorted(m for m in sys.modules if m.startswith('olado')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "['olado', 'olado.errors', 'olado.options']"


# ---------------------------------------------------------------------------- parsing ini strings
@pytest.mark.parametrize("text,value", [("true", True), ("Yes", True), ("ON", True), ("1", True),
                                        ("false", False), ("no", False), ("Off", False), ("0", False)])
def test_parse_booleans(text, value):
    assert parse_value(f" {text} ", bool) is value


def test_parse_bad_boolean_lists_the_words():
    with pytest.raises(ConfigError) as exc:
        parse_value("maybe", bool, file="f.ini", section="s", key="flag")
    where(exc, "f.ini", "[s]", "'flag'", "maybe", "true, false, yes, no, on, off, 1, 0")


@pytest.mark.parametrize("text,value", [("100", 100), ("-3", -3), ("1e3", 1000), ("2.0", 2)])
def test_parse_integers(text, value):
    parsed = parse_value(text, int)
    assert parsed == value and type(parsed) is int


@pytest.mark.parametrize("text", ["1.5", "many", "", "inf"])
def test_parse_bad_integer(text):
    with pytest.raises(ConfigError) as exc:
        parse_value(text, int, key="count")
    where(exc, "expected an integer", "an integer such as 100")


@pytest.mark.parametrize("text,value", [("1e-8", 1e-8), ("0.5", 0.5), ("1", 1.0), ("inf", math.inf),
                                        ("-inf", -math.inf)])
def test_parse_floats(text, value):
    parsed = parse_value(text, float)
    assert parsed == value and type(parsed) is float


def test_parse_bad_float():
    with pytest.raises(ConfigError) as exc:
        parse_value("fast", float, key="ratio")
    where(exc, "expected a number, got 'fast'", "1e-8, 0.5 or inf")


def test_parse_strings_unquote():
    assert parse_value(" 'quoted' ", str) == "quoted" and parse_value('"x y"', str) == "x y"
    assert parse_value("plain", str) == "plain" and parse_value("'", str) == "'"


@pytest.mark.parametrize("typ", [float | None, typing.Optional[float], int | str | None])
@pytest.mark.parametrize("text", ["none", "None", "null", "", "  "])
def test_parse_optional_none(typ, text):
    assert parse_value(text, typ) is None


def test_parse_optional_value_has_the_inner_type():
    assert parse_value("3", float | None) == 3.0 and type(parse_value("3", float | None)) is float
    with pytest.raises(ConfigError):
        parse_value("none", float)  # a non-optional number does not take none


def test_parse_mapping_is_refused():
    for typ in (dict, dict[str, int]):
        with pytest.raises(ConfigError) as exc:
            parse_value("{}", typ, key="table")
        where(exc, "[<solver>.raw]")


@pytest.mark.parametrize("text,value", [("5", 5), (" 7 ", 7), ("1e-3", 1e-3), ("adaptive", "adaptive"),
                                        ('"1"', "1"), ("'inf'", "inf"), ("-0.5", -0.5)])
def test_untyped_values(text, value):
    assert parse_scalar(text) == value and type(parse_scalar(text)) is type(value)
    assert parse_value(text, typing.Any) == value and parse_value(text, int | str) == value


def test_typed_values_pass_through_parsing():
    marker = object()
    assert parse_value(marker, float) is marker and parse_value(3, bool) == 3


# ---------------------------------------------------------------------------- validation
def test_unknown_option_names_settable_ones():
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "ratioo", 1.0, file="f.ini", section="s")
    where(exc, "f.ini", "[s]", "'ratioo'", "unknown option", "flag, count, ratio")
    assert "anything" not in exc.value.allowed


def test_validate_booleans():
    assert validate_value(Opts, "flag", True) is True
    assert validate_value(Opts, "flag", np.bool_(False)) is False
    for bad in (1, "true", None):
        with pytest.raises(ConfigError) as exc:
            validate_value(Opts, "flag", bad)
        where(exc, "expected true/false")


def test_validate_integers():
    for good in (3, np.int64(3), 3.0, np.int32(3)):
        value = validate_value(Opts, "count", good)
        assert value == 3 and type(value) is int
    for bad in (3.5, True, np.bool_(True), "3", None):
        with pytest.raises(ConfigError) as exc:
            validate_value(Opts, "count", bad)
        where(exc, "expected an integer")


def test_validate_floats():
    for good in (1, 0.25, np.float32(0.25), np.int64(1)):
        value = validate_value(Opts, "ratio", good)
        assert type(value) is float
    for bad in (True, "0.5", None, np.bool_(True)):
        with pytest.raises(ConfigError) as exc:
            validate_value(Opts, "ratio", bad)
        where(exc, "expected a number")
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "limit", math.nan)
    where(exc, "NaN is not allowed")


def test_validate_strings_and_mappings():
    assert validate_value(Opts, "text", "y") == "y"
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "text", 3)
    where(exc, "expected a string")
    assert validate_value(Opts, "typed_table", {"a": 1}) == {"a": 1}
    for key in ("table", "typed_table"):
        with pytest.raises(ConfigError) as exc:
            validate_value(Opts, key, [("a", 1)])
        where(exc, "expected a mapping")


def test_validate_optional_and_unions():
    assert validate_value(Opts, "limit", None) is None and validate_value(Opts, "limit", 2) == 2.0
    assert validate_value(Opts, "old_style", None) is None
    with pytest.raises(ConfigError):
        validate_value(Opts, "old_style", 0)  # the range applies to the inner value
    assert validate_value(Opts, "either", "s") == "s" and validate_value(Opts, "either", 2.5) == 2.5
    assert validate_value(Opts, "maybe", None) is None and validate_value(Opts, "maybe", [1]) == [1]
    assert validate_value(Opts, "anything", print) is print


def test_validate_choices_and_ranges():
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "name", "c", section="s")
    where(exc, "invalid value 'c'", "(allowed: a, b)")
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "ratio", 0.0)
    where(exc, "out of range", "> 0.0 and <= 1.0")
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "ratio", 1.5)
    where(exc, "out of range", "<= 1.0 and >= 0.0")
    with pytest.raises(ConfigError) as exc:
        validate_value(Opts, "count", -1)
    where(exc, "out of range", "(allowed: >= 0)")
    assert validate_value(Opts, "ratio", 1.0) == 1.0 and validate_value(Opts, "count", 0) == 0


# ---------------------------------------------------------------------------- parse + validate
def test_read_value_parses_then_validates():
    assert read_value(Opts, "ratio", " 1e-3 ") == 1e-3
    assert read_value(Opts, "limit", "none") is None and read_value(Opts, "flag", "yes") is True
    assert read_value(Opts, "ratio", 0.25) == 0.25  # a typed override is only validated
    with pytest.raises(ConfigError) as exc:
        read_value(Opts, "ratio", "2", file="f.ini", section="s")
    where(exc, "f.ini", "[s]", "'ratio'", "out of range")
    with pytest.raises(ConfigError) as exc:
        read_value(Opts, "ratio", "nan")
    where(exc, "NaN")
    with pytest.raises(ConfigError) as exc:
        read_value(Opts, "nope", "1")
    where(exc, "unknown option")


def test_file_and_code_give_identical_values():
    for key, text, value in [("count", "4", 4), ("ratio", "1", 1), ("flag", "on", True),
                             ("limit", "2", 2), ("name", "b", "b")]:
        from_file, from_code = read_value(Opts, key, text), validate_value(Opts, key, value)
        assert from_file == from_code and type(from_file) is type(from_code)


def test_make_options():
    base = make_options(Opts, None, count=5)
    assert base.count == 5 and base.ratio == 0.5
    again = make_options(Opts, base, ratio=1.0)
    assert again.count == 5 and again.ratio == 1.0 and again is not base
    assert make_options(Opts, {"count": 2.0}).count == 2
    with pytest.raises(ConfigError) as exc:
        make_options(Opts, ["count"])
    where(exc, "options must be a Opts or a dict, got list")
    with pytest.raises(ConfigError):
        make_options(Opts, None, count=-1)
