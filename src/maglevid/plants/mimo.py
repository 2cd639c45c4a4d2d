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
from maglevid.exceptions import DataError
from maglevid.plants.amb import AMBStages
from maglevid.plants.base import BaseKind, DiagnosisRun, shape_of

__all__ = ["KIND", "GenericMIMO"]


class _MimoStages(AMBStages):
    """The shared stages, with a baseline error that speaks of this kind: a Maggy log
    (9 field channels, 2 inputs) given to ``diagnose`` was told that "baseline='nominal'
    needs the design parameters in the recording (loop['nominal'])", the bearing's
    wording, where there is no nominal physics to give (found from outside,
    twenty-seventh session)."""

    #: A generic record has none of the bearing's parameters to drift-test.
    drift_parameters: tuple[str, ...] = ()

    def baseline(self, run: DiagnosisRun) -> None:
        loop = run.data.loop if isinstance(run.data.loop, Mapping) else {}
        if run.baseline == "nominal" and loop.get("nominal") is None:
            raise DataError(
                f"no nominal baseline for this recording ({shape_of(run.data)}): maglevid "
                "has no physical model of a generic multi-input multi-output plant, so "
                "there is nothing to diagnose it against; `maglevid identify` (identify() "
                "in Python) gives its black-box model (N4SID) and says whether this "
                "record can give the plant at all"
            )
        super().baseline(run)


_STAGES = _MimoStages()


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
        return _STAGES


KIND = GenericMIMO()
