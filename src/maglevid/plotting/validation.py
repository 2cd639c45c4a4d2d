"""Figures of model validation: residual correlations (``resid``) and fits (``compare``)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from maglevid.exceptions import DataError
from maglevid.identify.validation import Comparison, ResidualAnalysis

__all__ = ["plot_compare", "plot_resid"]


def _figure(size: tuple[float, float]) -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("plotting needs matplotlib: `pip install maglevid[plot]`") from exc
    return Figure(figsize=size, layout="constrained")


def plot_resid(analysis: ResidualAnalysis, *, path: str | os.PathLike[str] | None = None) -> Any:
    """Autocorrelation of each residual and its cross-correlation with each input, with bands.

    One row per output: the autocorrelation at lags 1..M with the white-noise
    band, then one panel per input with ``rho_eu(tau)``, ``tau = -M..M``, and the
    Bartlett band (``tau > 0``: past inputs; ``tau < 0`` is shaded, where
    feedback makes correlation expected).

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not isinstance(analysis, ResidualAnalysis):
        raise DataError(f"`analysis` must be a ResidualAnalysis; got {type(analysis).__name__}")
    ny, nu = analysis.cross_band.shape
    fig = _figure((3.0 * (nu + 1), 2.0 * ny + 0.6))
    axes = fig.subplots(ny, nu + 1, squeeze=False)
    pct = f"{analysis.level:.0%}"
    for i, name in enumerate(analysis.output_names):
        ax = axes[i, 0]
        ax.stem(analysis.lags[1:], analysis.autocorrelation[1:, i], basefmt=" ")
        ax.axhspan(-analysis.auto_band, analysis.auto_band, color="0.85", zorder=0)
        verdict = "white" if analysis.white[i] else "not white"
        ax.set_title(f"{name}: autocorrelation ({verdict})", fontsize="small")
        for j, uname in enumerate(analysis.input_names):
            ax = axes[i, j + 1]
            ax.axvspan(analysis.cross_lags[0], 0, color="0.95", zorder=0)
            ax.stem(analysis.cross_lags, analysis.cross_correlation[:, i, j], basefmt=" ")
            b = analysis.cross_band[i, j]
            ax.axhspan(-b, b, color="0.85", zorder=0)
            ax.set_title(f"{name} vs past {uname}", fontsize="small")
    for ax in axes[-1]:
        ax.set_xlabel("lag [control periods]")
    fig.suptitle(f"residual analysis, {pct} bands (N = {analysis.n_samples})", fontsize="medium")
    if path is not None:
        fig.savefig(os.fspath(path), dpi=110)
    return fig


def plot_compare(
    comparison: Comparison,
    *,
    max_samples: int = 2000,
    path: str | os.PathLike[str] | None = None,
) -> Any:
    """Measured outputs with the k-step predictions and the simulation, fit % in the legend."""
    if not isinstance(comparison, Comparison):
        raise DataError(f"`comparison` must be a Comparison; got {type(comparison).__name__}")
    n = min(int(max_samples), comparison.y.shape[0])
    t = np.arange(n) * comparison.dt
    ny = comparison.y.shape[1]
    fig = _figure((9.0, 1.9 * ny + 0.6))
    axes = fig.subplots(ny, 1, sharex=True, squeeze=False)[:, 0]
    curves = [
        (f"{k}-step", p, comparison.fit_percent[k]) for k, p in comparison.predictions.items()
    ]
    if comparison.simulation is not None:
        curves.append(
            (
                comparison.simulation_kind,
                comparison.simulation,
                comparison.fit_percent["simulation"],
            )
        )
    for j, name in enumerate(comparison.output_names):
        ax = axes[j]
        ax.plot(t, comparison.y[:n, j], color="0.3", lw=0.9, label="measured")
        for label, yhat, fit in curves:
            ax.plot(t, yhat[:n, j], lw=0.8, label=f"{label}: {fit[j]:.1f} %")
        ax.set_ylabel(name)
        ax.legend(loc="upper right", fontsize="x-small")
    axes[-1].set_xlabel("time [s]")
    if path is not None:
        fig.savefig(os.fspath(path), dpi=110)
    return fig
