"""Drift of a physical parameter over time: a stated test, not two points compared.

Given the history of one parameter (times ``t_i``, estimates ``y_i`` and their
standard errors ``s_i``), :func:`detect_drift` asks whether the parameter has a
linear trend, and if a tolerance band around a baseline is given, when the
trend will leave it.

Methods
-------
``"wls"`` (default)
    Weighted least-squares line with weights ``w_i = 1 / s_i**2`` and a
    t-test on the slope. Model::

        y_i = a + b (t_i - t_w) + e_i,   e_i ~ N(0, phi * s_i**2) independent,

    where ``t_w`` is the weighted mean time and ``phi`` a common scale of the
    stated errors, estimated from the residuals (reduced chi-square, n - 2
    degrees of freedom; ``absolute_sigma=True`` fixes ``phi = 1`` and uses the
    normal distribution instead). Under ``b = 0`` the statistic
    ``T = b_hat / se(b_hat)`` is Student-t with ``n - 2`` degrees of freedom
    exactly, so the false-alarm rate is ``alpha`` whatever the number of
    points. Without standard errors all weights are equal (ordinary least
    squares).
``"mann-kendall"``
    Non-parametric: Kendall's tau between time and value (exact null
    distribution for small samples without ties, normal approximation
    otherwise; ``scipy.stats.kendalltau``), with Sen's slope and its
    confidence interval (``scipy.stats.theilslopes``). Robust to outliers and
    non-normal errors, ignores the standard errors, and is less powerful than
    WLS when the WLS assumptions hold.

Both assume independent errors between recordings: estimates that share a
slowly varying disturbance (temperature, a re-tuned controller) are positively
correlated and make either test reject too often; see ``docs/history.md``.

Crossing time
-------------
With ``tolerance`` the limit is ``L = baseline + sign(b) * tolerance`` (the
side the trend moves to), and the projected crossing time solves
``a + b (t - t_w) = L``. Its confidence interval is Fieller's (exact for a
ratio of normal estimates under the model, unbounded when the slope is not
significantly non-zero at that level), its standard error the delta method.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import special, stats

from maglevid.exceptions import DataError

__all__ = ["STEP_SHARE", "DriftResult", "StepResult", "detect_drift", "detect_step"]

_METHODS = ("wls", "mann-kendall")
_ALTERNATIVES = ("two-sided", "increasing", "decreasing")


@dataclass(frozen=True)
class DriftResult:
    """Outcome of :func:`detect_drift`.

    Attributes
    ----------
    method : str
        ``"wls"`` (or ``"ols"`` when no standard errors were given) or
        ``"mann-kendall"``.
    n : int
        Number of points.
    slope, slope_se : float
        Trend in value units per time unit, and its standard error (for
        Mann-Kendall the half-width of Sen's interval over the normal quantile).
    slope_ci : (float, float)
        Confidence interval of the slope at ``confidence``.
    t_ref, value_at_ref : float
        A point of the fitted line: its value at time ``t_ref``.
    statistic : float
        t (WLS), z (WLS with ``absolute_sigma``) or Kendall's tau.
    dof : float or None
        Degrees of freedom of the t distribution (``None`` when normal/exact).
    p_value : float
        p-value of "no trend" against ``alternative``.
    alpha : float
        Significance level; ``drifting`` is ``p_value < alpha``.
    alternative : str
        ``"two-sided"``, ``"increasing"`` or ``"decreasing"``.
    drifting : bool
        Whether the test rejects "no trend" at level ``alpha``.
    scale : float or None
        WLS: sqrt of the reduced chi-square (Birge ratio). Near 1 when the
        stated standard errors explain the scatter around the line; well above
        1 means the points scatter more than their errors say.
    baseline, tolerance, limit : float or None
        The band ``baseline +- tolerance`` and the limit the trend heads to.
    projected_crossing_time : float or None
        When the fitted line reaches ``limit`` (same unit as the times); may
        be in the past.
    crossing_se : float or None
        Delta-method standard error of the crossing time (WLS only).
    crossing_ci : (float, float) or None
        Fieller confidence interval (WLS; ``(-inf, inf)`` when unbounded) or
        the interval from Sen's slope bounds (Mann-Kendall, approximate).
    confidence : float
        Level of ``slope_ci`` and ``crossing_ci``.
    notes : tuple of str
        What was assumed or found marginal.
    """

    method: str
    n: int
    slope: float
    slope_se: float
    slope_ci: tuple[float, float]
    t_ref: float
    value_at_ref: float
    statistic: float
    dof: float | None
    p_value: float
    alpha: float
    alternative: str
    drifting: bool
    scale: float | None
    baseline: float | None
    tolerance: float | None
    limit: float | None
    projected_crossing_time: float | None
    crossing_se: float | None
    crossing_ci: tuple[float, float] | None
    confidence: float
    notes: tuple[str, ...] = ()

    def value_at(self, t: float | np.ndarray) -> float | np.ndarray:
        """The fitted trend line at time(s) ``t``."""
        return self.value_at_ref + self.slope * (np.asarray(t, dtype=float) - self.t_ref)

    def to_dict(self) -> dict[str, Any]:
        def num(x: float | None) -> Any:
            if x is None or math.isfinite(x):
                return x
            return None if math.isnan(x) else ("inf" if x > 0 else "-inf")

        return {
            "method": self.method,
            "n": self.n,
            "slope": num(self.slope),
            "slope_se": num(self.slope_se),
            "slope_ci": [num(x) for x in self.slope_ci],
            "t_ref": self.t_ref,
            "value_at_ref": self.value_at_ref,
            "statistic": num(self.statistic),
            "dof": self.dof,
            "p_value": num(self.p_value),
            "alpha": self.alpha,
            "alternative": self.alternative,
            "drifting": self.drifting,
            "scale": num(self.scale),
            "baseline": self.baseline,
            "tolerance": self.tolerance,
            "limit": self.limit,
            "projected_crossing_time": num(self.projected_crossing_time),
            "crossing_se": num(self.crossing_se),
            "crossing_ci": None
            if self.crossing_ci is None
            else [num(x) for x in self.crossing_ci],
            "confidence": self.confidence,
            "notes": list(self.notes),
        }


def _vector(name: str, x: Any, n: int | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise DataError(f"`{name}` has shape {a.shape}; expected a 1-D array (one value per time)")
    if n is not None and a.shape[0] != n:
        raise DataError(f"`{name}` has {a.shape[0]} values; expected {n} (one per time)")
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.isfinite(a))[:5].tolist()
        raise DataError(f"`{name}` has NaN/inf at indices {bad}; expected finite values")
    return a


class _Dist:
    """Student-t with ``dof`` degrees of freedom, or the normal when ``dof`` is None.

    Through ``scipy.special`` ufuncs: a frozen ``scipy.stats`` distribution costs
    milliseconds per call, too much for Monte Carlo checks of the test's size.
    """

    def __init__(self, dof: float | None):
        self.dof = dof

    def cdf(self, x: float) -> float:
        return float(special.ndtr(x) if self.dof is None else special.stdtr(self.dof, x))

    def sf(self, x: float) -> float:
        return self.cdf(-x)  # symmetric

    def ppf(self, p: float) -> float:
        return float(special.ndtri(p) if self.dof is None else special.stdtrit(self.dof, p))


def _p_value(stat: float, dist: _Dist, alternative: str) -> float:
    if alternative == "two-sided":
        return min(1.0, 2.0 * dist.sf(abs(stat)))
    if alternative == "increasing":
        return dist.sf(stat)
    return dist.cdf(stat)


def _fieller(
    b: float, var_b: float, d: float, var_d: float, q: float
) -> tuple[float, float, tuple[float, float] | None]:
    """Root ``u* = -d / b`` of ``d + b u = 0``, its delta-method s.e. and Fieller interval.

    ``d`` and ``b`` are uncorrelated normal estimates (variances ``var_d``,
    ``var_b``). Fieller's set {u : (d + b u)^2 <= q^2 (var_d + u^2 var_b)} is
    the quadratic inequality ``A u^2 + B u + C <= 0`` below; it is a bounded
    interval iff ``A > 0``, i.e. iff ``|b| / se(b) > q`` (the slope is
    significant at the interval's level); ``None`` otherwise (unbounded).
    """
    u = -d / b
    se = math.sqrt(var_d + u * u * var_b) / abs(b)  # delta method
    A = b * b - q * q * var_b
    if A <= 0.0:
        return u, se, None
    B = 2.0 * b * d
    C = d * d - q * q * var_d
    # B^2 - 4AC = 4 q^2 (var_b d^2 + A var_d) >= 0 when A > 0: two real roots.
    half = math.sqrt(max(B * B - 4.0 * A * C, 0.0)) / (2.0 * A)
    centre = -B / (2.0 * A)
    return u, se, (centre - half, centre + half)


def detect_drift(
    times: Any,
    values: Any,
    std_errors: Any = None,
    *,
    alpha: float = 0.01,
    tolerance: float | None = None,
    baseline: float | None = None,
    alternative: str = "two-sided",
    method: str = "wls",
    absolute_sigma: bool = False,
    scale_floor: bool = False,
    confidence: float = 0.95,
) -> DriftResult:
    """Test a parameter's history for a linear drift; project when it leaves a band.

    Parameters
    ----------
    times : array_like, shape (n,)
        Times of the estimates, in any unit (e.g. seconds since 1970); the
        slope is per that unit. Need not be sorted; at least two distinct.
    values : array_like, shape (n,)
        The estimates.
    std_errors : array_like, shape (n,), optional
        Their standard errors (> 0). ``None``: equal weights (OLS).
    alpha : float
        Significance level of the test (false-alarm probability per call).
    tolerance : float, optional
        Half-width of the acceptable band around ``baseline`` (value units);
        enables the crossing-time projection.
    baseline : float, optional
        Centre of the band (e.g. the commissioning value). Default: the
        fitted line's value at the earliest time.
    alternative : {"two-sided", "increasing", "decreasing"}
        Direction of drift the test looks for.
    method : {"wls", "mann-kendall"}
        See the module docstring.
    absolute_sigma : bool
        WLS only: trust ``std_errors`` as absolute (z-test, ``phi = 1``)
        instead of estimating their common scale (t-test, default).
    scale_floor : bool
        WLS only: use ``phi = max(phi_hat, 1)`` with the same Student-t
        reference: the stated errors are inflated when the points scatter more
        than they say, never shrunk when they scatter less by chance. The
        statistic is never larger than the plain t-test's, so the level stays
        <= ``alpha`` whatever the true scale, and when the stated errors are
        right it is far below ``alpha``: repeated looks at a growing history
        stay within ``alpha`` (``docs/history.md``, drift test, repeated looks).
    confidence : float
        Level of the slope and crossing-time intervals.

    Returns
    -------
    DriftResult

    Raises
    ------
    DataError
        Wrong shapes, NaN/inf, non-positive standard errors, fewer than 3
        points (WLS) or 4 (Mann-Kendall), all times equal.

    Notes
    -----
    WLS estimate (module docstring model), with ``tau_i = t_i - t_w`` and
    ``t_w = sum w t / sum w``: the design columns ``1`` and ``tau`` are then
    orthogonal in the weighted inner product, so the least-squares solution is
    ``a = sum w y / sum w``, ``b = sum w tau y / S``, ``S = sum w tau^2``
    (no normal equations are formed; this is the QR solution of an orthogonal
    design), with ``var a = phi / sum w``, ``var b = phi / S``, ``cov(a, b) = 0``
    and ``phi = sum w r^2 / (n - 2)``.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(12.0)                      # months
    >>> y = 2.0 + 0.01 * t + 0.002 * np.array([1, -1, 0, 1, -2, 1, 0, -1, 2, 0, -1, 1])
    >>> r = detect_drift(t, y, np.full(12, 0.002), tolerance=0.2, baseline=2.0)
    >>> bool(r.drifting), round(r.slope, 4), round(r.projected_crossing_time)
    (True, 0.01, 20)
    """
    if method not in _METHODS:
        raise DataError(f"`method` = {method!r}; expected one of {list(_METHODS)}")
    if alternative not in _ALTERNATIVES:
        raise DataError(f"`alternative` = {alternative!r}; expected one of {list(_ALTERNATIVES)}")
    if not (0.0 < alpha < 1.0):
        raise DataError(f"`alpha` = {alpha!r}; expected 0 < alpha < 1")
    if not (0.0 < confidence < 1.0):
        raise DataError(f"`confidence` = {confidence!r}; expected 0 < confidence < 1")
    t = _vector("times", times)
    n = t.shape[0]
    y = _vector("values", values, n)
    se = None if std_errors is None else _vector("std_errors", std_errors, n)
    if se is not None and np.any(se <= 0):
        bad = np.flatnonzero(se <= 0)[:5].tolist()
        raise DataError(f"`std_errors` must be > 0; not at indices {bad}")
    if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
        raise DataError(f"`tolerance` = {tolerance!r}; expected a finite value > 0")
    if baseline is not None and not math.isfinite(baseline):
        raise DataError(f"`baseline` = {baseline!r}; expected a finite value")
    min_n = 3 if method == "wls" else 4
    if n < min_n:
        raise DataError(
            f"{n} point{'' if n == 1 else 's'}; a {method} drift test needs at least {min_n}"
        )
    if np.ptp(t) == 0.0:
        raise DataError("all `times` are equal; a trend needs at least two distinct times")
    notes: list[str] = []
    if n < 6:
        notes.append(f"only {n} points: the test has little power against slow drift")
    if method == "wls":
        return _wls(
            t,
            y,
            se,
            alpha,
            tolerance,
            baseline,
            alternative,
            absolute_sigma,
            confidence,
            notes,
            scale_floor,
        )
    return _mann_kendall(t, y, se, alpha, tolerance, baseline, alternative, confidence, notes)


def _limit(baseline: float | None, tolerance: float | None, slope: float) -> float | None:
    if tolerance is None or baseline is None or slope == 0.0:
        return None
    return baseline + math.copysign(tolerance, slope)


def _wls(
    t: np.ndarray,
    y: np.ndarray,
    se: np.ndarray | None,
    alpha: float,
    tolerance: float | None,
    baseline: float | None,
    alternative: str,
    absolute_sigma: bool,
    confidence: float,
    notes: list[str],
    scale_floor: bool = False,
) -> DriftResult:
    n = t.shape[0]
    if se is None:
        w = np.ones(n)
        name = "ols"
        if absolute_sigma:
            raise DataError("`absolute_sigma=True` needs `std_errors`")
    else:
        w = 1.0 / se**2
        name = "wls"
    sw = float(np.sum(w))
    t_w = float(np.sum(w * t) / sw)
    tau = t - t_w
    S = float(np.sum(w * tau * tau))
    # Rank decision scaled to the data: tau spread negligible against the times.
    if S <= (64 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(t))))) ** 2 * sw:
        raise DataError("the times are equal to working precision; no trend can be fitted")
    a = float(np.sum(w * y) / sw)  # value at t_w
    b = float(np.sum(w * tau * y) / S)  # slope (uses sum w tau = 0)
    r = y - a - b * tau
    dof = n - 2
    chi2 = float(np.sum(w * r * r))
    phi_hat = chi2 / dof
    if absolute_sigma:
        phi, dist, dof_out = 1.0, _Dist(None), None
    else:
        phi, dist, dof_out = phi_hat, _Dist(dof), float(dof)
        if scale_floor and se is not None:
            phi = max(phi_hat, 1.0)
    scale = math.sqrt(phi_hat) if se is not None else None
    if se is not None and dof >= 3:
        # Reduced chi-square far in the tail of chi2(dof)/dof: errors understated.
        p_chi = float(special.chdtrc(dof, chi2))
        if p_chi < 1e-3:
            notes.append(
                f"the points scatter {scale:.3g} times more than their standard errors say "
                f"(chi-square p = {p_chi:.2g}); the t-test accounts for it by estimating the scale"
                if not absolute_sigma
                else f"the points scatter {scale:.3g} times more than their standard errors say "
                f"(chi-square p = {p_chi:.2g}); absolute_sigma=True makes the test too eager"
            )
    var_a = phi / sw
    var_b = phi / S
    if var_b == 0.0:
        # A perfect fit: the slope is exact. Say so rather than divide by zero.
        notes.append("the points lie exactly on a line: zero residual, slope exact")
        stat = math.copysign(math.inf, b) if b != 0 else 0.0
        p = 0.0 if b != 0 else 1.0
        if (alternative == "increasing" and b <= 0) or (alternative == "decreasing" and b >= 0):
            p = 1.0
    else:
        stat = b / math.sqrt(var_b)
        p = _p_value(stat, dist, alternative)
    q = float(dist.ppf(0.5 + confidence / 2.0))
    slope_se = math.sqrt(var_b)
    slope_ci = (b - q * slope_se, b + q * slope_se)

    t0 = float(np.min(t))
    base = baseline
    limit = crossing = crossing_se = None
    crossing_ci = None
    if tolerance is not None:
        if base is None:
            base = a + b * (t0 - t_w)
            notes.append(
                f"baseline not given: the fitted value at the first time ({base:.6g}) is used"
            )
        limit = _limit(base, tolerance, b)
        if limit is not None:
            if baseline is None:
                # L = a + b (t0 - t_w) + s tol, so a + b (t - t_w) - L = b (t - t0) - s tol:
                # d = -(L - base) is exact, only b is uncertain; u counts from t0.
                u, crossing_se, interval = _fieller(b, var_b, -(limit - base), 0.0, q)
                origin = t0
            else:
                # a + b (t - t_w) - L: d = a - L with var(d) = var(a); u counts from t_w.
                u, crossing_se, interval = _fieller(b, var_b, a - limit, var_a, q)
                origin = t_w
            crossing = origin + u
            if interval is None:
                crossing_ci = (-math.inf, math.inf)
                notes.append(
                    f"the slope is not significantly non-zero at {confidence:.0%}: the "
                    "crossing time's confidence interval is unbounded"
                )
            else:
                crossing_ci = (origin + interval[0], origin + interval[1])
            if crossing < float(np.max(t)):
                notes.append("the fitted trend has already reached the limit")
    return DriftResult(
        method=name,
        n=n,
        slope=b,
        slope_se=slope_se,
        slope_ci=slope_ci,
        t_ref=t_w,
        value_at_ref=a,
        statistic=float(stat),
        dof=dof_out,
        p_value=float(p),
        alpha=float(alpha),
        alternative=alternative,
        drifting=bool(p < alpha),
        scale=scale,
        baseline=base,
        tolerance=tolerance,
        limit=limit,
        projected_crossing_time=crossing,
        crossing_se=crossing_se,
        crossing_ci=crossing_ci,
        confidence=float(confidence),
        notes=tuple(notes),
    )


def _mann_kendall(
    t: np.ndarray,
    y: np.ndarray,
    se: np.ndarray | None,
    alpha: float,
    tolerance: float | None,
    baseline: float | None,
    alternative: str,
    confidence: float,
    notes: list[str],
) -> DriftResult:
    n = t.shape[0]
    if se is not None:
        notes.append("Mann-Kendall ignores the standard errors (a rank test)")
    alt = {"two-sided": "two-sided", "increasing": "greater", "decreasing": "less"}[alternative]
    tau_res = stats.kendalltau(t, y, alternative=alt)
    p = float(tau_res.pvalue)
    tau = float(tau_res.statistic)
    if not math.isfinite(p):
        # kendalltau gives NaN when one variable is constant: no evidence of trend.
        p, tau = 1.0, 0.0
        notes.append("the values are all equal: no trend")
    sen = stats.theilslopes(y, t, alpha=confidence)
    b = float(sen.slope)
    lo_b, hi_b = float(sen.low_slope), float(sen.high_slope)
    z = float(special.ndtri(0.5 + confidence / 2.0))
    slope_se = (hi_b - lo_b) / (2.0 * z)
    t_ref = float(np.median(t))
    v_ref = float(np.median(y - b * t) + b * t_ref)
    base = baseline
    limit = crossing = None
    crossing_ci = None
    if tolerance is not None:
        if base is None:
            base = v_ref + b * (float(np.min(t)) - t_ref)
            notes.append(
                f"baseline not given: the Sen line's value at the first time ({base:.6g}) is used"
            )
        limit = _limit(base, tolerance, b)
        if limit is not None:
            crossing = t_ref + (limit - v_ref) / b
            # Approximate: the line pivots about (t_ref, v_ref) within Sen's slope interval.
            ends = [t_ref + (limit - v_ref) / s for s in (lo_b, hi_b) if s * b > 0]
            if len(ends) == 2:
                crossing_ci = (min(ends), max(ends))
            else:
                crossing_ci = (-math.inf, math.inf)
                notes.append("Sen's slope interval contains zero: the crossing time is unbounded")
            notes.append("Mann-Kendall crossing interval is approximate (slope bounds only)")
    return DriftResult(
        method="mann-kendall",
        n=n,
        slope=b,
        slope_se=slope_se,
        slope_ci=(lo_b, hi_b),
        t_ref=t_ref,
        value_at_ref=v_ref,
        statistic=tau,
        dof=None,
        p_value=p,
        alpha=float(alpha),
        alternative=alternative,
        drifting=bool(p < alpha),
        scale=None,
        baseline=base,
        tolerance=tolerance,
        limit=limit,
        projected_crossing_time=crossing,
        crossing_se=None,
        crossing_ci=crossing_ci,
        confidence=float(confidence),
        notes=tuple(notes),
    )


#: A history's step test runs at ``alpha / STEP_SHARE`` beside the drift test at
#: ``alpha``: a line's t-test rarely sees a step (its residuals are the step), so the
#: step test is a detector too, and the false-alarm rate stays <= 1.1 alpha; a real
#: step (a fault between two recordings) has p ~ 1e-9.
STEP_SHARE = 10


@dataclass(frozen=True)
class StepResult:
    """Outcome of :func:`detect_step`: a change-point (level shift) test.

    Attributes
    ----------
    n : int
    index : int
        The first point after the step (``values[index:]`` is the new level).
    before, after : float
        Weighted mean levels on each side; ``size = after - before``.
    size, size_se : float
    statistic : float
        ``|size| / size_se`` at the best split (scale estimated from the residuals).
    p_value : float
        Bonferroni over the ``n - 1`` candidate splits (conservative).
    chi2_step, chi2_line : float
        Weighted residual sums of squares of the two-level and the straight-line
        models (both two parameters): the smaller one describes the history.
    is_step : bool
        Significant at ``alpha`` and fits better than a line.
    alpha : float
    """

    n: int
    index: int
    before: float
    after: float
    size: float
    size_se: float
    statistic: float
    p_value: float
    chi2_step: float
    chi2_line: float
    is_step: bool
    alpha: float

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def detect_step(
    times: Any, values: Any, std_errors: Any = None, *, alpha: float = 0.01
) -> StepResult:
    """Test a parameter's history for a step (one change point) against a drift.

    For each split ``k`` (``1 <= k <= n - 1``, points sorted by time) the two
    weighted mean levels ``m_1`` (points ``< k``) and ``m_2`` give
    ``chi2_step(k) = sum w (y - m_side)^2``; the best split minimises it. With
    the scale ``phi = chi2_step / (n - 2)`` the step's t statistic is
    ``(m_2 - m_1) / sqrt(phi (1/W_1 + 1/W_2))`` (Student t, ``n - 2`` dof),
    its p-value multiplied by the ``n - 1`` splits tried (Bonferroni: the
    maximum over splits is not t distributed). A step is declared when that is
    below ``alpha`` *and* the two levels fit better than the WLS line of
    :func:`detect_drift` (same number of parameters): a fault that happened
    between two recordings is dated, not projected as a trend.

    Raises
    ------
    DataError
        Fewer than 3 points, or as :func:`detect_drift`.
    """
    t = _vector("times", times)
    n = t.shape[0]
    y = _vector("values", values, n)
    if n < 3:
        raise DataError(f"{n} points; a step test needs at least 3")
    se = np.ones(n) if std_errors is None else _vector("std_errors", std_errors, n)
    if np.any(se <= 0):
        raise DataError("`std_errors` must be > 0")
    order = np.argsort(t, kind="stable")
    t, y, w = t[order], y[order], 1.0 / se[order] ** 2
    cw, cwy, cwyy = np.cumsum(w), np.cumsum(w * y), np.cumsum(w * y * y)
    W1, S1, Q1 = cw[:-1], cwy[:-1], cwyy[:-1]
    W2, S2, Q2 = cw[-1] - W1, cwy[-1] - S1, cwyy[-1] - Q1
    chi2 = (Q1 - S1**2 / W1) + (Q2 - S2**2 / W2)  # two weighted means
    k = int(np.argmin(chi2))
    m1, m2 = float(S1[k] / W1[k]), float(S2[k] / W2[k])
    dof = n - 2
    phi = max(float(chi2[k]) / dof, 1e-300)
    size_se = math.sqrt(phi * (1.0 / W1[k] + 1.0 / W2[k]))
    stat = abs(m2 - m1) / size_se
    p = min(1.0, (n - 1) * 2.0 * float(special.stdtr(dof, -stat)))
    line = detect_drift(t, y, se[order], alpha=alpha)
    tau = t - line.t_ref
    chi2_line = float(np.sum(w * (y - line.value_at_ref - line.slope * tau) ** 2))
    return StepResult(
        n=n,
        index=k + 1,
        before=m1,
        after=m2,
        size=m2 - m1,
        size_se=size_se,
        statistic=stat,
        p_value=p,
        chi2_step=float(chi2[k]),
        chi2_line=chi2_line,
        is_step=bool(p < alpha and chi2[k] < chi2_line),
        alpha=float(alpha),
    )
