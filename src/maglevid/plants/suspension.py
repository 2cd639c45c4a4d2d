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
from types import MappingProxyType

from maglevid.data import ClosedLoopData
from maglevid.plants.amb import STAGES, AMBStages
from maglevid.plants.base import BaseKind, shape_of

__all__ = ["KIND", "InterSampledSuspension"]


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

    def stages(self, method: str) -> AMBStages:
        return STAGES


KIND = InterSampledSuspension()
