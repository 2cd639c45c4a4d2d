"""Persistent excitation signals ``r(k)`` added to the feedback (Gosiewski & Paszowski, eq. (16)).

Each input channel gets its own independent sequence, so that both amplifier
inputs are excited and the two columns of ``B`` can be told apart.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from maglevid.exceptions import DataError

__all__ = ["EXCITATION_KINDS", "make_excitation"]

#: Kinds :func:`make_excitation` accepts.
EXCITATION_KINDS = ("gaussian", "prbs")


def _stds(std: Any, n_channels: int) -> np.ndarray:
    s = np.asarray(std, dtype=float).reshape(-1)
    if s.size == 1:
        s = np.full(n_channels, s[0])
    if s.size != n_channels or not np.all(np.isfinite(s)) or np.any(s < 0):
        raise DataError(
            f"`std` must be one non-negative number or {n_channels} of them; got {std!r}"
        )
    return s


def make_excitation(
    n_samples: int,
    n_channels: int,
    *,
    std: Any,
    kind: str = "gaussian",
    hold: int = 1,
    rng: np.random.Generator,
) -> np.ndarray:
    """Excitation ``r``, shape ``(n_samples, n_channels)``, zero mean.

    Parameters
    ----------
    n_samples, n_channels : int
    std : float or sequence of float
        Standard deviation per channel (for ``"prbs"`` the two levels are
        ``+-std``, whose standard deviation is ``std``).
    kind : {"gaussian", "prbs"}
        ``"gaussian"``: white Gaussian noise. ``"prbs"``: pseudo-random binary
        sequence, each level drawn independently (random sign) and held for
        ``hold`` samples; with ``hold = 1`` it is white.
    hold : int
        Samples each PRBS level is held (a longer hold moves power to low
        frequencies; ``hold`` is ignored for ``"gaussian"``).
    rng : numpy.random.Generator
        Source of randomness (the only one).

    Examples
    --------
    >>> r = make_excitation(4, 2, std=0.5, kind="prbs", rng=np.random.default_rng(0))
    >>> sorted(set(np.abs(r).ravel().tolist()))
    [0.5]
    """
    if kind not in EXCITATION_KINDS:
        raise DataError(f"`kind` must be one of {EXCITATION_KINDS}; got {kind!r}")
    n_samples, n_channels, hold = int(n_samples), int(n_channels), int(hold)
    if n_samples < 0 or n_channels < 1 or hold < 1:
        raise DataError(
            f"need n_samples >= 0, n_channels >= 1, hold >= 1; got {n_samples}, {n_channels}, "
            f"{hold}"
        )
    s = _stds(std, n_channels)
    if kind == "gaussian":
        return rng.standard_normal((n_samples, n_channels)) * s
    n_levels = -(-n_samples // hold)
    levels = rng.integers(0, 2, size=(n_levels, n_channels)) * 2.0 - 1.0
    return np.repeat(levels, hold, axis=0)[:n_samples] * s
