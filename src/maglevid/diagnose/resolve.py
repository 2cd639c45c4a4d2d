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
allowed excitation, and the candidate spectrum that needs the shortest record.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from scipy import special

from maglevid.diagnose.compare import DEFAULT_TOLERANCE
from maglevid.diagnose.isolate import MODEL_ERROR_FLOOR, FaultHypothesis, IsolationResult

__all__ = ["Unresolved", "tolerance_of", "unresolved_parameters", "with_cramer_rao_plan"]


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
    #: From the Cramér-Rao plan (None without one): the shortest record with the
    #: present spectrum [s] and the level it needs [V rms] (within the amplifier
    #: and displacement limits), and the candidate spectrum with the shortest
    #: record, its seconds and level.
    plan_seconds: float | None = None
    plan_excitation: float | None = None
    plan_spectrum: str | None = None
    plan_seconds_spectrum: float | None = None
    plan_excitation_spectrum: float | None = None

    @property
    def resolvable(self) -> bool:
        return math.isfinite(self.length_factor)

    def advice(self) -> str:
        """One sentence: what this parameter needs."""
        head = (
            f"{self.parameter} ±{self.half_width_percent:.2g} % "
            f"(tolerance ±{self.tolerance_percent:.3g} %)"
        )
        if self.plan_seconds is not None:
            return head + ": " + self._plan_advice()
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

    def _plan_advice(self) -> str:
        from maglevid.identify.planning import spectrum_label

        parts = []
        if math.isfinite(self.more_seconds):
            parts.append(f"record about {_fmt_s(self.more_seconds)} more of the same excitation")
        if self.excitation_rms is not None and math.isfinite(self.excitation_factor):
            parts.append(f"raise it to {self.excitation_rms:.3g} V rms at this length")
        if self.plan_seconds is not None and math.isfinite(self.plan_seconds):
            parts.append(
                f"{_fmt_s(self.plan_seconds)} in all at {self.plan_excitation:.3g} V rms"
                " (the best level within the amplifier and displacement limits)"
            )
        if self.plan_spectrum is not None and self.plan_seconds_spectrum is not None:
            parts.append(
                f"{_fmt_s(self.plan_seconds_spectrum)} with a {spectrum_label(self.plan_spectrum)}"
                f" excitation at {self.plan_excitation_spectrum:.3g} V rms"
            )
        if not parts:
            return (
                "no record of this kind resolves it at any level within the limits "
                "(the model error grows with the excitation; use a wider tolerance)"
            )
        return ", or ".join(parts) + " (Cramér-Rao plan)"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("length_factor", "more_seconds", "plan_seconds", "plan_seconds_spectrum"):
            if d[k] is not None and not math.isfinite(d[k]):
                d[k] = None
        d["advice"] = self.advice()
        return d


def _fmt_s(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "no finite time"
    if seconds < 1:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds:.3g} s" if seconds < 600 else f"{seconds / 60:.3g} min"


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


def with_cramer_rao_plan(
    unresolved: list[Unresolved],
    iso: IsolationResult,
    design: Any,
    *,
    n_samples: int,
    excitation_std: float,
    tolerances: Mapping[str, float] | float,
    level: float = 0.95,
    max_excitation_std: float | None = None,
    max_displacement: float | None = None,
) -> list[Unresolved]:
    """``unresolved`` with the advice of the Cramér-Rao plan (module notes).

    Parameters
    ----------
    unresolved : list of Unresolved
        From :func:`unresolved_parameters`.
    iso : IsolationResult
        The isolation they come from (its single-cause sensitivities and model error).
    design : maglevid.identify.planning.DesignInformation
        The loop around the estimated bearing
        (:func:`maglevid.identify.planning.design_for_recording`).
    n_samples, excitation_std : the recording's length and excitation [V rms].
    tolerances, level : as in :func:`unresolved_parameters`.
    max_excitation_std, max_displacement : the planner's limits (its defaults).
    """
    from maglevid.identify import planning

    amp = planning.DEFAULT_MAX_EXCITATION_STD if max_excitation_std is None else max_excitation_std
    disp = planning.DEFAULT_MAX_DISPLACEMENT if max_displacement is None else max_displacement
    z = float(special.ndtri(0.5 + level / 2))
    singles = {h.parameters[0]: h for h in iso.singles if h.sensitivity}
    grid = _ExcitationGrid(design, amp, disp, excitation_std, iso.model_error)
    out = []
    for u in unresolved:
        h = singles.get(u.parameter)
        if h is None or not h.noise_std_errors:
            out.append(u)
            continue
        need = grid.needs(h, tolerance_of(u.parameter, tolerances) / z, n_samples)
        if need is None:
            out.append(u)
            continue
        present = design.spectrum
        best = min(need.seconds, key=lambda sp: need.seconds[sp][0])
        other = best != present and need.seconds[best][0] < need.seconds[present][0]
        exc = need.excitation_for_length
        k = need.samples_now / n_samples
        out.append(
            replace(
                u,
                length_factor=k,
                more_seconds=(k - 1) * n_samples * design.dt if math.isfinite(k) else math.inf,
                excitation_rms=exc,
                excitation_factor=(math.inf if exc is None else exc / excitation_std)
                if excitation_std > 0
                else u.excitation_factor,
                plan_seconds=need.seconds[present][0],
                plan_excitation=need.seconds[present][1],
                plan_spectrum=best if other else None,
                plan_seconds_spectrum=need.seconds[best][0] if other else None,
                plan_excitation_spectrum=need.seconds[best][1] if other else None,
            )
        )
    return out


@dataclass(frozen=True)
class _Need:
    seconds: dict[str, tuple[float, float]]  # spectrum -> (shortest record [s], at V rms)
    excitation_for_length: float | None  # present spectrum, present length [V rms]
    samples_now: float  # record length needed at the present excitation [samples]


class _ExcitationGrid:
    """Per-sample information and model error over excitation levels and spectra.

    The model error of the isolation (``iso.model_error``, relative to each
    v_i) grows with the loop's excursion; it is scaled with the excursion the
    design predicts at each level, never below the diagnosis's floor. A level
    that raises the floor above the tolerance is not a way forward, so the
    shortest record is sought over a grid of levels up to each spectrum's
    amplifier/displacement limit, not only at the limit.
    """

    N_LEVELS = 32

    def __init__(
        self, design: Any, amp: float, disp: float, excitation_std: float, model_error: float
    ) -> None:
        self.design = design
        self.floor = MODEL_ERROR_FLOOR
        self.eps_now = max(model_error, MODEL_ERROR_FLOOR)
        self.exc_now = excitation_std
        self.excursion_now = design.excursion(excitation_std)
        self.levels = {}
        for sp in (design.spectrum, *design.spectra):
            a_max = design.max_excitation(amp, disp, sp)
            for a in a_max * np.geomspace(1e-2, 1.0, self.N_LEVELS):
                self.levels.setdefault(sp, []).append(
                    (
                        float(a),
                        design.v_information(n_samples=1, excitation_std=a, spectrum=sp),
                        self.eps(float(a), sp),
                    )
                )

    def eps(self, a: float, spectrum: str | None = None) -> float:
        ratio = self.design.excursion(a, spectrum) / self.excursion_now
        return max(self.floor, self.eps_now * ratio)

    def needs(self, h: FaultHypothesis, half_width: float, n_samples: int) -> _Need | None:
        """Shortest records and the excitation at this length resolving ``h`` (or None).

        The variance of the log-factor at ``n`` samples, level ``a`` and model
        error ``eps`` is that of the isolation's own test (noise and model
        error together, not their separate variances added):
        ``1 / (g^T (kappa I_v(n, a)^-1 + diag((eps v)^2))^-1 g)``, with
        ``kappa = se_n^2 g^T I_v(N, a_now) g`` matching the method's own noise
        variance in this direction (1 for an efficient estimator, more for IV).
        """
        g = np.asarray(h.sensitivity)
        f = h.factors[0]
        t2 = (half_width / f) ** 2  # resolved when z f se_log <= tol
        d = self.design
        q_now = float(g @ d.v_information(n_samples=n_samples, excitation_std=self.exc_now) @ g)
        if q_now <= 0:
            return None
        kappa = (h.noise_std_errors[0] / f) ** 2 * q_now
        v2 = np.square(np.asarray(d.v, float))

        def var(n: float, info1: np.ndarray, eps: float) -> float:
            S = kappa * np.linalg.pinv(n * info1) + np.diag(eps * eps * v2)
            w = float(g @ np.linalg.lstsq(S, g, rcond=None)[0])
            return 1.0 / w if w > 0 else math.inf

        def samples(info1: np.ndarray, eps: float) -> float:
            if var(1e12, info1, eps) > t2:
                return math.inf
            lo, hi = 0.0, 12.0  # log10 n
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if var(10**mid, info1, eps) <= t2 else (mid, hi)
            return 10**hi

        seconds = {}
        for sp, rows in self.levels.items():
            best = min(((samples(info1, eps) * d.dt, a) for a, info1, eps in rows))
            seconds[sp] = best
        now = samples(
            d.v_information(n_samples=1, excitation_std=self.exc_now), self.eps(self.exc_now)
        )

        def resolved_at(a: float) -> bool:
            info = d.v_information(n_samples=1, excitation_std=a)
            return var(n_samples, info, self.eps(a)) <= t2

        levels = [a for a, _, _ in self.levels[d.spectrum]]
        first = next((a for a in levels if resolved_at(a)), None)
        if first is not None:
            lo = max([a for a in levels if a < first], default=0.0)
            hi = first
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if resolved_at(mid) else (mid, hi)
                if hi - lo < 1e-3 * hi:
                    break
            first = hi
        return _Need(seconds=seconds, excitation_for_length=first, samples_now=now)


def plan_unresolved(
    unresolved: list[Unresolved],
    iso: IsolationResult,
    data: Any,
    result: Any,
    *,
    tolerances: Mapping[str, float] | float,
    level: float = 0.95,
) -> tuple[list[Unresolved], str | None]:
    """:func:`with_cramer_rao_plan` for a recording and its identification result.

    Returns the advice and, when no plan can be made (no logged excitation, no
    operating point or noise model, a loop the plan cannot hold), the reason
    (the scaling rule's advice is then kept).
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
        planned = with_cramer_rao_plan(
            unresolved,
            iso,
            design,
            n_samples=data.n_samples,
            excitation_std=exc,
            tolerances=tolerances,
            level=level,
        )
    except (MaglevidError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return unresolved, f"no Cramér-Rao plan for the advice: {exc or type(exc).__name__}"
    return planned, None
