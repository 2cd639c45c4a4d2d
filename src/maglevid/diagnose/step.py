"""A step in a parameter's history: one sudden change rather than a slow drift.

A fault such as a failing amplifier moves a parameter once, between two
recordings; a heating coil moves it slowly. :func:`detect_step` tests, for every
split of the series into a before and an after (at least two points each), the
difference of the weighted means::

    z_k = (m_after - m_before) / sqrt(v_before + v_after)

with ``v = s^2 / sum(w)``, ``w = 1 / se^2`` and ``s^2 = max(1, chi^2 / dof)``
the scatter of the points about their segment means beyond their standard
errors (equal weights and ``s^2`` the points' own scatter when a standard error
is missing). The largest ``|z_k|``
is judged with a Bonferroni correction over the ``n - 3`` splits:
``p = min(1, (n - 3) * 2 Phi(-|z|))``, a conservative level-``alpha`` test.

:func:`step_fits_better` tells which of the two describes a series better: a
significant step whose two means leave less weighted scatter than the
straight line of the drift test.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import special

from maglevid.exceptions import DataError

__all__ = ["StepResult", "detect_step", "step_fits_better"]


@dataclass(frozen=True)
class StepResult:
    """The most significant step of a series."""

    index: int  # first point after the step
    before: float
    after: float
    z: float
    p_value: float
    alpha: float
    rss_step: float  # weighted residual sum of squares of the two-mean model

    @property
    def significant(self) -> bool:
        return self.p_value < self.alpha

    @property
    def size(self) -> float:
        return self.after - self.before

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "before": self.before,
            "after": self.after,
            "size": self.size,
            "z": self.z,
            "p_value": self.p_value,
            "alpha": self.alpha,
            "significant": self.significant,
        }


def _weights(y: np.ndarray, se: Any) -> tuple[np.ndarray, bool]:
    """Weights ``1 / se^2``, and whether the standard errors are known."""
    if se is None:
        return np.ones_like(y), False
    se = np.asarray(se, dtype=float)
    if se.shape != y.shape:
        raise DataError(f"`se` has shape {se.shape}; expected {y.shape}")
    if not np.all(np.isfinite(se) & (se > 0)):
        return np.ones_like(y), False  # unknown errors: equal weights, scatter from the data
    return 1.0 / se**2, True


def _mean(y: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    """Weighted mean, sum of weights, weighted residual sum of squares."""
    sw = float(w.sum())
    m = float(w @ y) / sw
    return m, sw, float(w @ (y - m) ** 2)


def detect_step(y: Any, se: Any = None, *, alpha: float = 0.01) -> StepResult | None:
    """The most significant single step of ``y`` (time order), or ``None`` below 5 points."""
    y = np.asarray(y, dtype=float)
    if y.ndim != 1 or not np.all(np.isfinite(y)):
        raise DataError("`y` must be a finite 1-D series")
    n = y.size
    if n < 5:
        return None
    w, known = _weights(y, se)
    best: tuple[float, int, float, float, float] | None = None
    for k in range(2, n - 1):
        m1, s1, r1 = _mean(y[:k], w[:k])
        m2, s2, r2 = _mean(y[k:], w[k:])
        scale = (r1 + r2) / (n - 2)
        scale = max(1.0, scale) if known else max(scale, np.finfo(float).tiny)
        z = (m2 - m1) / np.sqrt(scale * (1 / s1 + 1 / s2))
        if best is None or abs(z) > abs(best[0]):
            best = (float(z), k, m1, m2, r1 + r2)
    assert best is not None
    z, k, m1, m2, rss = best
    p = min(1.0, (n - 3) * float(special.erfc(abs(z) / np.sqrt(2))))
    return StepResult(k, m1, m2, z, p, alpha, rss)


def step_fits_better(t: Any, y: Any, se: Any, step: StepResult) -> bool:
    """Whether the two means of ``step`` leave less weighted scatter than a straight line."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    w = _weights(y, se)[0]
    X = np.column_stack([np.ones_like(t), t - t.mean()]) * np.sqrt(w)[:, None]
    coef = np.linalg.lstsq(X, y * np.sqrt(w), rcond=None)[0]
    rss_line = float(np.sum((y * np.sqrt(w) - X @ coef) ** 2))
    return step.rss_step < rss_line
