"""What a plant kind supplies, the registry of kinds, and one diagnosis in progress.

A kind of plant is one module of :mod:`maglevid.plants` (``amb.py``,
``suspension.py``, ``levitator.py``, ``mimo.py``) holding one object that
satisfies :class:`PlantKind`: how to recognise a recording of it, its
identification methods and default, its physical parameters with units, its
fault hypotheses and their signatures at the settled operating point, its
report panels, and the diagnosis stages (:class:`DiagnosisStages`: quality,
baseline, compare, isolate) that :func:`maglevid.diagnose.pipeline.diagnose`
runs for it. The pipeline asks the kind object and never names a kind
(docs/architecture.md, "Plant kinds").

A new kind is one new module and one :func:`register_kind` call; recognition
tries the kinds in registration order, the generic kind (``mimo``, which
recognises everything) always last.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError

if TYPE_CHECKING:
    from maglevid.diagnose.diagnosis import Diagnosis, QualityCheck

__all__ = [
    "GENERIC_KIND",
    "KINDS",
    "BaseKind",
    "DiagnosisRun",
    "DiagnosisStages",
    "PlantKind",
    "as_mapping",
    "cannot_diagnose",
    "checked_baseline_values",
    "identified_not_compared",
    "kind_of",
    "kinds_in_order",
    "moved_in_words",
    "parameter_units",
    "register_kind",
    "shape_of",
    "verdict_without_isolation",
]

#: The kind that recognises every recording: tried after all others.
GENERIC_KIND = "mimo"


@dataclass
class DiagnosisRun:
    """One diagnosis in progress: what the pipeline hands a kind's stages, and what they fill in.

    The pipeline sets the first block from the caller's arguments; the stages
    set ``quality``, ``identify_options``, ``base`` (a kind's own baseline
    record), ``result`` (the identification) and ``verdict`` inputs as they go.
    """

    data: ClosedLoopData
    method: str
    common: dict[str, Any]
    notes: list[str]
    baseline: Any
    tolerances: float | Mapping[str, float]
    level: float
    alpha: float
    store: Any = None
    machine: str | None = None
    when: Any = None
    method_options: Mapping[str, Any] | None = None
    #: The amplifiers' limit for the inconclusive verdict's plan [V rms], one for
    #: both inputs or one per input (None: the planner's default).
    max_excitation_std: float | tuple[float, ...] | None = None
    quality: tuple[QualityCheck, ...] = ()
    identify_options: dict[str, Any] = field(default_factory=dict)
    base: Any = None
    result: Any = None
    compared: Any = None


@runtime_checkable
class DiagnosisStages(Protocol):
    """A kind's diagnosis, as the pipeline's stages call it (in this order).

    Each stage returns ``None`` to go on, or a finished :class:`Diagnosis`
    (e.g. "cannot diagnose") that ends the journey before isolation; the
    identification between ``baseline`` and ``compare`` is the pipeline's
    (``identify_options`` with the method).
    """

    #: Parameters whose stored history is tested for drift after recording.
    drift_parameters: tuple[str, ...]

    def quality(self, run: DiagnosisRun) -> tuple[QualityCheck, ...]: ...

    def baseline(self, run: DiagnosisRun) -> None: ...

    def compare(self, run: DiagnosisRun) -> Diagnosis | None: ...

    def isolate(self, run: DiagnosisRun) -> Diagnosis: ...


@runtime_checkable
class PlantKind(Protocol):
    """What one kind of plant supplies (one module of :mod:`maglevid.plants` each)."""

    name: str
    description: str
    default_method: str
    method_reason: str
    #: Identification methods that suit the kind (registry names), default first.
    methods: tuple[str, ...]
    #: Physical parameters a diagnosis reports for the kind -> unit (SI).
    parameters: Mapping[str, str]
    #: Fault hypotheses -> their signature at the settled operating point, in words.
    hypotheses: Mapping[str, str]
    #: Section ids of the HTML report (``report/html.py``) that show this kind.
    report_panels: tuple[str, ...]

    def recognise(self, data: ClosedLoopData) -> str | None:
        """Why ``data`` is a recording of this kind (one phrase), or ``None``."""
        ...

    def choose_method(self, data: ClosedLoopData) -> tuple[str, str]:
        """The default method for this recording of the kind, and why."""
        ...

    def stages(self, method: str) -> DiagnosisStages:
        """The diagnosis stages for a recording of this kind identified with ``method``."""
        ...

    def signature(
        self, hypothesis: str, baseline: Any, operating_point: Any = None, *, step: float = 0.01
    ) -> dict[str, float]:
        """Relative change of each identified quantity when only ``hypothesis`` moves by
        ``step``, linearised at ``operating_point`` (the settled point)."""
        ...


class BaseKind:
    """What most kinds share: the default method whatever the recording, no fault model."""

    name: str
    default_method: str
    method_reason: str
    #: The method ``diagnose`` uses without ``--method`` when it differs from
    #: ``default_method`` (``None``: the same), why, and the diagnosis default it
    #: replaced (a machine whose history used it continues with it;
    #: :mod:`maglevid.diagnose.default_method`).
    diagnosis_method: str | None = None
    diagnosis_reason: str = ""
    former_diagnosis_method: str | None = None

    def choose_method(self, data: ClosedLoopData) -> tuple[str, str]:
        return self.default_method, self.method_reason

    def signature(
        self, hypothesis: str, baseline: Any, operating_point: Any = None, *, step: float = 0.01
    ) -> dict[str, float]:
        raise DataError(f"maglevid has no fault-isolation model of the {self.name} kind")


def cannot_diagnose(run: DiagnosisRun, reasons: list[str], *, prefix: str = "") -> Diagnosis:
    """The verdict when the data do not allow a diagnosis: say why, guess nothing."""
    from maglevid.diagnose.diagnosis import Diagnosis

    return Diagnosis(
        verdict="Cannot diagnose: " + prefix + "; ".join(reasons),
        verdict_code="cannot_diagnose",
        reasons=tuple(reasons),
        quality=run.quality,
        **run.common,
    )


KINDS: dict[str, PlantKind] = {}


def identified_not_compared(run: DiagnosisRun, reasons: list[str]) -> Diagnosis:
    """The verdict of a record with no baseline (no stated design, no history):
    identified with its intervals (``reasons``), nothing compared; stored, it is the
    next record's baseline. "Cannot diagnose", never a green "no change": as the
    bearing's (``plants.amb``, fourteenth session of issue 16); found from outside,
    twenty-eighth session: a fleet listed such a suspension "ok" and ``--fail-on-fault``
    passed it, having compared nothing."""
    from maglevid.diagnose.diagnosis import Diagnosis

    res = run.result
    stored = (
        "; stored, it is the history's first entry: later records are compared with it, "
        "so it should be one of a machine known to be healthy"
        if run.store is not None
        else ""
    )
    return Diagnosis(
        verdict=f"Cannot diagnose: no baseline (identified, not compared){stored}",
        verdict_code="cannot_diagnose",
        reasons=tuple(reasons),
        identification=res,
        quality=run.quality,
        baseline={"source": "none", "parameters": {}},
        identified_model=res.continuous_model,
        notes=(
            *run.notes,
            "record this diagnosis in a history store to compare later ones with it",
        ),
        **run.common,
    )


def checked_baseline_values(
    values: Mapping[str, Any],
    names: Sequence[str],
    *,
    plant: str,
    example: str,
    listed: Sequence[str] | None = None,
) -> dict[str, float]:
    """A baseline given as values: each a known name (``names``; ``listed`` the order the
    error lists them in, default ``names``) with a finite positive value, else the
    DataError that says which and why. A misspelt name was ignored and a NaN compared as
    "unchanged", a string raised a traceback, a negative value read as a -200 % fault
    (found from outside, issue 16, thirteenth session): each is the caller's error, said
    before any fitting. ``plant`` ("bearing") and ``example`` (JSON) word the messages."""
    if not values:
        raise DataError(
            f"the baseline names no parameters; give the {plant}'s values, e.g. {example} "
            "(maglevid diagnose --help lists the names)"
        )
    out = {}
    for k, v in values.items():
        if k not in names:
            close = difflib.get_close_matches(str(k), list(names), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise DataError(
                f"the baseline's {k!r} is not a parameter of the {plant}{hint}; known: "
                + ", ".join(names if listed is None else listed)
            )
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = float("nan")
        if not (math.isfinite(x) and x > 0.0) or isinstance(v, bool):
            raise DataError(
                f"the baseline's {k} is {v!r}: it must be a finite positive number (SI units)"
            )
        out[k] = x
    return out


def verdict_without_isolation(changes: list[Any], notes: list[str]) -> tuple[str, str]:
    """The verdict of a kind without a fault model: the significant changes with their
    numbers ("Changed against the baseline: ..."), else within tolerance, else none."""
    sig = [ch for ch in changes if ch.significant]
    if sig:
        notes.append("no fault isolation: the change is reported with its numbers only")
        return "Changed against the baseline: " + ", ".join(
            f"{ch.name} {ch.change_percent:+.1f} %" for ch in sig
        ), "unexplained_change"
    if any(ch.statistically_significant for ch in changes):
        return "Change within tolerance: " + moved_in_words(changes), "within_tolerance"
    return "No significant change", "no_change"


def moved_in_words(changes: list[Any]) -> str:
    """The statistically significant changes in words ("unstable pole +4.5 %"), or ''."""
    label = {"pole_rad_s": "unstable pole"}
    return ", ".join(
        f"{label.get(ch.name, ch.name)} {ch.change_percent:+.1f} %"
        for ch in changes
        if ch.statistically_significant
    )


def parameter_units(kind: str | None, result: Any) -> dict[str, str]:
    """SI unit of each parameter of an identification ``result`` that has one: the plant
    kind's own table (``PlantKind.parameters``), the method's (``extras["units"]``: the
    levitator's ``R``, ``ku``, ``k0``, ``v0``), else
    :func:`maglevid.physics.units.parameter_unit`. What ``maglevid identify`` prints
    and what a diagnosis stores in the history (whose levitator rows had no unit but
    ``i0``'s: found from outside, twenty-eighth session)."""
    from maglevid.physics.units import parameter_unit

    stated = getattr(KINDS.get(kind or ""), "parameters", None) or {}
    own = (getattr(result, "extras", None) or {}).get("units") or {}
    out = {}
    for k in result.parameters:
        unit = stated.get(k) or own.get(k) or parameter_unit(k)
        if unit:
            out[k] = unit
    return out


def register_kind(kind: PlantKind, *, replace: bool = False) -> PlantKind:
    """Add a kind to :data:`KINDS` (recognised before the generic kind); returns it.

    Raises :class:`DataError` when the object does not satisfy
    :class:`PlantKind` or the name is taken (unless ``replace``).
    """
    if not isinstance(kind, PlantKind):
        raise DataError(f"{kind!r} is not a plant kind (see maglevid.plants.base.PlantKind)")
    if kind.name in KINDS and not replace:
        raise DataError(f"a plant kind named {kind.name!r} is already registered")
    KINDS[kind.name] = kind
    return kind


def kinds_in_order() -> list[PlantKind]:
    """The kinds in the order recognition tries them: registration order, generic last."""
    return sorted(KINDS.values(), key=lambda k: k.name == GENERIC_KIND)


def shape_of(data: ClosedLoopData) -> str:
    """A recording's shape in words (the reasons of recognition quote it)."""
    return f"{data.ny} output(s), {data.nu} input(s), p = {data.p}"


def as_mapping(obj: Any) -> Mapping[str, Any]:
    """``obj`` when it is a mapping (a recording's loop or metadata), else ``{}``."""
    return obj if isinstance(obj, Mapping) else {}


def stated_kind(data: ClosedLoopData) -> str | None:
    """The kind the recording states (``loop["plant_kind"]``, else ``metadata["plant_kind"]``)."""
    for source in (as_mapping(data.loop), as_mapping(data.metadata)):
        kind = source.get("plant_kind")
        if kind is not None:
            if kind not in KINDS:
                raise DataError(
                    f"the recording states plant_kind {kind!r}; expected one of {', '.join(KINDS)}"
                )
            return str(kind)
    return None


def kind_of(data: ClosedLoopData) -> tuple[PlantKind, str]:
    """The recording's kind object and why (one sentence): stated, else recognised."""
    name = stated_kind(data)
    if name is not None:
        return KINDS[name], f"the recording states plant_kind = {name!r}"
    for kind in kinds_in_order():
        why = kind.recognise(data)
        if why is not None:
            return kind, why
    raise DataError(f"no plant kind recognises a recording of {shape_of(data)}")
