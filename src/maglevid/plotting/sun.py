"""Figures 6-9 of Sun et al.: singular values of the data matrix and estimated pole maps."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from maglevid.exceptions import DataError

__all__ = ["plot_pole_map", "plot_singular_values"]

_STYLES = ("-", "--", ":", "-.")


def _figure(size: tuple[float, float]) -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("plotting needs matplotlib: `pip install maglevid[plot]`") from exc
    return Figure(figsize=size, layout="constrained")


def plot_singular_values(
    curves: Mapping[str, Any],
    *,
    title: str = "Singular values of Phi (L = 20, M = 2500, j = p - 1)",
    path: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
) -> Any:
    """Fig. 6: singular values ``sigma_i`` of the data matrix, one curve per ``p``.

    Parameters
    ----------
    curves : mapping of label -> array_like
        Singular values, largest first (e.g. ``{"p = 1": s1, "p = 2": s2}``);
        drawn normalised by their largest, on a log axis.
    title : str
    path : str or path-like, optional
        Where to save the figure (PNG from the extension).

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not curves:
        raise DataError("`curves` is empty")
    fig = _figure((6.4, 3.8))
    ax = fig.add_subplot()
    floor = np.finfo(float).eps
    for i, (label, s) in enumerate(curves.items()):
        s = np.asarray(s, dtype=float)
        if s.ndim != 1 or s.size == 0:
            raise DataError(f"curve {label!r} must be a non-empty 1-D array; got {s.shape}")
        ax.semilogy(
            np.arange(1, s.size + 1),
            np.maximum(s / s[0], floor),
            _STYLES[i % len(_STYLES)],
            marker="o",
            ms=3,
            label=label,
        )
    ax.set_xlabel("i")
    ax.set_ylabel("sigma_i / sigma_1")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if path is not None:
        from maglevid.plotting.signals import save_figure

        save_figure(fig, path, dpi=120, overwrite=overwrite)
    return fig


def plot_pole_map(
    estimates: Sequence[Any],
    nominal: Any,
    *,
    title: str,
    zoom: tuple[float, float, float, float] | None = (0.7, 1.3, -0.3, 0.3),
    path: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
) -> Any:
    """Figs. 7-9: estimated poles of every run (``*``) and the nominal ones (``o``).

    Parameters
    ----------
    estimates : sequence of array_like
        Poles of each run (complex).
    nominal : array_like
        The true (nominal) poles.
    title : str
    zoom : (x0, x1, y0, y1) or None
        Axis limits around ``z = 1``; ``None`` shows everything.
    path : str or path-like, optional
        Where to save the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure((5.0, 4.4))
    ax = fig.add_subplot()
    th = np.linspace(0, 2 * np.pi, 721)
    ax.plot(np.cos(th), np.sin(th), "k-", lw=0.8, label="unit circle")
    first = True
    for z in estimates:
        z = np.asarray(z, dtype=complex).ravel()
        ax.plot(z.real, z.imag, "r*", ms=7, label="estimate" if first else None)
        first = False
    zn = np.asarray(nominal, dtype=complex).ravel()
    ax.plot(zn.real, zn.imag, "o", mfc="none", mec="b", ms=11, mew=1.6, label="nominal")
    if zoom is not None:
        ax.set_xlim(zoom[0], zoom[1])
        ax.set_ylim(zoom[2], zoom[3])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    if path is not None:
        from maglevid.plotting.signals import save_figure

        save_figure(fig, path, dpi=120, overwrite=overwrite)
    return fig
