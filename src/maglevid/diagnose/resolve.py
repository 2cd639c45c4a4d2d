"""Can the data resolve the tolerance? And if not, what record would?

A verdict of "no change" or "fault" promises that each parameter was measured
to better than its engineering tolerance. :func:`unresolved_parameters` checks
that promise on the single-cause fits of the isolation ("only k changed"): the
interval ``± z se_k`` of hypothesis ``k``'s factor must be no wider than its
tolerance ``tol_k``. Where it is wider, the verdict is *inconclusive* and this
module says what would resolve it, from the scaling of the covariance:

* the noise part of the variance falls as ``1/N`` (record length) and as
  ``1/a^2`` (excitation amplitude ``a``) -- the information matrix of a
  least-squares/IV fit grows with the number of samples and with the square
  of the excitation's power;
* the model-error part does not fall with more of the same data.

With ``se^2 ~ se_n^2 / k + se_f^2`` the data resolve ``tol`` when
``z^2 (se_n^2 / k + se_f^2) <= tol^2``, i.e. ``k >= se_n^2 / ((tol/z)^2 - se_f^2)``:
``k`` times the record length (``(k - 1) N dt`` seconds more of the same
excitation) or ``sqrt(k)`` times the excitation amplitude (which also moves the
magnet further from its linearisation, so the length is the safer lever).
When ``se_f >= tol/z`` no record resolves it: the model error alone exceeds
the tolerance.

This is a small, swappable rule: an experiment planner based on the
Cramer-Rao bound can replace :func:`unresolved_parameters` with the same
return type.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from scipy import special

from maglevid.diagnose.compare import DEFAULT_TOLERANCE
from maglevid.diagnose.isolate import FaultHypothesis, IsolationResult

__all__ = ["Unresolved", "tolerance_of", "unresolved_parameters"]


@dataclass(frozen=True)
class Unresolved:
    """One hypothesis whose interval is wider than its tolerance, and what would resolve it."""

    parameter: str
    tolerance_percent: float
    half_width_percent: float
    length_factor: float  # inf when no record length resolves it
    more_seconds: float  # inf likewise
    excitation_factor: float
    excitation_rms: float | None  # [V] the suggested excitation level, when known

    @property
    def resolvable(self) -> bool:
        return math.isfinite(self.length_factor)

    def advice(self) -> str:
        """One sentence: what this parameter needs."""
        head = (
            f"{self.parameter} ±{self.half_width_percent:.2g} % "
            f"(tolerance ±{self.tolerance_percent:.3g} %)"
        )
        if not self.resolvable:
            return (
                f"{head}: the model error alone exceeds the tolerance; no longer record of this "
                "kind resolves it (use a wider tolerance or a smaller excitation)"
            )
        level = (
            f" (about {self.excitation_rms:.3g} V rms)" if self.excitation_rms is not None else ""
        )
        return (
            f"{head}: record about {self.more_seconds:.3g} s more of the same excitation, "
            f"or raise the excitation about {self.excitation_factor:.2g}x{level}"
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("length_factor", "more_seconds"):
            if not math.isfinite(d[k]):
                d[k] = None
        d["advice"] = self.advice()
        return d


def tolerance_of(name: str, tolerances: Mapping[str, float] | float) -> float:
    """The relative tolerance of one parameter (a mapping falls back to the default)."""
    if isinstance(tolerances, Mapping):
        return float(tolerances.get(name, DEFAULT_TOLERANCE))
    return float(tolerances)


def _length_factor(h: FaultHypothesis, target: float) -> float:
    """``k`` with ``se_n^2 / k + se_f^2 = target^2`` (see module docs)."""
    se = h.factor_std_errors[0]
    if not h.noise_std_errors:  # no decomposition: all of it is noise
        return (se / target) ** 2
    se_n, se_f = h.noise_std_errors[0], h.floor_std_errors[0]
    if not math.isfinite(se) or se_f >= target:
        return math.inf
    return max(se_n**2 / (target**2 - se_f**2), (se / target) ** 2, 1.0)


def unresolved_parameters(
    iso: IsolationResult,
    tolerances: Mapping[str, float] | float,
    *,
    level: float = 0.95,
    duration_s: float | None = None,
    excitation_rms: float | None = None,
) -> list[Unresolved]:
    """Single-cause hypotheses whose interval at ``level`` is wider than their tolerance.

    Parameters
    ----------
    iso : IsolationResult
    tolerances : float or mapping
        Relative tolerance per parameter.
    level : float
        Confidence level of the interval.
    duration_s : float, optional
        The record's length [s] (for "seconds more").
    excitation_rms : float, optional
        The record's excitation level [V rms] (for the suggested level).

    Returns
    -------
    list of Unresolved, widest interval (relative to its tolerance) first.
    """
    z = float(special.ndtri(0.5 + level / 2))
    out = []
    for h in iso.singles:
        (name,) = h.parameters
        tol = tolerance_of(name, tolerances)
        se = h.factor_std_errors[0]
        if tol <= 0 or (math.isfinite(se) and z * se <= tol):
            continue
        k = _length_factor(h, tol / z)
        out.append(
            Unresolved(
                parameter=name,
                tolerance_percent=100 * tol,
                half_width_percent=100 * z * se,
                length_factor=k,
                more_seconds=(k - 1) * duration_s if duration_s is not None else math.inf,
                excitation_factor=math.sqrt(k),
                excitation_rms=(
                    math.sqrt(k) * excitation_rms
                    if excitation_rms is not None and math.isfinite(k)
                    else None
                ),
            )
        )
    return sorted(out, key=lambda u: -u.half_width_percent / u.tolerance_percent)
