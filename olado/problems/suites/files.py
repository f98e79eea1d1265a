"""A user's suite as a TOML file (docs/benchmarking.md, "Suite files"):

    [suite]                                   # optional
    description = "the LQ problems at three horizons"

    [[problem]]
    problem = "lq-box"                        # a name of `olado list`, or "module:function"
    name = "lq-box-half"                      # optional label (default: problem)
    N = [10, 20, 40]                          # optional: one horizon or a list
    starts = ["sif", "balance"]               # optional: values of the factory's `start` setting
    seeds = [1, 2, 3]                         # optional: also the start perturbed with each seed
    perturbation = { controls = 0.1, states = 0.05 }   # optional, the scales of the perturbation
    settings = { umax = 0.5 }                 # optional: the factory's other keyword arguments

Every ``[[problem]]`` table expands to one entry per horizon x start x (own start and each seed).
A ``"module:function"`` factory is imported with the file's folder on ``sys.path`` (workers
inherit it). Errors are :class:`olado.errors.ConfigError` naming the file, the table
(``[problem #i]``) and the key.

TOML rather than JSON: comments, and the same shape as the ini configs' sections; read by the
standard library (:mod:`tomllib`).
"""

from __future__ import annotations

import inspect
import sys
import tomllib
from pathlib import Path

from ...errors import ConfigError, OladoError

_KEYS = {"problem", "name", "N", "starts", "seeds", "perturbation", "settings"}
_SUITE_KEYS = {"description", "name"}


def _read(path: Path) -> dict:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError("suite file not found", file=str(path)) from None
    except IsADirectoryError:
        raise ConfigError("suite path is a directory, not a file", file=str(path)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not a valid TOML file ({exc})", file=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read the suite file ({exc})", file=str(path)) from None


def _list_of(value, typ, where, key, minimum=None):
    """``value`` (one item or a list of them) as a list of ``typ``; ConfigError otherwise."""
    items = value if isinstance(value, list) else [value]
    for item in items:
        if isinstance(item, bool) or not isinstance(item, typ):
            raise ConfigError(f"expected {typ.__name__} or a list of them, got {item!r}", **where, key=key)
        if minimum is not None and item < minimum:
            raise ConfigError(f"value {item!r} out of range", **where, key=key, allowed=f">= {minimum}")
    if not items:
        raise ConfigError("empty list", **where, key=key)
    return items


def _factory_parameters(entry_cls, problem, where):
    """(names of the factory's keyword parameters, whether it takes **kwargs)."""
    probe = entry_cls(name=problem, problem=problem, settings={})
    try:
        factory = probe.factory()
    except OladoError as exc:
        raise ConfigError(str(exc).split(": ", 1)[-1], **where, key="problem") from None
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return set(), True
    named = {k for k, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    return named, any(p.kind is p.VAR_KEYWORD for p in params.values())


def _check_settings(settings, named, var_kw, where, key="settings"):
    for name in settings:
        if name not in named and not var_kw:
            raise ConfigError(f"the problem factory takes no setting {name!r}", **where, key=f"{key}.{name}",
                              allowed=", ".join(sorted(named)) or "none")


def _expand(table, index, path, entry_cls) -> list:
    where = {"file": str(path), "section": f"problem #{index}"}
    if not isinstance(table, dict):
        raise ConfigError("expected a table", **where)
    unknown = sorted(set(table) - _KEYS)
    if unknown:
        raise ConfigError("unknown key", **where, key=unknown[0], allowed=", ".join(sorted(_KEYS)))
    problem = table.get("problem")
    if not isinstance(problem, str) or not problem:
        raise ConfigError("missing or empty" if problem in (None, "") else f"expected a string, got {problem!r}",
                          **where, key="problem")
    name = table.get("name", problem)
    if not isinstance(name, str) or not name:
        raise ConfigError(f"expected a non-empty string, got {name!r}", **where, key="name")
    settings = table.get("settings", {})
    if not isinstance(settings, dict):
        raise ConfigError(f"expected a table, got {settings!r}", **where, key="settings")
    perturbation = table.get("perturbation", {})
    if not isinstance(perturbation, dict) or set(perturbation) - {"controls", "states"}:
        raise ConfigError(f"expected a table with controls and/or states, got {perturbation!r}", **where,
                          key="perturbation", allowed="controls, states")
    for k, v in perturbation.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0:
            raise ConfigError(f"expected a number >= 0, got {v!r}", **where, key=f"perturbation.{k}")
    horizons = _list_of(table["N"], int, where, "N", minimum=1) if "N" in table else [None]
    starts = _list_of(table["starts"], str, where, "starts") if "starts" in table else [None]
    seeds = _list_of(table["seeds"], int, where, "seeds") if "seeds" in table else []
    named, var_kw = _factory_parameters(entry_cls, problem, where)
    _check_settings(settings, named, var_kw, where)
    for key, values in (("N", horizons), ("start", starts)):
        if values != [None] and key not in named and not var_kw:
            raise ConfigError(f"the problem factory takes no setting {key!r}", **where,
                              key="starts" if key == "start" else key, allowed=", ".join(sorted(named)) or "none")
        if values != [None] and key in settings:
            raise ConfigError(f"{key!r} given twice (here and in settings)", **where, key=f"settings.{key}")
    out = []
    for N in horizons:
        for start in starts:
            base = dict(settings, **({"N": N} if N is not None else {}), **({"start": start} if start else {}))
            common = {"name": name, "problem": problem, "settings": base, "source": str(path),
                      "group": name, "perturbation": dict(perturbation)}
            out.append(entry_cls(**common))
            out.extend(entry_cls(**common, start="perturbed", seed=seed) for seed in seeds)
    return out


def load_suite_file(path) -> list:
    """The entries of the TOML suite file ``path`` (see the module docstring)."""
    from . import SuiteEntry

    path = Path(path)
    data = _read(path)
    unknown = sorted(set(data) - {"suite", "problem"})
    if unknown:
        raise ConfigError("unknown table", file=str(path), section=unknown[0], allowed="[suite], [[problem]]")
    suite = data.get("suite", {})
    if not isinstance(suite, dict) or set(suite) - _SUITE_KEYS:
        bad = sorted(set(suite) - _SUITE_KEYS)[0] if isinstance(suite, dict) else None
        raise ConfigError("unknown key" if bad else "expected a table", file=str(path), section="suite", key=bad,
                          allowed=", ".join(sorted(_SUITE_KEYS)))
    tables = data.get("problem")
    if not isinstance(tables, list) or not tables:
        raise ConfigError("no [[problem]] tables: a suite needs at least one problem", file=str(path))
    folder = str(path.resolve().parent)
    if folder not in sys.path:  # "module:function" factories beside the suite file
        sys.path.insert(0, folder)
    entries, seen = [], {}
    for i, table in enumerate(tables, 1):
        for entry in _expand(table, i, path, SuiteEntry):
            if entry.key in seen:
                raise ConfigError(f"problem {entry.key[0]!r} N={entry.key[1]} start {entry.key[2]!r} appears twice "
                                  f"(also in [problem #{seen[entry.key]}]); give one of them another name",
                                  file=str(path), section=f"problem #{i}", key="name")
            seen[entry.key] = i
            entries.append(entry)
    return entries
