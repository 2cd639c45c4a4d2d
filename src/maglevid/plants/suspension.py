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
    that would bring each interval's half-width down to the tolerance (the estimate's
    variance falls as 1/length; the baseline's does not)."""
    words, factors, fixed = [], [], []
    for ch in open_:
        b = abs(ch.baseline)
        half = 0.5 * (ch.change_ci[1] - ch.change_ci[0]) / b
        total = float(np.hypot(ch.std_error, ch.baseline_std_error)) / b
        z = half / total if total > 0 else 0.0
        words.append(f"{_word(ch.name)} {ch.change_percent:+.1f} % (±{100 * half:.2g} %)")
        room = (ch.tolerance / z) ** 2 - (ch.baseline_std_error / b) ** 2 if z > 0 else -1.0
        if room > 0 and ch.std_error > 0:
            factors.append((ch.std_error / b) ** 2 / room)
        else:
            fixed.append(_word(ch.name))
    tol = 100 * open_[0].tolerance
    advice = []
    if factors:
        f = max(factors)
        advice.append(
            f"about {f * duration:.3g} s of the same loop ({f:.2g}x this record) would "
            f"bring the intervals to ±{tol:.3g} %"
        )
    if fixed:
        advice.append(
            f"{', '.join(fixed)}: the baseline's own uncertainty exceeds the tolerance "
            "whatever this record's length (a longer baseline record would decide)"
        )
    return (
        f"Inconclusive: the record cannot tell whether these moved beyond ±{tol:.3g} %: "
        + ", ".join(words)
        + "; "
        + "; ".join(advice)
    )


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
