"""Data-quality tools for real closed-loop records of magnetic suspensions.

Real logs are not simulations: the ball is lifted by hand, falls, sticks to the
magnet, rests on a stop; the command saturates; the documented controller, gains
or sample time may be wrong; the only excitation may be a few reference steps;
the sensor may be quantised to the size of the motion. This module finds the
usable parts and measures how informative they are, with signatures that know
nothing about a particular rig (position, command, reference, limits).

* :func:`find_levitation_segments` - where the body levitates, and why the rest
  is excluded (lift-off, below/above the position range, command at a limit,
  tracking error), with guard bands.
* :func:`compare_signals`, :func:`controller_equation_error` - is the logged
  command what the stated (linear) controller makes of the logged measurements?
* :func:`fit_pid_gains`, :func:`fit_controller_arx`, :func:`fit_cascade_gains`,
  :func:`scan_sample_time` - find gains or the sample time when they are unknown
  or wrong.
* :func:`signal_spectrum`, :func:`excitation_summary`,
  :func:`persistent_excitation_order`, :func:`regressor_condition_number`,
  :func:`estimate_quantisation_step`, :func:`quantisation_snr` - how much
  excitation and information the record holds.

Every threshold is a keyword argument with its default documented.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from scipy import optimize, signal

from maglevid._validation import as_signal, check_positive
from maglevid.control.cascade_pid import CascadeGains, cascade_state_space
from maglevid.exceptions import DataError, IdentificationError
from maglevid.lti import StateSpace

__all__ = [
    "ControllerFit",
    "Interval",
    "PIDFit",
    "ReplayCheck",
    "SampleTimeScan",
    "SegmentReport",
    "compare_signals",
    "controller_equation_error",
    "estimate_quantisation_step",
    "excitation_summary",
    "find_levitation_segments",
    "fit_cascade_gains",
    "fit_controller_arx",
    "fit_pid_gains",
    "persistent_excitation_order",
    "quantisation_snr",
    "regressor_condition_number",
    "scan_sample_time",
    "signal_spectrum",
    "split_segments",
]

log = logging.getLogger(__name__)


def _vector(x: Any, name: str, n: int | None = None) -> np.ndarray:
    return as_signal(x, name, n_samples=n, n_channels=1)[:, 0]


def _mask(mask: Any, n: int, name: str = "mask") -> np.ndarray:
    if mask is None:
        return np.ones(n, dtype=bool)
    m = np.asarray(mask)
    if m.shape != (n,) or m.dtype != bool:
        raise DataError(
            f"`{name}` must be a boolean array of shape ({n},); got {m.dtype} {m.shape}"
        )
    return m


# ----------------------------------------------------------------------------------------
# Levitating segments
# ----------------------------------------------------------------------------------------

#: Reason codes of excluded samples, with the text used in reports.
REASONS: Mapping[str, str] = MappingProxyType(
    {
        "lift-off": "lift-off transient: the record starts before the body levitates",
        "below-range": "position below the range (e.g. ball stuck to the magnet)",
        "above-range": "position above the range (e.g. ball fallen onto the bottom stop)",
        "command-low": "command at its lower limit (saturated)",
        "command-high": "command at its upper limit (saturated)",
        "tracking": "tracking error above the threshold (not under control)",
        "guard": "guard band around an excluded event (catch/release transient)",
        "short": "levitating piece shorter than min_duration",
    }
)


@dataclass(frozen=True)
class Interval:
    """Samples ``start:stop`` (stop exclusive) and why they are kept or excluded."""

    start: int
    stop: int
    reason: str

    @property
    def length(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True, eq=False)
class SegmentReport:
    """Result of :func:`find_levitation_segments`.

    Attributes
    ----------
    segments : tuple of Interval
        Usable pieces (reason ``"levitating"``), in time order.
    excluded : tuple of Interval
        Excluded pieces with their reason code (see :data:`REASONS`); a piece
        with several causes carries the first in the order lift-off, below-range,
        above-range, command-low, command-high, tracking, guard, short.
    n_samples : int
    dt : float
    thresholds : mapping
        The thresholds used.
    """

    segments: tuple[Interval, ...]
    excluded: tuple[Interval, ...]
    n_samples: int
    dt: float
    thresholds: Mapping[str, Any] = field(default_factory=dict)

    def mask(self) -> np.ndarray:
        """Boolean mask of the usable samples."""
        m = np.zeros(self.n_samples, dtype=bool)
        for s in self.segments:
            m[s.start : s.stop] = True
        return m

    @property
    def usable_fraction(self) -> float:
        return float(sum(s.length for s in self.segments)) / self.n_samples

    def bounds(self) -> list[tuple[int, int]]:
        """``[(start, stop), ...]`` of the usable segments (for identification options)."""
        return [(s.start, s.stop) for s in self.segments]

    def excluded_by_reason(self) -> dict[str, float]:
        """Seconds excluded per reason code."""
        out: dict[str, float] = {}
        for e in self.excluded:
            out[e.reason] = out.get(e.reason, 0.0) + e.length * self.dt
        return out

    def describe(self) -> str:
        lines = [
            f"{len(self.segments)} levitating segment(s), "
            f"{100 * self.usable_fraction:.1f} % of {self.n_samples} samples"
        ]
        rows: list[tuple[int, int, str]] = [(s.start, s.stop, "keep") for s in self.segments]
        # Adjacent excluded pieces (an event, its guards, the next event ...) as one row.
        merged: list[list[Any]] = []
        for e in self.excluded:
            if merged and merged[-1][1] == e.start:
                merged[-1][1] = e.stop
                if e.reason not in merged[-1][2]:
                    merged[-1][2].append(e.reason)
            else:
                merged.append([e.start, e.stop, [e.reason]])
        for a, b, reasons in merged:
            main = [r for r in reasons if r != "guard"] or reasons
            rows.append((a, b, "; ".join(REASONS.get(r, r) for r in main)))
        for a, b, what in sorted(rows):
            tag = "keep   " if what == "keep" else "exclude"
            text = "" if what == "keep" else f"  {what}"
            lines.append(f"  {tag} {a * self.dt:8.2f}-{b * self.dt:8.2f} s{text}")
        return "\n".join(lines)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """Start/stop of the runs of True in a boolean vector."""
    d = np.diff(np.r_[0, flags.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def find_levitation_segments(
    position: Any,
    *,
    dt: float,
    position_range: tuple[float, float],
    command: Any = None,
    command_limits: tuple[float, float] | None = None,
    limit_tolerance: float | None = None,
    reference: Any = None,
    max_tracking_error: float | None = None,
    exclude_saturation: bool = True,
    guard: float = 0.5,
    settle: float = 1.0,
    min_duration: float = 2.0,
) -> SegmentReport:
    """Find the pieces of a record where the body levitates under control.

    A sample is *bad* when the position is outside ``position_range``, the command
    sits at a limit (``exclude_saturation``), or the tracking error exceeds
    ``max_tracking_error``. Runs of bad samples are widened by ``guard`` seconds
    on both sides (the fall starts before the position leaves the range, the
    catch transient lasts after it comes back); a bad run at the very start is the
    lift-off and is widened by ``settle`` seconds after it instead. Good pieces
    shorter than ``min_duration`` are excluded too.

    Parameters
    ----------
    position : array_like, shape (N,)
        Measured position or gap (any unit; ``position_range`` in the same unit).
    dt : float
        Sample time [s].
    position_range : (low, high)
        Range of positions that count as levitating. For the UAQ levitator
        ``(2e-3, 10e-3)`` m (the README's 2-10 mm); for an AMB the retainer
        clearance minus a margin.
    command : array_like, shape (N,) or (N, nu), optional
        Controller output; with ``command_limits`` flags saturation.
    command_limits : (low, high), optional
        Command limits, e.g. ``(0, 9.86)`` V for UAQ, ``(-255, 255)`` for Maggy.
    limit_tolerance : float, optional
        A command within this distance of a limit counts as saturated. Default:
        ``1e-3`` of the limit span (the logged values are exact at the limits).
    reference : array_like, shape (N,), optional
        Position reference, for the tracking test.
    max_tracking_error : float, optional
        Largest ``|position - reference|`` under control (default: no test).
    exclude_saturation : bool
        Exclude saturated samples (default ``True``; a direct method that models
        the logged command may keep them, a method that assumes a linear
        controller must not).
    guard : float
        Seconds excluded before and after each bad run (default 0.5 s: about 3
        periods of the ~7 Hz unstable mode of the UAQ rig).
    settle : float
        Seconds excluded after the lift-off (default 1 s).
    min_duration : float
        Shortest usable piece in seconds (default 2 s).

    Returns
    -------
    SegmentReport

    Examples
    --------
    >>> import numpy as np
    >>> y = np.full(1000, 5e-3); y[:200] = 1e-3; y[600:650] = 20e-3
    >>> rep = find_levitation_segments(y, dt=0.01, position_range=(2e-3, 10e-3))
    >>> rep.bounds()
    [(300, 550), (700, 1000)]
    """
    dt = check_positive(dt, "dt")
    pos = _vector(position, "position")
    n = pos.size
    lo, hi = (float(v) for v in position_range)
    if not lo < hi:
        raise DataError(
            f"`position_range` must be (low, high) with low < high; got {position_range}"
        )
    codes: list[tuple[str, np.ndarray]] = [("below-range", pos < lo), ("above-range", pos > hi)]
    if command is not None and command_limits is not None:
        cmd = as_signal(command, "command", n_samples=n)
        ulo, uhi = (float(v) for v in command_limits)
        tol = 1e-3 * (uhi - ulo) if limit_tolerance is None else float(limit_tolerance)
        if exclude_saturation:
            codes.append(("command-low", np.any(cmd <= ulo + tol, axis=1)))
            codes.append(("command-high", np.any(cmd >= uhi - tol, axis=1)))
    if max_tracking_error is not None:
        if reference is None:
            raise DataError("`max_tracking_error` needs `reference`")
        ref = _vector(reference, "reference", n)
        codes.append(("tracking", np.abs(pos - ref) > float(max_tracking_error)))
    bad = np.zeros(n, dtype=bool)
    for _, c in codes:
        bad |= c
    g = round(guard / dt)
    s = round(settle / dt)
    label = np.full(n, "", dtype=object)
    runs = _runs(bad)
    for a, b in runs:
        label[a:b] = "lift-off" if a == 0 else next(nm for nm, c in codes if c[a:b].any())
    for a, b in runs:
        for lo_, hi_ in (
            (0 if a == 0 else max(0, a - g), a),
            (b, min(n, b + (s if a == 0 else g))),
        ):
            piece = label[lo_:hi_]
            piece[piece == ""] = "guard"
    min_len = round(min_duration / dt)
    segments = []
    for a, b in _runs(label == ""):
        if b - a >= min_len:
            segments.append(Interval(a, b, "levitating"))
        else:
            label[a:b] = "short"
    excluded: list[Interval] = []
    k = 0
    while k < n:
        j = k
        while j < n and label[j] == label[k]:
            j += 1
        if label[k] != "":
            excluded.append(Interval(k, j, str(label[k])))
        k = j
    thresholds = {
        "position_range": (lo, hi),
        "command_limits": None if command_limits is None else tuple(command_limits),
        "limit_tolerance": limit_tolerance,
        "max_tracking_error": max_tracking_error,
        "exclude_saturation": exclude_saturation,
        "guard": guard,
        "settle": settle,
        "min_duration": min_duration,
    }
    return SegmentReport(tuple(segments), tuple(excluded), n, dt, MappingProxyType(thresholds))


def split_segments(
    bounds: Sequence[tuple[int, int]],
    bad: Any,
    *,
    pad: tuple[int, int] = (0, 0),
    min_length: int = 1,
) -> list[tuple[int, int]]:
    """Cut segments where ``bad`` holds, dropping ``pad = (before, after)`` samples
    around each bad sample and pieces shorter than ``min_length``.

    Use it to keep a linear-controller method away from single saturated samples
    (``bad = command at a limit``, ``pad = (0, 1)``) or to give each operating point
    its own segment (``bad = reference changed``, ``pad = (0, settle)``), where
    :func:`find_levitation_segments` would exclude whole guard bands.
    """
    b = np.asarray(bad, dtype=bool).reshape(-1)
    n = b.size
    drop = b.copy()
    for k in range(1, pad[1] + 1):
        drop[k:] |= b[:-k]
    for k in range(1, pad[0] + 1):
        drop[:-k] |= b[k:]
    out = []
    for a0, b0 in bounds:
        if not (0 <= a0 < b0 <= n):
            raise DataError(f"segment ({a0}, {b0}) is outside 0..{n}")
        for a, c in _runs(~drop[a0:b0]):
            if c - a >= min_length:
                out.append((a0 + a, a0 + c))
    return out


# ----------------------------------------------------------------------------------------
# Does the stated controller reproduce the logged command?
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReplayCheck:
    """Agreement of a logged signal with its reproduction.

    ``rms`` and ``max_abs`` of the difference, ``correlation`` of the two signals,
    ``n`` samples compared, ``relative_rms`` = rms / std(logged).
    """

    rms: float
    max_abs: float
    correlation: float
    n: int
    relative_rms: float

    def passes(self, rms_tolerance: float) -> bool:
        return self.rms <= rms_tolerance


def compare_signals(logged: Any, reproduced: Any, *, mask: Any = None) -> ReplayCheck:
    """rms/max difference and correlation of a logged and a reproduced signal."""
    a = _vector(logged, "logged")
    b = _vector(reproduced, "reproduced", a.size)
    m = _mask(mask, a.size)
    if m.sum() < 2:
        raise DataError("`mask` leaves fewer than 2 samples to compare")
    d = a[m] - b[m]
    sa, sb = a[m].std(), b[m].std()
    corr = float(np.corrcoef(a[m], b[m])[0, 1]) if sa > 0 and sb > 0 else float("nan")
    rms = float(np.sqrt(np.mean(d**2)))
    return ReplayCheck(
        rms, float(np.max(np.abs(d))), corr, int(m.sum()), rms / sa if sa else np.inf
    )


def _polys_from_state_space(K: StateSpace) -> tuple[np.ndarray, np.ndarray]:
    """Common denominator ``D(z^-1)`` (monic) and numerators ``N_j(z^-1)`` of a SISO-output
    discrete controller, as coefficient arrays in powers of ``z^-1``."""
    if K.ny != 1:
        raise DataError(f"the controller must have one output; it has {K.ny}")
    # C adj(zI - A) b = det(zI - A + b C) - det(zI - A)  (a rank-one determinant update)
    den = np.poly(K.A) if K.nx else np.array([1.0])
    nums = []
    for j in range(K.nu):
        b = K.B[:, j : j + 1]
        num = (np.poly(K.A - b @ K.C) - den if K.nx else np.zeros(1)) + K.D[0, j] * den
        nums.append(num)
    return den, np.array(nums)


def controller_equation_error(
    controller: StateSpace, inputs: Any, output: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Equation error ``D(q) u - sum_j N_j(q) w_j`` of a linear discrete controller.

    For a controller ``u = sum_j N_j(z)/D(z) w_j`` this residual is exactly zero on
    noise-free data whatever the controller's (unknown) initial state: it needs no
    integrator anchoring, unlike a replay. It is the "velocity form" check of a PID
    generalised to any linear law (for a PI, ``D = 1 - z^-1``).

    Parameters
    ----------
    controller : StateSpace
        Discrete controller, inputs ``w`` (``nu`` channels), one output ``u``.
    inputs : array_like, shape (N, nu)
        Logged controller inputs.
    output : array_like, shape (N,)
        Logged controller output.

    Returns
    -------
    residual : ndarray, shape (N,)
        NaN for the first ``deg D`` samples (no full history).
    valid : ndarray of bool, shape (N,)
        Samples whose residual has a full history.
    """
    if not controller.is_discrete:
        raise DataError("`controller` must be a discrete StateSpace")
    w = as_signal(inputs, "inputs", n_channels=controller.nu)
    u = _vector(output, "output", w.shape[0])
    den, nums = _polys_from_state_space(controller)
    n = den.size - 1
    r = signal.lfilter(den, [1.0], u)
    for j in range(controller.nu):
        r -= signal.lfilter(nums[j], [1.0], w[:, j])
    r[:n] = np.nan
    valid = np.ones(u.size, dtype=bool)
    valid[:n] = False
    return r, valid


def _widen(bad: np.ndarray, n_after: int) -> np.ndarray:
    """Mark ``n_after`` samples after each bad sample as bad (history contamination)."""
    out = bad.copy()
    for k in range(1, n_after + 1):
        out[k:] |= bad[:-k]
    return out


# ----------------------------------------------------------------------------------------
# Gains and sample time
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PIDFit:
    """Least-squares PID gains from the velocity form.

    ``kp``, ``ki_dt`` (= ki dt), ``kd_over_dt`` (= kd / dt) are what the data
    determine; ``ki``, ``kd`` are filled when ``dt`` is known. ``covariance`` is
    that of ``(kp, ki_dt, kd_over_dt)`` (asymptotic, white equation error).
    """

    kp: float
    ki_dt: float
    kd_over_dt: float
    covariance: np.ndarray
    residual_rms: float
    n: int
    dt: float | None = None

    @property
    def ki(self) -> float:
        return float("nan") if self.dt is None else self.ki_dt / self.dt

    @property
    def kd(self) -> float:
        return float("nan") if self.dt is None else self.kd_over_dt * self.dt

    def std_errors(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def implied_dt(self, *, ki: float | None = None, kd: float | None = None) -> dict[str, float]:
        """Sample time implied by documented ``ki`` and/or ``kd`` (``ki dt`` / ``kd / dt``)."""
        out = {}
        if ki:
            out["from_ki"] = self.ki_dt / ki
        if kd:
            out["from_kd"] = kd / self.kd_over_dt if self.kd_over_dt else float("nan")
        return out


def _ls_with_cov(Phi: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """lstsq solution, residual and asymptotic covariance ``s^2 (Phi' Phi)^-1`` via SVD."""
    theta, *_ = np.linalg.lstsq(Phi, Y, rcond=None)
    e = Y - Phi @ theta
    dof = max(Phi.shape[0] - Phi.shape[1], 1)
    s2 = float(e @ e) / dof
    _, sv, Vt = np.linalg.svd(Phi, full_matrices=False)
    tol = sv[0] * max(Phi.shape) * np.finfo(float).eps
    inv = np.where(sv > tol, 1.0 / np.where(sv > tol, sv, 1.0) ** 2, np.inf)
    cov = (Vt.T * inv) @ Vt * s2
    return theta, e, cov


def fit_pid_gains(error: Any, output: Any, *, dt: float | None = None, mask: Any = None) -> PIDFit:
    """Fit ``v = kp e + I + kd (e_k - e_{k-1})/dt``, ``I_k = I_{k-1} + ki dt e_k``.

    Differencing removes the integrator state (velocity form)::

        v_k - v_{k-1} = kp (e_k - e_{k-1}) + (ki dt) e_k + (kd/dt)(e_k - 2 e_{k-1} + e_{k-2})

    solved by least squares on the samples where ``mask`` holds for ``k``, ``k-1``
    and ``k-2`` (exclude saturated or clamped samples). Only ``kp``, ``ki dt`` and
    ``kd/dt`` are identifiable; give ``dt`` to read ``ki`` and ``kd``.

    Parameters
    ----------
    error : array_like, shape (N,)
        Controller input (e.g. ``yd - y``).
    output : array_like, shape (N,)
        Controller output (before any limit, or masked where limited).
    dt : float, optional
    mask : array of bool, shape (N,), optional

    Returns
    -------
    PIDFit
    """
    e = _vector(error, "error")
    v = _vector(output, "output", e.size)
    m = _mask(mask, e.size)
    ok = m.copy()
    ok[:2] = False
    ok[2:] &= m[1:-1] & m[:-2]
    k = np.flatnonzero(ok)
    if k.size < 10:
        raise IdentificationError(f"only {k.size} usable samples for the PID fit; need >= 10")
    Phi = np.column_stack([e[k] - e[k - 1], e[k], e[k] - 2 * e[k - 1] + e[k - 2]])
    theta, res, cov = _ls_with_cov(Phi, v[k] - v[k - 1])
    return PIDFit(
        float(theta[0]),
        float(theta[1]),
        float(theta[2]),
        cov,
        float(np.sqrt(np.mean(res**2))),
        int(k.size),
        None if dt is None else check_positive(dt, "dt"),
    )


@dataclass(frozen=True, eq=False)
class ControllerFit:
    """A linear controller fitted as a difference equation (MISO ARX).

    ``u_k = -sum_i a_i u_{k-i} + sum_j sum_l b_{j,l} w_j(k - nk - l) + c``.

    Attributes
    ----------
    a : ndarray, shape (na,)
    b : ndarray, shape (n_inputs, nb)
    intercept : float
    covariance : ndarray
        Of ``[a, b.ravel(), intercept]``.
    r_squared : float
        Explained fraction of the variance of ``u`` on the samples used.
    residual_rms : float
    n : int
    """

    a: np.ndarray
    b: np.ndarray
    intercept: float
    covariance: np.ndarray
    r_squared: float
    residual_rms: float
    n: int
    residuals: np.ndarray

    def poles(self) -> np.ndarray:
        return np.roots(np.r_[1.0, self.a]) if self.a.size else np.array([])


def fit_controller_arx(
    inputs: Any,
    output: Any,
    *,
    na: int,
    nb: int,
    nk: int = 0,
    mask: Any = None,
    intercept: bool = True,
) -> ControllerFit:
    """Identify a linear controller ``u = N(q)/D(q) w`` from its logged inputs and output.

    Least squares (``lstsq``) on the difference equation; samples are used only
    where ``mask`` holds over the whole regressor history. ``nk = 0`` allows a
    direct feed-through (a digital controller computes ``u_k`` from ``w_k``).
    A fit with residuals at the output's rounding level means the law is linear
    with this structure.
    """
    w = as_signal(inputs, "inputs")
    u = _vector(output, "output", w.shape[0])
    n = u.size
    m = _mask(mask, n)
    h = max(na, nk + nb - 1)
    ok = _widen(~m, h)
    ok = ~ok
    ok[:h] = False
    k = np.flatnonzero(ok)
    if k.size < 10 * (na + w.shape[1] * nb + 1):
        raise IdentificationError(f"only {k.size} usable samples for the controller fit")
    cols = [-u[k - i] for i in range(1, na + 1)]
    for j in range(w.shape[1]):
        cols += [w[k - nk - l, j] for l in range(nb)]
    if intercept:
        cols.append(np.ones(k.size))
    Phi = np.column_stack(cols)
    theta, res, cov = _ls_with_cov(Phi, u[k])
    r2 = 1.0 - float(res.var()) / float(u[k].var()) if u[k].var() > 0 else float("nan")
    b = theta[na : na + w.shape[1] * nb].reshape(w.shape[1], nb)
    resid = np.full(n, np.nan)
    resid[k] = res
    return ControllerFit(
        theta[:na].copy(),
        b,
        float(theta[-1]) if intercept else 0.0,
        cov,
        r2,
        float(np.sqrt(np.mean(res**2))),
        int(k.size),
        resid,
    )


def fit_cascade_gains(
    yd: Any,
    y: Any,
    i: Any,
    u: Any,
    *,
    dt: float,
    mask: Any = None,
    initial: CascadeGains | None = None,
) -> tuple[CascadeGains, np.ndarray, float]:
    """Fit the five gains of the cascade (C1)-(C5) to logged ``yd, y, i, u``.

    Nonlinear least squares on the controller equation error
    (:func:`controller_equation_error`), which needs neither the logged current
    reference nor the integrator states. Samples are used where ``mask`` holds
    over the last two samples (the order of ``D``); exclude saturated samples.

    Returns
    -------
    gains : CascadeGains
        Fitted ``kp, ki, kd, kpi, kii`` (limits copied from ``initial``).
    std_errors : ndarray, shape (5,)
        Asymptotic standard errors of ``kp, ki, kd, kpi, kii``.
    residual_rms : float
        rms of the equation error [units of ``u``].
    """
    dt = check_positive(dt, "dt")
    init = CascadeGains.uaq() if initial is None else initial
    init = CascadeGains(**{**init.to_dict(), "dt": dt})
    w = np.column_stack(
        [
            _vector(yd, "yd"),
            _vector(y, "y"),
            _vector(i, "i"),
        ]
    )
    uu = _vector(u, "u", w.shape[0])
    m = _mask(mask, uu.size)
    ok = ~_widen(~m, 2)
    ok[:2] = False
    scale = np.array([init.kp, init.ki, init.kd, init.kpi, init.kii])
    scale = np.where(scale > 0, scale, 1.0)

    def resid(theta: np.ndarray) -> np.ndarray:
        kp, ki, kd, kpi, kii = theta * scale
        g = CascadeGains(
            kp=abs(kp), ki=abs(ki), kd=abs(kd), kpi=abs(kpi), kii=abs(kii),
            i_max=init.i_max, u_max=init.u_max, dt=dt, windup=init.windup,
        )  # fmt: skip
        r, _ = controller_equation_error(cascade_state_space(g), w, uu)
        return r[ok]

    sol = optimize.least_squares(resid, np.ones(5), method="lm", x_scale="jac")
    J = sol.jac * scale[None, :] ** -1
    theta = sol.x * scale
    dof = max(sol.fun.size - 5, 1)
    s2 = float(sol.fun @ sol.fun) / dof
    _, sv, Vt = np.linalg.svd(J, full_matrices=False)
    cov = (Vt.T / sv**2) @ Vt * s2
    g = CascadeGains(**{**init.to_dict(), **dict(zip(("kp", "ki", "kd", "kpi", "kii"), theta))})
    return g, np.sqrt(np.diag(cov)), float(np.sqrt(np.mean(sol.fun**2)))


@dataclass(frozen=True, eq=False)
class SampleTimeScan:
    """rms residual of a controller check for each candidate sample time."""

    candidates: np.ndarray
    rms: np.ndarray

    @property
    def best(self) -> float:
        return float(self.candidates[int(np.nanargmin(self.rms))])

    def contrast(self) -> float:
        """Second-smallest rms over the smallest (>> 1: the best candidate is clear)."""
        r = np.sort(self.rms[np.isfinite(self.rms)])
        return float(r[1] / r[0]) if r.size > 1 and r[0] > 0 else float("inf")


def scan_sample_time(
    candidates: Sequence[float], residual: Callable[[float], np.ndarray]
) -> SampleTimeScan:
    """Evaluate ``residual(dt)`` (e.g. a controller equation error with documented
    continuous-time gains at that ``dt``) for each candidate and report the rms."""
    c = np.asarray(candidates, dtype=float)
    if c.ndim != 1 or c.size == 0 or np.any(c <= 0):
        raise DataError("`candidates` must be a non-empty 1-D list of positive sample times")
    rms = np.empty(c.size)
    for j, dt in enumerate(c):
        r = np.asarray(residual(float(dt)), dtype=float)
        r = r[np.isfinite(r)]
        rms[j] = np.sqrt(np.mean(r**2)) if r.size else np.nan
    return SampleTimeScan(c, rms)


# ----------------------------------------------------------------------------------------
# Excitation and information
# ----------------------------------------------------------------------------------------


def signal_spectrum(
    x: Any, *, dt: float, nperseg: int | None = None, detrend: str = "linear"
) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density ``(f [Hz], P [unit^2/Hz])`` of one signal.

    ``nperseg`` defaults to ``min(N, 512)``; segments are linearly detrended.
    """
    dt = check_positive(dt, "dt")
    v = _vector(x, "x")
    nps = min(v.size, 512 if nperseg is None else int(nperseg))
    return signal.welch(v, fs=1.0 / dt, nperseg=nps, detrend=detrend)


def excitation_summary(
    signals: Mapping[str, Any],
    *,
    dt: float,
    fractions: Sequence[float] = (0.5, 0.9, 0.99),
    nperseg: int | None = None,
) -> dict[str, dict[str, float]]:
    """Per signal: rms, peak frequency and the frequencies below which the given
    fractions of the (detrended) variance lie.

    A reference made of a few steps has 90 % of its power below ~1 Hz; a loop
    signal driven by noise spreads it to the closed-loop modes. Compare with the
    plant's poles (the UAQ unstable pole is ~7 Hz; the Nyquist limit at 100 Hz
    sampling is 50 Hz).
    """
    out: dict[str, dict[str, float]] = {}
    for name, x in signals.items():
        f, P = signal_spectrum(x, dt=dt, nperseg=nperseg)
        cum = np.cumsum(P)
        total = cum[-1]
        row: dict[str, float] = {
            "rms": float(np.std(_vector(x, name))),
            "peak_hz": float(f[1:][np.argmax(P[1:])]) if f.size > 1 else float("nan"),
        }
        for q in fractions:
            row[f"f{round(100 * q)}_hz"] = (
                float(f[np.searchsorted(cum, q * total)]) if total > 0 else float("nan")
            )
        out[name] = row
    return out


def persistent_excitation_order(
    x: Any, *, max_order: int = 30, rtol: float = 1e-6, mask: Any = None
) -> tuple[int, np.ndarray]:
    """Largest ``n`` for which the ``n x n`` sample covariance of ``[x_k, ..., x_{k-n+1}]``
    is nonsingular (Ljung 1999, def. 13.1), and its condition numbers.

    The signal is mean-removed. "Nonsingular" means smallest over largest
    singular value of the lag matrix above ``sqrt(rtol)`` (``rtol`` on the
    covariance eigenvalues; default ``1e-6``: a direction with a millionth of the
    power carries no usable information when the outputs are quantised to ~1 %
    of their range). A constant is PE of order 0, one step of order ~1-2, a sum
    of ``s`` sinusoids of order ``2 s``; white noise of any order.

    Returns
    -------
    order : int
    condition : ndarray, shape (max_order,)
        Condition number of the covariance for n = 1..max_order.
    """
    v = _vector(x, "x")
    m = _mask(mask, v.size)
    v = v - v[m].mean()
    cond = np.empty(max_order)
    order = 0
    for n in range(1, max_order + 1):
        ok = ~_widen(~m, n - 1)
        ok[: n - 1] = False
        k = np.flatnonzero(ok)
        if k.size < 2 * n:
            cond[n - 1 :] = np.inf
            break
        H = np.column_stack([v[k - j] for j in range(n)])
        sv = np.linalg.svd(H, compute_uv=False)
        ratio = sv[0] / sv[-1] if sv[-1] > sv[0] * 1e-150 else np.inf
        c = ratio**2 if ratio < 1e150 else np.inf
        cond[n - 1] = c
        if sv[0] > 0 and c < 1.0 / rtol:
            order = n
    return order, cond


def regressor_condition_number(Phi: Any) -> float:
    """2-norm condition number of a regressor after scaling its columns to unit norm
    (the scaling removes the dependence on units, e.g. metres next to amperes)."""
    P = np.asarray(Phi, dtype=float)
    if P.ndim != 2:
        raise DataError(f"`Phi` must be 2-D; got shape {P.shape}")
    nrm = np.linalg.norm(P, axis=0)
    nrm[nrm == 0] = 1.0
    sv = np.linalg.svd(P / nrm, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")


def estimate_quantisation_step(x: Any, *, rel_tol: float = 0.5) -> float:
    """Quantisation step of a logged signal from the spacing of its distinct values.

    The distinct values are placed on an integer grid by the smallest spacing
    ``d`` (gaps rounded to multiples of ``d``; a gap within ``rel_tol`` of the
    multiple counts); the step is the least-squares slope of value vs level. This
    works when the values were printed with a few decimals (the UAQ gap, 48.9 um
    printed to 1 um, shows gaps of 48 and 49 um).
    """
    v = np.unique(_vector(x, "x"))
    if v.size < 3:
        raise DataError("`x` has fewer than 3 distinct values; no quantisation step to estimate")
    d = np.diff(v)
    dmin = d.min()
    levels = np.r_[0.0, np.cumsum(np.round(d / dmin))]
    off = np.abs(d / dmin - np.round(d / dmin))
    if np.any(off > rel_tol):
        log.info(
            "quantisation grid is irregular (%d gaps off the grid)", int((off > rel_tol).sum())
        )
    A = np.column_stack([levels, np.ones_like(levels)])
    slope, _ = np.linalg.lstsq(A, v, rcond=None)[0]
    return float(slope)


def quantisation_snr(x: Any, step: float, *, mask: Any = None) -> float:
    """Signal-to-quantisation-noise ratio in dB: ``10 log10(var(x) / (step^2/12))``.

    ``var(x)`` is taken after removing the mean (and with ``mask``). Below ~10 dB
    the quantisation noise is comparable to the motion itself (UAQ at rest:
    std 50-100 um against a 49 um step gives 11-17 dB).
    """
    v = _vector(x, "x")
    m = _mask(mask, v.size)
    step = check_positive(step, "step")
    var = float(np.var(v[m]))
    return float(10 * np.log10(var / (step**2 / 12.0))) if var > 0 else float("-inf")
