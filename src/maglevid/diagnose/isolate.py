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
from maglevid.physics.amb import AMBParameters, v_from_parameters

__all__ = [
    "HYPOTHESES",
    "FaultHypothesis",
    "IsolationResult",
    "isolate_fault",
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


def v_with_sensor_gains(
    p: AMBParameters, gx: float = 1.0, gi1: float = 1.0, gi2: float = 1.0
) -> np.ndarray:
    """v1..v9 as identified through sensors with gains ``gx``, ``gi1``, ``gi2``.

    Measured states ``z = T x`` with ``T = diag(gx, gx, gi1, gi2)``; the identified
    ``A_z = T A T^-1``, ``B_z = T B`` keep the structure of eq. (4) with
    ``v2 -> v2 gx/gi1``, ``v3 -> v3 gx/gi2``, ``v4 -> v4 gi1/gx``, ``v6 -> v6 gi2/gx``,
    ``v8 -> v8 gi1``, ``v9 -> v9 gi2`` (v1, v5, v7 unchanged).
    """
    v = v_from_parameters(p)
    return v * np.array([1.0, gx / gi1, gx / gi2, gi1 / gx, 1.0, gi2 / gx, 1.0, gi1, gi2])


def _v_of(theta: Mapping[str, float], base: AMBParameters) -> np.ndarray:
    phys = {k: v for k, v in theta.items() if k not in SENSOR_GAINS}
    gains = {k: v for k, v in theta.items() if k in SENSOR_GAINS}
    return v_with_sensor_gains(replace(base, **phys) if phys else base, **gains)


@dataclass(frozen=True)
class FaultHypothesis:
    """One fitted hypothesis: which parameters changed, by which factors, how well it fits."""

    parameters: tuple[str, ...]
    factors: tuple[float, ...]
    factor_std_errors: tuple[float, ...]
    chi2: float
    dof: int
    p_value: float

    @property
    def changes_percent(self) -> dict[str, float]:
        return {k: 100.0 * (f - 1.0) for k, f in zip(self.parameters, self.factors)}

    def describe(self) -> str:
        """Plain words, e.g. 'coil 1 resistance R1 +19.8 % (heating or a bad connection ...)'."""
        if not self.parameters:
            return "no significant change"
        parts = []
        for k, f, se in zip(self.parameters, self.factors, self.factor_std_errors):
            what, up, down = HYPOTHESES[k]
            parts.append(
                f"{what} {100 * (f - 1):+.1f} % ± {100 * se:.2g} % ({up if f > 1 else down})"
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

    def to_dict(self) -> dict[str, Any]:
        return {
            "best": self.best.to_dict(),
            "no_change": self.no_change.to_dict(),
            "explained": self.explained,
            "alpha": self.alpha,
            "indistinguishable": [h.to_dict() for h in self.indistinguishable],
            "candidates": [h.to_dict() for h in self.candidates[:8]],
        }


def _fit(
    names: Sequence[str],
    base: AMBParameters,
    v_hat: np.ndarray,
    L: np.ndarray,
) -> FaultHypothesis:
    # Whitened residual: L^T (v_hat - v(theta)), with W = L L^T.
    b0 = {k: (1.0 if k in SENSOR_GAINS else getattr(base, k)) for k in names}

    def resid(logc: np.ndarray) -> np.ndarray:
        theta = {k: b0[k] * math.exp(c) for k, c in zip(names, logc)}
        return L.T @ (v_hat - _v_of(theta, base))

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
    )


def isolate_fault(
    v_hat: Any,
    covariance: Any,
    baseline: AMBParameters,
    *,
    baseline_covariance: Any = None,
    hypotheses: Sequence[str] | None = None,
    alpha: float = 0.01,
    try_pairs: bool = True,
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
    # W = S^-1 = L L^T via the Cholesky factor of S (no explicit inverse).
    try:
        Ls = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise DataError(
            "`covariance` is not positive definite; cannot weigh the evidence"
        ) from None
    L = np.linalg.solve(Ls, np.eye(9)).T  # L L^T = S^-1
    names = list(hypotheses) if hypotheses is not None else list(HYPOTHESES)
    unknown = [n for n in names if n not in HYPOTHESES]
    if unknown:
        raise DataError(f"unknown hypotheses {unknown}; expected names from {list(HYPOTHESES)}")
    valid = {f.name for f in fields(AMBParameters)} | set(SENSOR_GAINS)
    names = [n for n in names if n in valid]

    none = _fit((), baseline, v_hat, L)
    singles = sorted((_fit((n,), baseline, v_hat, L) for n in names), key=lambda h: h.chi2)
    cands = list(singles)
    if try_pairs and none.p_value < alpha and singles[0].p_value < alpha:
        pairs = [_fit(pair, baseline, v_hat, L) for pair in itertools.combinations(names, 2)]
        cands = sorted(
            cands + pairs, key=lambda h: (h.p_value < alpha, h.chi2 + 4 * len(h.parameters))
        )
    if none.p_value >= alpha:
        return IsolationResult(none, tuple(cands), none, alpha, True, ())
    accepted = [h for h in cands if h.p_value >= alpha]
    if not accepted:
        return IsolationResult(cands[0], tuple(cands), none, alpha, False, ())
    k = min(len(h.parameters) for h in accepted)
    same_size = sorted((h for h in accepted if len(h.parameters) == k), key=lambda h: h.chi2)
    best = same_size[0]
    tie = tuple(h for h in same_size[1:] if h.chi2 - best.chi2 < 1.0)
    return IsolationResult(best, tuple(cands), none, alpha, True, tie)
