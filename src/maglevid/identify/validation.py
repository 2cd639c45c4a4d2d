"""Model validation as MATLAB users know it: ``resid`` and ``compare``.

:func:`resid` tests an identified model's one-step prediction errors ``e``:

* whiteness: the normalised autocorrelation ``rho_e(k)``, ``k = 1..M``, with the
  band ``+- z / sqrt(N)`` of a white sequence and the Ljung-Box statistic
  ``Q = N (N + 2) sum_k rho_e(k)^2 / (N - k)``, chi-square with ``M`` degrees of
  freedom under whiteness (Ljung, *System Identification*, 2nd ed., eq. (16.55));
* independence from past inputs: the cross-correlation ``rho_eu(tau)`` of
  ``e(t)`` and ``u(t - tau)``, ``tau = -M..M``, with the band of Bartlett's
  formula ``z sqrt(sum_k rho_e(k) rho_u(k) / N)`` and, for ``tau = 1..M``, the
  statistic ``zeta = N r^T (lambda R_phi)^-1 r`` with ``r = (1/N) sum phi(t) e(t)``,
  ``phi(t) = [u(t-1); ...; u(t-M)]`` and ``lambda = var e``, chi-square with
  ``M nu`` degrees of freedom when ``e`` is white and independent of past inputs,
  whatever the colour of ``u`` (Ljung eq. (16.59)).

Under feedback, ``u(t)`` depends on past outputs, hence on ``e(t - 1)``,
``e(t - 2)``...: correlation at negative lags (``e`` leading ``u``) is expected
and is not a model error; past inputs (``tau > 0``) must be uncorrelated with
the innovation ``e(t)``. The default level is 99 %, MATLAB's ``resid``.

:func:`compare` gives the fit in percent, ``100 (1 - ||y - y^|| / ||y - mean y||)``
per output, of the ``k``-step-ahead prediction (the state is reconstructed from the
last ``q`` measured samples through the observability matrix, ``q`` the smallest
window that observes the state, and propagated ``k`` steps with the logged input)
and of the simulation: open loop when the model is stable; for an unstable
model (a magnetic bearing) the identified plant in closed loop with the logged
controller (``data.loop``), driven by the logged excitation ``r``. The model is
never stabilised: when neither is possible the simulation fit is ``None`` with
the reason in ``notes``. Signals are taken about their means (the models are
linearised about the operating point).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import special

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, MaglevidError
from maglevid.lti import StateSpace

if TYPE_CHECKING:  # result.py calls into this module (IdentificationResult.resid)
    from maglevid.identify.result import IdentificationResult

__all__ = ["Comparison", "ResidualAnalysis", "compare", "resid", "residual_tests"]


@dataclass(frozen=True, eq=False)
class ResidualAnalysis:
    """Whiteness of the residuals and their independence from past inputs.

    Attributes
    ----------
    lags : ndarray, shape (M + 1,)
        ``0..M`` for ``autocorrelation``.
    autocorrelation : ndarray, shape (M + 1, ny)
        Normalised autocorrelation of each residual channel (1 at lag 0).
    auto_band : float
        Half-width of the ``level`` band of a white sequence, ``z / sqrt(N)``.
    cross_lags : ndarray, shape (2 M + 1,)
        ``-M..M``; ``tau > 0`` pairs ``e(t)`` with the past input ``u(t - tau)``.
    cross_correlation : ndarray, shape (2 M + 1, ny, nu)
    cross_band : ndarray, shape (ny, nu)
        Half-width of the ``level`` band by Bartlett's formula.
    whiteness_p, independence_p : ndarray, shape (ny,)
        p-values of the Ljung-Box and the past-input (Ljung eq. (16.59)) tests.
    """

    lags: np.ndarray
    autocorrelation: np.ndarray
    auto_band: float
    cross_lags: np.ndarray
    cross_correlation: np.ndarray
    cross_band: np.ndarray
    whiteness_p: np.ndarray
    independence_p: np.ndarray
    level: float
    n_samples: int
    output_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()

    @property
    def white(self) -> np.ndarray:
        """Per output: whiteness not rejected at ``1 - level``."""
        return self.whiteness_p > 1 - self.level

    @property
    def independent(self) -> np.ndarray:
        """Per output: independence from past inputs not rejected at ``1 - level``."""
        return self.independence_p > 1 - self.level

    def summary(self) -> str:
        lines = [f"residual analysis, N = {self.n_samples}, M = {self.lags[-1]}, {self.level:.0%}"]
        for i, name in enumerate(self.output_names):
            lines.append(
                f"{name:>8}: whiteness p = {self.whiteness_p[i]:.3g} "
                f"({'white' if self.white[i] else 'NOT white'}), past inputs p = "
                f"{self.independence_p[i]:.3g} "
                f"({'independent' if self.independent[i] else 'CORRELATED'})"
            )
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class Comparison:
    """Measured outputs beside the model's k-step predictions and its simulation.

    Attributes
    ----------
    y : ndarray, shape (N, ny)
        Measured outputs about their means.
    predictions : dict of int -> ndarray (N, ny)
        ``k``-step-ahead predictions (NaN where the window is not yet full).
    fit_percent : dict of int or "simulation" -> ndarray (ny,) or None
    simulation : ndarray (N, ny) or None
    simulation_kind : str
        ``"open loop"``, ``"closed loop with the logged controller"`` or ``"none"``.
    notes : tuple of str
    """

    y: np.ndarray
    predictions: dict[int, np.ndarray]
    fit_percent: dict[Any, np.ndarray | None]
    simulation: np.ndarray | None
    simulation_kind: str
    dt: float
    output_names: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)

    def summary(self) -> str:
        lines = [f"compare ({self.simulation_kind} simulation)"]
        for key, fit in self.fit_percent.items():
            label = f"{key}-step" if key != "simulation" else "simulation"
            vals = (
                "—"
                if fit is None
                else ", ".join(f"{n} {v:.1f} %" for n, v in zip(self.output_names, fit))
            )
            lines.append(f"{label:>12}: {vals}")
        lines.extend(f"note: {n}" for n in self.notes)
        return "\n".join(lines)


# ----------------------------------------------------------------- residual tests
def _correlation(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """``rho(tau) = sum_t a(t) b(t - tau) / (N sa sb)`` for ``tau = -M..M`` (biased)."""
    n = a.size
    full = np.correlate(a, b, mode="full")[n - 1 - max_lag : n + max_lag]
    return full / (n * a.std() * b.std())


def residual_tests(
    e: Any,
    u: Any,
    *,
    max_lag: int = 25,
    level: float = 0.99,
    output_names: Sequence[str] = (),
    input_names: Sequence[str] = (),
) -> ResidualAnalysis:
    """Whiteness and past-input tests of residuals ``e`` (N, ny) against inputs ``u`` (N, nu)."""
    e = np.asarray(e, dtype=float)
    u = np.asarray(u, dtype=float)
    e = e[:, None] if e.ndim == 1 else e
    u = u[:, None] if u.ndim == 1 else u
    if e.shape[0] != u.shape[0]:
        raise DataError(f"residuals have {e.shape[0]} samples and inputs {u.shape[0]}")
    n, ny = e.shape
    nu = u.shape[1]
    if not 1 <= max_lag < n // 4:
        raise DataError(f"`max_lag` must be in [1, N/4) = [1, {n // 4}); got {max_lag}")
    if not 0 < level < 1:
        raise DataError(f"`level` must be in (0, 1); got {level}")
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(u))):
        raise DataError("residuals and inputs must be finite")
    e = e - e.mean(axis=0)
    u = u - u.mean(axis=0)
    z = float(special.ndtri(0.5 + level / 2))
    M = max_lag
    auto = np.column_stack([_correlation(e[:, i], e[:, i], M)[M:] for i in range(ny)])
    cross = np.empty((2 * M + 1, ny, nu))
    band = np.empty((ny, nu))
    for i in range(ny):
        for j in range(nu):
            cross[:, i, j] = _correlation(e[:, i], u[:, j], M)
            ru = _correlation(u[:, j], u[:, j], M)
            re = _correlation(e[:, i], e[:, i], M)
            band[i, j] = z * np.sqrt(max(float(re @ ru), 1.0) / n)  # Bartlett
    k = np.arange(1, M + 1)
    q = n * (n + 2) * np.sum(auto[1:] ** 2 / (n - k)[:, None], axis=0)  # Ljung-Box
    p_white = special.chdtrc(M, q)
    p_indep = np.array([_past_input_p(e[:, i], u, M) for i in range(ny)])
    return ResidualAnalysis(
        lags=np.arange(M + 1),
        autocorrelation=auto,
        auto_band=z / np.sqrt(n),
        cross_lags=np.arange(-M, M + 1),
        cross_correlation=cross,
        cross_band=band,
        whiteness_p=p_white,
        independence_p=p_indep,
        level=level,
        n_samples=n,
        output_names=tuple(output_names) or tuple(f"e{i + 1}" for i in range(ny)),
        input_names=tuple(input_names) or tuple(f"u{j + 1}" for j in range(nu)),
    )


def _past_input_p(e: np.ndarray, u: np.ndarray, M: int) -> float:
    # phi(t) = [u(t-1); ...; u(t-M)], t = M..N-1; zeta = N r' (lambda R_phi)^-1 r (16.59).
    n = e.size
    phi = np.hstack([u[M - tau : n - tau] for tau in range(1, M + 1)])
    et = e[M:]
    N = et.size
    r = phi.T @ et / N
    R = phi.T @ phi / N
    lam = float(et @ et / N)
    zeta = N * float(r @ np.linalg.lstsq(lam * R, r, rcond=None)[0])
    return float(special.chdtrc(phi.shape[1], zeta))


def _signals(data: ClosedLoopData) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    if data.p != 1:
        raise DataError(
            f"resid/compare work on one output sample per control period; this record is "
            f"inter-sampled (p = {data.p})"
        )
    return np.asarray(data.y, dtype=float), np.asarray(data.u, dtype=float)


def _model(result: IdentificationResult, data: ClosedLoopData) -> StateSpace:
    sys = result.model
    if sys is None or not sys.is_discrete:
        raise DataError(f"the {result.method!r} result has no discrete model to validate")
    if (sys.nu, sys.ny) != (data.nu, data.ny):
        raise DataError(
            f"the model has {sys.nu} inputs and {sys.ny} outputs; the data {data.nu} and {data.ny}"
        )
    return sys


def resid(
    result: IdentificationResult,
    data: ClosedLoopData,
    *,
    max_lag: int = 25,
    level: float = 0.99,
) -> ResidualAnalysis:
    """Residual analysis of an identification result on a recording (MATLAB's ``resid``).

    Parameters
    ----------
    result : IdentificationResult
        Its one-step prediction errors (``result.residuals``) are tested when it
        has them; otherwise those of the 1-step predictor of :func:`compare`.
    data : ClosedLoopData
        The recording (inputs ``u``; one output sample per control period).
    max_lag : int
        Largest lag ``M`` (default 25, as MATLAB).
    level : float
        Confidence level of the bands and tests (default 0.99, as MATLAB).

    Returns
    -------
    ResidualAnalysis
    """
    y, u = _signals(data)
    if result.residuals is not None and np.asarray(result.residuals).shape[1:] == (data.ny,):
        e = np.asarray(result.residuals, dtype=float)
        u_e = u[u.shape[0] - e.shape[0] :]  # the residuals end with the record
    else:
        sys = _model(result, data)
        pred = _k_step(sys, y - y.mean(0), u - u.mean(0), 1)
        ok = np.all(np.isfinite(pred), axis=1)
        e, u_e = (y - y.mean(0))[ok] - pred[ok], u[ok]
    return residual_tests(
        e,
        u_e,
        max_lag=max_lag,
        level=level,
        output_names=data.channel_names("y"),
        input_names=data.channel_names("u"),
    )


# ----------------------------------------------------------------- compare
def _window(sys: StateSpace) -> int:
    """Smallest ``q`` whose observability matrix ``[C; CA; ...; CA^(q-1)]`` has rank ``nx``."""
    O = sys.C
    for q in range(1, sys.nx + 1):
        if np.linalg.matrix_rank(O) == sys.nx:
            return q
        O = np.vstack([O, sys.C @ np.linalg.matrix_power(sys.A, q)])
    raise DataError("the model is not observable from its outputs: no k-step prediction")


def _k_step(sys: StateSpace, y: np.ndarray, u: np.ndarray, k: int) -> np.ndarray:
    """``y^(t | t - k)``: the state at ``s = t - k - q + 1`` from ``y, u`` over ``s..s+q-1``."""
    A, B, C, D = sys.A, sys.B, sys.C, sys.D
    n, q = y.shape[0], _window(sys)
    O = np.vstack([C @ np.linalg.matrix_power(A, i) for i in range(q)])
    starts = np.arange(0, n - q - k + 1)
    # Y_s - T U_s = O x(s): subtract the input's part by simulating from x = 0.
    x = np.zeros((starts.size, sys.nx))
    rhs = np.empty((starts.size, q * sys.ny))
    for i in range(q):
        ui = u[starts + i]
        rhs[:, i * sys.ny : (i + 1) * sys.ny] = y[starts + i] - (x @ C.T + ui @ D.T)
        x = x @ A.T + ui @ B.T
    xs = np.linalg.lstsq(O, rhs.T, rcond=None)[0].T  # x(s), all windows at once
    for i in range(q - 1 + k):
        xs = xs @ A.T + u[starts + i] @ B.T
    t = starts + q - 1 + k
    out = np.full_like(y, np.nan)
    out[t] = xs @ C.T + u[t] @ D.T
    return out


def _fit(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    ok = np.all(np.isfinite(yhat), axis=1)
    err = np.linalg.norm(y[ok] - yhat[ok], axis=0)
    spread = np.linalg.norm(y[ok] - y[ok].mean(axis=0), axis=0)
    return 100.0 * (1.0 - err / np.where(spread > 0, spread, np.nan))


def _simulate(
    sys: StateSpace, data: ClosedLoopData, y: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray | None, str, str | None]:
    if np.all(np.abs(sys.poles()) < 1):
        return sys.simulate(u)[0], "open loop", None
    if data.r is None or not data.loop.get("controller"):
        return (
            None,
            "none",
            (
                "the model is unstable and the recording states no controller or excitation: "
                "no simulation (the model is never stabilised to make one)"
            ),
        )
    from maglevid.control.feedback import close_loop, controller_state_space

    try:
        loop = close_loop(sys, controller_state_space(dict(data.loop), plant=sys))
    except MaglevidError as exc:
        return None, "none", f"the logged controller cannot be closed around the model: {exc}"
    if not np.all(np.abs(loop.poles()) < 1):
        return None, "none", "the model is unstable even in closed loop with the logged controller"
    r = np.asarray(data.r, dtype=float)
    return loop.simulate(r - r.mean(axis=0))[0], "closed loop with the logged controller", None


def compare(
    result: IdentificationResult,
    data: ClosedLoopData,
    *,
    horizons: Sequence[int] = (1, 10),
) -> Comparison:
    """Fit of the model's k-step predictions and simulation to a recording (MATLAB's ``compare``).

    Parameters
    ----------
    result : IdentificationResult
        With a discrete model ``u -> y``.
    data : ClosedLoopData
        The recording to compare with (one output sample per control period).
    horizons : sequence of int
        Prediction horizons ``k >= 1`` in control periods.

    Returns
    -------
    Comparison
        ``fit_percent[k]`` per output and ``fit_percent["simulation"]`` (``None``
        with a note when the model can be simulated neither open loop nor in
        closed loop with the logged controller).
    """
    ks = [int(k) for k in horizons]
    if any(k < 1 for k in ks):
        raise DataError(f"`horizons` must be >= 1 control period; got {list(horizons)}")
    y, u = _signals(data)
    sys = _model(result, data)
    y, u = y - y.mean(axis=0), u - u.mean(axis=0)
    preds = {k: _k_step(sys, y, u, k) for k in ks}
    fits: dict[Any, np.ndarray | None] = {k: _fit(y, p) for k, p in preds.items()}
    sim, kind, why = _simulate(sys, data, y, u)
    fits["simulation"] = None if sim is None else _fit(y, sim)
    return Comparison(
        y=y,
        predictions=preds,
        fit_percent=fits,
        simulation=sim,
        simulation_kind=kind,
        dt=float(data.dt),
        output_names=data.channel_names("y"),
        notes=("signals are taken about their means",) + ((why,) if why else ()),
    )
