"""Figures 3-4 of Gosiewski & Paszowski: impulse responses, simulated vs identified."""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from maglevid.exceptions import DataError

__all__ = ["plot_impulse_comparison"]

_STYLES = ("-", "--", ":", "-.")


def plot_impulse_comparison(
    t: Any,
    curves: Mapping[str, Any],
    *,
    title: str,
    ylabel: str = "displacement x [um]",
    scale: float = 1e6,
    path: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
) -> Any:
    """Overlay impulse responses (the paper's Figs. 3 and 4).

    Parameters
    ----------
    t : array_like, shape (N,)
        Time [s] (drawn in ms).
    curves : mapping of label -> array_like, shape (N,)
        Responses in SI units; the first is drawn solid and wide, the others
        dashed on top, so that coinciding curves stay distinguishable.
    title : str
    ylabel : str
    scale : float
        Display factor (default m -> um).
    path : str or path-like, optional
        Where to save the figure (PNG from the extension).

    Returns
    -------
    matplotlib.figure.Figure
    """
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("plotting needs matplotlib: `pip install maglevid[plot]`") from exc
    t = np.asarray(t, dtype=float)
    if not curves:
        raise DataError("`curves` is empty")
    fig = Figure(figsize=(7, 3.6), layout="constrained")
    ax = fig.add_subplot()
    for i, (label, y) in enumerate(curves.items()):
        y = np.asarray(y, dtype=float)
        if y.shape != t.shape:
            raise DataError(f"curve {label!r} has shape {y.shape}; expected {t.shape}")
        ax.plot(
            t * 1e3,
            y * scale,
            _STYLES[i % len(_STYLES)],
            lw=3.0 if i == 0 else 1.4,
            alpha=0.55 if i == 0 else 1.0,
            label=label,
        )
    ax.set_xlabel("time [ms]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    if path is not None:
        from maglevid.plotting.signals import save_figure

        save_figure(fig, path, dpi=120, overwrite=overwrite)
    return fig
