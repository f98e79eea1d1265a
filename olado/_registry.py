"""Explicit lazy tables of named components: ``name -> "module:Class"``.

One shape for every registry of olado (solvers, QP methods, KKT back-ends): the table is
declared once, as data, in the package that owns the components; nothing is imported until a
name is looked up, so listing the names or choosing one component never imports the others.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping

from .errors import ConfigError


class LazyRegistry(Mapping):
    """Read-only mapping ``name -> class`` whose classes are imported on first lookup.

    ``kind`` names the component in errors ("solver", "QP method", "KKT back-end"), ``key`` the
    option that selects it; ``entries`` maps each name to ``"package.module:ClassName"``.
    """

    def __init__(self, kind: str, entries: dict[str, str], key: str | None = None):
        self.kind = kind
        self.key = key
        self._targets = dict(entries)
        self._loaded: dict[str, type] = {}

    def target(self, name: str) -> str:
        """``"module:Class"`` of ``name``, without importing it."""
        try:
            return self._targets[name]
        except KeyError:
            raise ConfigError(f"unknown {self.kind} {name!r}", key=self.key,
                              allowed=", ".join(self._targets)) from None

    def __getitem__(self, name: str) -> type:
        if name not in self._loaded:
            module, _, attr = self.target(name).partition(":")
            self._loaded[name] = getattr(importlib.import_module(module), attr)
        return self._loaded[name]

    def __contains__(self, name) -> bool:
        return name in self._targets

    def __iter__(self):
        return iter(self._targets)

    def __len__(self) -> int:
        return len(self._targets)

    def __repr__(self) -> str:
        return f"LazyRegistry({self.kind!r}, {list(self._targets)})"
