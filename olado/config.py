"""Ini files -> typed, validated solver options (docs/architecture.md, "Conventions").

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
applied on top of the file; keyword options (:func:`with_overrides`, ``olado.solve(..., tol=...)``)
on top of both.

This module reads files and layers values; reading and checking one value is
:mod:`olado.options`' job, the solver names come from :data:`olado.solvers.registry.SOLVERS`.
"""

from __future__ import annotations

import configparser
import dataclasses
import os
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .options import option_specs, parse_scalar, parse_value, raw_options_field, read_value, validate_value
from .solvers.registry import SOLVERS

__all__ = [
    "SolverConfig",
    "load_config",
    "config_from_kwargs",
    "with_overrides",
    "make_solver",
    "default_solver_name",
    "raw_options_field",
    "parse_overrides",
    "PROBLEM_KEYS",
]

#: Keys of the optional ``[problem]`` section and their types (matched case-insensitively).
PROBLEM_KEYS = {"name": str, "N": int, "start": str, "year": int}

_OVERRIDES = "<overrides>"
#: solvers tried, in order, when none is named
_DEFAULT_SOLVERS = ("ipopt", "trust-constr", "slsqp")


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
def default_solver_name() -> str:
    """The solver used when none is named: ``ipopt`` when cyipopt is installed (it exploits the
    sparse stage structure and is the reference solver of the paper), else SciPy's
    ``trust-constr`` (sparse-aware, always available)."""
    for name in (*_DEFAULT_SOLVERS, *sorted(SOLVERS)):
        if name in SOLVERS and SOLVERS[name].available():
            return name
    raise ConfigError("no solver is available", allowed=", ".join(sorted(SOLVERS)))


def _solver_class(name):
    """The class of solver ``name`` (its module imported now); an unknown name is a ConfigError."""
    _check_solver_name(name)
    return SOLVERS[name]


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


#: section -> key -> (value, origin: the file it was read from or "<overrides>")
Layers = dict[str, dict[str, tuple[Any, str]]]


def load_config(path=None, overrides=None) -> SolverConfig:
    """Read an ini file (or none) plus overrides into a validated :class:`SolverConfig`.

    ``path`` None means defaults only (solver: :func:`default_solver_name`). ``overrides``: a
    list of ``"section.key=value"`` strings (the CLI's ``--set``) or a dict (see the module
    docstring). Raises :class:`ConfigError` naming file, section, key and allowed values."""
    layers, source = _file_layers(path)
    pending = parse_overrides(overrides)
    solver = _selected_solver(layers, pending)
    for section, key, value in pending:
        layers.setdefault(section or solver, {})[key] = (value, _OVERRIDES)
    problem = _check_sections(layers, source)
    # every solver section is validated (presets for other solvers too); the selected one is used
    built = {name: _build_options(name, layers.get(name, {}), layers.get(f"{name}.raw", {}), source)
             for name in SOLVERS if name == solver or name in layers or f"{name}.raw" in layers}
    return SolverConfig(solver=solver, options=built[solver], problem=problem, source=source)


def _file_layers(path) -> tuple[Layers, str]:
    """The values of the ini file ``path`` (None: no file) and the config's source name."""
    if path is None:
        return {}, "<defaults>"
    if not isinstance(path, (str, os.PathLike)):
        raise ConfigError(f"expected a file path (str or pathlib.Path) or None, got {type(path).__name__} {path!r:.40}")
    source = str(Path(path))
    layers = {section: {k: (v, source) for k, v in items.items()}
              for section, items in _read_ini(Path(path)).items()}
    return layers, source


def _selected_solver(layers: Layers, pending) -> str:
    """``--set solver.name`` wins over the file's ``[solver] name``, which wins over the default."""
    name_entry = layers.get("solver", {}).get("name")
    for section, key, value in pending:
        if section == "solver" and key.lower() == "name":
            name_entry = (value, _OVERRIDES)
    if name_entry is None:
        return default_solver_name()
    solver = str(name_entry[0]).strip()
    _check_solver_name(solver, file=name_entry[1], section="solver", key="name")
    return solver


def _check_solver_name(name, *, file=None, section=None, key=None) -> None:
    if name not in SOLVERS:
        raise ConfigError(f"unknown solver {name!r}", file=file, section=section, key=key,
                          allowed=", ".join(sorted(SOLVERS)))


def _allowed_sections(solver=None) -> list[str]:
    """``[solver]``, ``[problem]`` and the sections of ``solver`` (None: of every solver)."""
    names = sorted(SOLVERS) if solver is None else [solver]
    return ["solver", "problem", *(s for name in names for s in (name, f"{name}.raw"))]


def _origin(items, source) -> str:
    return next(iter(items.values()))[1] if items else source


def _check_sections(layers: Layers, source) -> dict:
    """Reject unknown sections and keys outside the solvers' sections; the ``[problem]`` values."""
    problem: dict = {}
    for section, items in layers.items():
        if section == "solver":
            for key, (_, origin) in items.items():
                if key.lower() != "name":
                    raise ConfigError("unknown key", file=origin, section="solver", key=key, allowed="name")
        elif section == "problem":
            problem = _problem_section(items)
        elif section.endswith(".raw") and section[:-4] in SOLVERS:
            name = section[:-4]
            if raw_options_field(SOLVERS[name].Options, name) is None:
                raise ConfigError(f"solver {name!r} takes no pass-through options", file=_origin(items, source),
                                  section=section, allowed=_bracketed(_allowed_sections(name)[:3]))
        elif section not in SOLVERS:
            raise ConfigError("unknown section", file=_origin(items, source), section=section,
                              allowed=_bracketed(_allowed_sections()))
    return problem


def _bracketed(sections) -> str:
    return ", ".join(f"[{s}]" for s in sections)


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


def _build_options(name, items, raw_items, source):
    """The Options of solver ``name`` from its section's values and its ``.raw`` section's."""
    options_cls = SOLVERS[name].Options
    specs = option_specs(options_cls)
    raw_field = raw_options_field(options_cls, name)
    values = {}
    for key, (value, origin) in items.items():
        spec = specs.get(key)
        if spec is None or key == raw_field or (not spec.settable_from_file and isinstance(value, str)):
            why = "unknown option" if spec is None else (
                f"option '{key}' cannot be set from a file" if key != raw_field
                else f"write pass-through options in a [{name}.raw] section")
            settable = [s.name for s in specs.values() if s.settable_from_file and s.name != raw_field]
            raise ConfigError(why, file=origin, section=name, key=key, allowed=", ".join(settable))
        values[key] = read_value(options_cls, key, value, file=origin, section=name)
    if raw_items:
        raw = dict(getattr(options_cls(), raw_field) or {})
        for key, (value, _) in raw_items.items():
            raw[key] = parse_scalar(value) if isinstance(value, str) else value
        values[raw_field] = raw
    try:
        return options_cls(**values)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(str(exc), file=source, section=name) from None


# ---------------------------------------------------------------------------- from code
def config_from_kwargs(solver=None, **options) -> SolverConfig:
    """A :class:`SolverConfig` from keyword options, validated against the solver's Options
    (``solver`` None: :func:`default_solver_name`)."""
    name = default_solver_name() if solver is None else solver
    cls = _solver_class(name)
    checked = {k: validate_value(cls.Options, k, v, section=name) for k, v in options.items()}
    return SolverConfig(solver=name, options=cls.Options(**checked), problem={}, source="<kwargs>")


def with_overrides(config: SolverConfig, **options) -> SolverConfig:
    """A copy of ``config`` with keyword options replaced (validated)."""
    cls = _solver_class(config.solver)
    checked = {k: validate_value(cls.Options, k, v, section=config.solver) for k, v in options.items()}
    new_options = dataclasses.replace(config.options, **checked)
    return SolverConfig(solver=config.solver, options=new_options, problem=dict(config.problem),
                        source=config.source)


def make_solver(config: SolverConfig):
    """Instantiate the configured solver with its options."""
    return _solver_class(config.solver)(config.options)
