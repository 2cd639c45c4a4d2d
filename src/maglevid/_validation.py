"""Checks at the public boundary: one place that turns bad input into clear errors."""

from __future__ import annotations

from typing import Any

import numpy as np

from maglevid.exceptions import DataError

__all__ = ["as_matrix", "as_signal", "check_finite", "check_positive", "readonly"]


def readonly(a: np.ndarray) -> np.ndarray:
    """Return a read-only float64 copy of ``a`` (immutable models and data)."""
    out = np.array(a, dtype=float, copy=True)
    out.setflags(write=False)
    return out


def check_finite(a: np.ndarray, name: str) -> None:
    """Raise :class:`DataError` naming ``name`` and the first bad sample if ``a`` has NaN/inf."""
    if a.dtype.kind == "f" and np.isfinite(np.add.reduce(a, axis=None)):
        return  # a NaN or inf makes the sum NaN or inf: one pass, no boolean temporary
    bad = ~np.isfinite(a)
    if bad.any():
        idx = np.argwhere(bad)[0]
        kind = "NaN" if np.isnan(a[tuple(idx)]) else "inf"
        raise DataError(
            f"`{name}` contains {int(bad.sum())} non-finite value(s) ({kind} first at index "
            f"{tuple(int(i) for i in idx)}); remove or interpolate them before use"
        )


def check_positive(value: Any, name: str) -> float:
    """Return ``value`` as a float, raising :class:`DataError` unless finite and > 0."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise DataError(f"`{name}` must be a positive number; got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise DataError(f"`{name}` must be a positive number; got {value!r}")
    return v


def as_signal(
    x: Any,
    name: str,
    *,
    n_samples: int | None = None,
    n_channels: int | None = None,
    min_samples: int = 1,
    copy: bool = True,
) -> np.ndarray:
    """Validate a time-first signal and return it as a read-only ``(N, n_channels)`` array.

    A 1-D array is one channel. A wrong shape is an error, never silently transposed.
    ``copy=False`` returns the validated float array itself (no read-only copy), for
    callers that only read it and keep no reference (a fit over a long record).
    """
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(
            f"`{name}` must be 1-D or 2-D (time first); got {a.ndim}-D shape {a.shape}"
        )
    want_n = "N" if n_samples is None else str(n_samples)
    want_c = "n" if n_channels is None else str(n_channels)
    if (n_samples is not None and a.shape[0] != n_samples) or (
        n_channels is not None and a.shape[1] != n_channels
    ):
        raise DataError(
            f"`{name}` has shape {a.shape}; expected ({want_n}, {want_c}) with time along axis 0"
        )
    if a.shape[0] < min_samples:
        raise DataError(f"`{name}` has {a.shape[0]} samples; at least {min_samples} are needed")
    check_finite(a, name)
    return readonly(a) if copy else a


def as_matrix(x: Any, name: str, shape: tuple[int | None, int | None] | None = None) -> np.ndarray:
    """Validate a finite 2-D matrix (a scalar or 1-D vector is not reshaped) and copy it."""
    a = np.asarray(x, dtype=float)
    if a.ndim != 2:
        raise DataError(f"`{name}` must be a 2-D matrix; got shape {a.shape}")
    if shape is not None:
        for axis, want in enumerate(shape):
            if want is not None and a.shape[axis] != want:
                raise DataError(f"`{name}` has shape {a.shape}; expected {shape}")
    check_finite(a, name)
    return readonly(a)
