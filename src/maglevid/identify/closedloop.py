"""Shared machinery of the same-rate closed-loop methods (pem, indirect, two-stage, greybox).

The four methods of :mod:`maglevid.identify.pem`, :mod:`~maglevid.identify.indirect`,
:mod:`~maglevid.identify.twostage` and :mod:`~maglevid.identify.greybox` work on
records where inputs and outputs share one sample time (``p = 1``), the situation
of most real logs. What they share lives here:

* channel specifications (``"y:0"``, ``"y:gap"``, ``"u"``, ``"r:0"``) resolved
  against a :class:`~maglevid.data.ClosedLoopData`;
* segments (``[(start, stop), ...]``, e.g. from
  :func:`maglevid.diagnose.quality.find_levitation_segments`);
* polynomial (ARMAX) models in innovations form, their one-step and k-step
  predictors. A predictor of an unstable plant is stable when its noise
  polynomial ``C`` is (ARX: ``C = 1``); no method ever simulates an unstable model
  open loop, neither to fit it nor to validate it;
* the unstable pole with its delta-method covariance.

Conventions: ``A(q) = 1 + a1 q^-1 + ... + a_na q^-na``;
``B(q) = b1 q^-nk + ... + b_nb q^-(nk+nb-1)``; ``C(q) = 1 + c1 q^-1 + ...``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError, ModelError
from maglevid.lti import StateSpace, undiscretize

__all__ = [
    "Channel",
    "InnovationsModel",
    "close_loop",
    "extend_covariance",
    "fit_percent",
    "innovations_from_polynomials",
    "pole_statistics",
    "resolve_channel",
    "resolve_segments",
    "simo_polynomials_to_state_space",
    "stabilise_noise_polynomial",
]

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------
# Channels and segments
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Channel:
    """One resolved channel: the signal name, its column, its label and its samples."""

    signal: str
    index: int
    name: str
    values: np.ndarray

    @property
    def spec(self) -> str:
        return f"extra:{self.name}" if self.signal == "extra" else f"{self.signal}:{self.index}"


def resolve_channel(data: ClosedLoopData, spec: str) -> Channel:
    """Resolve ``"signal[:channel]"`` (channel = index or name) against a recording.

    ``"y:1"`` is the second output, ``"y:i"`` the output named ``i``, ``"u"`` the only
    input channel, ``"extra:yd"`` a control-rate extra channel kept by
    :func:`maglevid.io.read_recording` in ``metadata["extra_signals"]`` (e.g. the
    position reference of the UAQ records). Only same-rate records are accepted
    (``p = 1``).

    Raises
    ------
    DataError
        Unknown signal or channel, a missing signal, or ``p > 1``.
    """
    if data.p != 1:
        raise DataError(
            f"same-rate closed-loop methods need p = 1; the recording has p = {data.p} "
            "(use an inter-sampling method)"
        )
    if not isinstance(spec, str) or not spec:
        raise DataError(f"channel specification must be a string like 'y:0'; got {spec!r}")
    sig, _, ch = spec.partition(":")
    if sig == "extra":
        return _extra_channel(data, spec, ch)
    if sig not in ("y", "u", "r", "u_f"):
        raise DataError(f"channel {spec!r}: unknown signal {sig!r}; expected y, u, r or u_f")
    arr = data.y if sig == "y" else getattr(data, sig)
    if arr is None:
        raise DataError(f"channel {spec!r}: the recording has no {sig!r} signal")
    names = data.channel_names(sig)
    if ch == "":
        if arr.shape[1] != 1:
            raise DataError(
                f"channel {spec!r}: {sig!r} has {arr.shape[1]} channels {names}; name one"
            )
        idx = 0
    elif ch.lstrip("-").isdigit():
        idx = int(ch)
        if not 0 <= idx < arr.shape[1]:
            raise DataError(f"channel {spec!r}: index {idx} outside 0..{arr.shape[1] - 1}")
    elif ch in names:
        idx = names.index(ch)
    else:
        raise DataError(f"channel {spec!r}: no channel named {ch!r}; {sig!r} has {names}")
    return Channel(sig, idx, names[idx], np.asarray(arr[:, idx]))


def _extra_channel(data: ClosedLoopData, spec: str, name: str) -> Channel:
    extras = data.metadata.get("extra_signals") or {}
    if name not in extras:
        raise DataError(
            f"channel {spec!r}: no extra signal {name!r}; the recording has {sorted(extras)}"
        )
    values = np.asarray(extras[name].get("values"), dtype=float).reshape(-1)
    if values.size != data.n_samples:
        raise DataError(
            f"channel {spec!r}: {values.size} samples for {data.n_samples} control periods"
        )
    if not np.all(np.isfinite(values)):
        raise DataError(f"channel {spec!r} contains NaN or inf")
    return Channel("extra", 0, name, values)


def resolve_segments(
    data: ClosedLoopData, segments: Sequence[Sequence[int]] | None, *, min_length: int
) -> list[tuple[int, int]]:
    """Validate ``[(start, stop), ...]`` (stop exclusive); ``None`` means the whole record.

    Segments must be sorted, disjoint and at least ``min_length`` samples long.
    """
    n = data.n_samples
    if segments is None:
        segs = [(0, n)]
    else:
        try:
            segs = [(int(a), int(b)) for a, b in segments]
        except (TypeError, ValueError):
            raise DataError(
                f"`segments` must be a list of (start, stop) pairs; got {segments!r}"
            ) from None
    if not segs:
        raise DataError("`segments` is empty")
    last = 0
    for a, b in segs:
        if not (0 <= a < b <= n):
            raise DataError(f"segment ({a}, {b}) is outside the recording's 0..{n}")
        if a < last:
            raise DataError(f"segments must be sorted and disjoint; ({a}, {b}) overlaps")
        if b - a < min_length:
            raise DataError(
                f"segment ({a}, {b}) has {b - a} samples; this model needs >= {min_length}"
            )
        last = b
    return segs


# ----------------------------------------------------------------------------------------
# Polynomial models
# ----------------------------------------------------------------------------------------


def stabilise_noise_polynomial(c: np.ndarray) -> tuple[np.ndarray, bool]:
    """Reflect roots of a monic noise polynomial ``C`` outside the unit circle.

    ``C(q) e`` and ``C*(q) e'`` with reflected roots have the same spectrum up to a
    scale, so this changes the *noise model* only, never the plant: it keeps the
    ARMAX predictor ``1/C`` stable (spectral factorisation, Ljung 1999 sec. 2.3).
    Returns the monic polynomial and whether anything was reflected.
    """
    c = np.asarray(c, dtype=float)
    if c.size <= 1:
        return c, False
    r = np.roots(c)
    bad = np.abs(r) >= 1.0
    if not bad.any():
        return c, False
    r = np.where(bad, 1.0 / np.conj(np.where(bad, r, 1.0)), r)
    r = np.where(np.abs(r) >= 1.0, r * (1 - 1e-9), r)
    return np.real(np.poly(r)), True


@dataclass(frozen=True, eq=False)
class InnovationsModel:
    """Discrete innovations form ``x+ = A x + B u + K e``, ``y = C x + D u + e``.

    The one-step predictor ``x+ = (A - K C) x + (B - K D) u + K y`` is stable when
    ``A - K C`` is; it is what the PEM criterion and the k-step validation use.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray

    def predictor_poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A - self.K @ self.C)

    def predict(self, y: np.ndarray, u: np.ndarray, *, k: int = 1) -> np.ndarray:
        """``k``-step-ahead predictions ``y(t | t-k)``, shape like ``y``.

        Starts from ``x = 0``; the first ``k`` predictions have no full history
        (callers discard a burn-in). ``k = 1`` is the one-step predictor.
        """
        y = np.atleast_2d(y.T).T
        u = np.atleast_2d(u.T).T
        n = y.shape[0]
        nx = self.A.shape[0]
        AK = self.A - self.K @ self.C
        BK = self.B - self.K @ self.D
        X = np.empty((n, nx))  # X[t] = x(t | t-1)
        x = np.zeros(nx)
        for t in range(n):
            X[t] = x
            x = AK @ x + BK @ u[t] + self.K @ y[t]
        if k == 1:
            return X @ self.C.T + u @ self.D.T
        # x(t | t-k) = A^(k-1) x(t-k+1 | t-k) + sum of inputs u(t-k+1 .. t-1)
        Z = X[: n - k + 1].copy()
        for j in range(k - 1):
            Z = Z @ self.A.T + u[j : j + Z.shape[0]] @ self.B.T
        out = np.full_like(y, np.nan, dtype=float)
        out[k - 1 :] = Z @ self.C.T + u[k - 1 :] @ self.D.T
        return out


def innovations_from_polynomials(
    a: np.ndarray, bs: Sequence[np.ndarray], c: np.ndarray | None = None
) -> InnovationsModel:
    """Observer-canonical innovations form of ``A y = sum_j B_j u_j + C e`` (MISO).

    ``a = [1, a1, ..., ]``, each ``bs[j] = [b_j0, b_j1, ...]`` in powers of ``q^-1``
    (``b_j0`` is a direct feed-through), ``c = [1, c1, ...]`` (default 1: ARX).
    With ``n`` the largest degree::

        A_o[i, 0] = -a_{i+1},  A_o[i, i+1] = 1,
        B_o[i, j] = b_{j,i+1} - a_{i+1} b_{j,0},  D[0, j] = b_{j,0},
        K_o[i]    = c_{i+1} - a_{i+1},            C_o = [1, 0, ..., 0].
    """
    a = np.asarray(a, dtype=float)
    c = np.array([1.0]) if c is None else np.asarray(c, dtype=float)
    n = max(a.size - 1, c.size - 1, *(np.asarray(b).size - 1 for b in bs), 1)

    def pad(p: np.ndarray) -> np.ndarray:
        out = np.zeros(n + 1)
        out[: p.size] = p
        return out

    ap, cp = pad(a), pad(c)
    A = np.zeros((n, n))
    A[:, 0] = -ap[1:]
    A[: n - 1, 1:] = np.eye(n - 1)
    B = np.zeros((n, len(bs)))
    D = np.zeros((1, len(bs)))
    for j, b in enumerate(bs):
        bp = pad(np.asarray(b, dtype=float))
        B[:, j] = bp[1:] - ap[1:] * bp[0]
        D[0, j] = bp[0]
    K = (cp[1:] - ap[1:])[:, None]
    C = np.zeros((1, n))
    C[0, 0] = 1.0
    return InnovationsModel(A, B, C, D, K)


def simo_polynomials_to_state_space(
    a: np.ndarray,
    bs: Sequence[np.ndarray],
    dt: float,
    *,
    input_name: str = "u",
    output_names: Sequence[str] = (),
) -> StateSpace:
    """Discrete SIMO model ``y_j = B_j(q)/A(q) u`` (common denominator) as a StateSpace.

    Polynomials in powers of ``q^-1``; ``bs[j][0]`` is the direct term.
    Controllable canonical form.
    """
    a = np.asarray(a, dtype=float)
    n = max(a.size - 1, *(np.asarray(b).size - 1 for b in bs))
    den = np.zeros(n + 1)
    den[: a.size] = a
    num = np.zeros((len(bs), n + 1))
    for j, b in enumerate(bs):
        b = np.asarray(b, dtype=float)
        num[j, : b.size] = b
    # Controllable canonical form of sum_i b_i z^(n-i) / sum_i a_i z^(n-i):
    # first row -a, ones below the diagonal, C_j = b_j[1:] - b_j[0] a[1:], D_j = b_j[0].
    A = np.zeros((n, n))
    A[0] = -den[1:]
    A[1:, :-1] = np.eye(n - 1)
    B = np.zeros((n, 1))
    B[0, 0] = 1.0
    C = num[:, 1:] - num[:, :1] * den[None, 1:]
    D = num[:, :1]
    return StateSpace(A, B, C, D, dt, (), (input_name,), tuple(output_names))


def continuous_or_note(model: StateSpace, notes: list[str]) -> StateSpace | None:
    """``undiscretize(model)`` or ``None`` with a note saying why not."""
    try:
        return undiscretize(model)
    except ModelError as exc:
        notes.append(f"no continuous-time model: {exc}")
        return None


def close_loop(plant: StateSpace, controller: StateSpace, feedback: Sequence[int]) -> StateSpace:
    """Closed loop of a discrete plant and a discrete controller.

    Parameters
    ----------
    plant : StateSpace
        ``y = P u``, ``ny`` outputs, ``nu`` inputs, no direct feed-through.
    controller : StateSpace
        ``u = K [w_1, ..., w_m]`` with ``nu`` outputs. Its inputs are either plant
        outputs (listed in ``feedback``) or exogenous signals (all the others, in
        their order: references, excitation).
    feedback : sequence of int
        ``feedback[j]`` is the plant output fed to controller input ``j``, or ``-1``
        for an exogenous controller input.

    Returns
    -------
    StateSpace
        Inputs: the exogenous controller inputs; outputs: ``[y; u]``; states
        ``[x_plant; x_controller]``.
    """
    if not (plant.is_discrete and controller.is_discrete):
        raise ModelError("close_loop needs two discrete models")
    if np.any(plant.D != 0):
        raise ModelError("the plant must have no direct feed-through (an algebraic loop)")
    if controller.ny != plant.nu or len(feedback) != controller.nu:
        raise ModelError(
            f"controller has {controller.nu} inputs and {controller.ny} outputs; "
            f"expected {len(feedback)} inputs and {plant.nu} outputs"
        )
    fb = [j for j, f in enumerate(feedback) if f >= 0]
    ex = [j for j, f in enumerate(feedback) if f < 0]
    S = np.zeros((controller.nu, plant.ny))  # controller input <- plant output
    for j in fb:
        S[j, feedback[j]] = 1.0
    Bk_fb = controller.B @ S
    Dk_fb = controller.D @ S
    Bk_ex = controller.B[:, ex]
    Dk_ex = controller.D[:, ex]
    Ap, Bp, Cp = plant.A, plant.B, plant.C
    A = np.block([[Ap + Bp @ Dk_fb @ Cp, Bp @ controller.C], [Bk_fb @ Cp, controller.A]])
    B = np.vstack([Bp @ Dk_ex, Bk_ex])
    C = np.block([[Cp, np.zeros((plant.ny, controller.nx))], [Dk_fb @ Cp, controller.C]])
    D = np.vstack([np.zeros((plant.ny, len(ex))), Dk_ex])
    return StateSpace(A, B, C, D, plant.dt)


# ----------------------------------------------------------------------------------------
# Fit and poles
# ----------------------------------------------------------------------------------------


def fit_percent(y: np.ndarray, yhat: np.ndarray, segments: Sequence[tuple[int, int]]) -> float:
    """``100 (1 - ||y - yhat|| / ||y - mean||)`` over the segments (means per segment),
    ignoring NaN predictions (burn-in)."""
    num = 0.0
    den = 0.0
    for a, b in segments:
        ys, ps = y[a:b], yhat[a:b]
        ok = np.isfinite(ps)
        if ok.sum() < 2:
            continue
        num += float(np.sum((ys[ok] - ps[ok]) ** 2))
        den += float(np.sum((ys[ok] - ys[ok].mean()) ** 2))
    return 100.0 * (1.0 - np.sqrt(num / den)) if den > 0 else float("nan")


def _largest_real_root(a: np.ndarray) -> complex:
    r = np.roots(a)
    if r.size == 0:
        raise IdentificationError("the polynomial has no roots")
    real = r[np.abs(r.imag) <= 1e-9 * np.maximum(1.0, np.abs(r))]
    pool = real if real.size else r
    return complex(pool[np.argmax(np.abs(pool))])


def pole_statistics(
    poly_of_theta: Any,
    theta: np.ndarray,
    dt: float,
    *,
    prefix: str = "",
) -> tuple[dict[str, float], np.ndarray, list[str]]:
    """The largest real root ``z`` of a polynomial ``poly_of_theta(theta)`` (powers of
    ``q^-1``, leading 1) and its continuous equivalent ``ln(z)/dt`` [rad/s].

    Returns ``(values, J, notes)``: ``values`` maps ``{prefix}pole_z`` and
    ``{prefix}pole_rad_s``; ``J`` (2 x len(theta)) is their Jacobian by central
    differences, for :func:`extend_covariance` (the delta method, as
    :func:`maglevid.identify.result.propagate_covariance`). A largest root inside
    the unit circle is reported as is, with a note: an estimate is never reflected.
    """
    notes: list[str] = []
    z = _largest_real_root(poly_of_theta(theta))
    if abs(z.imag) > 0:
        notes.append(f"{prefix}largest root is complex ({z:.4g}); its modulus is reported")
    if abs(z) <= 1.0:
        notes.append(
            f"{prefix}estimate has no unstable real pole (largest |z| = {abs(z):.4g}): "
            "the data do not show the instability; the estimate is reported as is"
        )
    zr = float(abs(z)) if abs(z.imag) > 0 else float(z.real)
    if zr <= 0:
        notes.append(f"{prefix}largest real root is negative ({zr:.4g}); rad/s uses |z|")

    def f(th: np.ndarray) -> np.ndarray:
        zz = _largest_real_root(poly_of_theta(th))
        zz = abs(zz) if abs(zz.imag) > 0 else zz.real
        return np.array([zz, np.log(abs(zz)) / dt])

    values = {f"{prefix}pole_z": zr, f"{prefix}pole_rad_s": float(np.log(abs(zr)) / dt)}
    J = np.empty((2, theta.size))
    for i in range(theta.size):
        h = 1e-6 * max(abs(theta[i]), 1e-12)
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        J[:, i] = (f(tp) - f(tm)) / (2 * h)
    return values, J, notes


def extend_covariance(
    cov: np.ndarray | None, jacobians: Sequence[np.ndarray]
) -> np.ndarray | None:
    """Covariance of ``[theta, g_1(theta), g_2(theta), ...]`` from ``cov(theta)`` and the
    Jacobians ``J_i`` of the derived quantities (delta method: ``J cov J'``).

    Columns of ``J`` that are exactly zero do not turn an infinite (unidentifiable)
    variance into NaN through ``0 * inf``.
    """
    if cov is None:
        return None
    J = np.vstack(list(jacobians))
    n, m = cov.shape[0], J.shape[0]
    used = np.flatnonzero(np.any(J != 0, axis=0))
    Ju = J[:, used]
    with np.errstate(invalid="ignore"):
        cross = Ju @ cov[used, :]
        pc = Ju @ cov[np.ix_(used, used)] @ Ju.T
    cross = np.where(np.isnan(cross), np.inf, cross)
    pc = np.where(np.isnan(pc), np.inf, pc)
    ext = np.zeros((n + m, n + m))
    ext[:n, :n] = cov
    ext[n:, :n] = cross
    ext[:n, n:] = cross.T
    ext[n:, n:] = pc
    return ext


def covariance_from_jacobian(J: np.ndarray, residuals: np.ndarray, n_params: int) -> np.ndarray:
    """``s^2 (J' J)^-1`` through the SVD of ``J`` (no normal equations).

    Directions with singular values below ``max(J.shape) eps s_max`` are
    unidentifiable; their variance is reported as ``inf``, not hidden.
    """
    dof = max(residuals.size - n_params, 1)
    s2 = float(residuals @ residuals) / dof
    _, sv, Vt = np.linalg.svd(J, full_matrices=False)
    tol = sv[0] * max(J.shape) * np.finfo(float).eps if sv.size else 0.0
    good = sv > tol
    cov = (Vt[good].T / sv[good] ** 2) @ Vt[good] * s2
    if not good.all():
        null = Vt[~good]
        cov = np.where(np.abs(null.T @ null) > 1e-12, np.inf, cov)
    return cov
