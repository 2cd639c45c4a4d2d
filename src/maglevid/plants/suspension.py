"""The inter-sampled magnetic suspension (Sun, Miyake, Ohmori & Sano) as a plant kind.

Recognised by outputs sampled ``p > 1`` times per control period; identified by
the direct inter-sampling method, whose physical parameters are those of eq. (27)
(with a mass, and through the force balance eq. (26)). maglevid has no fault
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
    default_method = "intersample"
    method_reason = (
        "the direct inter-sampling method (Sun et al.) identifies the unstable plant "
        "from u and y alone"
    )
    methods = ("intersample", "pem", "indirect", "two-stage")
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

    def stages(self, method: str) -> AMBStages:
        return STAGES


KIND = InterSampledSuspension()
