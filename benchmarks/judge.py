"""The verdicts of ``make bench``: a target is met only by a measurement of this run.

Every target of ``BENCHMARKS.md`` goes through one :class:`Judge`, which knows
three verdicts and nothing else:

``met``
    the figures the target names were measured in this run and pass its bar;
``not met``
    they were measured and fail it (a shortfall: its paragraph says why and
    what is planned);
``not measured``
    a figure is missing: the peer is not installed, failed, ran out of time or
    memory, the size was not run (``--quick``), or the result carries no
    number. It is counted in the headline, never turned into ``met``.

The helpers below are the only ways run_all makes a verdict:

* :func:`measured` says whether a result row holds a time (and no error);
* :meth:`Judge.faster` compares our time with a peer's (``ours <= factor x
  peer``) and is "not measured" when either is missing;
* :meth:`Judge.accurate` compares an error with a stated accuracy bar
  (:func:`accuracy_bar`): twice the Cramér-Rao bound where the estimation code
  provides one, else a stated relative bound; a missing or non-finite error is
  "not measured", a bar that is not met is "not met".
* the bar on physical parameters of one record (:func:`crb_sigmas_bar`,
  :func:`crb_normalised_error`): every ``|v_i error|`` within ``k`` Cramér-Rao
  standard deviations of *that* record's bound, ``sigma_CRB,i``; judged as
  ``max_i |e_i| / sigma_CRB,i <= k``. No bound (or no estimate) is "not
  measured", never a fallback to a looser bar.

The CRB bar, ``k = 4`` (:data:`CRB_SIGMAS`): an efficient, unbiased estimator
(errors Gaussian with the bound as standard deviation) fails it on one record
with probability at most ``9 x 2 Phi(-4) = 5.7e-4`` (union bound over v1..v9,
:func:`crb_false_alarm`); one at 1.3x the bound (issue 13's efficiency target)
at most ``9 x 2 Phi(-4/1.3) = 0.019``. IV at ~5x the bound fails it nearly
always -- the bar tells an efficient estimator from a consistent one.

Example
-------
>>> j = Judge()
>>> j.faster("no slower than SLICOT", ours={"time_s": 1.0}, peer=None, peer_name="SLICOT")
'not measured'
>>> j.accurate("v1..v9 within the bar", error=0.3, bar=accuracy_bar(stated=0.1))
'not met'
>>> j.headline()
'2 targets: 0 met, 1 not met, 1 not measured'
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = [
    "CRB_SIGMAS",
    "MET",
    "NOT_MEASURED",
    "NOT_MET",
    "AccuracyBar",
    "Judge",
    "Verdict",
    "accuracy_bar",
    "crb_false_alarm",
    "crb_normalised_error",
    "crb_sigmas_bar",
    "measured",
    "why_not_measured",
]

MET = "met"
NOT_MET = "not met"
NOT_MEASURED = "not measured"

#: How each verdict is printed in the target table.
_MARK = {MET: "met", NOT_MET: "**not met**", NOT_MEASURED: "*not measured*"}


@dataclass(frozen=True)
class Verdict:
    """One row of the target table."""

    target: str
    measured: str
    status: str
    plan: str = ""
    #: The mark of the run it was made from (``Judge.stamp`` when it was made).
    stamp: str = ""


@dataclass(frozen=True)
class AccuracyBar:
    """An error bound and where it comes from (printed beside the verdict)."""

    bound: float
    source: str


def accuracy_bar(*, stated: float, crb: float | None = None, factor: float = 2.0) -> AccuracyBar:
    """The bar of a target on physical parameters.

    ``factor`` times the Cramér-Rao bound ``crb`` (relative standard deviation
    of the parameter at this record length) where the estimation code provides
    one (``maglevid.identify.cramer_rao``, issue 13: the hook in
    ``run_all._crb_hook``); otherwise the ``stated`` relative bound.
    """
    if crb is not None and math.isfinite(crb) and crb > 0:
        return AccuracyBar(factor * crb, f"{factor:g} x the Cramér-Rao bound {crb:.1e}")
    return AccuracyBar(stated, f"stated bound {stated:.0%}")


#: The CRB bar's width in Cramér-Rao standard deviations (module notes).
CRB_SIGMAS = 4.0


def crb_false_alarm(k: float = CRB_SIGMAS, *, n: int = 9, inflation: float = 1.0) -> float:
    """Upper bound on the probability that a correct estimator fails the CRB bar.

    Union bound over ``n`` Gaussian errors with standard deviation ``inflation``
    times the bound: ``min(1, n 2 Phi(-k / inflation))`` (correlated errors
    fail it less often, never more)."""
    return min(1.0, n * math.erfc(k / inflation / math.sqrt(2.0)))


def crb_sigmas_bar(k: float = CRB_SIGMAS) -> AccuracyBar:
    """The bar ``max_i |e_i| / sigma_CRB,i <= k`` (pair with :func:`crb_normalised_error`)."""
    return AccuracyBar(
        k,
        f"every |v_i error| within {k:g} sigma_CRB,i of this record; a correct efficient "
        f"estimator fails it with p <= {crb_false_alarm(k):.1e}, one at 1.3x the bound "
        f"with p <= {crb_false_alarm(k, inflation=1.3):.2f}",
    )


def crb_normalised_error(errors: Any, sigma: Any) -> float | None:
    """``max_i |errors_i| / sigma_i``; None when either is missing, not finite or
    ``sigma`` is not positive (then the target is "not measured")."""
    if errors is None or sigma is None:
        return None
    e = [float(x) for x in errors]
    s = [float(x) for x in sigma]
    if len(e) != len(s) or not e:
        return None
    if not all(math.isfinite(x) for x in e) or not all(math.isfinite(x) and x > 0 for x in s):
        return None
    return max(abs(a) / b for a, b in zip(e, s))


def measured(row: Mapping[str, Any] | None, key: str = "time_s") -> bool:
    """True when ``row`` holds a finite ``key`` and no error or skip."""
    if row is None or "error" in row or "skipped" in row:
        return False
    v = row.get(key)
    return isinstance(v, (int, float)) and math.isfinite(v)


def why_not_measured(row: Mapping[str, Any] | None, name: str) -> str:
    """A short reason a row is not a measurement."""
    if row is None:
        return f"{name} not run"
    if "skipped" in row:
        return f"{name} skipped: {_short(row['skipped'])}"
    if "error" in row:
        return f"{name} failed: {_short(row['error'])}"
    return f"{name} gave no number"


def _short(text: Any, n: int = 90) -> str:
    s = " ".join(str(text).split())
    return s if len(s) <= n else s[: n - 3].rsplit(" ", 1)[0] + " ..."


class Judge:
    """Collects the verdicts of one run; the only place a verdict is made."""

    def __init__(self, stamp: str = "") -> None:
        self.verdicts: list[Verdict] = []
        #: The mark of every verdict made from now on (a modified tree, a section measured
        #: at another commit than the report's: ``benchmarks/store.py``).
        self.stamp = stamp

    # ---------------------------------------------------------------- verdicts
    def add(self, target: str, measured_text: str, met: bool | None, plan: str = "") -> str:
        """Record a verdict: ``met`` True/False from a measurement, None when not measured."""
        status = NOT_MEASURED if met is None else (MET if met else NOT_MET)
        self.verdicts.append(Verdict(target, measured_text, status, plan, self.stamp))
        return status

    def not_measured(self, target: str, why: str) -> str:
        """A target whose figures this run does not have (the reason is printed)."""
        return self.add(target, why, None)

    def faster(
        self,
        target: str,
        *,
        ours: Mapping[str, Any] | None,
        peer: Mapping[str, Any] | None,
        peer_name: str,
        ours_name: str = "maglevid",
        factor: float = 1.0,
        plan: str = "",
    ) -> str:
        """Met when ``ours.time_s <= factor * peer.time_s``, both measured in this run."""
        if not measured(ours):
            return self.not_measured(target, why_not_measured(ours, ours_name))
        if not measured(peer):
            return self.not_measured(target, why_not_measured(peer, peer_name))
        assert ours is not None and peer is not None
        t, tp = float(ours["time_s"]), float(peer["time_s"])
        text = f"{ours_name} {t:.3g} s; {peer_name} {tp:.3g} s (maglevid x{t / tp:.2g} its time)"
        return self.add(target, text, t <= factor * tp, plan)

    def accurate(
        self,
        target: str,
        *,
        error: float | None,
        bar: AccuracyBar,
        detail: str = "",
        plan: str = "",
    ) -> str:
        """Met when ``error <= bar.bound``; a missing or non-finite error is not measured."""
        if error is None or not math.isfinite(error):
            return self.not_measured(target, detail or "no error measured")
        text = f"{detail + '; ' if detail else ''}error {error:.1e} vs bar {bar.bound:.1e} "
        text += f"({bar.source})"
        return self.add(target, text, error <= bar.bound, plan)

    # ----------------------------------------------------------------- output
    def count(self, status: str) -> int:
        return sum(v.status == status for v in self.verdicts)

    def headline(self) -> str:
        n = len(self.verdicts)
        return (
            f"{n} targets: {self.count(MET)} met, {self.count(NOT_MET)} not met, "
            f"{self.count(NOT_MEASURED)} not measured"
        )

    def table(self) -> list[str]:
        """Markdown rows (with header) of every verdict, in the order made."""
        out = ["| target | measured | verdict |", "|---|---|---|"]
        for v in self.verdicts:
            out.append(f"| {v.target} | {v.measured} | {_MARK[v.status]}{v.stamp} |")
        return out

    def shortfalls(self) -> list[str]:
        """One paragraph per target not met that has a plan."""
        return [
            f"**{v.target}.** {v.plan}" for v in self.verdicts if v.status == NOT_MET and v.plan
        ]


def calibration_bands(records: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where a calibrated estimator's RMS z and 95 % coverage fall on ``records`` records,
    98 % of the time: ``sqrt(chi2_n / n)`` and the binomial's +-2.33 sd. A record counts
    once, whatever the parameters pooled from it (they move together: the suspension's
    alpha, eta, L and pole; the bearing's v1..v9), which widens the bands."""
    from scipy import stats

    n = max(int(records), 1)
    lo, hi = stats.chi2.ppf([0.01, 0.99], n)
    rms = (math.sqrt(lo / n), math.sqrt(hi / n))
    half = 2.33 * math.sqrt(0.95 * 0.05 / n)
    return rms, (max(0.0, 0.95 - half), 1.0)
