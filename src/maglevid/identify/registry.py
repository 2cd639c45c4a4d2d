"""Names of the identification methods, for ``maglevid identify --method NAME``.

A module of :mod:`maglevid.identify` registers methods by defining
``METHODS = {"name": fit_function}``; each function takes a
:class:`~maglevid.data.ClosedLoopData` and keyword options and returns an
:class:`~maglevid.identify.result.IdentificationResult`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from maglevid._plugins import modules_with
from maglevid.exceptions import DataError

__all__ = ["available_methods", "get_method"]


def available_methods() -> dict[str, Callable[..., Any]]:
    """All registered methods, by name."""
    out: dict[str, Callable[..., Any]] = {}
    for mod in modules_with("maglevid.identify", "METHODS"):
        for name, fn in mod.METHODS.items():
            if name in out:
                raise RuntimeError(f"identification method {name!r} is registered twice")
            out[name] = fn
    return out


def get_method(name: str) -> Callable[..., Any]:
    """The fit function registered as ``name``; a clear error lists the valid names."""
    methods = available_methods()
    if name not in methods:
        raise DataError(f"unknown method {name!r}; available: {', '.join(sorted(methods))}")
    return methods[name]
