"""The inter-sampled magnetic suspension (Sun, Miyake, Ohmori & Sano) as a plant kind.

Recognised by outputs sampled ``p > 1`` times per control period; identified by
maximum likelihood on every inter-sample (``intersample-ml``: eq. (27)'s physics
through a Kalman predictor, consistent under a force disturbance and the nonlinear
plant's distortion) where the recording states the ball's mass and the coil's
resistance, else by Sun et al.'s direct inter-sampling method, whose physical
parameters are those of eq. (27) (with a mass, and through the force balance
eq. (26)). maglevid has no fault
model of the suspension: a diagnosis runs the shared stages
(:class:`maglevid.plants.amb.AMBStages`), comparing what the baseline states,
without isolation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.diagnose.checks import (
    check_channels_move,
    check_length,
    check_output_clipping,
    check_sample_time,
    check_saturation,
)
from maglevid.diagnose.compare import compare_parameters
from maglevid.diagnose.diagnosis import Diagnosis, QualityCheck
from maglevid.exceptions import DataError, MaglevidError
from maglevid.plants.base import (
    BaseKind,
    DiagnosisRun,
    as_mapping,
    cannot_diagnose,
    checked_baseline_values,
    identified_not_compared,
    shape_of,
    verdict_without_isolation,
)

__all__ = ["COMPARED", "KIND", "InterSampledSuspension", "SuspensionStages"]


class InterSampledSuspension(BaseKind):
    """Outputs inter-sampled ``p`` times per control period (Sun et al.)."""

    name = "intersampled-suspension"
    description = "suspension with outputs inter-sampled p times per control period (Sun et al.)"
    default_method = "intersample-ml"
    method_reason = (
        "maximum likelihood on every inter-sample through the Kalman predictor, started "
        "from Sun et al.'s direct inter-sampling estimate: consistent under a force "
        "disturbance and the plant's nonlinearity, which bias Sun et al.'s output-error "
        "steps (docs/sun.md), and 4-5x more precise on alpha, eta and L"
    )
    #: Without the ball's mass or the coil's resistance (``intersample-ml`` needs both).
    fallback_method = "intersample"
    fallback_reason = (
        "the direct inter-sampling method (Sun et al.) identifies the unstable plant "
        "from u and y alone (the recording states no ball mass and coil resistance, "
        "which the maximum-likelihood method intersample-ml needs)"
    )
    methods = ("intersample-ml", "intersample", "pem", "indirect", "two-stage")
    #: eq. (27) and the force balance eq. (26) (physics/suspension.py).
    parameters: Mapping[str, str] = MappingProxyType(
        {
            "pole_rad_s": "s⁻¹",
            "alpha": "N·m⁻¹",
            "eta": "N·A⁻¹",
            "L": "H",
            "R": "Ω",
            "gap": "m",
            "I": "A",
            "Q": "H·m",
            "L_inf": "H",
            "Y_offset": "m",
        }
    )
    hypotheses: Mapping[str, str] = MappingProxyType(
        {}
    )  # no fault model of the suspension in maglevid
    report_panels = ("verdict", "parameters", "poles", "responses", "trends", "quality", "method")

    def recognise(self, data: ClosedLoopData) -> str | None:
        return f"outputs inter-sampled ({shape_of(data)})" if data.p > 1 else None

    def choose_method(self, data: ClosedLoopData) -> tuple[str, str]:
        """``intersample-ml`` where ``loop["physical"]`` states ``M`` and ``R``, else
        ``intersample``."""
        phys = data.loop.get("physical", {}) if hasattr(data.loop, "get") else {}
        if "M" in phys and "R" in phys:
            return self.default_method, self.method_reason
        return self.fallback_method, self.fallback_reason

    def stages(self, method: str) -> SuspensionStages:
        return STAGES


#: What a diagnosis compares: the unstable pole and eq. (27)'s physics (``R`` where the
#: method estimated it); ``I`` and ``Y_offset`` follow from ``eta`` and ``gap``.
COMPARED = ("pole_rad_s", "alpha", "eta", "L", "R", "gap", "Q", "L_inf")


@dataclass
class _Base:
    values: dict[str, tuple[float, float]]
    source: str


class SuspensionStages:
    """The suspension's diagnosis: the record's own checks (a noise-driven loop has no
    excitation ``r``: Sun et al.'s setting), the baseline (the design the recording
    states in ``loop["design"]``, the machine's history, or a mapping of parameter
    values), the physical parameters compared jointly; no fault model, so a change is
    reported with its numbers, not isolated."""

    drift_parameters: tuple[str, ...] = COMPARED

    def quality(self, run: DiagnosisRun) -> tuple[QualityCheck, ...]:
        data = run.data
        return (
            check_length(data),
            check_channels_move(data),
            check_sample_time(data),
            check_saturation(data),
            check_output_clipping(data),
        )

    def baseline(self, run: DiagnosisRun) -> None:
        """Resolve the baseline before identifying (a bad one is the caller's error)."""
        b = run.baseline
        if isinstance(b, Mapping) and not isinstance(b, str):
            run.base = _Base(_given(b), "given values")
        elif b in ("nominal", None):
            design = as_mapping(run.data.loop).get("design")
            if not design:
                raise DataError(
                    "baseline='nominal' needs the suspension's design in the recording "
                    "(loop['design']: alpha, eta, L, ...); compare with the machine's history "
                    "(--baseline history with --machine and --store) or give the values "
                    "(a JSON file of " + ", ".join(COMPARED) + ")"
                )
            run.base = _Base(_given(design), "design (loop['design'] in the recording)")
        elif b == "history":
            if run.store is None or run.machine is None:
                raise DataError("baseline='history' needs `history` (a store) and `machine`")
            try:
                stored = run.store.latest_estimates(
                    run.machine, method=run.method, before=run.when,
                    exclude_recording=run.common["recording_hash"],
                )  # fmt: skip
            except MaglevidError:  # a machine not in the store yet: its first record
                stored = {}
            values = {k: (e.value, e.std_error or 0.0) for k, e in stored.items() if k in COMPARED}
            design = as_mapping(run.data.loop).get("design")
            if not values and design:  # the machine's first record: its design (as the AMB)
                run.notes.append(
                    f"no earlier diagnosis of {run.machine!r} in the history: compared with "
                    "the design (loop['design'] in the recording)"
                )
                run.base = _Base(_given(design), "design (no history yet)")
            else:
                run.base = _Base(values, "earlier identification (history)" if values else "")
        else:
            raise DataError(
                "`baseline` must be 'nominal', 'history' or a mapping of the suspension's "
                f"parameters; got {b!r}"
            )

    def compare(self, run: DiagnosisRun) -> Diagnosis | None:
        result, base = run.result, run.base
        se = result.std_errors()
        estimates = {
            k: (result.parameters[k], se.get(k, float("nan")))
            for k in COMPARED
            if k in result.parameters
        }
        if not any(k in estimates for k in ("alpha", "eta", "L")):
            return cannot_diagnose(
                run,
                [
                    f"{run.method} gave no physical parameters (the ball's mass is needed: "
                    "loop['physical']['M'] or --option mass=...)"
                ],
            )
        if not base.values:
            return identified_not_compared(
                run,
                [
                    f"{_label(k)} {v:.4g} ± {1.96 * s:.2g} (95 %)"
                    for k, (v, s) in estimates.items()
                ],
            )
        changes = compare_parameters(
            estimates, base.values, tolerances=run.tolerances, level=run.level, joint=True
        )
        if not changes:
            return cannot_diagnose(
                run,
                ["the baseline names none of " + ", ".join(estimates) + ": nothing to compare"],
            )
        run.compared = changes
        return None

    def isolate(self, run: DiagnosisRun) -> Diagnosis:
        """No fault model: the changes with their numbers; a question the record cannot
        decide (an interval across the tolerance) is "inconclusive", with the record
        length that would decide it."""
        changes, result = run.compared, run.result
        verdict, code = verdict_without_isolation(changes, run.notes)
        open_ = [ch for ch in changes if ch.status == "not resolved"]
        if code in ("no_change", "within_tolerance") and open_:
            verdict, code = _inconclusive(open_, run.data.n_samples * run.data.dt), "inconclusive"
        reasons = [
            f"{_label(ch.name)} {ch.estimate:.4g} vs baseline {ch.baseline:.4g}: "
            f"{ch.change_percent:+.1f} % ({ch.status})"
            for ch in changes
        ]
        heavier = _mass_reading(changes)
        if heavier is not None:
            verdict += f" (or {heavier[0]})"
            reasons.append(heavier[1])
        return Diagnosis(
            verdict=verdict,
            verdict_code=code,
            reasons=tuple(reasons),
            identification=result,
            changes=tuple(changes),
            quality=run.quality,
            baseline={
                "source": run.base.source,
                "parameters": {k: list(v) for k, v in run.base.values.items()},
            },
            identified_model=result.continuous_model,
            notes=(*run.notes, "maglevid has no fault model of the suspension: no isolation"),
            **run.common,
        )


def _mass_reading(changes: list[Any]) -> tuple[str, str] | None:
    """A changed ``Q`` read as the other cause it can be: the method holds the stated
    mass ``M`` and the loop's data give ``Q/M`` only (``Q = 2 M g eta^2 / alpha^2``), so
    shorted turns (``Q`` x f) and a body ``1/f`` times as heavy as stated give the same
    record. Measured (linear plant, 180 s): ``M`` x1.2 read "eta -9.0 %, Q -17.3 %", as
    ``Q`` x0.83 would (found from outside, twenty-fifth session). ``None`` where ``Q``
    did not change."""
    q = next((ch for ch in changes if ch.name == "Q" and ch.status == "changed"), None)
    if q is None or not q.change_percent > -100.0:
        return None
    heavier = 100.0 / (1.0 + q.change_percent / 100.0) - 100.0
    short = f"a body {heavier:+.1f} % heavier than stated"
    return short, (
        f"Q is read at the stated mass M (the loop's data give Q/M only): Q "
        f"{q.change_percent:+.1f} % is also the design's Q with {short}; shorted turns "
        "and a heavier body give the same record (weigh the body to tell them apart)"
    )


def _inconclusive(open_: list[Any], duration: float) -> str:
    """The verdict for changes whose interval crosses the tolerance, and the record length
    that would decide them.

    An interval decides when it lies wholly inside ``± tol`` or wholly beyond it, so
    the half-width that decides an estimate where it stands is its distance from the
    boundary, ``d = | |c| - tol |`` (the bearing's rule, ``diagnose.resolve``), not the
    tolerance (found from outside, twenty-eighth session: a 240 s healthy record at Q
    -1.5 % ± 3.9 % was told that 146 s, "0.61x this record", would bring the intervals to
    ±5 %; it needs ±3.5 %, ~300 s). On a short record an estimate lies near the boundary
    by chance and that length is huge; the length that brings every interval to
    ``± tol / 2`` is then said too: it decides a parameter that has not moved (its
    estimate within its half-width of 0 at the intervals' level). The estimate's
    variance falls as 1/length, the baseline's does not (no model-error term: the
    suspension has no fault model)."""
    words, fixed, at_edge = [], [], []
    stand: list[tuple[float, Any]] = []  # (length factor, change) deciding c where it is
    half_tol: list[float] = []  # length factors to ± tol / 2
    for ch in open_:
        b = abs(ch.baseline)
        half = 0.5 * (ch.change_ci[1] - ch.change_ci[0]) / b
        total = float(np.hypot(ch.std_error, ch.baseline_std_error)) / b
        z = half / total if total > 0 else 0.0
        words.append(f"{_word(ch.name)} {ch.change_percent:+.1f} % (±{100 * half:.2g} %)")
        f_half = _length_factor(ch, 0.5 * ch.tolerance, z)
        if f_half is not None:
            half_tol.append(f_half)
        d = abs(abs(ch.change_percent) / 100.0 - ch.tolerance)
        if d <= 0.0:
            at_edge.append(_word(ch.name))
            continue
        f = _length_factor(ch, d, z)
        if f is None:
            fixed.append(_word(ch.name))
        else:
            stand.append((f, ch))
    tol = 100 * open_[0].tolerance
    advice = []
    if stand:
        f, near = max(stand, key=lambda t: t[0])
        h = max(half_tol) if half_tol else 0.0
        if 1.0 < h < f:
            advice.append(
                f"about {h * duration:.3g} s of the same loop ({h:.2g}x this record) would "
                f"bring every interval to ±{tol / 2:.3g} %, which decides a parameter that "
                f"has not moved; the estimates as they stand would need about "
                f"{f * duration:.3g} s ({f:.2g}x: {_word(near.name)} "
                f"{near.change_percent:+.1f} % is the nearest to ±{tol:.3g} %)"
            )
        else:
            advice.append(
                f"about {f * duration:.3g} s of the same loop ({f:.2g}x this record) would "
                f"decide them, if the estimates stay where they are (each interval wholly "
                f"inside or beyond ±{tol:.3g} %)"
            )
    if fixed:
        advice.append(
            f"{', '.join(fixed)}: the baseline's own uncertainty exceeds the estimate's "
            "distance from the tolerance whatever this record's length (a longer baseline "
            "record would decide)"
        )
    if at_edge:
        advice.append(f"{', '.join(at_edge)}: estimated at the tolerance itself")
    return (
        f"Inconclusive: the record cannot tell whether these moved beyond ±{tol:.3g} %: "
        + ", ".join(words)
        + "; "
        + "; ".join(advice)
    )


def _length_factor(ch: Any, target: float, z: float) -> float | None:
    """Times this record's length that brings ``ch``'s interval half-width (relative) to
    ``target`` (``z`` its multiple of the standard error); None where the baseline's own
    share alone is wider."""
    b = abs(ch.baseline)
    room = (target / z) ** 2 - (ch.baseline_std_error / b) ** 2 if z > 0 else -1.0
    if room > 0 and ch.std_error > 0:
        return float((ch.std_error / b) ** 2 / room)
    return None


def _word(name: str) -> str:
    return {"pole_rad_s": "unstable pole"}.get(name, name)


def _label(name: str) -> str:
    return {"pole_rad_s": "unstable pole [rad/s]"}.get(name, name)


def _given(values: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """A baseline of values: names of the compared parameters (:data:`COMPARED`; ``I`` and
    ``Y_offset`` follow from ``eta`` and ``gap``), finite and positive, taken as exact."""
    checked = checked_baseline_values(
        values, COMPARED, plant="suspension", example='{"alpha": 1011, "eta": 8.45, "L": 0.872}'
    )
    return {k: (x, 0.0) for k, x in checked.items()}


STAGES = SuspensionStages()
KIND = InterSampledSuspension()
