"""Grey-box identification of the single-magnet levitator's physical parameters.

The model is :mod:`maglevid.physics.levitator` (inductance law ``L(y) = k0 + k/(1+y/a)``,
mass known). On each segment the nonlinear model is linearised at the segment's
mean gap ``y0`` (eqs. (LIN1)-(LIN2)) with the equilibrium current ``i0(theta, y0)`` of
eq. (Q1), so the *level* of the current ties ``k`` and ``a`` together while the
dynamics fix ``sqrt(2 g/(a + y0))``: static and dynamic information in one
criterion. The linear model is sampled (ZOH for the held command ``u``; FOH,
straight lines between samples, for the measured current when it is the input)
and put in innovations form with the steady-state Kalman gain of a physical
noise model (held acceleration/voltage disturbances, white sensor noise; their
intensity ratios are estimated too); the parameters minimise the one-step
prediction errors (Ljung 1999, sec. 4.2 "grey-box" and 7.2). A Kalman predictor
is stable, so the unstable plant is never simulated open loop.

Models
------
``mechanical`` (default)
    input: measured coil current ``i``; output: gap ``y``. Parameters ``a``, ``k``
    (and ``K``). The plant whose pole the physics predicts, independent of the
    coil and driver.
``electromechanical``
    input: command ``u``; outputs ``y``, ``i``. Parameters ``a``, ``k``, ``k0``,
    ``R`` and ``ku`` (driver gain); the command offset (driver drop ``v0``) is
    absorbed by the segment's mean command.

Derived: the unstable pole ``p = sqrt(2 g/(a + y_ref))`` [rad/s] and ``z = exp(p dt)``
at a reference gap, the current gain ``b = 2 g / i0`` and the equilibrium current,
each with a delta-method standard error.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg as sla
from scipy import optimize

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.closedloop import (
    InnovationsModel,
    covariance_from_jacobian,
    extend_covariance,
    fit_percent,
    resolve_channel,
    resolve_segments,
)
from maglevid.identify.result import IdentificationResult
from maglevid.lti import StateSpace
from maglevid.physics.levitator import LevitatorParameters, linearize

__all__ = [
    "METHODS",
    "fit_equilibrium_line",
    "fit_greybox_levitator",
    "sample_foh",
    "sample_zoh",
]

log = logging.getLogger(__name__)

MODELS = ("mechanical", "electromechanical")


def sample_foh(A: np.ndarray, B: np.ndarray, C: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """First-order-hold sampling (input linear between samples).

    ``x_{k+1} = Phi x_k + G0 u_k + G1 (u_{k+1} - u_k)`` with ``Phi, G0, G1`` read off
    ``expm([[A dt, B dt, 0], [0, 0, I], [0, 0, 0]])``; in the causal state
    ``xi_k = x_k - G1 u_k``::

        xi_{k+1} = Phi xi_k + (G0 - G1 + Phi G1) u_k,   y_k = C xi_k + C G1 u_k

    Returns ``(Phi, Gamma, C, D)``.
    """
    nx, nu = B.shape
    M = np.zeros((nx + 2 * nu, nx + 2 * nu))
    M[:nx, :nx] = A * dt
    M[:nx, nx : nx + nu] = B * dt
    M[nx : nx + nu, nx + nu :] = np.eye(nu)
    E = sla.expm(M)
    Phi, G0, G1 = E[:nx, :nx], E[:nx, nx : nx + nu], E[:nx, nx + nu :]
    return Phi, G0 - G1 + Phi @ G1, C, C @ G1


def sample_zoh(A: np.ndarray, B: np.ndarray, C: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """Zero-order-hold sampling (Gosiewski & Paszowski eq. (7)): ``(Phi, Gamma, C, 0)``."""
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx] = A * dt
    M[:nx, nx:] = B * dt
    E = sla.expm(M)
    return E[:nx, :nx], E[:nx, nx:], C, np.zeros((C.shape[0], nu))


def _equilibrium_current(m: float, g: float, k: float, a: float, y0: float) -> float:
    return (a + y0) * np.sqrt(2.0 * m * g / (k * a))  # eq. (Q1)


def fit_greybox_levitator(
    data: ClosedLoopData,
    *,
    model: str = "mechanical",
    gap: str = "y:0",
    current: str = "y:1",
    command: str = "u:0",
    m: float = 0.018,
    g: float = 9.81,
    use_equilibrium: bool = True,
    flux_lag: bool = False,
    free_gain: bool = False,
    initial: LevitatorParameters | None = None,
    current_hold: str = "foh",
    segments: Sequence[Sequence[int]] | None = None,
    y_ref: float | None = None,
    burn_in: int = 20,
    k_step: int = 3,
    max_nfev: int | None = None,
) -> IdentificationResult:
    """Physical parameters of the levitator by one-step prediction error (grey box).

    Parameters
    ----------
    data : ClosedLoopData
        Same-rate record with the gap and the coil current (and the command for
        ``model="electromechanical"``).
    model : {"mechanical", "electromechanical"}
    gap, current, command : str
        Channels (``"y:0"``, ``"y:1"``, ``"u:0"``), SI units (m, A, V).
    m, g : float
        Known mass [kg] and gravity [m/s^2].
    use_equilibrium : bool
        Tie each segment's current level to the equilibrium current ``i0(a, k, y0)``
        of eq. (Q1) (default). Segments at different gaps then fix ``a`` and ``k``
        from the static force balance alone; the dynamics add the pole. With
        ``False`` the segment's mean current is used as ``i0`` and only the
        dynamics speak (``a`` from ``p``; ``k`` is then not estimated).
    flux_lag : bool
        ``mechanical`` only: the force follows the current through a first-order
        lag ``tau`` (eddy currents in a solid core); ``tau`` is estimated.
    free_gain : bool
        ``mechanical`` only: the current gain is ``beta * 2 g / i0`` with ``beta``
        estimated (``beta = 1`` is the force law F1); a test of the force law.
    initial : LevitatorParameters, optional
        Starting values (default: the published UAQ values with the driver of the
        UAQ twin for the electrical part).
    current_hold : {"foh", "zoh"}
        How the measured current is read between samples (``mechanical``). The
        current is not held by anything: FOH is closer to its real course.
    segments : list of (start, stop), optional
        Levitating pieces, each at about one operating point (split at reference
        steps); the model is linearised at each segment's mean gap.
    y_ref : float, optional
        Gap at which the pole is reported (default: mean gap of the first segment).
    burn_in : int
        Predictor samples discarded at the start of each segment.
    k_step : int
        Horizon of the k-step prediction fit (short: an unstable model amplifies
        the state error by ``z^k``).
    max_nfev : int, optional

    Returns
    -------
    IdentificationResult
        ``parameters``: ``a``, ``k`` (``k0``, ``R``, ``ku``; ``tau``; ``beta``), then
        ``pole_rad_s`` and ``pole_z`` at ``y_ref``, ``current_gain`` and ``i0`` at the
        first segment's gap. Covariance from the Jacobian of the prediction errors
        (``s^2 (J'J)^-1``), extended to the derived quantities by the delta method.
    """
    if model not in MODELS:
        raise DataError(f"`model` must be one of {MODELS}; got {model!r}")
    if current_hold not in ("foh", "zoh"):
        raise DataError(f"`current_hold` must be 'foh' or 'zoh'; got {current_hold!r}")
    if model == "electromechanical" and (flux_lag or free_gain or not use_equilibrium):
        raise DataError(
            "flux_lag, free_gain and use_equilibrium=False apply to the mechanical model only"
        )
    ych = resolve_channel(data, gap)
    ich = resolve_channel(data, current)
    y, i = ych.values, ich.values
    u = resolve_channel(data, command).values if model == "electromechanical" else None
    segs = resolve_segments(data, segments, min_length=burn_in + 20)
    dt = data.dt
    y0s = np.array([y[a:b].mean() for a, b in segs])
    ibar = np.array([i[a:b].mean() for a, b in segs])
    ubar = None if u is None else np.array([u[a:b].mean() for a, b in segs])
    y_ref = float(y0s[0]) if y_ref is None else float(y_ref)
    p0 = initial if initial is not None else LevitatorParameters(m=m, g=g, R=5.05, ku=0.515)
    if model == "mechanical":
        names = ["a"] + (["k"] if use_equilibrium else [])
        names += (["tau"] if flux_lag else []) + (["beta"] if free_gain else [])
        start = {"a": p0.a, "k": p0.k, "tau": 5e-3, "beta": 1.0}
        ny = 1
    else:
        names = ["a", "k", "k0", "R", "ku"]
        start = {"a": p0.a, "k": p0.k, "k0": p0.k0, "R": p0.R, "ku": p0.ku}
        ny = 2
    phys0 = np.array([start[n] for n in names])
    n_phys = phys0.size
    notes: list[str] = [
        f"grey box ({model}), mass m = {m} kg known; linearised at each segment's mean gap",
    ]
    if not use_equilibrium:
        notes.append("use_equilibrium=False: i0 = segment mean current; k not estimated")

    def unpack(th: np.ndarray) -> dict[str, float]:
        d = dict(zip(names, th.tolist()))
        d.setdefault("tau", 0.0)
        d.setdefault("beta", 1.0)
        return d

    def i0_of(d: dict[str, float], s: int) -> float:
        if "k" in d:
            return _equilibrium_current(m, g, d["k"], d["a"], y0s[s])  # eq. (Q1)
        return float(ibar[s])

    def continuous(d: dict[str, float], s: int) -> tuple[np.ndarray, ...]:
        """(A_c, B_c, C, B_w) of segment s; B_w: the process-noise inputs."""
        y0 = y0s[s]
        i0 = i0_of(d, s)
        p2 = 2.0 * g / (d["a"] + y0)  # eq. (LIN1)
        b = d["beta"] * 2.0 * g / i0  # eq. (LIN1)
        if model == "mechanical" and not flux_lag:
            A = np.array([[0.0, 1.0], [p2, 0.0]])
            return A, np.array([[0.0], [-b]]), np.array([[1.0, 0.0]]), np.array([[0.0], [1.0]])
        if model == "mechanical":
            tau = d["tau"]
            A = np.array([[0.0, 1.0, 0.0], [p2, 0.0, -b], [0.0, 0.0, -1.0 / tau]])
            B = np.array([[0.0], [0.0], [1.0 / tau]])
            return A, B, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0], [1.0], [0.0]])
        par = LevitatorParameters(m=m, g=g, a=d["a"], k=d["k"], k0=d["k0"], R=d["R"], ku=d["ku"])
        sc = linearize(par, y0)
        Bw = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0 / float(par.inductance(y0))]])
        return sc.A, sc.B, sc.C, Bw

    def sample(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, ...]:
        if model == "mechanical" and current_hold == "foh":
            return sample_foh(A, B, C, dt)
        return sample_zoh(A, B, C, dt)

    # Noise model: the innovations gain of each segment is the steady-state Kalman gain of
    # that segment's sampled model for held white process noise (an acceleration
    # disturbance; for the electromechanical model also a voltage disturbance) and white
    # measurement noise. Only intensity ratios matter, so the parameters are
    # log(sigma_w / sigma_y) (and log(sigma_i / sigma_y)). A Kalman predictor is stable by
    # construction (Anderson & Moore 1979, sec. 4.4): no unstable predictor can occur.
    if model == "mechanical":
        noise_names = ["log_acc_over_y"]
        noise0 = np.array([np.log(0.3 / 3e-5)])
    else:
        noise_names = ["log_acc_over_y", "log_volt_over_y", "log_i_over_y"]
        noise0 = np.array([np.log(0.3 / 3e-5), np.log(0.3 / 3e-5), np.log(3e-3 / 3e-5)])

    def predictor(th: np.ndarray, s: int) -> tuple[InnovationsModel, np.ndarray, np.ndarray]:
        d = unpack(th[:n_phys])
        lq = th[n_phys:]
        a0, b0 = segs[s]
        A, B, C, Bw = continuous(d, s)
        Phi, Gam, Cd, D = sample(A, B, C)
        _, Gw, _, _ = sample_zoh(A, Bw, C, dt)
        sw = np.exp(lq[: Bw.shape[1]])
        Rn = np.eye(1) if ny == 1 else np.diag([1.0, np.exp(2 * lq[2])])
        Q = (Gw * sw**2) @ Gw.T
        P = sla.solve_discrete_are(Phi.T, Cd.T, Q, Rn)
        Kg = Phi @ P @ Cd.T @ np.linalg.inv(Cd @ P @ Cd.T + Rn)
        i0 = i0_of(d, s)
        if model == "mechanical":
            U = (i[a0:b0] - i0)[:, None]  # with use_equilibrium, the level of i is physics
            Yd = (y[a0:b0] - y0s[s])[:, None]
        else:
            U = (u[a0:b0] - ubar[s])[:, None]
            Yd = np.column_stack([y[a0:b0] - y0s[s], i[a0:b0] - i0])
        return InnovationsModel(Phi, Gam, Cd, D, Kg), Yd, U

    theta0 = np.r_[phys0, noise0]
    scale = np.r_[np.abs(phys0), np.ones(noise0.size)]
    Y = np.column_stack([y, i]) if ny == 2 else y[:, None]
    wts = np.array([1.0 / max(np.std(Y[a:b, j]) for a, b in segs) for j in range(ny)])
    n_res = sum(b - a - burn_in for a, b in segs) * ny

    def residuals(z: np.ndarray) -> np.ndarray:
        th = z * scale
        out = []
        for s in range(len(segs)):
            try:
                inn, Yd, U = predictor(th, s)
            except (np.linalg.LinAlgError, ValueError):
                return np.full(n_res, 1e3)
            e = (Yd - inn.predict(Yd, U, k=1)) * wts[None, :]
            out.append(e[burn_in:].ravel())
        return np.concatenate(out)

    # Physical parameters stay positive (bounds keep every step physical; a penalty would
    # leave the trust region blind).
    lower = np.r_[np.full(n_phys, 1e-3), np.full(noise0.size, -np.inf)]
    if np.all(residuals(theta0 / scale) == 1e3):
        raise IdentificationError("no Kalman predictor at the starting parameters")
    sol = optimize.least_squares(
        residuals, theta0 / scale, method="trf", bounds=(lower, np.inf), max_nfev=max_nfev
    )
    if not sol.success:
        notes.append(f"optimiser stopped: {sol.message}")
    theta = sol.x * scale
    J = sol.jac / scale[None, :]
    cov_all = covariance_from_jacobian(J, sol.fun, theta.size)
    th_phys = theta[:n_phys]
    cov = cov_all[:n_phys, :n_phys]
    if np.any(np.isclose(sol.x[:n_phys], 1e-3)):
        notes.append("a physical parameter sits at its lower bound (1e-3 of its start)")

    def derived(t: np.ndarray) -> np.ndarray:
        d = unpack(t)
        p = np.sqrt(2.0 * g / (d["a"] + y_ref))  # eq. (LIN1)
        i0 = i0_of(d, 0)
        return np.array([p, np.exp(p * dt), d["beta"] * 2.0 * g / i0, i0])

    dvals = derived(th_phys)
    Jd = np.empty((4, n_phys))
    for j in range(n_phys):
        h = 1e-6 * abs(th_phys[j])
        tp, tm = th_phys.copy(), th_phys.copy()
        tp[j] += h
        tm[j] -= h
        Jd[:, j] = (derived(tp) - derived(tm)) / (2 * h)
    ext = extend_covariance(cov, [Jd])
    params = dict(zip([*names, "pole_rad_s", "pole_z", "current_gain", "i0"],
                      [*th_phys.tolist(), *dvals.tolist()]))  # fmt: skip
    yhat1 = np.full(Y.shape, np.nan)
    yhatk = np.full(Y.shape, np.nan)
    resid = np.full(Y.shape, np.nan)
    for s, (a0, b0) in enumerate(segs):
        inn, Yd, U = predictor(theta, s)
        off = Y[a0:b0] - Yd
        p1 = inn.predict(Yd, U, k=1)
        pk = inn.predict(Yd, U, k=k_step)
        p1[:burn_in] = np.nan
        pk[: burn_in + k_step - 1] = np.nan
        yhat1[a0:b0], yhatk[a0:b0] = p1 + off, pk + off
        resid[a0:b0] = Yd - p1
    fit: dict[str, float] = {}
    chn = [ych.name] + ([ich.name] if ny == 2 else [])
    for j, nm in enumerate(chn):
        fit[f"one_step_fit_percent_{nm}"] = fit_percent(Y[:, j], yhat1[:, j], segs)
        fit[f"{k_step}_step_fit_percent_{nm}"] = fit_percent(Y[:, j], yhatk[:, j], segs)
    d = unpack(th_phys)
    A, B, C, _ = continuous(d, 0)
    in_name = "i" if model == "mechanical" else "u"
    out_names = ("y",) if ny == 1 else ("y", "i")
    cont = StateSpace(A, B, C, None, None, (), (in_name,), out_names)
    Phi, Gam, Cd, D = sample(A, B, C)
    disc = StateSpace(Phi, Gam, Cd, D, dt, (), (in_name,), out_names)
    if model == "mechanical":
        notes.append(f"input: measured current read with {current_hold.upper()} between samples")
    notes.append(
        f"pole reported at y_ref = {y_ref * 1e3:.3f} mm; models (discrete, continuous), "
        f"gain and i0 at the first segment's gap {y0s[0] * 1e3:.3f} mm"
    )
    notes.append("'a' includes any offset of the gap sensor (only a + y enters the force)")
    return IdentificationResult(
        method="greybox-levitator",
        model=disc,
        parameters=params,
        covariance=ext,
        n_samples=int(sum(b - a for a, b in segs)),
        options={
            "model": model,
            "gap": gap,
            "current": current,
            "command": command,
            "m": m,
            "g": g,
            "use_equilibrium": use_equilibrium,
            "flux_lag": flux_lag,
            "free_gain": free_gain,
            "current_hold": current_hold,
            "segments": [list(s) for s in segs],
            "y_ref": y_ref,
            "burn_in": burn_in,
            "k_step": k_step,
            "initial": p0.to_dict(),
        },
        residuals=resid,
        fit=fit,
        notes=tuple(notes),
        continuous_model=cont,
        extras={
            "noise_parameters": dict(zip(noise_names, theta[n_phys:].tolist())),
            "segment_gaps": y0s.tolist(),
            "segment_mean_currents": ibar.tolist(),
            "segment_model_currents": [i0_of(d, s) for s in range(len(segs))],
        },
    )


def fit_equilibrium_line(
    gaps: Any,
    currents: Any,
    *,
    m: float = 0.018,
    g: float = 9.81,
    y_ref: float = 0.005,
    dt: float = 0.01,
) -> dict[str, float]:
    """``a``, ``k`` and the pole from equilibrium currents at several gaps (eq. (Q1)).

    ``i0 = c (a + y0)`` with ``c = sqrt(2 m g / (k a))`` is a straight line in ``y0``:
    least squares gives slope ``c`` and intercept ``c a``, so ``a = intercept/slope``,
    ``k = 2 m g / (a c^2)`` and the pole ``sqrt(2 g/(a + y_ref))`` - from *static*
    data alone, without any dynamics. Standard errors by the delta method from the
    line's covariance (white scatter about the line; two points give no scatter and
    NaN errors).
    """
    y0 = np.asarray(gaps, dtype=float).reshape(-1)
    i0 = np.asarray(currents, dtype=float).reshape(-1)
    if y0.size != i0.size or y0.size < 2 or np.ptp(y0) <= 0:
        raise DataError("need at least two distinct gaps with one current each")
    X = np.column_stack([y0, np.ones_like(y0)])
    (c, ca), *_ = np.linalg.lstsq(X, i0, rcond=None)
    dof = y0.size - 2
    if dof > 0:
        s2 = float(np.sum((i0 - X @ [c, ca]) ** 2)) / dof
        _, sv, Vt = np.linalg.svd(X, full_matrices=False)
        cov = (Vt.T / sv**2) @ Vt * s2
    else:
        cov = np.full((2, 2), np.nan)

    def f(t: np.ndarray) -> np.ndarray:
        a = t[1] / t[0]
        p = np.sqrt(2.0 * g / (a + y_ref))
        return np.array([a, 2.0 * m * g / (a * t[0] ** 2), p, np.exp(p * dt)])

    th = np.array([c, ca])
    val = f(th)
    J = np.empty((4, 2))
    for j in range(2):
        h = 1e-6 * abs(th[j])
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        J[:, j] = (f(tp) - f(tm)) / (2 * h)
    se = np.sqrt(np.diag(J @ cov @ J.T)) if dof > 0 else np.full(4, np.nan)
    names = ("a", "k", "pole_rad_s", "pole_z")
    out = dict(zip(names, val.tolist()))
    out.update({f"{n}_se": float(e) for n, e in zip(names, se)})
    out["slope"] = float(c)
    out["n_points"] = float(y0.size)
    return out


METHODS = {"greybox-levitator": fit_greybox_levitator}
