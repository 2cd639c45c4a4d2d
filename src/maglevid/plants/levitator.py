"""The one-coil levitator (steel ball or permanent magnet under an electromagnet) as a plant kind.

Recognised by one input and outputs ``[gap]`` or ``[gap, current]`` (the UAQ
steel ball, a permanent-magnet levitator); identified by the levitator model
family (``levitator``), or by ``pem`` when the log has no coil current.

Its diagnosis (:class:`LevitatorStages`, for ``levitator`` and
``greybox-levitator``) delegates to :mod:`maglevid.diagnose.levitator`: the
levitating segments are the quality check, the unstable pole ``sqrt(2 g / (a +
y0))`` at the operating gap and the inductance law's ``a`` are compared with an
earlier identification or the published physics. maglevid has no fault model of
the levitator: a change is reported with its numbers, not attributed to a cause.
Any other method runs the shared stages (:class:`maglevid.plants.amb.AMBStages`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.diagnose import levitator as lev
from maglevid.diagnose.compare import compare_parameters
from maglevid.diagnose.diagnosis import Diagnosis, QualityCheck
from maglevid.exceptions import MaglevidError
from maglevid.plants.amb import STAGES, AMBStages
from maglevid.plants.base import BaseKind, DiagnosisRun, as_mapping, cannot_diagnose, shape_of

__all__ = ["KIND", "Levitator", "LevitatorStages"]


@dataclass
class _Compared:
    changes: list[Any]
    values: dict[str, tuple[float, float]]
    source: str
    y_ref: float


class LevitatorStages:
    """Segments, grey box, the pole and ``a`` against the baseline (see the module)."""

    drift_parameters: tuple[str, ...] = ()

    def quality(self, run: DiagnosisRun) -> tuple[QualityCheck, ...]:
        quality, segments = lev.levitator_checks(run.data)
        run.identify_options = {"segments": segments, **dict(run.method_options or {})}
        return quality

    def baseline(self, run: DiagnosisRun) -> None:
        """An earlier identification from the history (filtered once identified)."""
        stored: dict[str, Any] = {}
        if run.baseline == "history" and run.store is not None and run.machine is not None:
            try:
                stored = run.store.latest_estimates(
                    run.machine, method=run.method, before=run.when,
                    exclude_recording=run.common["recording_hash"],
                )  # fmt: skip
            except MaglevidError:
                stored = {}
        run.base = stored

    def compare(self, run: DiagnosisRun) -> Diagnosis | None:
        """The pole, ``a``, ``k``, current gain and ``i0`` against the baseline."""
        result, data = run.result, run.data
        estimates, y_ref = lev.levitator_estimates(result)
        if not np.isfinite(estimates["pole_rad_s"][0]):
            return cannot_diagnose(
                run,
                [n for n in result.notes if n.startswith("no pole")] or ["no pole identified"],
                prefix="identification gave no pole: ",
            )
        values = {k: (e.value, e.std_error or 0.0) for k, e in run.base.items() if k in estimates}
        source = "earlier identification (history)" if run.base else ""
        if not values and lev.levitator_baseline(data) is None:
            return lev.levitator_without_baseline(
                result, estimates, y_ref, run.quality, run.notes, run.common
            )
        if not values:
            values = lev.levitator_baseline_values(lev.levitator_baseline(data), y_ref)
            source = "published physics of the rig (recording metadata)"
            if run.baseline == "history":
                run.notes.append(
                    "no earlier diagnosis in the history: compared with the published physics"
                )
        changes = compare_parameters(estimates, values, tolerances=run.tolerances, level=run.level)
        run.compared = _Compared(changes, values, source, y_ref)
        return None

    def isolate(self, run: DiagnosisRun) -> Diagnosis:
        """No fault model: the verdict says what changed, with its numbers."""
        c, result = run.compared, run.result
        changes = c.changes
        sig = [ch for ch in changes if ch.significant]
        pole = next(ch for ch in changes if ch.name == "pole_rad_s")
        lo, hi = result.confidence_intervals(run.level)["pole_rad_s"]
        reasons = [
            f"unstable pole {pole.estimate:.4g} rad/s (95 % CI {lo:.4g} … {hi:.4g}) at the "
            f"operating gap {1e3 * c.y_ref:.3g} mm; baseline {pole.baseline:.4g} rad/s "
            f"({pole.change_percent:+.1f} %, {pole.status})"
        ]
        reasons += [
            f"{ch.name} = {ch.estimate:.4g} vs baseline {ch.baseline:.4g}: "
            f"{ch.change_percent:+.1f} %"
            for ch in sig
            if ch.name != "pole_rad_s"
        ]
        if sig:
            verdict = "Changed against the baseline: " + ", ".join(
                f"{ch.name} {ch.change_percent:+.1f} %" for ch in sig
            )
            code = "unexplained_change"
            run.notes.append(
                "a levitator has no fault-isolation model in maglevid yet: the change is "
                "reported with its numbers, not attributed to a cause ('a' also absorbs a "
                "gap-sensor offset)"
            )
        elif any(ch.statistically_significant for ch in changes):
            verdict, code = "Change within tolerance", "within_tolerance"
        else:
            verdict, code = "No significant change", "no_change"
        return Diagnosis(
            verdict=verdict,
            verdict_code=code,
            reasons=tuple(reasons),
            identification=result,
            changes=tuple(changes),
            quality=run.quality,
            baseline={"source": c.source, "parameters": {k: list(v) for k, v in c.values.items()}},
            identified_model=result.continuous_model,
            notes=tuple(run.notes),
            **run.common,
        )


#: The levitator's own stages.
STAGES_LEVITATOR = LevitatorStages()


class Levitator(BaseKind):
    """One coil: one input, outputs ``[gap]`` or ``[gap, current]``."""

    name = "levitator"
    description = "one-coil levitator (steel ball or permanent magnet under an electromagnet)"
    default_method = "levitator"
    method_reason = (
        "the levitator model family (force and inductance laws, flux lag) fitted as "
        "grey boxes on the levitating segments, the model chosen by multi-step "
        "prediction on held-out segments; one consensus pole whose interval covers "
        "the spread between segments and models"
    )
    methods = ("levitator", "greybox-levitator", "pem")
    #: Methods with the levitator's own diagnosis (the others run the shared stages).
    diagnosis_methods = ("levitator", "greybox-levitator")
    #: The diagnosed quantities at the operating gap (diagnose/levitator.py).
    parameters: Mapping[str, str] = MappingProxyType(
        {
            "pole_rad_s": "s⁻¹",
            "a": "m",
            "k": "H",
            "current_gain": "m·s⁻²·A⁻¹",
            "i0": "A",
        }
    )
    hypotheses: Mapping[str, str] = MappingProxyType(
        {}
    )  # no fault model of the levitator in maglevid yet
    report_panels = ("verdict", "parameters", "poles", "responses", "trends", "quality", "method")

    def recognise(self, data: ClosedLoopData) -> str | None:
        if not (data.nu == 1 and data.ny in (1, 2)):
            return None
        outputs = "[gap, current]" if data.ny == 2 else "[gap]"
        law = as_mapping(as_mapping(data.metadata).get("plant")).get("inductance_model")
        return f"one input and outputs {outputs} ({shape_of(data)}" + (
            f"; stated law {law})" if law else ")"
        )

    def choose_method(self, data: ClosedLoopData) -> tuple[str, str]:
        if data.ny == 1:
            return (
                "pem",
                "a levitator log without the coil current: direct prediction error u -> gap",
            )
        return self.default_method, self.method_reason

    def stages(self, method: str) -> LevitatorStages | AMBStages:
        return STAGES_LEVITATOR if method in self.diagnosis_methods else STAGES


KIND = Levitator()
