"""Names of the identification methods, for ``maglevid identify --method NAME``.

A module of :mod:`maglevid.identify` registers methods by defining
``METHODS = {"name": fit_function}``; each function takes a
:class:`~maglevid.data.ClosedLoopData` and keyword options and returns an
:class:`~maglevid.identify.result.IdentificationResult`. Its one-line
description (``--method list``) is ``DESCRIPTIONS[name]`` where the module
defines it, else the first line of the function's docstring.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from maglevid._plugins import modules_with
from maglevid.exceptions import DataError

__all__ = ["available_methods", "describe_methods", "get_method"]


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


def describe_methods() -> dict[str, str]:
    """One line of description per registered method, by name (sorted)."""
    out: dict[str, str] = {}
    for mod in modules_with("maglevid.identify", "METHODS"):
        described = getattr(mod, "DESCRIPTIONS", {})
        for name, fn in mod.METHODS.items():
            doc = (getattr(fn, "__doc__", None) or "").strip().splitlines()
            out[name] = described.get(name) or (doc[0].replace("``", "") if doc else "")
    return dict(sorted(out.items()))
