"""Maximum likelihood on every inter-sample: the suspension's physics through a Kalman predictor.

Sun et al.'s steps (:mod:`maglevid.identify.intersample`) are consistent when the only
noise is on the measured output: the inter-samples ``y_j``, ``j >= 1``, whose noise the
loop never sees, are then an open-loop experiment. A force on the ball, or the
nonlinear plant's own distortion (eq. (25) is not eq. (27) at the loop's excursion),
enters *inside* the loop: it moves the ball, the controller answers it, and the
output-error fit of the inter-samples then reads the feedback as plant dynamics.
Measured (docs/sun.md, "Beyond the paper"): a 0.05 N rms force (1 % of the ball's
weight) moves Sun's unstable pole by +15 % (3.6 of its standard errors); on the
nonlinear plant at the paper's 0.1 mm noise the pole is +5 % off and ``Q`` -18 %
(-4.4 standard errors), at 0.2 mm the physical parameters are not found at all.

This method fits the suspension's linearised physics (eq. (27), corrected: ``alpha``,
``eta``, ``L`` with the printed ``M`` and ``R``) at the fast rate ``Delta = T/p`` with
the voltage held over each control period, in innovations form with a free Kalman
gain ``K`` (3 numbers: any stationary force, voltage and sensor noise), by minimising
the one-step prediction errors of *every* output sample, ``y_0`` included (Ljung
1999, sec. 13.4: the direct prediction-error method is consistent in closed loop when
the noise model can describe the noise). The predictor ``Ad - K C`` is stable, so
the unstable plant is never simulated open loop. The control law samples only
``y_0``: with ``p >= 2`` the loop is periodically time-varying and the data are
informative although the reference is zero (with ``p = 1`` they are not: Sun et
al.'s Case 1). For a scalar output the likelihood is the sum of squared prediction
errors; the covariance is ``s^2 (J^T J)^{-1}`` of their Jacobian (Cramér-Rao at the
estimate); the derived parameters (force balance eq. (26), T-model, poles) by the
delta method.

Starts: the electrical time constant ``L/R`` on a grid (10 ms to 0.3 s), ``eta``
from the DC gain and ``alpha`` from the unstable pole of Sun et al.'s estimate
(robust where its physical parameters are not), Sun's own physical parameters when
they are valid, each with the Kalman gains of three force-noise levels; the lowest
cost wins.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy import optimize, signal

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError, ModelError
from maglevid.identify.closedloop import (
    covariance_from_jacobian,
    simo_polynomials_to_state_space,
)
from maglevid.identify.intersample import (
    PHYSICS_OPTIONS,
    _known_physics,
    _signals,
    fit_intersample,
)
from maglevid.identify.multirate import intersample_numerators
from maglevid.identify.options import Option
from maglevid.identify.result import IdentificationResult, propagate_covariance
from maglevid.lti import StateSpace, discretize
from maglevid.physics.suspension import STATE_NAMES, continuous_from_t_model

__all__ = ["METHODS", "OPTIONS", "fit_intersample_ml"]

log = logging.getLogger(__name__)

#: Electrical time constants ``L/R`` [s] the starts try (the paper's coil: 78 ms).
START_TIME_CONSTANTS = (0.01, 0.03, 0.1, 0.3)
#: Resistances [ohm] the starts try when the recording states none.
START_RESISTANCES = (1.0, 10.0, 100.0)
#: Force-noise levels (log of the ratio to the sensor noise, N/m) whose Kalman gains
#: start ``K``: practically none, moderate, and the force dominating.
START_FORCE_LEVELS = (-4.0, 2.0, 8.0)
#: Prediction errors dropped at the start: the predictor from ``x = 0`` until its
#: slowest mode has fallen to this fraction.
TRANSIENT_DECAY = 1e-4
#: The predictor must leave at least this share of the record.
MAX_BURN_IN_SHARE = 0.25
#: Starts finished after the first, short pass (the lowest costs).
FINISHED_STARTS = 2
_SHORT_NFEV = 10
#: How far (natural log) a physical parameter may go from the first start: 1e11 either way.
_LOG_RANGE = 25.0


def _continuous(phys: np.ndarray, M: float, R: float) -> tuple[np.ndarray, np.ndarray]:
    """``A_c`` and ``[b_u, b_force, b_voltage]`` of eq. (27) at ``phys = (alpha, eta, L)``
    (``(alpha, eta, L, R)`` with the resistance free, ``R`` then ignored).

    States ``[y, dy/dt, i]`` (``y`` the gap's deviation, down positive); a force
    disturbance pushes the ball away from the magnet, a voltage disturbance adds to
    ``u``. The same matrices as :func:`~maglevid.physics.suspension.suspension_state_space`
    (test).
    """
    al, eta, L = phys[:3]
    R = phys[3] if len(phys) > 3 else R
    A = np.array([[0.0, 1.0, 0.0], [al / M, 0.0, -eta / M], [0.0, eta / L, -R / L]])
    B = np.array([[0.0, 0.0, 0.0], [0.0, 1.0 / M, 0.0], [1.0 / L, 0.0, 1.0 / L]])
    return A, B


def _sampled(phys: np.ndarray, M: float, R: float, delta: float) -> tuple[np.ndarray, ...]:
    """ZOH over one inter-sample ``delta``: ``(Ad, Bd)`` with ``Bd``'s three columns."""
    A, B = _continuous(phys, M, R)
    X = np.zeros((6, 6))
    X[:3, :3], X[:3, 3:] = A * delta, B * delta
    E = sla.expm(X)
    return E[:3, :3], E[:3, 3:]


def _kalman_gain(Ad: np.ndarray, Bd: np.ndarray, log_force: float) -> np.ndarray:
    """Steady-state predictor gain for a held force of ``exp(log_force)`` N per metre
    of sensor noise (no voltage noise): a start for ``K``."""
    Q = np.exp(2.0 * log_force) * np.outer(Bd[:, 1], Bd[:, 1]) + 1e-14 * np.eye(3)
    C = np.array([[1.0, 0.0, 0.0]])
    P = sla.solve_discrete_are(Ad.T, C.T, Q, np.eye(1))
    return (Ad @ P @ C.T / (1.0 + (C @ P @ C.T)[0, 0])).ravel()


@dataclass(frozen=True)
class _Predictor:
    """One-step prediction errors of the fast-rate innovations model.

    ``theta = [ln alpha, ln eta, ln L, (ln R), K / k_scale]`` (``n_phys`` logs); ``y``
    (N p) and ``u`` (N p, held) without their means; the first ``burn`` errors dropped.
    """

    y: np.ndarray
    u: np.ndarray
    M: float
    R: float
    delta: float
    burn: int
    k_scale: np.ndarray
    centre: np.ndarray  # ln [alpha, eta, L, (R)] of the first start

    @property
    def n_phys(self) -> int:
        return self.centre.size

    def errors(self, theta: np.ndarray) -> np.ndarray:
        # a cost above any stable predictor's: outside eq. (27)'s plausible range (a
        # step to 1e-11..1e11 times a value: the exponential would overflow) or unstable
        penalty = np.full(self.y.size - self.burn, 1e3 * np.std(self.y))
        n = self.n_phys
        if not np.all(np.abs(theta[:n] - self.centre) < _LOG_RANGE):
            return penalty
        with np.errstate(over="ignore", invalid="ignore"):
            Ad, Bd = _sampled(np.exp(theta[:n]), self.M, self.R, self.delta)
        K = theta[n:] * self.k_scale
        Abar = Ad - np.outer(K, [1.0, 0.0, 0.0])
        if not np.all(np.isfinite(Abar)) or np.max(np.abs(np.linalg.eigvals(Abar))) >= 1.0:
            return penalty
        C = np.array([[1.0, 0.0, 0.0]])
        num_u, den = signal.ss2tf(Abar, Bd[:, :1], C, np.zeros((1, 1)))
        num_y, _ = signal.ss2tf(Abar, K[:, None], C, np.zeros((1, 1)))
        e = self.y - signal.lfilter(num_y[0], den, self.y) - signal.lfilter(num_u[0], den, self.u)
        return e[self.burn :]

    def predictor_radius(self, theta: np.ndarray) -> float:
        Ad, _ = _sampled(np.exp(theta[: self.n_phys]), self.M, self.R, self.delta)
        K = theta[self.n_phys :] * self.k_scale
        return float(np.max(np.abs(np.linalg.eigvals(Ad - np.outer(K, [1.0, 0.0, 0.0])))))


def _starts(
    sun: IdentificationResult, M: float, resistances: tuple[float, ...], free: bool
) -> list[tuple[str, np.ndarray]]:
    """Physical starts ``(name, [alpha, eta, L(, R)])`` from Sun et al.'s estimate (module
    notes), one set per resistance tried; ``R`` is appended when it is free."""
    a = np.r_[1.0, [sun.parameters[f"a{i}"] for i in (1, 2, 3)]]
    b = np.r_[0.0, [sun.parameters[f"b{i}"] for i in (1, 2, 3)]]
    out = []
    try:
        s, k = continuous_from_t_model(a, b, sun.model.dt)
    except (ModelError, ValueError):  # no continuous reading: its physics is no start
        s, k = np.zeros(0), 0.0
    pole = float(np.max(s.real)) if s.size else 0.0
    for R in resistances if pole > 0 and k < 0 else ():
        for tau in START_TIME_CONSTANTS:
            L = tau * R
            eta = -k * M * L
            # the characteristic polynomial of eq. (27) vanishes at the unstable pole
            al = (M * L * pole**3 + M * R * pole**2 + eta**2 * pole) / (L * pole + R)
            name = f"L/R = {tau:g} s" + (f", R = {R:.4g} ohm" if free else "")
            out.append((name, np.array([al, eta, L, R][: 4 if free else 3])))
    phys = [sun.parameters.get(k_) for k_ in ("alpha", "eta", "L")]
    if free:
        phys.append(sun.parameters.get("R", resistances[0]))
    if all(v is not None and np.isfinite(v) and v > 0 for v in phys):
        out.append(("Sun et al.'s physical parameters", np.array(phys, dtype=float)))
    return out


def _fit(pred: _Predictor, starts: list[tuple[str, np.ndarray]], max_nfev: int):  # type: ignore[no-untyped-def]
    """Short fits from every start and force level, the best :data:`FINISHED_STARTS`
    finished; returns the best ``least_squares`` result and the table of starts."""
    trials = []
    for name, phys in starts:
        Ad, Bd = _sampled(phys, pred.M, pred.R, pred.delta)
        for level in START_FORCE_LEVELS:
            try:
                K0 = _kalman_gain(Ad, Bd, level) / pred.k_scale
            except (np.linalg.LinAlgError, ValueError):
                continue
            x0 = np.r_[np.log(phys), K0]
            r = _least_squares(pred, x0, _SHORT_NFEV)
            trials.append({"start": name, "force_level": level, "cost": 2.0 * r.cost, "r": r})
    if not trials:
        raise IdentificationError("no start gave a stable Kalman predictor")
    trials.sort(key=lambda t: t["cost"])
    best = None
    for t in trials[:FINISHED_STARTS]:
        r = _least_squares(pred, t["r"].x, max_nfev)
        t["finished_cost"] = 2.0 * r.cost
        if best is None or r.cost < best.cost:
            best = r
    table = [{k: v for k, v in t.items() if k != "r"} for t in trials]
    return best, table


def _least_squares(pred: _Predictor, x0: np.ndarray, max_nfev: int):  # type: ignore[no-untyped-def]
    return optimize.least_squares(
        pred.errors, x0, method="trf", x_scale="jac", diff_step=1e-6, max_nfev=max_nfev,
        ftol=1e-10, xtol=1e-10, gtol=1e-10,
    )  # fmt: skip


def _burn_in(
    starts: list[tuple[str, np.ndarray]], M: float, R: float, delta: float, n: int
) -> int:
    """Errors to drop: the slowest start predictor's transient to :data:`TRANSIENT_DECAY`."""
    rho = 0.0
    for _, phys in starts:
        Ad, Bd = _sampled(phys, M, R, delta)
        for level in START_FORCE_LEVELS:
            try:
                K = _kalman_gain(Ad, Bd, level)
            except (np.linalg.LinAlgError, ValueError):
                continue
            rho = max(rho, float(np.max(np.abs(np.linalg.eigvals(Ad - np.outer(K, [1, 0, 0]))))))
    burn = int(np.ceil(np.log(TRANSIENT_DECAY) / np.log(rho))) if 0 < rho < 1 else n // 10
    return min(burn, int(MAX_BURN_IN_SHARE * n))


def fit_intersample_ml(
    data: ClosedLoopData,
    *,
    mass: float | None = None,
    resistance: float | None = None,
    gravity: float | None = None,
    output: int = 0,
    free_resistance: bool = False,
    burn_in: int | None = None,
    max_nfev: int = 400,
) -> IdentificationResult:
    """Physical parameters of the suspension by maximum likelihood on every inter-sample.

    Consistent under feedback with force and voltage disturbances and with the
    nonlinear plant's distortion, which bias :func:`~maglevid.identify.intersample.fit_intersample`
    (module notes); started from that estimate.

    Parameters
    ----------
    data : ClosedLoopData
        Multi-rate recording, ``p >= 2``, single input held over each control period.
    mass, resistance, gravity : float, optional
        Ball mass [kg] (needed), coil-circuit resistance [ohm] and gravity [m/s^2];
        default ``data.loop["physical"]["M"]``, ``["R"]``, ``["g"]`` (gravity else
        9.80665). Without a resistance ``R`` is estimated too.
    output : int
        Output channel (position) when ``y`` has several.
    free_resistance : bool
        Estimate ``R`` even where it is known (a coil that heats up: its resistance
        is what changed); eq. (27) with the mass has four free parameters, but
        ``eta``, ``L``, ``R`` are then weakly determined (measured: +-200 % on 18 s of
        the simulator's noise-driven loop, where ``R`` given leaves +-6 %).
    burn_in : int, optional
        Prediction errors dropped at the record's start (default: the start
        predictors' transient to 1e-4, at most a quarter of the samples).
    max_nfev : int
        Limit on prediction-error evaluations of each finished fit.

    Returns
    -------
    IdentificationResult
        ``parameters``: ``a1..a3``, ``b1..b3`` (the T-model of ``y_0``),
        ``pole_z``/``pole_rad_s``, ``alpha``, ``eta``, ``L`` (``R`` when free) and
        through the force balance ``gap``, ``I``, ``Q``, ``L_inf`` (``Y_offset`` when
        ``loop["operating_point"]["Y"]`` is known); ``covariance``: Cramér-Rao at the
        estimate, delta method for the derived ones; ``residuals``: the one-step
        prediction errors; ``extras``: the Kalman gain, the starts and Sun et al.'s
        estimate of the pole.

    Raises
    ------
    DataError
        ``p < 2``, no or several inputs, no mass, too short a record.
    IdentificationError
        No start gives a stable predictor, or the fit ends without an unstable pole.

    Examples
    --------
    >>> from maglevid.simulate.suspension import simulate_suspension
    >>> rec = simulate_suspension(p=3, duration=6.0, rng=0)
    >>> res = fit_intersample_ml(rec)
    >>> 0.8 < res.parameters["L"] / rec.metadata["truth"]["parameters"]["L"] < 1.2
    True
    """
    u, Y, M, R, g = _checked(data, mass, resistance, gravity, output, burn_in)
    p, T = data.p, data.dt
    free = bool(free_resistance) or R is None
    notes = [
        "direct maximum likelihood on every inter-sample through the Kalman predictor "
        "(free gain): consistent under feedback with force disturbances and the plant's "
        "nonlinearity, which bias the output-error steps of `intersample`"
    ]
    if R is None:
        notes.append(
            "the coil circuit's resistance is not known: R is estimated with the rest; "
            "eq. (27) then reads eta, L and R through a small difference of large numbers "
            "(on 18 s of the simulator's noise-driven loop, +-200 % against +-6 % with R "
            "given): an ohmmeter reading of R (option resistance=) resolves them"
        )
    sun = fit_intersample(data, output=output, mass=M, resistance=R, gravity=g)
    starts = _starts(sun, M, START_RESISTANCES if R is None else (R,), free)
    if not starts:
        raise IdentificationError(
            "Sun et al.'s estimate has no unstable real pole with a negative gain, so "
            "there is no start for the physical fit (the record may not be a suspension "
            "under feedback, or far too short)"
        )
    R = float(starts[0][1][3]) if R is None else R  # the model's R when it is not free
    delta = T / p
    yf = Y.ravel() - float(np.mean(Y))
    uf = np.repeat(u - float(np.mean(u)), p)
    burn = _burn_in(starts, M, R, delta, yf.size) if burn_in is None else int(burn_in)
    n_theta = len(starts[0][1]) + 3
    if yf.size - burn < 50 * n_theta:
        raise DataError(
            f"the record has {yf.size} output samples, {yf.size - burn} after the "
            f"predictor's start-up: at least {50 * n_theta} are needed for {n_theta} "
            "parameters"
        )
    Ad, Bd = _sampled(starts[0][1], M, R, delta)
    k_scale = np.maximum(np.abs(_kalman_gain(Ad, Bd, START_FORCE_LEVELS[1])), 1e-12)
    pred = _Predictor(yf, uf, M, R, delta, burn, k_scale, np.log(starts[0][1]))
    best, table = _fit(pred, starts, max_nfev)
    if not best.success or best.nfev >= max_nfev:
        notes.append(
            f"the fit stopped after {best.nfev} evaluations without meeting its tolerance"
        )
    rho = pred.predictor_radius(best.x)
    if rho**burn > 1e-2:
        notes.append(
            f"the predictor's slowest mode ({rho:.4g} per sample) had not died out within "
            f"the {burn} samples dropped; pass burn_in= a larger number"
        )
    options = dict(mass=M, resistance=None if free else R, gravity=g, output=output,
                   free_resistance=free, burn_in=burn, max_nfev=max_nfev, p=p)  # fmt: skip
    extras = {"starts": table, "intersample_pole_rad_s": sun.parameters["pole_rad_s"]}
    extras["intersample_physical"] = {
        k: sun.parameters[k] for k in ("alpha", "eta", "L", "R") if k in sun.parameters
    }
    return _result(data, pred, best, g, options, notes, extras)


def _result(data, pred, best, g, options, notes, extras):  # type: ignore[no-untyped-def]
    """The :class:`IdentificationResult`: the derived parameters by the delta method from
    the physical ones' Cramér-Rao covariance, the T-model, the inter-sample numerators."""
    p, T, n = data.p, data.dt, pred.n_phys
    theta = best.x
    cov_theta = _covariance(pred, theta)
    M, R, delta = pred.M, pred.R, pred.delta
    names, derived = _derived(M, R, g, delta, p, _operating_point(data), free=n == 4)
    values, cov = propagate_covariance(derived, theta[:n], cov_theta[:n, :n])
    parameters = dict(zip(names, values.tolist()))
    if parameters["pole_rad_s"] <= 0:
        raise IdentificationError(
            f"the fit ended without an unstable pole (largest {parameters['pole_rad_s']:.4g} "
            "rad/s): eq. (27)'s suspension is unstable, so the record does not fit it"
        )
    a_full, b_full = np.r_[1.0, values[:3]], np.r_[0.0, values[3:6]]
    B_inter, B_cov = propagate_covariance(
        _numerators(M, R, delta, p), theta[:n], cov_theta[:n, :n]
    )
    A_c, B_c = _continuous(np.exp(theta[:n]), M, R)
    e = best.fun
    yv = pred.y[pred.burn :]
    extras = {
        "B_intersample": B_inter.reshape(p - 1, 4).tolist(),
        "B_intersample_std_error": np.sqrt(np.clip(np.diag(B_cov), 0, None))
        .reshape(p - 1, 4)
        .tolist(),
        "kalman_gain": (theta[n:] * pred.k_scale).tolist(),
        "kalman_gain_std": (np.sqrt(np.diag(cov_theta)[n:]) * pred.k_scale).tolist(),
        **extras,
    }
    return IdentificationResult(
        method="intersample-ml",
        model=simo_polynomials_to_state_space(a_full, [b_full], T, output_names=("y",)),
        parameters=parameters,
        covariance=0.5 * (cov + cov.T),
        n_samples=data.n_samples,
        options=options,
        residuals=e[:, None],
        fit={
            "one_step_fit_percent": 100.0 * (1.0 - float(np.linalg.norm(e) / np.linalg.norm(yv))),
            "sigma_e": float(np.sqrt(np.mean(e**2))),
            "predictor_radius": pred.predictor_radius(theta),
        },
        notes=tuple(notes),
        continuous_model=StateSpace(
            A_c, B_c[:, :1], np.array([[1.0, 0.0, 0.0]]), None, None, STATE_NAMES, ("u",), ("y",)
        ),
        extras=extras,
    )


def _checked(data, mass, resistance, gravity, output, burn_in):  # type: ignore[no-untyped-def]
    """The signals ``u`` (N), ``Y`` (N, p) and ``M``, ``R``, ``g``, or the DataError that
    says what the recording lacks."""
    u, Y = _signals(data, output)
    M, R, g = _known_physics(data, mass, resistance, gravity)
    if data.p < 2:
        raise DataError(
            "the recording has p = 1 (no inter-samples): with the reference at zero the "
            "closed loop is not informative (Sun et al.'s Case 1); record the output p >= 2 "
            "times per control period"
        )
    if M is None:
        raise DataError(
            "intersample-ml needs the ball's mass: mass=... (maglevid identify --option "
            "mass=0.54), or loop['physical']['M'] in the recording; `intersample` identifies "
            "the polynomials without it"
        )
    if burn_in is not None and (isinstance(burn_in, bool) or burn_in < 0):
        raise DataError(f"`burn_in` must be an integer >= 0; got {burn_in!r}")
    return u, Y, M, R, g


def _covariance(pred: _Predictor, theta: np.ndarray) -> np.ndarray:
    """``s^2 (J^T J)^{-1}`` of the prediction errors (central differences, steps of
    ``1e-5`` in the logs and the scaled gain; the project's
    :func:`~maglevid.identify.closedloop.covariance_from_jacobian` on the columns scaled
    to unit norm)."""
    e0 = pred.errors(theta)
    J = np.empty((e0.size, theta.size))
    for i in range(theta.size):
        h = 1e-5 * max(abs(theta[i]), 1.0)
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        J[:, i] = (pred.errors(tp) - pred.errors(tm)) / (2.0 * h)
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    return covariance_from_jacobian(J / d, e0, theta.size) / np.outer(d, d)


def _operating_point(data: ClosedLoopData) -> float | None:
    op = data.loop.get("operating_point", {}) if hasattr(data.loop, "get") else {}
    return float(op["Y"]) if "Y" in op else None


def _numerators(M: float, R: float, delta: float, p: int):  # type: ignore[no-untyped-def]
    """The map ``ln [alpha, eta, L(, R)] -> B_1..B_{p-1}`` (Theorem 2, z^0..z^-3), flat."""

    def f(x: np.ndarray) -> np.ndarray:
        return intersample_numerators(_delta_model(np.exp(x), M, R, delta), p)[1][1:].ravel()

    return f


def _delta_model(phys: np.ndarray, M: float, R: float, delta: float) -> StateSpace:
    """Eq. (27) from ``u`` to ``y`` ZOH-sampled at the inter-sample ``delta``."""
    A, B = _continuous(phys, M, R)
    return discretize(StateSpace(A, B[:, :1], np.array([[1.0, 0.0, 0.0]]), None, None), delta)


def _derived(  # type: ignore[no-untyped-def]
    M: float, R: float, g: float, delta: float, p: int, Y_op: float | None, *, free: bool
):
    """Names and the map ``ln [alpha, eta, L(, R)] -> [a, b, pole_z, pole_rad_s, alpha,
    eta, L, (R), gap, I, Q, L_inf, (Y_offset)]`` (intersample's order)."""
    names = [f"a{k}" for k in (1, 2, 3)] + [f"b{k}" for k in (1, 2, 3)]
    names += ["pole_z", "pole_rad_s", "alpha", "eta", "L", *(["R"] if free else [])]
    names += ["gap", "I", "Q", "L_inf", *(["Y_offset"] if Y_op is not None else [])]

    def f(x: np.ndarray) -> np.ndarray:
        phys = np.exp(x)
        al, eta, L = phys[:3]
        A, _ = _continuous(phys, M, R)
        a, Bj = intersample_numerators(_delta_model(phys, M, R, delta), p)
        pole = float(np.max(np.linalg.eigvals(A).real))
        gap, I_ = 2 * M * g / al, 2 * M * g / eta
        Q = eta * gap**2 / I_
        out = [*a[1:], *Bj[0, 1:], np.exp(pole * delta * p), pole, al, eta, L, *phys[3:]]
        out += [gap, I_, Q]
        out.append(L - Q / gap)
        if Y_op is not None:
            out.append(gap - Y_op)
        return np.array(out, dtype=float)

    return names, f


METHODS = {"intersample-ml": fit_intersample_ml}
#: Its options, declared once (maglevid.identify.options; defaults: fit_intersample_ml's).
OPTIONS = {
    "intersample-ml": (
        *PHYSICS_OPTIONS,
        Option("free_resistance", "bool", "estimate R even where it is known (a coil "
               "that heats up)"),
        Option("burn_in", "int", "prediction errors dropped at the start (default: the "
               "predictor's transient)", low=0, optional=True),
        Option("max_nfev", "int", "limit on prediction-error evaluations per finished fit",
               low=1),
    )
}  # fmt: skip
