"""Compare identified parameters with a baseline: significant twice over.

A change is reported only when it is significant twice over (issue 5):

1. *statistically*: the difference lies outside the combined confidence interval,
   ``|theta - theta_b| > z_{1-(1-level)/2} sqrt(se^2 + se_b^2)`` (the baseline's
   standard error is 0 for design values);
2. *in engineering terms*: the relative change exceeds the user's tolerance for
   that parameter, ``|theta - theta_b| > tol |theta_b|``.

A change that passes only the first test is "detectable but within tolerance",
one that passes only the second is "not resolved by the data" (the record is
too short or too noisy to tell); so is one whose interval reaches beyond the
tolerance, whatever its point says.

**Many parameters at once** (``joint=True``). Thirteen free estimates, each at its
own 95 % level, show some "changed" on a healthy record by chance: a nonlinear
bearing under a 1 N force disturbance had ``Ls1`` +6.1 % (95 % interval +0.8 …
+11.5 %) "changed" while all nine v_i agreed with the baseline (chi2 = 8.96 with 9
dof, p = 0.44; found from outside, issue 16, fourteenth and fifteenth sessions). With
``joint`` the intervals hold for all compared parameters together (Bonferroni: each
at ``1 - (1 - level)/m``), so the chance that any of them reads "changed" on an
unchanged machine stays below ``1 - level``.

**Model error.** The standard error of an estimate covers the noise only; a
noise-free record of the nonlinear magnet has standard errors of ~1e-13 and
still departs from the linearisation by a fraction of its excursion.
``model_errors`` (absolute standard deviations per parameter, estimated by the
caller) enter the combined interval in quadrature:
``sqrt(se^2 + se_b^2 + me^2)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from scipy import special  # not scipy.stats: 0.6 s to import for one quantile

from maglevid.exceptions import DataError

__all__ = ["DEFAULT_TOLERANCE", "ParameterChange", "compare_parameters"]

#: Default engineering tolerance: 5 % relative change.
DEFAULT_TOLERANCE = 0.05


@dataclass(frozen=True)
class ParameterChange:
    """One parameter's comparison with its baseline."""

    name: str
    estimate: float
    std_error: float
    baseline: float
    baseline_std_error: float
    change: float
    change_percent: float
    change_ci: tuple[float, float]
    tolerance: float
    statistically_significant: bool
    exceeds_tolerance: bool
    model_error: float = 0.0
    #: the number of parameters the interval's level holds for jointly (1: its own)
    joint_over: int = 1

    @property
    def significant(self) -> bool:
        """Both tests pass: a change worth reporting."""
        return self.statistically_significant and self.exceeds_tolerance

    def on_its_own(self, level: float = 0.95) -> ParameterChange:
        """This comparison with the interval at ``level`` for this parameter alone (a
        joint interval narrowed back): for a cause a separate test has already singled
        out (the verdict's), where the family is no longer all the parameters."""
        if self.joint_over <= 1:
            return self
        zj = float(special.ndtri(1.0 - (1.0 - level) / (2 * self.joint_over)))
        se_c = (self.change_ci[1] - self.change_ci[0]) / (2 * zj)
        z = float(special.ndtri(0.5 + level / 2))
        d = self.change
        return replace(
            self,
            change_ci=(d - z * se_c, d + z * se_c),
            statistically_significant=bool(np.isfinite(se_c) and abs(d) > z * se_c),
            joint_over=1,
        )

    @property
    def interval_label(self) -> str:
        """``"CI"``, or ``"joint CI (all 13)"`` when the level holds for several at once."""
        return "CI" if self.joint_over <= 1 else f"joint CI (all {self.joint_over})"

    @property
    def interval_within_tolerance(self) -> bool:
        """The whole interval of the change lies inside ``±tolerance``."""
        band = self.tolerance * abs(self.baseline)
        return bool(max(abs(self.change_ci[0]), abs(self.change_ci[1])) <= band)

    @property
    def status(self) -> str:
        """``changed`` (both tests), ``within tolerance`` (detectable, and the whole
        interval inside the tolerance), ``unchanged`` (not detectable, the whole interval
        inside the tolerance) or ``not resolved`` (the interval reaches beyond the
        tolerance without both tests passing: the data cannot tell). Before the
        seventeenth session an interval of -12 ... +9 % read "unchanged" against a ±5 %
        tolerance and +1.7 ... +5.2 % "within tolerance" (found from outside)."""
        if self.significant:
            return "changed"
        if not self.interval_within_tolerance:
            return "not resolved"
        return "within tolerance" if self.statistically_significant else "unchanged"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["change_ci"] = list(self.change_ci)
        d["significant"] = self.significant
        d["status"] = self.status
        return d


def _pair(v: Any) -> tuple[float, float]:
    if isinstance(v, (tuple, list)):
        return float(v[0]), float(v[1]) if len(v) > 1 and v[1] is not None else 0.0
    return float(v), 0.0


def compare_parameters(
    estimates: Mapping[str, Any],
    baseline: Mapping[str, Any],
    *,
    tolerances: Mapping[str, float] | float = DEFAULT_TOLERANCE,
    level: float = 0.95,
    model_errors: Mapping[str, float] | None = None,
    joint: bool = False,
) -> list[ParameterChange]:
    """Compare each parameter present in both mappings.

    Parameters
    ----------
    estimates, baseline : mapping of name -> value or (value, std_error)
        A bare value has standard error 0 (a design value).
    tolerances : float or mapping of name -> float
        Relative engineering tolerance per parameter (default 5 %); names not in
        the mapping get :data:`DEFAULT_TOLERANCE`.
    level : float
        Confidence level of the combined interval.
    model_errors : mapping of name -> float, optional
        Model-error standard deviation per parameter (absolute units; default 0).
    joint : bool
        The intervals hold at ``level`` for all compared parameters together
        (Bonferroni over their number ``m``; ``joint_over = m``), not each on its own.

    Returns
    -------
    list of ParameterChange, in the order of ``estimates``.
    """
    if not 0 < level < 1:
        raise DataError(f"`level` must be in (0, 1); got {level}")
    names = [k for k in estimates if k in baseline]
    family = len(names) if joint and names else 1
    z = float(special.ndtri(1.0 - (1.0 - level) / (2 * family)))
    out = []
    for name in names:
        est = estimates[name]
        v, se = _pair(est)
        b, se_b = _pair(baseline[name])
        tol = (
            float(tolerances)
            if not isinstance(tolerances, Mapping)
            else float(tolerances.get(name, DEFAULT_TOLERANCE))
        )
        if tol < 0:
            raise DataError(f"tolerance for {name!r} must be >= 0; got {tol}")
        me = float((model_errors or {}).get(name, 0.0))
        se_c = float(np.hypot(np.hypot(se if np.isfinite(se) else np.inf, se_b), me))
        d = v - b
        stat = bool(np.isfinite(se_c) and abs(d) > z * se_c)
        exceeds = bool(abs(d) > tol * abs(b))
        out.append(
            ParameterChange(
                name=name,
                estimate=v,
                std_error=se,
                baseline=b,
                baseline_std_error=se_b,
                change=d,
                change_percent=100.0 * d / b if b != 0 else float("nan"),
                change_ci=(d - z * se_c, d + z * se_c),
                tolerance=tol,
                statistically_significant=stat,
                exceeds_tolerance=exceeds,
                model_error=me,
                joint_over=family,
            )
        )
    return out
