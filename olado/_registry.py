"""Explicit lazy tables of named components: ``name -> "module:Class"``.

One shape for every registry of olado (solvers, QP methods, KKT back-ends): the table is
declared once, as data, in the package that owns the components; nothing is imported until a
name is looked up, so listing the names or choosing one component never imports the others.

An entry is a ``"module:Class"`` string, or an :class:`Entry` that also carries what a listing
shows without importing anything: a one-line summary and the optional modules the component
needs (checked with :func:`importlib.util.find_spec`, which finds a module without importing it).
"""

from __future__ import annotations

import dataclasses
import importlib
import sys
import importlib.util
from collections.abc import Mapping

from .errors import ConfigError


@dataclasses.dataclass(frozen=True)
class Entry:
    """One component of a registry: where its class is (``"package.module:ClassName"``), a
    one-line summary, the optional top-level modules it needs and how to install them."""

    target: str
    summary: str = ""
    requires: tuple[str, ...] = ()
    install: str = ""


class LazyRegistry(Mapping):
    """Mapping ``name -> class`` whose classes are imported on first lookup.

    ``kind`` names the component in errors ("solver", "QP method", "KKT back-end"), ``key`` the
    option that selects it; ``entries`` maps each name to ``"package.module:ClassName"`` or an
    :class:`Entry`. :meth:`add` declares one more entry at run time (a plug-in, a test's dummy).
    """

    def __init__(self, kind: str, entries: dict[str, str | Entry], key: str | None = None):
        self.kind = kind
        self.key = key
        self._entries = {name: _as_entry(e) for name, e in entries.items()}
        self._loaded: dict[str, type] = {}

    def entry(self, name: str) -> Entry:
        """The :class:`Entry` of ``name``, without importing it; an unknown name is a
        :class:`ConfigError` naming the allowed ones."""
        try:
            return self._entries[name]
        except KeyError:
            raise ConfigError(f"unknown {self.kind} {name!r}", key=self.key,
                              allowed=", ".join(self._entries)) from None

    def target(self, name: str) -> str:
        """``"module:Class"`` of ``name``, without importing it."""
        return self.entry(name).target

    def summary(self, name: str) -> str:
        return self.entry(name).summary

    def missing(self, name: str) -> list[str]:
        """The optional modules ``name`` needs that are not installed (none imported to tell)."""
        return [module for module in self.entry(name).requires if importlib.util.find_spec(module) is None]

    def add(self, name: str, target: str | Entry | type) -> None:
        """Declare ``name`` (replacing an entry of that name); ``target`` may be a class itself."""
        if isinstance(target, type):
            self._entries[name] = Entry(f"{target.__module__}:{target.__qualname__}")
            self._loaded[name] = target
            return
        self._entries[name] = _as_entry(target)
        self._loaded.pop(name, None)

    def remove(self, name: str) -> None:
        self.entry(name)
        del self._entries[name]
        self._loaded.pop(name, None)

    def __getitem__(self, name: str) -> type:
        if name not in self._loaded:
            module, _, attr = self.target(name).partition(":")
            self._loaded[name] = getattr(importlib.import_module(module), attr)
        return self._loaded[name]

    def get(self, name, default=None):
        return self[name] if name in self._entries else default

    def __contains__(self, name) -> bool:
        return name in self._entries

    def __iter__(self):
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"LazyRegistry({self.kind!r}, {list(self._entries)})"


def _as_entry(entry: str | Entry) -> Entry:
    return entry if isinstance(entry, Entry) else Entry(entry)


def lazy_attributes(module_name: str, names: dict[str, str], submodules=()):
    """``(__getattr__, __dir__)`` for a package whose public names load on first access (PEP 562):
    ``names`` maps each name to the module that defines it, ``submodules`` lists the package's
    submodules reachable as attributes. A loaded value is stored on the package, so each name
    is imported once."""

    def __getattr__(name):
        if name in names:
            value = getattr(importlib.import_module(names[name]), name)
        elif name in submodules:
            value = importlib.import_module(f"{module_name}.{name}")
        else:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        setattr(sys.modules[module_name], name, value)
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[module_name])) | set(names) | set(submodules))

    return __getattr__, __dir__
