"""Does the interval decide the tolerance? And if not, what record would?

A verdict promises which side of its engineering tolerance each cause lies on:
"fault" that the change is beyond it, "within tolerance" and "no change" that
it is inside. :func:`unresolved_parameters` checks that promise on the
isolation's fits ("only k changed", and the best pair): the interval
``c_k ± z se_k`` of the change ``c_k = f_k - 1`` must lie wholly beyond
``± tol_k`` or wholly inside it (:func:`interval_side`). (A single-cause fit
wholly beyond its tolerance while the isolation keeps "nothing changed" is
flagged only when its interval is wider than the tolerance, with the tolerance
as the half-width to reach: the rule before the straddling one.) Where it straddles the
boundary the verdict is *inconclusive*, and the half-width that would clear the
boundary is the estimate's distance from it, ``d_k = | |c_k| - tol_k |`` (not
the tolerance: an estimate at 4.1 % against 5 % needs ±0.9 %). The factor's
standard error already holds the baseline's uncertainty (the isolation adds
its covariance), so the interval is that of the change, not only of the
estimate. This module says what would bring the half-width to ``d_k``, from
the scaling of the covariance (``target = d_k / z`` below; the estimate
itself moves with more data, so the advice holds "if it stays where it is"):

* the noise part of the variance falls as ``1/N`` (record length) and as
  ``1/a^2`` (excitation amplitude ``a``) -- the information matrix of a
  least-squares/IV fit grows with the number of samples and with the square
  of the excitation's power;
* the model-error part does not fall with more of the same data.

With ``se^2 ~ se_n^2 / k + se_f^2`` the data resolve ``tol`` when
``z^2 (se_n^2 / k + se_f^2) <= d^2``, i.e. ``k >= se_n^2 / ((d/z)^2 - se_f^2)``:
``k`` times the record length (``(k - 1) N dt`` seconds more of the same
excitation) or ``sqrt(k)`` times the excitation amplitude (which also moves the
magnet further from its linearisation, so the length is the safer lever).
When ``se_f >= d/z`` no record resolves it: the model error alone exceeds
the distance.

**The baseline's own uncertainty.** A diagnosis compares the estimate with a
baseline; when the baseline is itself an estimate (a stored history, an
earlier fit) its covariance ``S_b`` is part of the isolation's noise variance
(:func:`~maglevid.diagnose.isolate.isolate_fault`) but does not fall with a
longer record of the present state. With ``se_b`` the baseline's share
(``g`` the hypothesis's sensitivity, ``se_b^2 = 1 / (g^T S_b^-1 g)``) the rule
becomes ``k = (se_n^2 - se_b^2) / (d^2/z^2 - se_b^2 - se_f^2)``, and when
``se_b >= d/z`` the advice says that the baseline itself is too uncertain to
decide: re-record the baseline (or widen the tolerance).

**The Cramér-Rao plan** (:func:`with_cramer_rao_plan`). The rule above treats
all of the noise part as excitation-driven; in a closed loop part of the
information comes from the noise itself, and a different spectrum of the same
rms can carry much more. Where the recording allows it (a logged excitation,
the operating point, a noise model from the fit), the advice is recomputed
from the Fisher information of the loop around the estimated bearing
(:mod:`maglevid.identify.planning`): for the hypothesis "only k changed", with
``g = dv/dlog c_k``, the noise variance of its log-factor scales as
``1 / (g^T I_v(N, a, spectrum) g)``, so

    se_n'^2 = se_n^2 (g^T I_v(N, a_now, present) g) / (g^T I_v(N', a', s') g)

and the plan states the excitation at this length that resolves it (within
the amplifier and displacement limits), the length needed at the largest
allowed excitation, and the candidate spectrum *and split between the two
coils* (:data:`maglevid.identify.planning.DEFAULT_SPLITS`; the information of
independent excitations adds, ``I_v = a1^2 I_1 + a2^2 I_2 + I_e``) that needs the
shortest record. The baseline's covariance is added unscaled:
``var(n) = 1 / (g^T (kappa I_v(n)^-1 + S_b + diag((eps v)^2))^-1 g)``.

``eps`` at a planned level is the isolation's own term
(:func:`~maglevid.diagnose.isolate.model_error_term`) of the excursion that
record would have (the recording's, scaled by the design's prediction), so the
advice promises the interval the diagnosis of the advised record will state.
When no record within the limits resolves a cause, the advice says why: the
model error at its smallest over the levels (and the baseline) leaves a
half-width ``w`` wider than the one that decides it; it names the tolerances an
interval of half-width ``w`` about the estimate would decide
(``>= |c| + w`` or ``<= |c| - w``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from scipy import special

from maglevid.diagnose.compare import DEFAULT_TOLERANCE
from maglevid.diagnose.isolate import (
    MODEL_ERROR_FLOOR,
    FaultHypothesis,
    IsolationResult,
    model_error_term,
    relative_excursion,
)
from maglevid.diagnose.isolate import _std_error as isolate_std_error
from maglevid.exceptions import DataError

#: The longest record the plan searches [samples] (``smallest_satisfying`` up to 1e12).
PLAN_MAX_SAMPLES = 1e12

__all__ = [
    "Unresolved",
    "bounds_side",
    "interval_side",
    "tolerance_of",
    "unresolved_parameters",
    "with_cramer_rao_plan",
]


@dataclass(frozen=True)
class Unresolved:
    """One cause whose interval straddles its tolerance, and what would resolve it."""

    parameter: str
    tolerance_percent: float
    half_width_percent: float
    length_factor: float  # inf when no record length resolves it
    more_seconds: float  # inf likewise
    excitation_factor: float
    excitation_rms: float | None  # [V] the suggested excitation level, when known
    #: From the Cramér-Rao plan (None without one): the shortest record with the
    #: present spectrum [s] and the level it needs [V rms] (within the amplifier
    #: and displacement limits), and the candidate spectrum with the shortest
    #: record, its seconds and level.
    plan_seconds: float | None = None
    plan_excitation: float | None = None
    plan_spectrum: str | None = None
    plan_seconds_spectrum: float | None = None
    plan_excitation_spectrum: float | None = None
    #: That candidate's share of the excitation power on input 1 (0.5: both alike).
    plan_share: float | None = None
    #: The baseline's own 95 % half-width [%] when it is an estimate (None: exact).
    baseline_percent: float | None = None
    #: The estimated change [%] and the half-width [%] that would clear the
    #: tolerance from it (its distance from the boundary; None: the tolerance).
    estimate_percent: float | None = None
    needed_percent: float | None = None
    #: The fit it comes from ("only R1 changed": ("R1",); a pair: both names).
    hypothesis: tuple[str, ...] = ()
    level_percent: float = 95.0
    #: The amplifiers' limit [V rms, the smaller input's] the scaling rule's
    #: "raise the excitation" must respect (None: not stated).
    amplifier_limit: float | None = None
    #: From the Cramér-Rao plan: the 95 % half-width [%] that the model error
    #: (at its floor, the smallest it gets at any level) and the baseline leave
    #: however long the record (None: no plan).
    model_error_percent: float | None = None
    #: That smallest model error of each v_i [relative] (None: no plan).
    model_error_min: float | None = None
    #: The Cramér-Rao plan's model sees this record resolve the cause where the fit does
    #: not: a force disturbance informs the fit beside the excitation, so the scaling
    #: rule's "raise the excitation" promises too much (a longer record does not).
    disturbance_informs: bool = False

    @property
    def target_percent(self) -> float:
        """The half-width [%] that decides the verdict (the distance, else the tolerance)."""
        return self.tolerance_percent if self.needed_percent is None else self.needed_percent

    @property
    def resolvable(self) -> bool:
        return math.isfinite(self.length_factor)

    @property
    def baseline_limited(self) -> bool:
        """The baseline alone is uncertain beyond the tolerance: no new record helps."""
        return self.baseline_percent is not None and self.baseline_percent >= self.target_percent

    def advice(self) -> str:
        """One sentence: what this parameter needs."""
        head = self._head()
        if self.baseline_limited:
            return (
                f"{head}: the baseline itself is uncertain by ±{self.baseline_percent:.2g} %, "
                "so no record of the present state decides it; re-record the baseline "
                "(a longer or more strongly excited record of the reference state) "
                "or widen the tolerance"
            )
        if self.plan_seconds is not None:
            return head + ": " + self._plan_advice()
        if not self.resolvable:
            what = "the model error alone exceeds"
            if self.baseline_percent:
                what = (
                    f"the model error and the baseline's own ±{self.baseline_percent:.2g} % exceed"
                )
            # (not "the tolerance": the half-width that decides it, which an estimate
            # near the boundary makes small -- 0.2 % of model error against a 5 %
            # tolerance read as if it exceeded the tolerance; found from outside, issue
            # 16, thirteenth session)
            return (
                f"{head}: {what} the ±{self.target_percent:.2g} % that decides it; no longer "
                "record of this kind resolves it (use a wider tolerance or a smaller excitation)"
            )
        return (
            f"{head}: record about {self.more_seconds:.3g} s more of the same excitation"
            + self._over_the_limit()
            + self._raise_advice()
        )

    def _over_the_limit(self) -> str:
        """Where the record's own level already exceeds the stated amplifier limit, "the
        same excitation" is not allowed: the length at the limit instead (the
        information grows with the level squared and the length; found from outside,
        issue 16, fourteenth session: "12.3 s more of the same excitation" at 1 V under a
        stated 0.8 V limit)."""
        f, exc, lim, k = (self.excitation_factor, self.excitation_rms, self.amplifier_limit,
                          self.length_factor)  # fmt: skip
        if lim is None or exc is None or not (math.isfinite(k) and k > 1 and f > 0):
            return ""
        own = exc / f
        if own <= lim:
            return ""
        duration = self.more_seconds / (k - 1)
        at_limit = duration * (k * (own / lim) ** 2 - 1)
        return (
            f" (but the record's own {own:.3g} V rms is above the stated {lim:.3g} V rms "
            f"limit: at the limit, about {at_limit:.3g} s more)"
        )

    def _raise_advice(self) -> str:
        """The scaling rule's "raise the excitation", within the amplifiers' limit."""
        f, exc, lim = self.excitation_factor, self.excitation_rms, self.amplifier_limit
        if lim is not None and exc is not None and exc > lim:
            return (
                f" (raising the excitation about {f:.2g}x, to {exc:.3g} V rms, would exceed "
                f"the amplifiers' {lim:.3g} V rms limit)"
            )
        if lim is not None and exc is None:
            return (
                f", or raise the excitation about {f:.2g}x if the amplifiers allow it (limit "
                f"{lim:.3g} V rms; the recording logs no excitation level)"
            )
        level = f" (about {exc:.3g} V rms)" if exc is not None else ""
        if self.disturbance_informs:
            # m x1.1 under a 2 N force: "raise about 1.4x" narrowed the interval 1.15x,
            # not 1.37x; the length advice held (found from outside, seventeenth session)
            return (
                f", or raise the excitation by more than about {f:.2g}x{level}: part of "
                "the information here comes from the bearing's own force disturbance, "
                "which a stronger excitation does not add to"
            )
        return f", or raise the excitation about {f:.2g}x{level}"

    def _head(self) -> str:
        if self.estimate_percent is None:
            return (
                f"{self.parameter} ±{self.half_width_percent:.2g} % "
                f"(tolerance ±{self.tolerance_percent:.3g} %)"
            )
        c, w, tol = self.estimate_percent, self.half_width_percent, self.tolerance_percent
        # no "± w" (elsewhere "±" is one standard error), and three digits at the ends so
        # that +4.96 ... +5.04 % does not read "+5 … +5" (seen from outside, seventeenth
        # session: "+3.5 … +5 %" hid that the interval crossed +5 %)
        head = (
            f"{self.parameter} {c:+.3g} % ({self.level_percent:.3g} % interval "
            f"{c - w:+.3g} … {c + w:+.3g} %)"
        )
        if abs(c) - w > tol:  # beyond, but not the isolation's answer
            return f"{head} is wider than its tolerance ±{tol:.3g} %"
        return (
            f"{head} straddles its tolerance ±{tol:.3g} %; deciding it needs "
            f"±{self.target_percent:.2g} % (the estimate's distance from the boundary, "
            "if it stays there)"
        )

    def _plan_advice(self) -> str:
        from maglevid.identify.planning import describe_excitation, format_seconds, spectrum_label

        parts = []
        if math.isfinite(self.more_seconds) and self.more_seconds > 0:
            parts.append(
                f"record about {format_seconds(self.more_seconds)} more of the same excitation"
                + self._over_the_limit()
            )
        if self.excitation_rms is not None and math.isfinite(self.excitation_factor):
            how = "raise" if self.excitation_factor >= 1.0 else "lower"
            parts.append(f"{how} it to {self.excitation_rms:.3g} V rms at this length")
        same = self.plan_excitation == self.excitation_rms  # "raise it" says it already
        if self.plan_seconds is not None and math.isfinite(self.plan_seconds) and not same:
            parts.append(
                f"{format_seconds(self.plan_seconds)} in all at {self.plan_excitation:.3g} V rms"
                " (the best level within the amplifier and displacement limits)"
            )
        if self.plan_spectrum is not None and self.plan_seconds_spectrum is not None:
            how = describe_excitation(self.plan_excitation_spectrum or 0.0, self.plan_share or 0.5)
            parts.append(
                f"{format_seconds(self.plan_seconds_spectrum)} if you {how} "
                f"({spectrum_label(self.plan_spectrum)})"
            )
        if not parts and self.baseline_percent:
            return (
                f"the baseline's own ±{self.baseline_percent:.2g} % and the model error leave "
                "no record of the present state, at any level within the limits, that decides "
                "it; re-record the baseline or widen the tolerance"
            )
        if not parts:
            return self._no_record_advice()
        out = ", or ".join(parts) + " (Cramér-Rao plan)"
        if self.baseline_percent is not None:
            out += f"; the baseline's own ±{self.baseline_percent:.2g} % is counted"
        return out

    def _no_record_advice(self) -> str:
        """Why no record within the limits resolves it, and which tolerance would be decided."""
        w = self.model_error_percent
        if w is None or self.estimate_percent is None:
            return (
                "no record of this kind resolves it at any level within the limits "
                "(use a wider tolerance)"
            )
        c = abs(self.estimate_percent)
        if w < self.target_percent:  # the floor leaves room: the record would be too long
            return (
                f"it needs more than {PLAN_MAX_SAMPLES:.0e} samples at every level within the "
                "amplifier and displacement limits (use a wider tolerance)"
            )
        wider = f"a tolerance of at least ±{c + w:.3g} %"
        if c - w > 0:
            wider += f" (or at most ±{c - w:.3g} %)"
        return (
            f"the model error alone leaves ±{w:.2g} % however long the record and however "
            f"low the level (the diagnosis's model error at its smallest, "
            f"{100 * (self.model_error_min or 0):.2g} % of each v_i: max("
            f"{100 * MODEL_ERROR_FLOOR:.2g} %, 2 e^2), e the loop's relative excursion), "
            f"more than the ±{self.target_percent:.2g} % that decides it, so no record "
            f"resolves it: {wider} would be decided"
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("length_factor", "more_seconds", "plan_seconds", "plan_seconds_spectrum"):
            if d[k] is not None and not math.isfinite(d[k]):
                d[k] = None
        d["advice"] = self.advice()
        return d


def tolerance_of(name: str, tolerances: Mapping[str, float] | float) -> float:
    """The relative tolerance of one parameter (a mapping falls back to the default)."""
    if isinstance(tolerances, Mapping):
        return float(tolerances.get(name, DEFAULT_TOLERANCE))
    return float(tolerances)


def interval_side(change: float, half_width: float, tolerance: float) -> str:
    """Where the interval ``change ± half_width`` lies against ``± tolerance`` (relative).

    ``"beyond"`` (wholly outside: a fault), ``"inside"`` (wholly within: no
    fault) or ``"straddles"`` (the data cannot decide). A non-finite half-width
    straddles.
    """
    return bounds_side(change - half_width, change + half_width, tolerance)


def bounds_side(low: float, high: float, tolerance: float) -> str:
    """Where the interval ``[low, high]`` of a relative change lies against ``± tolerance``.

    The rule of :func:`interval_side` for an interval that is not symmetric about
    its estimate (e.g. a change in log units mapped back by ``expm1``). A NaN bound,
    or an interval from ``-inf`` to ``inf``, straddles.
    """
    if low > tolerance or high < -tolerance:
        return "beyond"
    if low >= -tolerance and high <= tolerance:
        return "inside"
    return "straddles"


def _baseline_se(h: FaultHypothesis, baseline_covariance: Any) -> float:
    """``f se_b``: the baseline's share of hypothesis ``h``'s standard error (module notes)."""
    if baseline_covariance is None or not h.sensitivity:
        return 0.0
    S_b = np.asarray(baseline_covariance, dtype=float)
    if S_b.shape != (9, 9):
        raise DataError(f"`baseline_covariance` must be 9x9; got {S_b.shape}")
    se = isolate_std_error(np.asarray(h.sensitivity), S_b)
    return h.factors[0] * se if math.isfinite(se) else 0.0


def _length_factor(h: FaultHypothesis, target: float, se_b: float = 0.0, j: int = 0) -> float:
    """``k`` with ``(se_n^2 - se_b^2) / k + se_b^2 + se_f^2 = target^2`` (module notes)."""
    se = h.factor_std_errors[j]
    if not h.noise_std_errors:  # no decomposition: all of it is noise
        return (se**2 - se_b**2) / (target**2 - se_b**2) if target > se_b else math.inf
    se_n, se_f = h.noise_std_errors[j], h.floor_std_errors[j]
    fixed = se_b**2 + se_f**2  # what more of the present state cannot shrink
    if not math.isfinite(se) or fixed >= target**2:
        return math.inf
    return max(max(se_n**2 - se_b**2, 0.0) / (target**2 - fixed), (se / target) ** 2, 1.0)


def unresolved_parameters(
    iso: IsolationResult,
    tolerances: Mapping[str, float] | float,
    *,
    level: float = 0.95,
    duration_s: float | None = None,
    excitation_rms: float | None = None,
    baseline_covariance: Any = None,
) -> list[Unresolved]:
    """The isolation's causes whose interval at ``level`` straddles their tolerance.

    Checked: every single-cause fit, and the best fit when it is a pair (its
    own factors and intervals); where the isolation has an answer, only the fits the
    data do not reject (p at or above the isolation's alpha) besides it. A cause is
    unresolved when ``c ± z se`` is
    neither wholly beyond nor wholly inside ``± tol`` (:func:`interval_side`);
    the half-width that would decide it is ``| |c| - tol |`` (module notes).

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
    baseline_covariance : array_like, shape (9, 9), optional
        The baseline's covariance of v1..v9, as given to
        :func:`~maglevid.diagnose.isolate.isolate_fault` (module notes).

    Returns
    -------
    list of Unresolved, the furthest from deciding (half-width over the one
    needed) first.
    """
    z = float(special.ndtri(0.5 + level / 2))
    fits = [*iso.singles, *([iso.best] if len(iso.best.parameters) > 1 else [])]
    if iso.explained:
        # a cause the data reject (its own fit's chi2 test) needs no deciding: listed
        # beside an R1 +50 % fault, "gi1 -5 % straddles its tolerance" came from a fit
        # with chi2 = 53074 (found from outside, issue 16, thirteenth session)
        fits = [h for h in fits if h is iso.best or not h.p_value < iso.alpha]
    out = []
    for h in fits:
        for j, name in enumerate(h.parameters):
            tol = tolerance_of(name, tolerances)
            c, se = h.factors[j] - 1.0, h.factor_std_errors[j]
            side = interval_side(c, z * se, tol) if tol > 0 else "inside"
            if side == "inside" or (side == "beyond" and (h is iso.best or z * se <= tol)):
                continue
            # Straddling: the estimate's distance from the boundary decides it. Beyond
            # in a fit that is not the isolation's answer ("nothing changed" was not
            # rejected) and wider than the tolerance: the tolerance (module notes).
            need = abs(abs(c) - tol) if side == "straddles" else tol
            se_b = _baseline_se(h, baseline_covariance)
            k = _length_factor(h, need / z, se_b, j) if need > 0 else math.inf
            out.append(
                Unresolved(
                    parameter=name,
                    tolerance_percent=100 * tol,
                    half_width_percent=100 * z * se,
                    length_factor=k,
                    more_seconds=(k - 1) * duration_s
                    if duration_s is not None and math.isfinite(k)
                    else math.inf,
                    excitation_factor=math.sqrt(k),
                    excitation_rms=(
                        math.sqrt(k) * excitation_rms
                        if excitation_rms is not None and math.isfinite(k)
                        else None
                    ),
                    baseline_percent=100 * z * se_b if baseline_covariance is not None else None,
                    estimate_percent=100 * c,
                    needed_percent=100 * need,
                    hypothesis=h.parameters,
                    level_percent=100 * level,
                )
            )
    return sorted(out, key=lambda u: -u.half_width_percent / max(u.target_percent, 1e-300))


def with_cramer_rao_plan(
    unresolved: list[Unresolved],
    iso: IsolationResult,
    design: Any,
    *,
    n_samples: int,
    excitation_std: float,
    tolerances: Mapping[str, float] | float,
    level: float = 0.95,
    max_excitation_std: Any = None,
    max_displacement: float | None = None,
    baseline_covariance: Any = None,
    splits: Any = None,
    excursion: float | None = None,
) -> list[Unresolved]:
    """``unresolved`` with the advice of the Cramér-Rao plan (module notes).

    Parameters
    ----------
    unresolved : list of Unresolved
        From :func:`unresolved_parameters`.
    iso : IsolationResult
        The isolation they come from (its single-cause sensitivities).
    design : maglevid.identify.planning.DesignInformation
        The loop around the estimated bearing
        (:func:`maglevid.identify.planning.design_for_recording`).
    n_samples, excitation_std : the recording's length and excitation [V rms].
    tolerances, level : as in :func:`unresolved_parameters` (each entry of ``unresolved``
        carries the half-width that decides it, its distance from the tolerance).
    max_excitation_std, max_displacement : the planner's limits (its defaults).
    baseline_covariance : array_like, shape (9, 9), optional
        The baseline's covariance of v1..v9 (as given to the isolation): it
        does not fall with the record length.
    splits : sequence of float, optional
        Candidate shares of the excitation on input 1
        (default :data:`~maglevid.identify.planning.DEFAULT_SPLITS`).
    excursion : float, optional
        The recording's largest relative excursion
        (:func:`~maglevid.diagnose.isolate.relative_excursion`); the model error
        of a planned record is :func:`~maglevid.diagnose.isolate.model_error_term`
        of it scaled by the design's excursion at the planned level. None: the
        design's predicted excursion at ``excitation_std``.
    """
    from maglevid.identify import planning

    amp = planning.DEFAULT_MAX_EXCITATION_STD if max_excitation_std is None else max_excitation_std
    disp = planning.DEFAULT_MAX_DISPLACEMENT if max_displacement is None else max_displacement
    splits = planning.DEFAULT_SPLITS if splits is None else tuple(splits)
    splits = (*splits, planning.limit_share(amp))  # each input at its own limit
    z = float(special.ndtri(0.5 + level / 2))
    singles = {h.parameters[0]: h for h in iso.singles if h.sensitivity}
    S_b = None if baseline_covariance is None else np.asarray(baseline_covariance, float)
    e_now = design.excursion(excitation_std) if excursion is None else excursion
    grid = _ExcitationGrid(design, amp, disp, excitation_std, e_now, splits, S_b)
    limit = min(planning.amplifier_limits(amp))  # what the scaling rule's advice keeps to
    out = []
    for u in unresolved:
        h = singles.get(u.parameter) if len(u.hypothesis) <= 1 else None  # a pair: scaling rule
        if h is None or not h.noise_std_errors or u.baseline_limited or u.target_percent <= 0:
            out.append(replace(u, amplifier_limit=limit))
            continue
        need = grid.needs(h, u.target_percent / 100 / z, n_samples)
        if need is None or need.samples_now <= n_samples:
            # no plan, or one whose model sees this very record resolve it: it disagrees
            # with the isolation's interval (a large force disturbance, which excites the
            # bearing itself: it advised 0 V rms there), so the scaling rule advises
            informs = need is not None and design.noise.force_std > 0
            out.append(replace(u, amplifier_limit=limit, disturbance_informs=informs))
            continue
        present = (design.spectrum, 0.5)
        best = min(need.seconds, key=lambda c: need.seconds[c][0])
        other = best != present and need.seconds[best][0] < need.seconds[present][0]
        exc = need.excitation_for_length
        k = need.samples_now / n_samples
        seconds, level = need.seconds[present]
        if exc is not None and seconds <= n_samples * design.dt * (1 + 1e-9):
            level = exc  # the shortest is this length: its level refined, one clause
        out.append(
            replace(
                u,
                length_factor=k,
                more_seconds=(k - 1) * n_samples * design.dt if math.isfinite(k) else math.inf,
                excitation_rms=exc,
                excitation_factor=(math.inf if exc is None else exc / excitation_std)
                if excitation_std > 0
                else u.excitation_factor,
                plan_seconds=seconds,
                plan_excitation=level,
                plan_spectrum=best[0] if other else None,
                plan_seconds_spectrum=need.seconds[best][0] if other else None,
                plan_excitation_spectrum=need.seconds[best][1] if other else None,
                plan_share=best[1] if other else None,
                model_error_percent=100 * z * need.floor_std,
                model_error_min=need.eps_min,
            )
        )
    return out


@dataclass(frozen=True)
class _Need:
    #: (spectrum, share) -> (shortest record [s], at V rms)
    seconds: dict[tuple[str, float], tuple[float, float]]
    excitation_for_length: float | None  # present spectrum, present length [V rms]
    samples_now: float  # record length needed at the present excitation [samples]
    floor_std: float  # what no record shrinks: model error at its smallest and baseline [relative]
    eps_min: float  # the smallest model error of each v_i at any level [relative]


class _ExcitationGrid:
    """Per-sample information and model error over excitation levels, spectra and splits.

    The model error of each v_i at a level is the measured law of the
    linearisation's bias (:func:`maglevid.identify.planning.model_error_of_excursion`,
    ``2 e^2`` of v_i, ``e`` the excursion the design predicts at that level),
    never below the diagnosis's floor (:data:`~maglevid.diagnose.isolate.MODEL_ERROR_FLOOR`):
    :func:`~maglevid.diagnose.isolate.model_error_term`, the same term the
    isolation counts, so the advice promises the interval the advised record's
    diagnosis states (docs/diagnosis.md, "Model error"). A level that raises the
    bias above the tolerance is not a way forward, so the shortest record is
    sought over a grid of levels up to each candidate's amplifier/displacement
    limit, not only at the limit.
    """

    N_LEVELS = 24

    def __init__(
        self,
        design: Any,
        amp: Any,
        disp: float,
        excitation_std: float,
        excursion: float,
        splits: tuple[float, ...],
        baseline_covariance: np.ndarray | None,
    ) -> None:
        self.design = design
        self.exc_now = excitation_std
        self.excursion_now = excursion
        self.excursion_design_now = design.excursion(excitation_std)
        self.S_b = np.zeros((9, 9)) if baseline_covariance is None else baseline_covariance
        self.v2 = np.square(np.asarray(design.v, float))
        # (spectrum, share) -> [(level, inverse information per sample, model error)]
        self.levels: dict[tuple[str, float], list[tuple[float, np.ndarray, float]]] = {}
        for sp in design.parts:
            for share in dict.fromkeys([0.5, *splits]):
                a_max = design.max_excitation(amp, disp, sp, share)
                self.levels[(sp, share)] = [
                    (float(a), self._inverse(float(a), sp, share), self.eps(float(a), sp, share))
                    for a in a_max * np.geomspace(1e-2, 1.0, self.N_LEVELS)
                ]

    def _inverse(self, a: float, spectrum: str | None = None, share: float = 0.5) -> np.ndarray:
        info = self.design.v_information(
            n_samples=1, excitation_std=a, spectrum=spectrum, share=share
        )
        return np.linalg.pinv(info)

    def eps(self, a: float, spectrum: str | None = None, share: float = 0.5) -> float:
        """The isolation's model error of each v_i for a record at level ``a``.

        :func:`~maglevid.diagnose.isolate.model_error_term` of the excursion that
        record would have: the recording's own, scaled by the design's prediction.
        """
        ratio = self.design.excursion(a, spectrum, share) / self.excursion_design_now
        return model_error_term(self.excursion_now * ratio)

    def _var(self, g: np.ndarray, cov_n: np.ndarray, eps: float) -> float:
        """Variance of the log-factor under ``cov_n + S_b + diag((eps v)^2)``."""
        S = cov_n + self.S_b + np.diag(eps * eps * self.v2)
        w = float(g @ np.linalg.lstsq(S, g, rcond=None)[0])
        return 1.0 / w if w > 0 else math.inf

    def needs(self, h: FaultHypothesis, half_width: float, n_samples: int) -> _Need | None:
        """Shortest records and the excitation at this length resolving ``h`` (or None).

        The variance of the log-factor at ``n`` samples, level ``a`` and model
        error ``eps`` is that of the isolation's own test (noise, baseline and
        model error together, not their separate variances added):
        ``1 / (g^T (kappa I_v(n, a)^-1 + S_b + diag((eps v)^2))^-1 g)``, with
        ``kappa`` matching the isolation's noise variance (the method's and the
        baseline's) in this direction: 1 for an efficient estimator, more for IV.
        """
        from maglevid.identify.planning import smallest_satisfying

        g = np.asarray(h.sensitivity)
        f = h.factors[0]
        t2 = (half_width / f) ** 2  # resolved when z f se_log <= tol
        inv_now = self._inverse(self.exc_now) / n_samples
        se_n2 = (h.noise_std_errors[0] / f) ** 2
        # kappa: the method's noise variance over the bound's, with S_b unscaled.
        log_kappa = smallest_satisfying(
            lambda lk: self._var(g, 10**lk * inv_now, 0.0) >= se_n2, -12.0, 12.0, xtol=1e-6
        )
        if log_kappa is None or not np.all(np.isfinite(inv_now)):
            return None
        kappa = 10**log_kappa

        def samples(inv1: np.ndarray, eps: float) -> float:
            n = smallest_satisfying(
                lambda ln: self._var(g, kappa * inv1 / 10**ln, eps) <= t2,
                0.0,
                math.log10(PLAN_MAX_SAMPLES),
                xtol=1e-3,
            )
            return math.inf if n is None else 10**n  # PLAN_MAX_SAMPLES at most

        # Never shorter than the recording: a level that would resolve it in fewer
        # samples is proposed at the recording's length (the lowest such level wins
        # the tie), since a shorter record may fail the quality checks and the fit.
        seconds = {
            c: min(
                (max(samples(inv1, eps), n_samples) * self.design.dt, a) for a, inv1, eps in rows
            )
            for c, rows in self.levels.items()
        }
        now = samples(self._inverse(self.exc_now), self.eps(self.exc_now))

        def resolved_at(a: float) -> bool:
            return self._var(g, kappa * self._inverse(a) / n_samples, self.eps(a)) <= t2

        levels = [a for a, _, _ in self.levels[(self.design.spectrum, 0.5)]]
        first = _nearest_resolving(levels, resolved_at, self.exc_now)
        eps_min = min([self.eps(0.0), *(e for rows in self.levels.values() for *_, e in rows)])
        floor_std = f * math.sqrt(self._var(g, np.zeros((9, 9)), eps_min))
        return _Need(seconds, first, now, floor_std, eps_min)


def _nearest_resolving(levels: list[float], resolved_at: Any, now: float) -> float | None:
    """The level at this length nearest the present one that resolves: the smallest at or
    above it (refined down to it), else the largest on the grid below it.

    Not the smallest resolving level overall: on a record that a large force
    disturbance excites, the disturbance alone carries information while the model
    error grows with the excitation, so that level was 0 V ("raise it to 0 V rms",
    found from outside, issue 16, thirteenth session) where 4 V resolved the same
    record too. The least change to the experiment is what is advised; None where the
    plan's model already sees the present level resolve it (its model and the
    isolation's interval disagree: the scaling rule's length is advised instead)."""
    from maglevid.identify.planning import smallest_satisfying

    if resolved_at(now):  # the plan's model sees the record resolved: no level to advise
        return None
    ok = [a for a in levels if resolved_at(a)]
    above = [a for a in ok if a > now]
    if above:
        a = min(above)
        lo = max([b for b in levels if b < a] + [now])
        return smallest_satisfying(resolved_at, lo, a, xtol=1e-3 * a)
    return max(ok) if ok else None


def plan_unresolved(
    unresolved: list[Unresolved],
    iso: IsolationResult,
    data: Any,
    result: Any,
    *,
    tolerances: Mapping[str, float] | float,
    level: float = 0.95,
    baseline_covariance: Any = None,
    max_excitation_std: Any = None,
) -> tuple[list[Unresolved], str | None]:
    """:func:`with_cramer_rao_plan` for a recording and its identification result.

    ``baseline_covariance`` is the baseline's covariance of v1..v9 (as given to
    the isolation; None for an exact baseline); ``max_excitation_std`` the
    amplifiers' limit [V rms], one or one per input (None: the planner's
    default). Returns the advice and, when no
    plan can be made (no logged excitation, no operating point or noise model,
    a loop the plan cannot hold), the reason (the scaling rule's advice is
    then kept).
    """
    from maglevid.exceptions import MaglevidError
    from maglevid.identify import planning

    if not unresolved:
        return unresolved, None
    try:
        design = planning.design_for_recording(
            data,
            v=planning.v_of_result(result),
            noise=planning.noise_of_result(result),
            n_simulate=10_000,
        )
        exc = float(np.mean(np.std(np.asarray(data.r), axis=0)))
        e_now = relative_excursion(data.y, design.gap, design.i0) if design.i0 else None
        planned = with_cramer_rao_plan(
            unresolved,
            iso,
            design,
            n_samples=data.n_samples,
            excitation_std=exc,
            tolerances=tolerances,
            level=level,
            baseline_covariance=baseline_covariance,
            max_excitation_std=max_excitation_std,
            excursion=e_now,
        )
    except (MaglevidError, ArithmeticError, np.linalg.LinAlgError) as exc:
        # The scaling rule's advice stays: its "raise the excitation" within the
        # amplifiers' limit (issue 13: it proposed any level without a logged r).
        amp = max_excitation_std
        amp = planning.DEFAULT_MAX_EXCITATION_STD if amp is None else amp
        try:
            limit: float | None = min(planning.amplifier_limits(amp))
        except MaglevidError:
            limit = None
        kept = [replace(u, amplifier_limit=limit) for u in unresolved]
        return kept, f"no Cramér-Rao plan for the advice: {exc or type(exc).__name__}"
    return planned, None
