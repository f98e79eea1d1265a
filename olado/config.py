"""Ini files -> typed, validated solver options (ARCHITECTURE.md, "Conventions").

An olado configuration file is a plain ini file::

    [solver]
    name = ipopt              ; a registry name: ipopt, slsqp, trust-constr, ...

    [ipopt]                   ; fields of the solver's Options dataclass, typed and range-checked
    tol = 1e-8
    max_iter = 500
    max_time = inf
    verbose = 1

    [ipopt.raw]               ; passed through untouched to the back-end (IPOPT's own option names)
    mu_strategy = adaptive
    print_level = 0

    [problem]                 ; optional, used by the command line: olado solve
    name = zambezi12
    N = 24
    start = sif
    year = 1

Values are read as what the option's declared type says: integers, floats (``inf``, ``-inf`` and
``1e-8`` included), booleans (``true/false``, ``yes/no``, ``on/off``, ``1/0``) and strings; an
optional option (``float | None``) also takes ``none``. In a ``[<solver>.raw]`` section, whose
keys are not known in advance, a value that reads as an integer becomes an int, one that reads as
a number a float, anything else a string (write ``1.0``, not ``1``, for a floating-point IPOPT
option). The raw section lands in the Options field that carries pass-through options: a dict
field whose metadata has ``raw=True``, or that is named ``raw_options`` or ``<solver>_options``
(``ipopt_options`` for IPOPT).

Sections named after another registered solver are validated too but not applied, so one file may
hold presets for several solvers and ``[solver] name`` (or ``--set solver.name=...``) picks one.
Anything else -- an unknown section, an unknown key, a value of the wrong type or out of range --
is a :class:`~olado.errors.ConfigError` that names the file, the section, the key and the allowed
values.

Overrides (the command line's ``--set``, or :func:`load_config`'s ``overrides``) are
``"section.key=value"`` strings, or a dict ``{"section.key": value}`` / ``{"section": {key:
value}}``; a key with no section (``"tol=1e-6"``) goes to the selected solver's section. They are
applied on top of the file.
"""

from __future__ import annotations

import configparser
import dataclasses
import typing
from pathlib import Path
from typing import Any

from .errors import ConfigError

__all__ = [
    "SolverConfig",
    "load_config",
    "config_from_kwargs",
    "make_solver",
    "default_solver_name",
    "solver_available",
    "raw_options_field",
    "parse_overrides",
    "PROBLEM_KEYS",
]

#: Keys of the optional ``[problem]`` section and their types (matched case-insensitively).
PROBLEM_KEYS = {"name": str, "N": int, "start": str, "year": int}

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")
_OVERRIDES = "<overrides>"


@dataclasses.dataclass
class SolverConfig:
    """A validated configuration: which solver, its typed Options, the ``[problem]`` section
    (possibly empty) and where it came from (a file path, ``<kwargs>`` or ``<defaults>``)."""

    solver: str
    options: Any
    problem: dict = dataclasses.field(default_factory=dict)
    source: str = "<defaults>"

    def options_dict(self) -> dict:
        """The options as a plain dict (for logging and results)."""
        return {f.name: getattr(self.options, f.name) for f in dataclasses.fields(self.options)}


# ---------------------------------------------------------------------------- solver lookup
def _registry():
    from .solvers import registry

    return registry


def solver_available(cls_or_name) -> bool:
    """True when the solver's optional back-end can be imported (e.g. cyipopt for ipopt).

    A solver class may say so itself through an ``available()`` classmethod (or a boolean
    ``available`` attribute); a solver that says nothing is taken to be available."""
    cls = cls_or_name
    if isinstance(cls_or_name, str):
        try:
            cls = _registry().get_solver_class(cls_or_name)
        except ConfigError:
            return False
    for attr in ("available", "is_available", "backend_available"):
        probe = getattr(cls, attr, None)
        if probe is None:
            continue
        try:
            return bool(probe() if callable(probe) else probe)
        except Exception:  # a broken back-end is a missing one
            return False
    return True


def default_solver_name() -> str:
    """The solver used when none is named: ``ipopt`` when cyipopt is installed (it exploits the
    sparse stage structure and is the reference solver of the paper), else SciPy's
    ``trust-constr`` (sparse-aware, always available)."""
    solvers = _registry().available_solvers()
    for name in ("ipopt", "trust-constr", "slsqp"):
        if name in solvers and solver_available(solvers[name]):
            return name
    for name, cls in sorted(solvers.items()):
        if solver_available(cls):
            return name
    raise ConfigError("no solver is available", allowed=", ".join(sorted(solvers)))


def _solver_class(name, *, file=None, section=None, key=None):
    reg = _registry()
    solvers = reg.available_solvers()
    if name not in solvers:
        raise ConfigError(f"unknown solver {name!r}", file=file, section=section, key=key,
                          allowed=", ".join(sorted(solvers)))
    return solvers[name]


# ---------------------------------------------------------------------------- typing helpers
def _type_hints(options_cls) -> dict:
    try:
        return typing.get_type_hints(options_cls)
    except Exception:  # unresolvable annotation: fall back to the raw strings
        return {f.name: f.type for f in dataclasses.fields(options_cls)}


def _is_dict_type(typ) -> bool:
    return typ is dict or typing.get_origin(typ) is dict


def raw_options_field(options_cls, solver_name: str) -> str | None:
    """Name of the Options field that receives a ``[<solver>.raw]`` section, or None.

    In order: a dict field with metadata ``raw=True``; a field named ``<solver>_options``
    (dashes as underscores); a field named ``raw_options``."""
    hints = _type_hints(options_cls)
    fields = {f.name: f for f in dataclasses.fields(options_cls)}
    for f in fields.values():
        if f.metadata.get("raw") and _is_dict_type(hints.get(f.name)):
            return f.name
    for candidate in (solver_name.replace("-", "_").replace(".", "_") + "_options", "raw_options"):
        if candidate in fields and _is_dict_type(hints.get(candidate, dict)):
            return candidate
    return None


def _split_optional(typ):
    """(inner type, allows None) for ``X | None`` / ``Optional[X]``."""
    args = typing.get_args(typ)
    origin = typing.get_origin(typ)
    if origin is typing.Union or type(typ).__name__ == "UnionType":
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1 and len(args) == 2:
            return inner[0], True
        return Any, type(None) in args
    return typ, False


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


def _unquote(text: str) -> str:
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    return text


def parse_scalar(text: str):
    """Best-effort typing of an untyped value (raw back-end options): int, float or str."""
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    number = _parse_number(text)
    return text if number is None else number


def parse_value(text, typ, *, file=None, section=None, key=None):
    """Convert an ini string to the declared type ``typ`` (validation of range/choices is
    :func:`olado.solvers.base.validate_value`'s job)."""
    if not isinstance(text, str):  # already typed (dict overrides, keyword arguments)
        return text
    text = text.strip()
    inner, optional = _split_optional(typ)
    if optional and text.lower() in ("none", "null", ""):
        return None
    typ = inner
    if typ is bool:
        low = text.lower()
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        raise ConfigError(f"expected a boolean, got {text!r}", file=file, section=section, key=key,
                          allowed="true, false, yes, no, on, off, 1, 0")
    if typ is int:
        value = _parse_number(text)
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {text!r}", file=file, section=section,
                              key=key, allowed="an integer such as 100")
        return value
    if typ is float:
        value = _parse_number(text)
        if value is None:
            raise ConfigError(f"expected a number, got {text!r}", file=file, section=section,
                              key=key, allowed="a number such as 1e-8, 0.5 or inf")
        return float(value)
    if typ is str:
        return _unquote(text)
    if _is_dict_type(typ):
        raise ConfigError("a mapping cannot be written as one value; use a [<solver>.raw] section",
                          file=file, section=section, key=key)
    return parse_scalar(text)


# ---------------------------------------------------------------------------- reading
def _read_ini(path: Path) -> dict:
    """{section: {key: value-string}} of an ini file, with olado's error messages."""
    parser = configparser.ConfigParser(interpolation=None, inline_comment_prefixes=(";", "#"),
                                       empty_lines_in_values=False)
    parser.optionxform = str  # keys keep their case: IPOPT's options are case-sensitive
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError("configuration file not found", file=str(path)) from None
    except IsADirectoryError:
        raise ConfigError("configuration path is a directory, not a file", file=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read configuration file ({exc})", file=str(path)) from None
    try:
        parser.read_string(text, source=str(path))
    except configparser.DuplicateSectionError as exc:
        raise ConfigError("section appears twice", file=str(path), section=exc.section) from None
    except configparser.DuplicateOptionError as exc:
        raise ConfigError("key appears twice", file=str(path), section=exc.section,
                          key=exc.option) from None
    except configparser.MissingSectionHeaderError as exc:
        raise ConfigError(f"line {exc.lineno}: a key before any [section] header", file=str(path),
                          allowed="[solver], [problem], [<solver>], [<solver>.raw]") from None
    except configparser.Error as exc:
        raise ConfigError(f"not a valid ini file ({exc.message.splitlines()[0]})",
                          file=str(path)) from None
    if parser.defaults():
        raise ConfigError("a [DEFAULT] section is not supported", file=str(path), section="DEFAULT",
                          allowed="[solver], [problem], [<solver>], [<solver>.raw]")
    return {s: dict(parser.items(s, raw=True)) for s in parser.sections()}


def _split_override(item):
    """'section.key=value' -> (section, key, value); 'key=value' -> (None, key, value)."""
    if not isinstance(item, str) or "=" not in item:
        raise ConfigError(f"override {item!r} is not of the form section.key=value",
                          file=_OVERRIDES, allowed="section.key=value, e.g. ipopt.tol=1e-6")
    lhs, value = item.split("=", 1)
    lhs = lhs.strip()
    if not lhs:
        raise ConfigError(f"override {item!r} has no key", file=_OVERRIDES,
                          allowed="section.key=value, e.g. ipopt.tol=1e-6")
    section, _, key = lhs.rpartition(".")
    return (section or None), key.strip(), value.strip()


def parse_overrides(overrides) -> list:
    """Normalise overrides to a list of (section or None, key, value)."""
    if overrides is None:
        return []
    out = []
    if isinstance(overrides, dict):
        for lhs, value in overrides.items():
            if isinstance(value, dict):
                out.extend((str(lhs), str(k), v) for k, v in value.items())
                continue
            section, _, key = str(lhs).rpartition(".")
            out.append((section or None, key, value))
        return out
    if isinstance(overrides, str):
        overrides = [overrides]
    for item in overrides:
        out.append(_split_override(item))
    return out


def load_config(path=None, overrides=None) -> SolverConfig:
    """Read an ini file (or none) plus overrides into a validated :class:`SolverConfig`.

    ``path`` None means defaults only (solver: :func:`default_solver_name`). ``overrides``: a
    list of ``"section.key=value"`` strings (the CLI's ``--set``) or a dict (see the module
    docstring). Raises :class:`ConfigError` naming file, section, key and allowed values."""
    # layered raw values: section -> key -> (value, origin)
    layers: dict[str, dict[str, tuple[Any, str]]] = {}
    source = "<defaults>"
    if path is not None:
        path = Path(path)
        source = str(path)
        for section, items in _read_ini(path).items():
            layers.setdefault(section, {}).update({k: (v, source) for k, v in items.items()})
    pending = parse_overrides(overrides)

    # which solver: --set solver.name wins over the file, which wins over the default
    name_entry = layers.get("solver", {}).get("name")
    for section, key, value in pending:
        if section == "solver" and key.lower() == "name":
            name_entry = (value, _OVERRIDES)
    if name_entry is None:
        solver = default_solver_name()
    else:
        solver = str(name_entry[0]).strip()
        _solver_class(solver, file=name_entry[1], section="solver", key="name")
    for section, key, value in pending:
        if section is None:
            section = solver
        layers.setdefault(section, {})[key] = (value, _OVERRIDES)

    solvers = _registry().available_solvers()
    allowed_sections = ["solver", "problem"]
    for sname in sorted(solvers):
        allowed_sections += [sname, f"{sname}.raw"]
    allowed_text = ", ".join(f"[{s}]" for s in allowed_sections)

    options = None
    problem: dict = {}
    for section, items in layers.items():
        if section == "solver":
            for key, (value, origin) in items.items():
                if key.lower() != "name":
                    raise ConfigError("unknown key", file=origin, section="solver", key=key,
                                      allowed="name")
        elif section == "problem":
            problem = _problem_section(items)
        elif section.endswith(".raw") and section[:-4] in solvers:
            sname = section[:-4]
            cls = solvers[sname]
            if raw_options_field(cls.Options, sname) is None:
                origin = next(iter(items.values()))[1] if items else source
                raise ConfigError(f"solver {sname!r} takes no pass-through options", file=origin,
                                  section=section, allowed=", ".join(f"[{s}]" for s in
                                                                     allowed_sections[:2] + [sname]))
        elif section in solvers:
            pass  # checked below
        else:
            origin = next(iter(items.values()))[1] if items else source
            raise ConfigError("unknown section", file=origin, section=section, allowed=allowed_text)

    # validate every solver's section (presets for other solvers too), build the selected one
    for sname in [s for s in solvers if s in layers or f"{s}.raw" in layers] + [solver]:
        built = _build_options(solvers[sname], sname, layers.get(sname, {}),
                               layers.get(f"{sname}.raw", {}), source)
        if sname == solver:
            options = built
    return SolverConfig(solver=solver, options=options, problem=problem, source=source)


def _problem_section(items) -> dict:
    canonical = {k.lower(): k for k in PROBLEM_KEYS}
    out = {}
    for key, (value, origin) in items.items():
        name = canonical.get(key.lower())
        if name is None:
            raise ConfigError("unknown key", file=origin, section="problem", key=key,
                              allowed=", ".join(PROBLEM_KEYS))
        typ = PROBLEM_KEYS[name]
        value = parse_value(value, typ, file=origin, section="problem", key=key)
        if typ is int and (isinstance(value, bool) or not isinstance(value, int)):
            raise ConfigError(f"expected an integer, got {value!r}", file=origin, section="problem",
                              key=key)
        if name == "N" and value < 1:
            raise ConfigError(f"value {value!r} out of range", file=origin, section="problem",
                              key=key, allowed=">= 1")
        out[name] = value
    return out


def _build_options(cls, sname, items, raw_items, source):
    from .solvers.base import validate_value

    options_cls = cls.Options
    hints = _type_hints(options_cls)
    fields = {f.name: f for f in dataclasses.fields(options_cls)}
    raw_field = raw_options_field(options_cls, sname)
    settable = [f.name for f in fields.values() if f.metadata.get("ini", True) and f.name != raw_field]
    values = {}
    for key, (value, origin) in items.items():
        f = fields.get(key)
        if f is None or key == raw_field or (not f.metadata.get("ini", True) and isinstance(value, str)):
            why = "unknown option" if f is None else (
                f"option '{key}' cannot be set from a file" if key != raw_field
                else f"write pass-through options in a [{sname}.raw] section")
            raise ConfigError(why, file=origin, section=sname, key=key, allowed=", ".join(settable))
        typed = parse_value(value, hints.get(key, Any), file=origin, section=sname, key=key)
        values[key] = validate_value(options_cls, key, typed, file=origin, section=sname)
    if raw_items:
        raw = dict(getattr(options_cls(), raw_field) or {}) if raw_field else {}
        for key, (value, origin) in raw_items.items():
            raw[key] = parse_scalar(value) if isinstance(value, str) else value
        values[raw_field] = raw
    try:
        return options_cls(**values)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(str(exc), file=source, section=sname) from None


# ---------------------------------------------------------------------------- from code
def config_from_kwargs(solver=None, **options) -> SolverConfig:
    """A :class:`SolverConfig` from keyword options, validated against the solver's Options
    (``solver`` None: :func:`default_solver_name`)."""
    from .solvers.base import validate_value

    name = default_solver_name() if solver is None else solver
    cls = _solver_class(name)
    checked = {k: validate_value(cls.Options, k, v, section=name) for k, v in options.items()}
    return SolverConfig(solver=name, options=cls.Options(**checked), problem={}, source="<kwargs>")


def with_overrides(config: SolverConfig, **options) -> SolverConfig:
    """A copy of ``config`` with keyword options replaced (validated)."""
    from .solvers.base import validate_value

    cls = _solver_class(config.solver)
    checked = {k: validate_value(cls.Options, k, v, section=config.solver) for k, v in options.items()}
    new_options = dataclasses.replace(config.options, **checked)
    return SolverConfig(solver=config.solver, options=new_options, problem=dict(config.problem),
                        source=config.source)


def make_solver(config: SolverConfig):
    """Instantiate the configured solver with its options."""
    cls = _solver_class(config.solver)
    return cls(config.options)
