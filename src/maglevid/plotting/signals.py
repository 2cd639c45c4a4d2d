"""Time plots of a closed-loop recording (matplotlib, no pyplot state, no GUI)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError

__all__ = ["plot_signals"]

# Display scaling per unit: SI in the data, readable units on the axes.
_DISPLAY = {"m": (1e6, "um"), "A": (1e3, "mA"), "V": (1.0, "V")}


def plot_signals(
    data: ClosedLoopData,
    *,
    path: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    max_samples: int = 2000,
    title: str | None = None,
) -> Any:
    """Plot outputs, feedback and excitation of a recording against time.

    One panel per output channel (displacement in um, currents in mA), then one
    panel with ``u_f`` and ``r`` per input channel [V]. Only the first
    ``max_samples`` control periods are drawn, so that individual samples stay
    visible.

    Parameters
    ----------
    data : ClosedLoopData
    path : str or path-like, optional
        Where to save the figure (format from the extension, e.g. ``.png``).
    max_samples : int
        Control periods drawn from the start of the record.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
        Built with the object-oriented API (works headless; no global backend
        is changed).
    """
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("plotting needs matplotlib: `pip install maglevid[plot]`") from exc
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    n = min(int(max_samples), data.n_samples)
    if n < 1:
        raise DataError(f"`max_samples` must be >= 1; got {max_samples!r}")
    t = data.time[:n]
    inputs = [s for s in ("u_f", "r") if getattr(data, s) is not None]
    n_panels = data.ny + (data.nu if inputs else 0)
    fig = Figure(figsize=(9, 1.9 * n_panels + 0.6), layout="constrained")
    axes = fig.subplots(n_panels, 1, sharex=True, squeeze=False)[:, 0]
    y = np.asarray(data.y_control)[:n]
    for j, (name, unit) in enumerate(zip(data.channel_names("y"), data.channel_units("y"))):
        scale, shown = _DISPLAY.get(unit, (1.0, unit))
        axes[j].plot(t, y[:, j] * scale, lw=0.8)
        axes[j].set_ylabel(f"{name} [{shown}]" if shown else name)
    for i in range(data.nu if inputs else 0):
        ax = axes[data.ny + i]
        for sig in inputs:
            arr = np.asarray(getattr(data, sig))[:n, i]
            ax.plot(t, arr, lw=0.8, label=data.channel_names(sig)[i])
        unit = data.channel_units(inputs[0])[i]
        ax.set_ylabel(f"input {i + 1} [{unit}]" if unit else f"input {i + 1}")
        ax.legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    if path is not None:
        save_figure(fig, path, dpi=110, overwrite=overwrite)
    return fig


def save_figure(
    fig: Any, path: str | os.PathLike[str], *, dpi: int = 120, overwrite: bool = False
) -> Path:
    """Save ``fig`` to ``path`` by the rules of every maglevid output.

    Through :func:`maglevid.io.write_output`: atomically, never over an
    existing file unless ``overwrite``, never over a folder or special file;
    the format comes from the extension.
    """
    from maglevid.io import write_output

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    return write_output(
        path, lambda tmp: fig.savefig(os.fspath(tmp), dpi=dpi, format=fmt), overwrite=overwrite
    )
