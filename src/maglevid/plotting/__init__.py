"""Figures (matplotlib, object-oriented API: headless, no global state changed).

Every plot function is importable from here, e.g.
``from maglevid.plotting import plot_signals, plot_resid``; matplotlib is
imported only when one is used.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public plot function -> the module that defines it.
_WHERE = {
    "plot_signals": "signals",
    "plot_parameter_changes": "diagnosis",
    "plot_pole_maps": "diagnosis",
    "plot_impulse_responses": "diagnosis",
    "plot_frequency_responses": "diagnosis",
    "plot_trends": "diagnosis",
    "plot_impulse_comparison": "gosiewski",
    "plot_pole_map": "sun",
    "plot_singular_values": "sun",
    "plot_resid": "validation",
    "plot_compare": "validation",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"maglevid.plotting.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'maglevid.plotting' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
