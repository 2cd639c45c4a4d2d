"""A generic multi-input multi-output plant (identification only) as a plant kind.

Any recording no other kind recognises (e.g. Maggy: 9 field channels, 2
inputs): a black-box subspace model of ``u -> y``. maglevid has no physical
model, parameter map or fault hypotheses for it; a diagnosis runs the shared
stages (:class:`maglevid.plants.amb.AMBStages`), which compare only what the
given baseline names and isolate nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from maglevid.data import ClosedLoopData
from maglevid.plants.amb import STAGES, AMBStages
from maglevid.plants.base import BaseKind, shape_of

__all__ = ["KIND", "GenericMIMO"]


class GenericMIMO(BaseKind):
    """Anything else: identification only."""

    name = "mimo"
    description = "generic multi-input multi-output plant"
    default_method = "n4sid"
    method_reason = (
        "no physical model of this plant in maglevid: a black-box subspace model (N4SID) of u -> y"
    )
    methods = ("n4sid", "moesp", "pbsid", "ssarx", "pem")
    parameters: Mapping[str, str] = MappingProxyType({})
    hypotheses: Mapping[str, str] = MappingProxyType({})
    report_panels = ("verdict", "poles", "responses", "quality", "method")

    def recognise(self, data: ClosedLoopData) -> str | None:
        return f"no physical model matches {shape_of(data)}"

    def stages(self, method: str) -> AMBStages:
        return STAGES


KIND = GenericMIMO()
