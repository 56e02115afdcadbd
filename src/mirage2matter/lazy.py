"""Names a package hands out on first use: its ``__init__`` stays light (no torch), so that the command line and the
stages' Configs read a package's settings without loading what its models and renderers need; and work that needs a
third-party module done when that module is imported (:func:`when_imported`), without importing it."""

from __future__ import annotations

import importlib
import importlib.abc
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_names", "when_imported"]


def lazy_names(package: str, modules: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: ``modules`` maps each lazy name to the submodule that defines it."""

    def __getattr__(name: str) -> Any:
        if name not in modules:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        sub = importlib.import_module(f"{package}.{modules[name]}")
        # bind the submodule's lazy names in the package, as an eager import would (a lazy name must not be its
        # submodule's own name: importing the submodule sets the package's attribute of that name to the module)
        pkg = sys.modules[package]
        for other, where in modules.items():
            if where == modules[name]:
                setattr(pkg, other, getattr(sub, other))
        return getattr(sub, name)

    return __getattr__


def when_imported(module: str, then: Callable[[], None]) -> None:
    """Call ``then()`` once ``module`` is imported: now if it already is, else right after its first import (a
    one-shot import hook), so that a package can register itself with a library it does not load itself."""
    if module in sys.modules:
        then()
    else:
        sys.meta_path.insert(0, _AfterImport(module, then))


class _AfterImport(importlib.abc.MetaPathFinder):
    """Finds ``module`` through the finders after it and runs ``then`` once the module's code has run."""

    def __init__(self, module: str, then: Callable[[], None]) -> None:
        self.module, self.then = module, then

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != self.module or self not in sys.meta_path:
            return None
        later = sys.meta_path[sys.meta_path.index(self) + 1 :]
        spec = next((s for f in later if hasattr(f, "find_spec") and (s := f.find_spec(fullname, path, target))), None)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        run = spec.loader.exec_module

        def exec_module(mod: Any) -> None:
            run(mod)
            if self in sys.meta_path:  # stays until the module has run: a find_spec alone (a probe) is no import
                sys.meta_path.remove(self)
                self.then()

        spec.loader.exec_module = exec_module  # this spec's loader only (a finder makes one per found module)
        return spec
