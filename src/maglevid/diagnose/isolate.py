"""Fault isolation: which physical change explains the identified v1..v9?

Every fault of the two-coil bearing leaves a signature in ``v = (v1, ..., v9)``
(Gosiewski & Paszowski eq. (4)):

================  =========================================  ===========================
hypothesis        physical meaning                           elements that move
================  =========================================  ===========================
``R1``            coil 1 resistance (heating, bad contact)   v5
``K1``            coil 1 constant N1^2 A mu0 (shorted turns) v1, v2, v4, v5, v8 together
``Ls1``           coil 1 leakage inductance                  v4, v5, v8 by one factor
``kw1``           amplifier 1 gain                           v8
``m``             rotor mass                                 v1, v2, v3 by one factor
``x0``, ``i0``    operating point (air gap, bias current)    all force and coupling terms
``gx``            displacement-sensor gain                   v2, v3 up / v4, v6 down
``gi1``           current-sensor gain, coil 1                v2 down / v4, v8 up
================  =========================================  ===========================

(and the same for coil/amplifier/sensor 2). A sensor gain ``g`` on a measured
state rescales that state in the identified model (``x_meas = g x``), i.e. a
diagonal similarity of the physical realization, which is how it enters ``v``.

The test: with the identified ``v_hat`` and its covariance ``S`` (plus the
baseline's covariance when the baseline is itself an estimate), each hypothesis
``H_k`` "only parameter k changed" is fitted by weighted least squares over one
factor ``c_k`` and judged by its chi-square statistic

    chi2_k = min_c (v_hat - v(theta_b; k -> c theta_b,k))^T W (...),  W = (S + S_b)^-1

with 8 degrees of freedom (9 elements, 1 fitted factor); "no change" has 9.
"No change" is rejected when either its own chi-square (9 dof) or the likelihood
ratio against the best single cause (``chi2_none - chi2_k``, 1 dof, Bonferroni over
the causes) is significant at ``alpha / 2`` (two tests, Bonferroni: the false-alarm
rate stays <= alpha); the ratio test sees a change that one physical cause spreads
over several v_i, which the 9-dof test dilutes.

**The operating point.** A real controller applies the *nominal* bias voltages
and its integral action holds the rotor at ``x = 0``; a fault therefore moves the
coil currents the bearing settles at (a coil-2 K -8 % needs more current in coil
2 and, by force balance ``K1 I1^2 = K2 I2^2``, changes coil 1's too; a higher
resistance with the nominal bias voltage carries less current). The identified
``v`` is the linearisation at *that* point, so each hypothesis predicts ``v``
there (:class:`MeasuredOperatingPoint`, :func:`maglevid.physics.amb.linearized_v`):
the measured displacement and coil-current levels of the recording, the
currents taken relative to the hypothesis's own bias ``i0`` (so "only i0
changed" stays a hypothesis). Without an operating point the design point
``x = 0, I1 = I2 = i0`` is used (the linearised plant of the paper).

**Model error.** ``S`` alone is the noise's covariance; a noise-free record
of the nonlinear magnet has ``S`` ~ 0 but ``v`` still departs from the
linearisation by a fraction of the excursion. Every test therefore uses
``S + S_b + diag((epsilon v_b)^2)`` with the relative model error
``epsilon`` (estimated by the caller from the recording, see
:func:`maglevid.diagnose.pipeline.diagnose`: :func:`model_error_term` of the
loop's relative excursion, the measured ``2 e^2`` floored at 0.1 %).
Pairs of simultaneous faults (7 dof) are tried when no single hypothesis fits.
A hypothesis is accepted when its p-value exceeds ``alpha``; among accepted
ones the smallest chi-square wins, and hypotheses within a chi-square
difference of 1 of the winner are reported as indistinguishable.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from scipy import optimize, special

from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters, linearized_v, v_from_parameters

__all__ = [
    "HYPOTHESES",
    "MODEL_ERROR_FLOOR",
    "FaultHypothesis",
    "IsolationResult",
    "MeasuredOperatingPoint",
    "isolate_fault",
    "model_error_term",
    "relative_excursion",
    "v_with_sensor_gains",
]

#: Sensor-gain pseudo-parameters (1 = healthy).
SENSOR_GAINS = ("gx", "gi1", "gi2")

#: Hypotheses tried, with the plain-language explanation of an increase / decrease.
HYPOTHESES: dict[str, tuple[str, str, str]] = {
    # name: (what, meaning if up, meaning if down)
    "R1": (
        "coil 1 resistance R1",
        "heating or a bad connection in coil 1",
        "check coil 1 (lower resistance than designed)",
    ),
    "R2": (
        "coil 2 resistance R2",
        "heating or a bad connection in coil 2",
        "check coil 2 (lower resistance than designed)",
    ),
    "K1": (
        "coil 1 constant K1 = N1^2 A mu0",
        "more effective turns in coil 1 than designed",
        "shorted turns in coil 1 (force/current factor and inductance down together)",
    ),
    "K2": (
        "coil 2 constant K2 = N2^2 A mu0",
        "more effective turns in coil 2 than designed",
        "shorted turns in coil 2 (force/current factor and inductance down together)",
    ),
    "Ls1": (
        "coil 1 leakage inductance Ls1",
        "coil 1 leakage inductance up",
        "coil 1 leakage inductance down",
    ),
    "Ls2": (
        "coil 2 leakage inductance Ls2",
        "coil 2 leakage inductance up",
        "coil 2 leakage inductance down",
    ),
    "kw1": (
        "amplifier 1 gain kw1",
        "amplifier 1 gain up",
        "amplifier 1 gain down (amplifier 1 or its supply)",
    ),
    "kw2": (
        "amplifier 2 gain kw2",
        "amplifier 2 gain up",
        "amplifier 2 gain down (amplifier 2 or its supply)",
    ),
    "m": (
        "rotor mass m",
        "rotor mass up (added mass, deposits)",
        "rotor mass down (lost part, erosion)",
    ),
    "x0": (
        "air gap x0",
        "air gap wider than designed (operating point)",
        "air gap narrower than designed (operating point)",
    ),
    "i0": (
        "bias current i0",
        "bias current above design (operating point)",
        "bias current below design (operating point)",
    ),
    "gx": (
        "displacement-sensor gain",
        "displacement sensor reads high",
        "displacement sensor reads low",
    ),
    "gi1": (
        "coil 1 current-sensor gain",
        "coil 1 current sensor reads high",
        "coil 1 current sensor reads low",
    ),
    "gi2": (
        "coil 2 current-sensor gain",
        "coil 2 current sensor reads high",
        "coil 2 current sensor reads low",
    ),
}


#: Smallest relative model error of each v_i: the conversions (ZOH logarithm,
#: eq. (4) read off a realisation) and a real bearing's unmodelled dynamics are
#: not trusted below 0.1 %, far below any engineering tolerance.
MODEL_ERROR_FLOOR = 1e-3


def relative_excursion(y: Any, x0: float, i0: float) -> float:
    """The loop's largest relative excursion ``max(std x / x0, std i1 / i0, std i2 / i0)``.

    ``y`` is the recording's (x, i1, i2), time first. What the linearisation's
    model error grows with (:func:`model_error_term`).
    """
    y = np.asarray(y, dtype=float)
    if y.ndim != 2 or y.shape[1] != 3:
        raise DataError(f"`y` must be (n_samples, 3) for x, i1, i2; got shape {y.shape}")
    return float(np.max(np.std(y, axis=0) / np.array([x0, i0, i0])))


def model_error_term(excursion: float) -> float:
    """The relative model error of each v_i the isolation counts: ``max(0.1 %, 2 e^2)``.

    ``e`` is the loop's largest relative excursion (:func:`relative_excursion`);
    ``2 e^2`` is the measured bias of the linear model on the nonlinear bearing
    (:func:`maglevid.identify.planning.model_error_of_excursion`, the planner's
    law, not a second copy), floored at :data:`MODEL_ERROR_FLOOR`. One function
    for the verdict (the isolation's covariance, through
    :func:`maglevid.plants.amb.estimate_model_error`) and for the inconclusive
    verdict's advice (:mod:`maglevid.diagnose.resolve`, at the excursion a
    planned record would have), so that the advice promises the interval the
    diagnosis of the advised record states.

    Until issue 13 (h13diag) the term was ``max(0.1 %, e)``, first order in
    ``e`` and ~100x the measured bias at 1 V. Measured on the nonlinear bearing
    at the CLI defaults (benchmarks/measure_verdict_model_error.py,
    docs/diagnosis.md "Model error"): at 1 V (147 records) the same verdicts
    but one (a fault planted on its tolerance: inconclusive -> within
    tolerance), the planted cause's rms z 0.52 -> 0.70; at 4 V, the
    amplifiers' limit the advice may propose (26 records), every healthy
    record "inconclusive" before and "no significant change" now, the faults
    alike, rms z 0.06 -> 0.49. The fit's record-to-record part (~a/sqrt(N),
    which the stated standard errors leave out) is covered at both levels:
    |z| > 1.96 on 3 of 137 faulty records.

    Examples
    --------
    >>> model_error_term(0.004)  # 1 V on the default bearing: the floor
    0.001
    >>> round(model_error_term(0.03), 6)  # 3 % excursion: 2 x 0.03^2
    0.0018
    """
    from maglevid.identify.planning import model_error_of_excursion

    if not (np.isfinite(excursion) and excursion >= 0):
        raise DataError(f"`excursion` must be finite and >= 0; got {excursion!r}")
    return max(MODEL_ERROR_FLOOR, model_error_of_excursion(float(excursion)))


@dataclass(frozen=True)
class MeasuredOperatingPoint:
    """Where the bearing sat during a recording, relative to the design point.

    ``x`` [m] the settled displacement, ``dI1``, ``dI2`` [A] the settled coil
    currents minus the design bias ``i0`` (what a log of deviations carries as
    its mean), ``source`` how they were found.
    """

    x: float = 0.0
    dI1: float = 0.0
    dI2: float = 0.0
    source: str = "design point"

    def v(self, p: AMBParameters) -> np.ndarray:
        """v1..v9 of the bearing ``p`` linearised here (its own bias ``p.i0``)."""
        return linearized_v(p, x=self.x, I1=p.i0 + self.dI1, I2=p.i0 + self.dI2)

    def to_dict(self) -> dict[str, Any]:
        return {"x": self.x, "dI1": self.dI1, "dI2": self.dI2, "source": self.source}


def v_with_sensor_gains(
    p: AMBParameters,
    gx: float = 1.0,
    gi1: float = 1.0,
    gi2: float = 1.0,
    *,
    operating_point: MeasuredOperatingPoint | None = None,
) -> np.ndarray:
    """v1..v9 as identified through sensors with gains ``gx``, ``gi1``, ``gi2``.

    Measured states ``z = T x`` with ``T = diag(gx, gx, gi1, gi2)``; the identified
    ``A_z = T A T^-1``, ``B_z = T B`` keep the structure of eq. (4) with
    ``v2 -> v2 gx/gi1``, ``v3 -> v3 gx/gi2``, ``v4 -> v4 gi1/gx``, ``v6 -> v6 gi2/gx``,
    ``v8 -> v8 gi1``, ``v9 -> v9 gi2`` (v1, v5, v7 unchanged).
    """
    v = v_from_parameters(p) if operating_point is None else operating_point.v(p)
    return v * np.array([1.0, gx / gi1, gx / gi2, gi1 / gx, 1.0, gi2 / gx, 1.0, gi1, gi2])


def _v_of(
    theta: Mapping[str, float], base: AMBParameters, op: MeasuredOperatingPoint | None
) -> np.ndarray:
    phys = {k: v for k, v in theta.items() if k not in SENSOR_GAINS}
    gains = {k: v for k, v in theta.items() if k in SENSOR_GAINS}
    p = replace(base, **phys) if phys else base
    return v_with_sensor_gains(p, **gains, operating_point=op)


@dataclass(frozen=True)
class FaultHypothesis:
    """One fitted hypothesis: which parameters changed, by which factors, how well it fits."""

    parameters: tuple[str, ...]
    factors: tuple[float, ...]
    factor_std_errors: tuple[float, ...]
    chi2: float
    dof: int
    p_value: float
    #: Standard errors of the factors from the noise alone and from the model
    #: error alone (what more data can and cannot shrink); empty when not computed.
    noise_std_errors: tuple[float, ...] = ()
    floor_std_errors: tuple[float, ...] = ()
    #: ``dv / dlog c`` of a single-cause fit at its estimate (for experiment
    #: planning, :mod:`maglevid.diagnose.resolve`); empty otherwise.
    sensitivity: tuple[float, ...] = ()

    @property
    def changes_percent(self) -> dict[str, float]:
        return {k: 100.0 * (f - 1.0) for k, f in zip(self.parameters, self.factors)}

    def describe(self) -> str:
        """Plain words, e.g. 'coil 1 resistance R1 +19.8 % ± 0.4 % s.e. (heating or a bad
        connection ...)': one standard error, labelled (the report's intervals and the
        advice's half-widths are 95 %; an unlabelled "±" read as either)."""
        if not self.parameters:
            return "no significant change"
        parts = []
        for k, f, se in zip(self.parameters, self.factors, self.factor_std_errors):
            what, up, down = HYPOTHESES[k]
            parts.append(
                f"{what} {100 * (f - 1):+.1f} % ± {100 * se:.2g} % s.e. ({up if f > 1 else down})"
            )
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        return {
            "parameters": list(self.parameters),
            "factors": list(self.factors),
            "factor_std_errors": list(self.factor_std_errors),
            "changes_percent": self.changes_percent,
            "chi2": self.chi2,
            "dof": self.dof,
            "p_value": self.p_value,
            "noise_std_errors": list(self.noise_std_errors),
            "floor_std_errors": list(self.floor_std_errors),
            "description": self.describe(),
        }


@dataclass(frozen=True)
class IsolationResult:
    """Outcome of :func:`isolate_fault`."""

    best: FaultHypothesis
    candidates: tuple[FaultHypothesis, ...]
    no_change: FaultHypothesis
    alpha: float
    explained: bool
    indistinguishable: tuple[FaultHypothesis, ...] = field(default=())
    model_error: float = 0.0
    operating_point: MeasuredOperatingPoint | None = None
    single_cause_p_value: float = 1.0

    @property
    def singles(self) -> tuple[FaultHypothesis, ...]:
        """The single-cause fits ("only k changed"), best first."""
        return tuple(h for h in self.candidates if len(h.parameters) == 1)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model_error": self.model_error,
            "single_cause_p_value": self.single_cause_p_value,
            "operating_point": (
                None if self.operating_point is None else self.operating_point.to_dict()
            ),
            "best": self.best.to_dict(),
            "no_change": self.no_change.to_dict(),
            "explained": self.explained,
            "alpha": self.alpha,
            "indistinguishable": [h.to_dict() for h in self.indistinguishable],
            "candidates": [h.to_dict() for h in self.candidates[:8]],
        }


@dataclass(frozen=True)
class _Weights:
    """The covariances a fit is judged against: total = noise + model error."""

    L: np.ndarray  # L L^T = (S_noise + S_floor)^-1
    S_noise: np.ndarray
    S_floor: np.ndarray


def _std_error(g: np.ndarray, S: np.ndarray) -> float:
    """Standard error of one log-factor with sensitivity ``g = dv/dlog c`` under ``S``."""
    info = float(g @ np.linalg.lstsq(S, g, rcond=None)[0]) if np.any(S) else np.inf
    return 1.0 / math.sqrt(info) if info > 0 else math.inf


def _fit(
    names: Sequence[str],
    base: AMBParameters,
    v_hat: np.ndarray,
    w: _Weights,
    op: MeasuredOperatingPoint | None,
) -> FaultHypothesis:
    # Whitened residual: L^T (v_hat - v(theta)), with W = L L^T.
    b0 = {k: (1.0 if k in SENSOR_GAINS else getattr(base, k)) for k in names}

    def v_at(logc: np.ndarray) -> np.ndarray:
        return _v_of({k: b0[k] * math.exp(c) for k, c in zip(names, logc)}, base, op)

    def resid(logc: np.ndarray) -> np.ndarray:
        return w.L.T @ (v_hat - v_at(logc))

    noise_se: tuple[float, ...] = ()
    floor_se: tuple[float, ...] = ()
    g = np.zeros(0)
    if names:
        sol = optimize.least_squares(
            resid, np.zeros(len(names)), method="lm", xtol=1e-14, ftol=1e-14
        )
        logc, r = sol.x, sol.fun
        # Covariance of log-factors from the whitened Jacobian (Gauss-Newton).
        J = sol.jac
        try:
            cov = np.linalg.pinv(J.T @ J)
            se_log = np.sqrt(np.clip(np.diag(cov), 0, None))
        except np.linalg.LinAlgError:  # pragma: no cover - pinv rarely fails
            se_log = np.full(len(names), np.nan)
        if len(names) == 1:
            # The two parts of the uncertainty: noise (shrinks as 1/N and 1/amplitude^2)
            # and model error (does not shrink with more of the same data).
            h = 1e-6
            g = (v_at(logc + h) - v_at(logc - h)) / (2 * h)
            f = math.exp(logc[0])
            noise_se = (f * _std_error(g, w.S_noise),)
            floor_se = (f * _std_error(g, w.S_floor),)
    else:
        logc, r, se_log = np.zeros(0), resid(np.zeros(0)), np.zeros(0)
    chi2 = float(r @ r)
    dof = v_hat.size - len(names)
    factors = np.exp(logc)
    return FaultHypothesis(
        parameters=tuple(names),
        factors=tuple(float(f) for f in factors),
        factor_std_errors=tuple(float(f * s) for f, s in zip(factors, se_log)),
        chi2=chi2,
        dof=dof,
        p_value=float(special.chdtrc(dof, chi2)),
        noise_std_errors=noise_se,
        floor_std_errors=floor_se,
        sensitivity=tuple(float(x) for x in g),
    )


def _single_cause_p_value(none: FaultHypothesis, singles: Sequence[FaultHypothesis]) -> float:
    """p-value of "nothing changed" against the best single cause (Bonferroni over causes).

    Likelihood ratio ``chi2_none - chi2_k`` ~ chi2(1) under "nothing changed" for each
    single cause ``k``; the best of ``n`` is judged at ``n`` times its p-value. More
    powerful than the 9-dof test when one physical cause moved several v_i together.
    """
    if not singles:
        return 1.0
    lr = max(none.chi2 - singles[0].chi2, 0.0)
    return float(min(1.0, len(singles) * special.chdtrc(1, lr)))


def isolate_fault(
    v_hat: Any,
    covariance: Any,
    baseline: AMBParameters,
    *,
    baseline_covariance: Any = None,
    hypotheses: Sequence[str] | None = None,
    alpha: float = 0.01,
    try_pairs: bool = True,
    operating_point: MeasuredOperatingPoint | None = None,
    model_error: float = 0.0,
) -> IsolationResult:
    """Find the physical change that explains an identified ``v`` (see module docs).

    Parameters
    ----------
    v_hat : array_like, shape (9,)
        Identified v1..v9.
    covariance : array_like, shape (9, 9)
        Their covariance (from the identification).
    baseline : AMBParameters
        The bearing as designed, or as identified earlier.
    baseline_covariance : array_like, shape (9, 9), optional
        Covariance of the baseline's ``v`` when it is itself an estimate.
    hypotheses : sequence of str, optional
        Names from :data:`HYPOTHESES` (default: all).
    alpha : float
        Significance level of the chi-square tests.
    try_pairs : bool
        Also fit pairs of simultaneous changes when no single one fits.
    operating_point : MeasuredOperatingPoint, optional
        Where the bearing settled in the recording; each hypothesis predicts
        ``v`` there (default: the design point).
    model_error : float
        Relative model error ``epsilon`` of each ``v_i`` (adds
        ``diag((epsilon v_b)^2)`` to the covariance; 0 = none).

    Returns
    -------
    IsolationResult

    Examples
    --------
    >>> import numpy as np
    >>> p = AMBParameters.nominal()
    >>> v = p.with_fault(R1=1.2).v()
    >>> res = isolate_fault(v, np.diag((1e-4 * v) ** 2), p)
    >>> res.best.parameters, round(res.best.factors[0], 6)
    (('R1',), 1.2)
    """
    v_hat = np.asarray(v_hat, dtype=float).reshape(-1)
    if v_hat.size != 9:
        raise DataError(f"`v_hat` must hold v1..v9; got {v_hat.size} values")
    S = np.asarray(covariance, dtype=float)
    if S.shape != (9, 9):
        raise DataError(f"`covariance` must be 9x9; got {S.shape}")
    if baseline_covariance is not None:
        S = S + np.asarray(baseline_covariance, dtype=float)
    if not (np.isfinite(model_error) and model_error >= 0):
        raise DataError(f"`model_error` must be >= 0; got {model_error}")
    v_b = _v_of({}, baseline, operating_point)
    S_floor = np.diag((model_error * v_b) ** 2)
    # W = S^-1 = L L^T via the Cholesky factor of S (no explicit inverse).
    try:
        Ls = np.linalg.cholesky(S + S_floor)
    except np.linalg.LinAlgError:
        raise DataError(
            "`covariance` is not positive definite; cannot weigh the evidence"
        ) from None
    w = _Weights(np.linalg.solve(Ls, np.eye(9)).T, S, S_floor)  # L L^T = (S + S_floor)^-1
    names = list(hypotheses) if hypotheses is not None else list(HYPOTHESES)
    unknown = [n for n in names if n not in HYPOTHESES]
    if unknown:
        raise DataError(f"unknown hypotheses {unknown}; expected names from {list(HYPOTHESES)}")
    valid = {f.name for f in fields(AMBParameters)} | set(SENSOR_GAINS)
    names = [n for n in names if n in valid]

    op = operating_point

    def fit(names: Sequence[str]) -> FaultHypothesis:
        return _fit(names, baseline, v_hat, w, op)

    none = fit(())
    singles = sorted((fit((n,)) for n in names), key=lambda h: h.chi2)
    cands = list(singles)
    p_lr = _single_cause_p_value(none, singles)
    changed = min(none.p_value, p_lr) < alpha / 2  # two tests, Bonferroni
    if try_pairs and changed and singles[0].p_value < alpha:
        pairs = [fit(pair) for pair in itertools.combinations(names, 2)]
        cands = sorted(
            cands + pairs, key=lambda h: (h.p_value < alpha, h.chi2 + 4 * len(h.parameters))
        )
    extra = {
        "model_error": float(model_error),
        "operating_point": op,
        "single_cause_p_value": p_lr,
    }
    if not changed:
        return IsolationResult(none, tuple(cands), none, alpha, True, (), **extra)
    accepted = [h for h in cands if h.p_value >= alpha]
    if not accepted:
        return IsolationResult(cands[0], tuple(cands), none, alpha, False, (), **extra)
    k = min(len(h.parameters) for h in accepted)
    same_size = sorted((h for h in accepted if len(h.parameters) == k), key=lambda h: h.chi2)
    best = same_size[0]
    tie = tuple(h for h in same_size[1:] if h.chi2 - best.chi2 < 1.0)
    return IsolationResult(best, tuple(cands), none, alpha, True, tie, **extra)
