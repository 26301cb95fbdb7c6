"""A package's public names, imported on first use (PEP 562).

A package ``__init__`` lists where each of its names lives and hands the table here::

    _LAZY_MODULES = {"vp2.run.config": ["RunConfig"], ...}
    __getattr__, __dir__, __all__ = lazy_exports(__name__, _LAZY_MODULES)

so that importing one module of the package does not import the others (or torch).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any


def lazy_exports(
    package: str, modules: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """The ``__getattr__``, ``__dir__`` and ``__all__`` of ``package``, whose names live in
    ``modules`` (module path -> the names it defines)."""
    where = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(where[name]), name)

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *where})

    return __getattr__, __dir__, sorted(where)
