"""The fleet summary: which machines changed and why, which drift, what could not be diagnosed.

Built after a run from the outcomes of its recordings and the history store:

* a machine's **state** is its latest diagnosis by recording time, whether
  made in this run or found in the store (an older recording diagnosed today
  does not hide a newer one diagnosed last week);
* **drift** is tested once per machine and parameter over the machine's whole
  stored history (:func:`machine_drifts`), one test per identification method
  (methods have different biases: mixed, they would fake a trend), with a
  Bonferroni split of ``alpha`` over the machine's tests so that ``alpha`` is
  the false-alarm probability per machine, not per parameter;
* **problems** are the recordings of this run that have no usable diagnosis:
  unreadable or missing files, quality failures, exceptions, lost workers.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import numpy as np

from maglevid.fleet.trends import MIN_DRIFT_POINTS, diagnosed_parameters, iso_time
from maglevid.fleet.worker import UNREADABLE_METHOD, RecordingOutcome

__all__ = [
    "CHANGED_VERDICTS",
    "SUMMARY_VERSION",
    "FleetSummary",
    "MachineSummary",
    "machine_drifts",
    "machines_drifts",
    "summarize_fleet",
]

logger = logging.getLogger(__name__)

SUMMARY_VERSION = 1

#: Verdicts that make a machine "changed".
CHANGED_VERDICTS: tuple[str, ...] = ("fault", "unexplained_change")

_DAY = 86400.0
#: Seconds since 1970 of 0001-01-02 and 9999-12-30: what a datetime can show.
_MIN_TIME, _MAX_TIME = -62135510400.0, 253402128000.0


def _num(x: Any) -> Any:
    if x is None:
        return None
    x = float(x)
    if math.isnan(x):
        return None
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x


def _tolerance(tolerances: Any, parameter: str) -> float:
    from maglevid.diagnose.compare import DEFAULT_TOLERANCE

    if tolerances is None:
        return DEFAULT_TOLERANCE
    if isinstance(tolerances, Mapping):
        return float(tolerances.get(parameter, DEFAULT_TOLERANCE))
    return float(tolerances)


def machine_drifts(
    store: Any,
    machine: str,
    *,
    alpha: float = 0.01,
    tolerances: float | Mapping[str, float] | None = None,
    parameters: Sequence[str] | None = None,
    min_points: int = MIN_DRIFT_POINTS,
) -> list[dict[str, Any]]:
    """Drift tests of one machine's parameters over its stored history.

    One weighted least-squares t-test on the slope
    (:func:`~maglevid.diagnose.drift.detect_drift`, method ``"wls"``) per
    parameter and identification method with at least ``min_points`` points
    that have a standard error; each at level ``alpha / k`` (Bonferroni, ``k``
    the number of tests made for the machine), so that the probability of any
    false drift alarm for a drift-free machine is at most ``alpha``.

    Parameters
    ----------
    store : HistoryStore
    machine : str
    alpha : float
        Family-wise false-alarm probability for the machine.
    tolerances : float or mapping, optional
        Relative band half-width per parameter around its latest stored
        baseline (default 5 %); the test projects when the trend leaves it.
    parameters : sequence of str, optional
        Default: the pipeline's ``DIAGNOSED_PARAMETERS``.
    min_points : int

    Returns
    -------
    list of dict
        Per test: ``parameter``, ``method``, ``n``, ``drifting``, ``alpha`` (the
        per-test level), ``p_value``, ``slope_per_day`` (value units),
        ``slope_percent_per_day`` (of the baseline), ``baseline``,
        ``tolerance_percent``, ``projected_crossing`` (ISO date or ``None``),
        ``first``, ``last`` (ISO times), ``notes``.
    """
    from maglevid.diagnose.drift import STEP_SHARE, detect_drift, detect_step
    from maglevid.diagnose.history import NotFoundError
    from maglevid.exceptions import DataError

    names = tuple(parameters) if parameters is not None else diagnosed_parameters()
    try:
        table = store.estimates_table(machine, parameters=list(names))
    except NotFoundError:
        return []
    groups: dict[tuple[str, str], np.ndarray] = {}
    method = table["method"]
    param = table["parameter"]
    for key in dict.fromkeys(zip(param.tolist(), method.tolist())):
        if key[1] == UNREADABLE_METHOD:
            continue
        rows = (param == key[0]) & (method == key[1])
        rows &= np.isfinite(table["value"]) & (np.nan_to_num(table["std_error"], nan=0.0) > 0)
        if int(rows.sum()) >= min_points and np.ptp(table["time"][rows]) > 0:
            groups[key] = rows
    if not groups:
        return []
    level = alpha / len(groups)
    out = []
    for (name, meth), rows in groups.items():
        t = table["time"][rows]
        y = table["value"][rows]
        se = table["std_error"][rows]
        base = table["baseline"][rows]
        base = base[np.isfinite(base)]
        baseline = float(base[-1]) if base.size else float(y[np.argmin(t)])
        tol = _tolerance(tolerances, name)
        t0 = float(t.min())
        try:
            r = detect_drift(
                (t - t0) / _DAY,
                y,
                se,
                alpha=level,
                tolerance=tol * abs(baseline) if baseline != 0 else None,
                baseline=baseline if baseline != 0 else None,
            )
        except DataError as exc:
            out.append({"parameter": name, "method": meth, "skipped": str(exc)})
            continue
        crossing = None
        notes = list(r.notes)
        # A step (change-point test) at a tenth of the level: see diagnose.pipeline.
        step = detect_step((t - t0) / _DAY, y, se, alpha=level / STEP_SHARE)
        if step.is_step:  # a dated step, not a trend: nothing to project
            ts = np.sort(t)
            notes.append(
                f"a step of {100 * step.size / baseline if baseline else float('nan'):+.3g} % "
                f"between {iso_time(float(ts[step.index - 1]))[:10]} and "
                f"{iso_time(float(ts[step.index]))[:10]} "
                f"(change-point test p = {step.p_value:.2g})"
            )
        elif r.projected_crossing_time is not None and math.isfinite(r.projected_crossing_time):
            when = t0 + r.projected_crossing_time * _DAY
            if when <= float(t.max()):  # never project a crossing already past
                notes.append("the fitted trend is already beyond the tolerance")
            elif _MIN_TIME <= when <= _MAX_TIME:
                crossing = iso_time(when)
            else:  # a nearly flat trend meets its limit beyond any calendar
                notes.append("the projected crossing is beyond the years 1-9999")
        out.append(
            {
                "parameter": name,
                "method": meth,
                "n": r.n,
                "alpha": level,
                "p_value": _num(r.p_value),
                "slope_per_day": _num(r.slope),
                "slope_percent_per_day": _num(100.0 * r.slope / baseline) if baseline else None,
                "baseline": baseline,
                "tolerance_percent": 100.0 * tol,
                "projected_crossing": crossing,
                "kind": "step" if step.is_step else "drift",
                "drifting": r.drifting or step.is_step,
                "first": iso_time(t0),
                "last": iso_time(float(t.max())),
                "notes": notes,
            }
        )
    return out


def machines_drifts(
    machines: Sequence[str],
    store: str,
    schema: str | None,
    *,
    alpha: float,
    tolerances: Mapping[str, Any],
) -> dict[str, list[dict[str, Any]]]:
    """:func:`machine_drifts` of several machines, with the worker's store connection.

    A Dask task of the summary: one store query and ~13 small fits per machine
    (about 14 ms on the benchmark machine) add up for thousands of machines, so
    the runner spreads them over the workers.
    """
    from maglevid.fleet.worker import _store

    st = _store(store, schema)
    return {m: machine_drifts(st, m, alpha=alpha, tolerances=tolerances.get(m)) for m in machines}


@dataclass(frozen=True)
class MachineSummary:
    """One machine in the fleet summary.

    Attributes
    ----------
    name : str
    n_recordings : int
        Recordings of this machine named in the run.
    counts : mapping
        Outcome status -> number of this run's recordings.
    latest : mapping or None
        The latest usable diagnosis (by recording time, this run or earlier):
        ``recording``, ``recorded_at``, ``verdict_code``, ``verdict``, ``cause``,
        ``changes``, ``reasons``, ``in_this_run``.
    drifts : tuple of mapping
        Every drift test made (see :func:`machine_drifts`).
    problems : tuple of mapping
        This run's recordings without a usable diagnosis: ``recording``,
        ``status``, ``reason``.
    report : str or None
        The HTML report written for the machine.
    """

    name: str
    n_recordings: int
    counts: Mapping[str, int]
    latest: Mapping[str, Any] | None
    drifts: tuple[Mapping[str, Any], ...] = ()
    problems: tuple[Mapping[str, Any], ...] = ()
    report: str | None = None

    @property
    def changed(self) -> bool:
        return self.latest is not None and self.latest.get("verdict_code") in CHANGED_VERDICTS

    @property
    def drifting(self) -> tuple[Mapping[str, Any], ...]:
        return tuple(d for d in self.drifts if d.get("drifting"))

    @property
    def inconclusive(self) -> bool:
        """The latest diagnosis could not resolve the tolerance (never shown as ok)."""
        return self.latest is not None and self.latest.get("verdict_code") == "inconclusive"

    @property
    def state(self) -> str:
        """``changed``, ``drifting``, ``inconclusive``, ``ok``, or ``undiagnosed``."""
        if self.changed:
            return "changed"
        if self.drifting:
            return "drifting"
        if self.latest is None:
            return "undiagnosed"
        if self.inconclusive:
            return "inconclusive"
        return "ok"

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "state": self.state,
            "n_recordings": self.n_recordings,
            "counts": dict(self.counts),
            "latest": None if self.latest is None else dict(self.latest),
            "drifting": [d["parameter"] + f" ({d['method']})" for d in self.drifting],
            "drifts": [dict(d) for d in self.drifts],
            "problems": [dict(p) for p in self.problems],
            "report": self.report,
        }


@dataclass(frozen=True)
class FleetSummary:
    """The result of :func:`maglevid.fleet.run_fleet`.

    ``to_dict()`` is JSON-safe and versioned (``"format": "maglevid-fleet-summary"``);
    :func:`maglevid.report.fleet.write_fleet_summary` renders it as HTML.
    """

    store: str
    machines: tuple[MachineSummary, ...]
    outcomes: tuple[RecordingOutcome, ...]
    run: Mapping[str, Any] = field(default_factory=dict)

    @property
    def counts(self) -> dict[str, int]:
        """Outcome status -> number of recordings."""
        return dict(Counter(o.status for o in self.outcomes))

    @property
    def verdicts(self) -> dict[str, int]:
        """Verdict code -> number of recordings with a diagnosis."""
        return dict(Counter(o.verdict_code for o in self.outcomes if o.verdict_code))

    @property
    def changed(self) -> tuple[MachineSummary, ...]:
        return tuple(m for m in self.machines if m.changed)

    @property
    def drifting(self) -> tuple[MachineSummary, ...]:
        return tuple(m for m in self.machines if m.drifting)

    @property
    def inconclusive(self) -> tuple[MachineSummary, ...]:
        return tuple(m for m in self.machines if m.state == "inconclusive")

    @property
    def problems(self) -> tuple[RecordingOutcome, ...]:
        return tuple(o for o in self.outcomes if o.problem is not None)

    def machine(self, name: str) -> MachineSummary:
        for m in self.machines:
            if m.name == name:
                return m
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": "maglevid-fleet-summary",
            "version": SUMMARY_VERSION,
            "store": self.store,
            "run": dict(self.run),
            "counts": self.counts,
            "verdicts": self.verdicts,
            "changed": [m.name for m in self.changed],
            "drifting": [m.name for m in self.drifting],
            "inconclusive": [m.name for m in self.inconclusive],
            "n_problems": len(self.problems),
            "machines": [m.to_dict() for m in self.machines],
            "recordings": [o.to_dict() for o in self.outcomes],
        }


def _latest_from_record(rec: Any) -> dict[str, Any]:
    s = rec.summary
    changes = [
        {
            "parameter": c.get("name"),
            "change_percent": c.get("change_percent"),
            "status": c.get("status"),
        }
        for c in (s.get("changes") or [])
        if c.get("significant")
    ]
    iso = s.get("isolation") or {}
    cause = None
    if iso.get("explained") and (iso.get("best") or {}).get("parameters"):
        cause = iso["best"].get("description")
    return {
        "recording": rec.recording_path,
        "recorded_at": rec.recorded_at.isoformat(),
        "verdict_code": rec.verdict_code,
        "verdict": rec.verdict,
        "cause": cause,
        "changes": changes,
        "reasons": list(s.get("reasons") or []),
        "method": rec.method,
        "in_this_run": False,
    }


def _latest_from_outcome(o: RecordingOutcome) -> dict[str, Any]:
    return {
        "recording": o.recording,
        "recorded_at": o.recorded_at,
        "verdict_code": o.verdict_code,
        "verdict": o.verdict,
        "cause": o.cause,
        "changes": [dict(c) for c in o.changes],
        "reasons": list(o.reasons),
        "method": o.method,
        "in_this_run": True,
    }


def _usable(code: str | None) -> bool:
    return code is not None and code != "cannot_diagnose"


def _when(text: str | None) -> datetime:
    if not text:
        return datetime.min.replace(tzinfo=timezone.utc)
    return datetime.fromisoformat(text)


def summarize_fleet(
    outcomes: Iterable[RecordingOutcome],
    store: Any,
    *,
    earlier: Mapping[str, Sequence[Any]] | None = None,
    tolerances: Mapping[str, Any] | None = None,
    alpha: float = 0.01,
    drifts: Mapping[str, Sequence[Mapping[str, Any]]] | None = None,
    run: Mapping[str, Any] | None = None,
) -> FleetSummary:
    """The fleet summary of a run's ``outcomes`` and the store's history.

    Parameters
    ----------
    outcomes : iterable of RecordingOutcome
        One per job of the run.
    store : HistoryStore
        Open store (read after the run: the drift tests see this run's diagnoses).
    earlier : mapping, optional
        Machine -> the :class:`~maglevid.diagnose.history.DiagnosisRecord` list
        the store held before the run (for the latest state of each machine).
    tolerances : mapping, optional
        Machine -> its tolerances (for the drift tests' crossing projection).
    alpha : float
        Family-wise drift false-alarm probability per machine.
    drifts : mapping, optional
        Machine -> its drift tests, when computed elsewhere (the runner computes
        them on the workers); default: computed here with ``store``.
    run : mapping, optional
        Facts about the run (workers, times, batch size) kept in the summary.
    """
    outcomes = tuple(outcomes)
    earlier = earlier or {}
    tolerances = tolerances or {}
    by_machine: dict[str, list[RecordingOutcome]] = {}
    for o in outcomes:
        by_machine.setdefault(o.machine, []).append(o)
    machines = []
    for name in sorted(by_machine):
        outs = by_machine[name]
        candidates = [
            _latest_from_record(r)
            for r in earlier.get(name, ())
            if r.method != UNREADABLE_METHOD and _usable(r.verdict_code)
        ]
        candidates += [
            _latest_from_outcome(o)
            for o in outs
            if o.status == "diagnosed" and _usable(o.verdict_code)
        ]
        latest = max(candidates, key=lambda c: _when(c["recorded_at"]), default=None)
        problems = tuple(
            {"recording": o.recording, "status": o.status, "reason": o.problem}
            for o in outs
            if o.problem is not None
        )
        reports = [o.report for o in outs if o.report]
        machines.append(
            MachineSummary(
                name=name,
                n_recordings=len(outs),
                counts=dict(Counter(o.status for o in outs)),
                latest=latest,
                drifts=tuple(
                    drifts[name]
                    if drifts is not None and name in drifts
                    else machine_drifts(store, name, alpha=alpha, tolerances=tolerances.get(name))
                ),
                problems=problems,
                report=reports[-1] if reports else None,
            )
        )
    return FleetSummary(
        store=str(getattr(store, "location", store)),
        machines=tuple(machines),
        outcomes=outcomes,
        run=dict(run or {}),
    )
