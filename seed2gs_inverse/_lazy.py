"""Packages whose public names are imported from their submodules on first use (PEP 562).

The package's ``__init__`` and ``pipeline/__init__`` use it: importing the
rasterizer loads Numba, which ``import seed2gs_inverse`` and building the
``seed2gs`` parser must not (docs/architecture.md, "Imports").
"""

from __future__ import annotations

import importlib
import sys
import types

__all__ = ["install"]


class _LazyPackage(types.ModuleType):
    """A package whose names in ``_lazy_names`` (name -> submodule) resolve on first use.

    A public function wins over its namesake submodule: importing
    ``pipeline.extract`` binds the submodule on the package, which would
    otherwise replace the function ``extract`` for everyone after it.
    """

    _lazy_names: dict = {}

    def __getattr__(self, name: str):
        module = self._lazy_names.get(name)
        if module is None:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", self.__name__), name)
        setattr(self, name, value)  # cache: later lookups skip __getattr__
        return value

    def __dir__(self):
        return sorted(set(self.__dict__) | set(self._lazy_names))

    def __setattr__(self, name, value):
        if isinstance(value, types.ModuleType) and self._lazy_names.get(name) == name:
            value = getattr(value, name)
        super().__setattr__(name, value)


def install(package: str, names: dict) -> None:
    """Make ``package`` (already in ``sys.modules``) resolve ``names`` (public name -> submodule) lazily."""
    cls = type("_LazyPackage", (_LazyPackage,), {"_lazy_names": dict(names)})
    sys.modules[package].__class__ = cls
