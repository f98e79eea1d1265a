"""Options of olado's components: declaration, parsing from ini strings and validation, in one place.

An options class is a dataclass whose fields are declared with :func:`option` (default, help
text, allowed choices, numeric range, whether an ini file may set it)::

    @dataclasses.dataclass
    class MyOptions:
        tol: float = option(1e-8, "stopping tolerance", min=0.0, min_exclusive=True)
        method: str = option("a", "which variant", choices=("a", "b"))
        limit: float | None = option(None, "None: no limit")

The declared type says how a value is read and checked: ``bool``, ``int`` (within the range of
a 32-bit C int, :data:`INT_LIMIT`), ``float``, ``str``, ``dict`` (or ``dict[...]``),
``Callable`` (anything callable; never from a file), each optionally ``| None``; any other type
is passed through unchecked. :func:`validate_value` checks (and coerces) a typed value, e.g. a keyword argument;
:func:`read_value` first parses an ini string (:func:`parse_value`) and then validates it, so a
value from a file and the same value given in code end up identical. Every error is a
:class:`~olado.errors.ConfigError` naming where the value came from and what is allowed.

This module is a leaf: it imports nothing of olado but :mod:`olado.errors`.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import math
import sys
import typing
from typing import Any

from .errors import ConfigError

__all__ = ["option", "option_fields", "OptionSpec", "option_specs", "split_optional", "is_dict_type", "is_callable_type",
           "parse_value", "parse_scalar", "validate_value", "read_value", "make_options", "raw_options_field"]

#: every integer option is a C int somewhere (IPOPT's and the QP back-ends' iteration limits)
INT_LIMIT = 2**31 - 1

TRUE_WORDS = ("true", "yes", "on", "1")
FALSE_WORDS = ("false", "no", "off", "0")
NONE_WORDS = ("none", "null", "")


# ---------------------------------------------------------------------------- declaration
def option(default, help="", *, choices=None, min=None, max=None, min_exclusive=False, ini=True, raw=False):
    """Declare an option: a dataclass field with validation metadata. ``ini=False``: not settable
    from a file (a callable, say); ``raw=True`` marks the dict option that receives an ini file's
    ``[<solver>.raw]`` section (:mod:`olado.config`)."""
    meta = {"help": help, "choices": choices, "min": min, "max": max,
            "min_exclusive": min_exclusive, "ini": ini, "raw": raw}
    if isinstance(default, (dict, list)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def option_fields(options_cls):
    """The dataclass fields of an options class, in declaration order."""
    return dataclasses.fields(options_cls)


@dataclasses.dataclass(frozen=True)
class OptionSpec:
    """One option as the engine sees it: its field, the declared type hint, and that hint with
    ``None`` split off (``kind``: the type values are parsed and checked as; ``optional``: None
    is allowed)."""

    field: dataclasses.Field
    hint: Any
    kind: Any
    optional: bool

    @property
    def name(self) -> str:
        return self.field.name

    @property
    def meta(self):
        return self.field.metadata

    @property
    def settable_from_file(self) -> bool:
        return self.meta.get("ini", True)


#: options class -> {name: OptionSpec}; the one cache of resolved type hints (classes do not change)
_SPECS: dict = {}


def option_specs(options_cls) -> dict:
    """``{name: OptionSpec}`` of an options class, in declaration order (cached per class)."""
    specs = _SPECS.get(options_cls)
    if specs is None:
        hints = _type_hints(options_cls)
        specs = {}
        for f in dataclasses.fields(options_cls):
            hint = hints.get(f.name, Any)
            kind, optional = split_optional(hint)
            specs[f.name] = OptionSpec(f, hint, kind, optional)
        _SPECS[options_cls] = specs
    return specs


def _type_hints(options_cls) -> dict:
    try:
        return typing.get_type_hints(options_cls)
    except Exception:  # an unresolvable annotation: the raw strings (values then go unchecked)
        return {f.name: f.type for f in dataclasses.fields(options_cls)}


def split_optional(typ):
    """``(inner type, allows None)``: ``X | None`` -> ``(X, True)``; a union of several types
    -> ``(Any, None among them)``; anything else -> ``(typ, False)``."""
    if typing.get_origin(typ) is typing.Union or type(typ).__name__ == "UnionType":
        args = typing.get_args(typ)
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1 and len(args) == 2:
            return inner[0], True
        return Any, type(None) in args
    return typ, False


def is_dict_type(typ) -> bool:
    return typ is dict or typing.get_origin(typ) is dict


def is_callable_type(typ) -> bool:
    """``Callable`` or ``Callable[[...], ...]`` (of collections.abc or typing)."""
    return typ is collections.abc.Callable or typing.get_origin(typ) is collections.abc.Callable


def raw_options_field(options_cls, solver_name: str) -> str | None:
    """Name of the options field that receives a ``[<solver>.raw]`` section, or None.

    In order: a dict field with metadata ``raw=True``; a field named ``<solver>_options``
    (dashes as underscores); a field named ``raw_options``."""
    specs = option_specs(options_cls)
    for spec in specs.values():
        if spec.meta.get("raw") and is_dict_type(spec.hint):
            return spec.name
    for candidate in (solver_name.replace("-", "_").replace(".", "_") + "_options", "raw_options"):
        if candidate in specs and is_dict_type(specs[candidate].hint):
            return candidate
    return None


# ---------------------------------------------------------------------------- parsing ini strings
def _parse_number(text):
    """int, else float, else None."""
    try:
        return int(text, 10)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return None


def _is_quoted(text: str) -> bool:
    return len(text) >= 2 and text[0] == text[-1] and text[0] in "'\""


def _unquote(text: str) -> str:
    return text[1:-1] if _is_quoted(text) else text


def parse_scalar(text: str):
    """Best-effort typing of an untyped value (raw back-end options): int, float or str."""
    text = text.strip()
    if _is_quoted(text):
        return text[1:-1]
    number = _parse_number(text)
    return text if number is None else number


def parse_value(text, typ, *, file=None, section=None, key=None):
    """Convert an ini string to the declared type ``typ``; a value that is not a string (a typed
    override, a keyword argument) is returned as it is. Range and choices are
    :func:`validate_value`'s job."""
    kind, optional = split_optional(typ)
    return _parse(text, kind, optional, file=file, section=section, key=key)


def _parse(text, kind, optional, *, file, section, key):
    if not isinstance(text, str):
        return text
    text = text.strip()
    if optional and text.lower() in NONE_WORDS:
        return None
    if kind is bool:
        low = text.lower()
        if low in TRUE_WORDS or low in FALSE_WORDS:
            return low in TRUE_WORDS
        raise ConfigError(f"expected a boolean, got {text!r}", file=file, section=section, key=key,
                          allowed="true, false, yes, no, on, off, 1, 0")
    if kind is int:
        value = _parse_number(text)
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {text!r}", file=file, section=section,
                              key=key, allowed="an integer such as 100")
        return value
    if kind is float:
        value = _parse_number(text)
        if value is None:
            raise ConfigError(f"expected a number, got {text!r}", file=file, section=section,
                              key=key, allowed="a number such as 1e-8, 0.5 or inf")
        return float(value)
    if kind is str:
        return _unquote(text)
    if is_dict_type(kind):
        raise ConfigError("a mapping cannot be written as one value; use a [<solver>.raw] section",
                          file=file, section=section, key=key)
    return parse_scalar(text)


# ---------------------------------------------------------------------------- validation
def _numpy_scalar_types():
    """(bool, integer, floating) scalar types of numpy, or empty tuples when numpy has not been
    imported (then no value can be a numpy scalar, and this module need not import numpy)."""
    np = sys.modules.get("numpy")
    if np is None:
        return (), (), ()
    return (np.bool_,), (np.integer,), (np.floating,)


def _spec(options_cls, name, *, file=None, section=None) -> OptionSpec:
    specs = option_specs(options_cls)
    if name not in specs:
        raise ConfigError("unknown option", file=file, section=section, key=name,
                          allowed=", ".join(s.name for s in specs.values() if s.settable_from_file))
    return specs[name]


def validate_value(options_cls, name, value, *, file=None, section=None):
    """Check (and coerce) one typed option value; raise ConfigError naming where it came from."""
    return _check(_spec(options_cls, name, file=file, section=section), value, file=file, section=section)


def read_value(options_cls, name, value, *, file=None, section=None):
    """One option value from a file or an override: a string is parsed as the declared type,
    then checked as :func:`validate_value` checks a typed value."""
    spec = _spec(options_cls, name, file=file, section=section)
    typed = _parse(value, spec.kind, spec.optional, file=file, section=section, key=name)
    return _check(spec, typed, file=file, section=section)


def _check(spec: OptionSpec, value, *, file, section):
    if spec.optional and value is None:
        return None
    where = {"file": file, "section": section, "key": spec.name}
    value = _check_type(spec.kind, value, where)
    _check_bounds(spec.meta, value, where)
    return value


def _check_type(kind, value, where):
    np_bool, np_int, np_float = _numpy_scalar_types()
    if kind is bool:
        if not isinstance(value, (bool, *np_bool)):
            raise ConfigError(f"expected true/false, got {value!r}", **where)
        return bool(value)
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, (int, *np_int)):
            if not (isinstance(value, float) and value.is_integer()):
                raise ConfigError(f"expected an integer, got {value!r}", **where)
        value = int(value)
        if abs(value) > INT_LIMIT:
            raise ConfigError(f"value {value!r} out of range: integer options are C ints of the "
                              "back-ends", **where, allowed=f"-{INT_LIMIT} .. {INT_LIMIT}")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float, *np_int, *np_float)):
            raise ConfigError(f"expected a number, got {value!r}", **where)
        value = float(value)
        if math.isnan(value):
            raise ConfigError("NaN is not allowed", **where)
        return value
    if kind is str and not isinstance(value, str):
        raise ConfigError(f"expected a string, got {value!r}", **where)
    if is_dict_type(kind) and not isinstance(value, dict):
        raise ConfigError(f"expected a mapping, got {value!r}", **where)
    if is_callable_type(kind) and not callable(value):
        raise ConfigError(f"expected a function (a callable), got {type(value).__name__} {value!r:.40}", **where)
    return value


def _check_bounds(meta, value, where):
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"invalid value {value!r}", **where, allowed=", ".join(map(str, choices)))
    lo, hi, exclusive = meta.get("min"), meta.get("max"), meta.get("min_exclusive")
    if lo is not None and (value < lo or (exclusive and value == lo)):
        allowed = f"{'>' if exclusive else '>='} {lo}" + (f" and <= {hi}" if hi is not None else "")
        raise ConfigError(f"value {value!r} out of range", **where, allowed=allowed)
    if hi is not None and value > hi:
        raise ConfigError(f"value {value!r} out of range", **where,
                          allowed=f"<= {hi}" + (f" and >= {lo}" if lo is not None else ""))


def make_options(options_cls, given=None, **overrides):
    """A validated options object from an instance or a dict of ``options_cls`` plus keyword
    overrides."""
    if isinstance(given, options_cls):
        values = {f.name: getattr(given, f.name) for f in option_fields(options_cls)}
    elif given is None:
        values = {}
    elif isinstance(given, dict):
        values = dict(given)
    else:
        raise ConfigError(f"options must be a {options_cls.__name__} or a dict, got {type(given).__name__}")
    values.update(overrides)
    checked = {name: validate_value(options_cls, name, value) for name, value in values.items()}
    return options_cls(**checked)
