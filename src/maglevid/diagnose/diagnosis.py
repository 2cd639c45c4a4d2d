"""The diagnosis of one recording: what the report, the history and the CLI show."""

from __future__ import annotations

import html
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from maglevid._tables import html_table, number
from maglevid.diagnose.compare import ParameterChange
from maglevid.diagnose.isolate import IsolationResult
from maglevid.identify.result import IdentificationResult
from maglevid.jsonable import to_jsonable
from maglevid.lti import StateSpace
from maglevid.physics.units import parameter_unit as _unit

__all__ = ["DIAGNOSIS_VERSION", "VERDICT_CODES", "Diagnosis", "QualityCheck"]

DIAGNOSIS_VERSION = 1

#: Verdict codes, from best to worst news.
VERDICT_CODES = (
    "no_change",  # nothing significant twice over
    "within_tolerance",  # statistically detectable, below the engineering tolerance
    "inconclusive",  # an interval straddles its tolerance: the data cannot tell
    "drift",  # no fault yet, but a parameter trends towards its tolerance (history)
    "fault",  # a change explained by one (or two) physical causes
    "unexplained_change",  # significant changes no hypothesis explains
    "cannot_diagnose",  # the data do not allow a diagnosis (quality)
)


_FRAME_COLUMNS = (
    "baseline", "estimate", "std_error", "change_percent", "ci_low_percent", "ci_high_percent",
    "tolerance_percent", "status", "unit",
)  # fmt: skip


#: The two-coil bearing's parameters, whose table header explains the free estimates.
_BEARING_NAMES = frozenset({"R1", "R2", "L1", "L2", "ki1", "ki2", "kw1", "kw2", "x0"})


def _percent_interval(c: ParameterChange) -> tuple[float, float]:
    """The change's confidence interval in % of the baseline (NaN for a zero baseline)."""
    b = c.baseline if c.baseline != 0 else float("nan")
    return 100 * c.change_ci[0] / b, 100 * c.change_ci[1] / b


@dataclass(frozen=True)
class QualityCheck:
    """One data-quality check: passed or not, the number it is based on, and why it matters."""

    name: str
    passed: bool
    value: float
    threshold: float
    message: str
    blocking: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "passed": self.passed,
            "value": to_jsonable(float(self.value)),
            "threshold": to_jsonable(float(self.threshold)),
            "message": self.message,
            "blocking": self.blocking,
        }


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """The diagnosis of one recording.

    Attributes
    ----------
    verdict : str
        Plain words, first thing a person reads ("Coil 1 resistance R1 up 19.8 % ...").
    verdict_code : str
        One of :data:`VERDICT_CODES`.
    reasons : tuple of str
        The parameters and numbers that support the verdict.
    method, method_reason : str
        Identification method used and why it was chosen.
    identification : IdentificationResult or None
        ``None`` when the quality checks stopped the diagnosis.
    changes : tuple of ParameterChange
        Every compared parameter, significant or not.
    isolation : IsolationResult or None
    quality : tuple of QualityCheck
    baseline : mapping
        ``{"source": ..., "parameters": {name: (value, se)}, "v": [...], "v_covariance": ...}``.
    baseline_model, identified_model : StateSpace or None
        Continuous models in physical coordinates (for poles, impulse and frequency responses).
    drifts : tuple of mapping
        Parameters whose history shows a significant trend (with a history
        store): ``{"parameter", "slope_percent_per_day", "p_value",
        "projected_crossing", "method", ...}``.
    resolution : tuple of mapping
        The causes whose interval straddles their tolerance, each with
        what would resolve it (:class:`maglevid.diagnose.resolve.Unresolved`
        as a dict: ``parameter``, ``more_seconds``, ``excitation_rms``, ``advice``).
    percentage_index : mapping or None
        ``{"A_p": array, "B_p": array}`` (NaN where the baseline element is zero).
    plant_kind : str or None
        The recording's plant kind; the HTML report shows its ``report_panels``.
    machine, recording, recording_hash : str or None
    dt : float or None
        Control period of the recording (for the discrete models).
    """

    verdict: str
    verdict_code: str
    reasons: tuple[str, ...] = ()
    method: str = ""
    method_reason: str = ""
    identification: IdentificationResult | None = None
    changes: tuple[ParameterChange, ...] = ()
    isolation: IsolationResult | None = None
    quality: tuple[QualityCheck, ...] = ()
    baseline: Mapping[str, Any] = field(default_factory=dict)
    baseline_model: StateSpace | None = None
    identified_model: StateSpace | None = None
    percentage_index: Mapping[str, Any] | None = None
    machine: str | None = None
    recording: str | None = None
    recording_hash: str | None = None
    dt: float | None = None
    created_at: str | None = None
    notes: tuple[str, ...] = ()
    drifts: tuple[Mapping[str, Any], ...] = ()
    resolution: tuple[Mapping[str, Any], ...] = ()
    #: The recording's plant kind (:mod:`maglevid.plants`; the report shows its panels).
    plant_kind: str | None = None

    def __post_init__(self) -> None:
        if self.verdict_code not in VERDICT_CODES:
            raise ValueError(f"verdict_code {self.verdict_code!r} not in {VERDICT_CODES}")
        for name in ("reasons", "changes", "quality", "notes", "drifts", "resolution"):
            object.__setattr__(self, name, tuple(getattr(self, name)))

    @property
    def significant_changes(self) -> tuple[ParameterChange, ...]:
        return tuple(c for c in self.changes if c.significant)

    @property
    def can_diagnose(self) -> bool:
        return self.verdict_code != "cannot_diagnose"

    def estimates(self) -> dict[str, tuple[float, float]]:
        """Identified parameters as ``{name: (value, std_error)}`` (empty if none)."""
        if self.identification is None:
            return {}
        se = self.identification.std_errors()
        return {k: (v, se[k]) for k, v in self.identification.parameters.items()}

    def summary(self) -> str:
        """A short text: verdict first, then the evidence."""
        lines = [f"VERDICT: {self.verdict}"]
        if self.machine:
            lines.append(f"machine: {self.machine}")
        if self.recording:
            lines.append(f"recording: {self.recording}")
        lines.extend(f"  - {r}" for r in self.reasons)
        if self.resolution:
            lines.append("to resolve the tolerance:")
            lines.extend(f"  - {u['advice']}" for u in self.resolution)
        if self.method:
            lines.append(f"method: {self.method} ({self.method_reason})")
        failed = [q for q in self.quality if not q.passed]
        lines.append(
            "data quality: "
            + ("all checks passed" if not failed else "; ".join(q.message for q in failed))
        )
        if self.changes:
            joint = max(c.joint_over for c in self.changes)
            bearing = any(c.name in _BEARING_NAMES for c in self.changes)
            lines.append(
                (
                    "free estimates (every parameter fitted, m and i0 at the baseline's: a "
                    "change of m scales every coil and amplifier parameter alike; the "
                    "verdict's number is the constrained fit of its cause"
                    if bearing
                    else "estimates against the baseline"
                )
                + (
                    f"{'; ' if bearing else ' ('}the intervals hold for all {joint} at "
                    "once, so a healthy machine shows none 'changed' by chance"
                    + (", the verdict's cause's on its own" if bearing else "")
                    if joint > 1
                    else ""
                )
                + ("):" if bearing or joint > 1 else ":")
            )
            lines.append(
                f"{'parameter':>10} {'baseline':>12} {'estimate':>12} {'change %':>10} "
                f"{'95% CI of change %':>22}  status"
            )
            for c in self.changes:
                lo, hi = _percent_interval(c)
                lines.append(
                    f"{c.name:>10} {c.baseline:>12.5g} {c.estimate:>12.5g} "
                    f"{c.change_percent:>+10.2f} [{lo:>+9.2f}, {hi:>+9.2f}]  {c.status}"
                )
        lines.extend(f"note: {n}" for n in self.notes)
        return "\n".join(lines)

    def __repr__(self) -> str:
        changed = ", ".join(c.name for c in self.significant_changes) or "none"
        verdict = self.verdict if len(self.verdict) <= 100 else self.verdict[:99] + "…"
        return (
            f"<Diagnosis {self.verdict_code}: {verdict!r} machine={self.machine!r} "
            f"method={self.method!r} changed=[{changed}]>"
        )

    def to_dataframe(self) -> Any:
        """Every compared parameter as a ``pandas.DataFrame`` indexed by name.

        Columns: ``baseline``, ``estimate``, ``std_error``, ``change_percent``,
        ``ci_low_percent``, ``ci_high_percent`` (the 95 % interval of the change,
        in % of the baseline), ``tolerance_percent``, ``status``, ``unit``.
        """
        import pandas as pd

        cols: dict[str, list[Any]] = {k: [] for k in _FRAME_COLUMNS}
        for c in self.changes:
            lo, hi = _percent_interval(c)
            row = (
                c.baseline,
                c.estimate,
                c.std_error,
                c.change_percent,
                lo,
                hi,
                100 * c.tolerance,
            )
            for k, v in zip(_FRAME_COLUMNS, (*row, c.status, _unit(c.name))):
                cols[k].append(v)
        return pd.DataFrame(cols, index=pd.Index([c.name for c in self.changes], name="parameter"))

    def _repr_html_(self) -> str:
        rows = []
        for c in self.changes:
            lo, hi = _percent_interval(c)
            rows.append(
                (
                    c.name,
                    _unit(c.name) or "",
                    number(c.baseline),
                    number(c.estimate),
                    f"{c.change_percent:+.2f} %",
                    f"{lo:+.2f} … {hi:+.2f} %",
                    c.status,
                )
            )
        header = ("parameter", "unit", "baseline", "estimate", "change", "95 % interval", "status")
        reasons = "".join(f"<li>{html.escape(r)}</li>" for r in self.reasons)
        return (
            f"<div><p><b>{html.escape(self.verdict_code.replace('_', ' '))}</b>: "
            f"{html.escape(self.verdict)}</p>"
            + (f"<ul>{reasons}</ul>" if reasons else "")
            + (html_table(header, rows) if rows else "")
            + f"<p>method: {html.escape(self.method)}</p></div>"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe, versioned: the same content as the report, for machines."""
        pi = None
        if self.percentage_index is not None:
            pi = {k: to_jsonable(np.asarray(v)) for k, v in self.percentage_index.items()}
        return {
            "format": "maglevid-diagnosis",
            "version": DIAGNOSIS_VERSION,
            "verdict": self.verdict,
            "verdict_code": self.verdict_code,
            "plant_kind": self.plant_kind,
            "reasons": list(self.reasons),
            "machine": self.machine,
            "recording": self.recording,
            "recording_hash": self.recording_hash,
            "created_at": self.created_at,
            "method": self.method,
            "method_reason": self.method_reason,
            "quality": [q.to_dict() for q in self.quality],
            "changes": [c.to_dict() for c in self.changes],
            "isolation": None if self.isolation is None else self.isolation.to_dict(),
            "baseline": to_jsonable(dict(self.baseline)),
            "identification": None
            if self.identification is None
            else self.identification.to_dict(),
            "baseline_model": None
            if self.baseline_model is None
            else self.baseline_model.to_dict(),
            "identified_model": None
            if self.identified_model is None
            else self.identified_model.to_dict(),
            "percentage_index": pi,
            "dt": self.dt,
            "notes": list(self.notes),
            "drifts": [to_jsonable(dict(d)) for d in self.drifts],
            "resolution": [to_jsonable(dict(u)) for u in self.resolution],
        }
