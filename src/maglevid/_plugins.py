"""Discovery of the modules of a package that declare an attribute.

Commands, simulation scenarios, identification methods and reproductions are
found by module: adding one means adding one file, with no central list to edit.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

__all__ = ["modules_with"]


def modules_with(package: str, attribute: str) -> list[ModuleType]:
    """Import every public module of ``package`` and return those defining ``attribute``."""
    pkg = importlib.import_module(package)
    out = []
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{package}.{info.name}")
        if hasattr(mod, attribute):
            out.append(mod)
    return out
