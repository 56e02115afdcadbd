"""Names a package hands out on first use: its ``__init__`` stays light (no torch), so that the command line and the
stages' Configs read a package's settings without loading what its models and renderers need."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_names"]


def lazy_names(package: str, modules: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: ``modules`` maps each lazy name to the submodule that defines it."""

    def __getattr__(name: str) -> Any:
        if name not in modules:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        sub = importlib.import_module(f"{package}.{modules[name]}")
        # bind the submodule's lazy names in the package, as an eager import would: importing the submodule has just
        # set the package's attribute of the submodule's name (render.composite) to the module, not the function
        pkg = sys.modules[package]
        for other, where in modules.items():
            if where == modules[name]:
                setattr(pkg, other, getattr(sub, other))
        return getattr(sub, name)

    return __getattr__
