"""From a bearing's recording to a diagnosis a person can act on.

:func:`diagnose` runs the same stages for every kind of plant; the recording's
kind (:func:`maglevid.plants.kind_of`, one module of :mod:`maglevid.plants` per
kind) supplies what each stage does for it, and this module never names a kind:

1. **quality**: the kind's data-quality checks; a failed blocking check gives
   "cannot diagnose, because ..." instead of a wrong answer;
2. **identify**: the method (the kind's default for this recording, or the
   caller's) fitted to the recording, after the kind has resolved the baseline;
3. **compare**: the kind's diagnosed parameters against the baseline,
   significant twice over (:mod:`maglevid.diagnose.compare`);
4. **isolate**: the kind's fault hypotheses at the settled operating point
   (:mod:`maglevid.diagnose.isolate` for the AMB) and the verdict;
5. **record**: with a history store, storing this diagnosis (idempotent on the
   recording's content hash) and the drift test over the machine's earlier
   diagnoses (:mod:`maglevid.diagnose.drift`) of the kind's drift parameters;
6. **report**: above this layer (:mod:`maglevid.report.html`), the panels the
   kind names in ``report_panels``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import replace
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.diagnose.compare import DEFAULT_TOLERANCE
from maglevid.diagnose.diagnosis import Diagnosis
from maglevid.exceptions import DataError, MaglevidError
from maglevid.jsonable import to_json_nulls
from maglevid.plants import DIAGNOSED_PARAMETERS, DiagnosisRun, DiagnosisStages, kind_of
from maglevid.plants.base import cannot_diagnose, parameter_units

if TYPE_CHECKING:  # the annotation of `baseline` (what a two-coil AMB's stages accept)
    from maglevid.physics.amb import AMBParameters

__all__ = ["DIAGNOSED_PARAMETERS", "choose_method", "diagnose", "recording_hash"]

logger = logging.getLogger(__name__)


def recording_hash(data: ClosedLoopData) -> str:
    """SHA-256 of a recording's signals and description (the history's idempotency key)."""
    h = hashlib.sha256()
    for sig in ("y", "u", "r", "u_f"):
        a = data.y if sig == "y" else getattr(data, sig)
        h.update(sig.encode())
        if a is not None:
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    desc = data.to_dict()
    desc["metadata"] = {k: v for k, v in desc["metadata"].items() if k not in ("source",)}
    h.update(json.dumps(desc, sort_keys=True, default=str).encode())
    return h.hexdigest()


def choose_method(
    data: ClosedLoopData, *, history: Any = None, machine: str | None = None
) -> tuple[str, str]:
    """The method :func:`diagnose` uses for this recording without a stated one, and why:
    the plant kind's, ``ml`` for a two-coil bearing, or the method a machine's history
    in ``history`` continues with (:mod:`maglevid.diagnose.default_method`)."""
    from maglevid.diagnose.default_method import choose_diagnosis_method

    return choose_diagnosis_method(data, history=history, machine=machine)[:2]


def _read(recording: Any, mapping: Any) -> tuple[ClosedLoopData, str | None]:
    """The recording and where it came from (a path, or the recording's ``source``)."""
    if isinstance(recording, ClosedLoopData):
        meta = recording.metadata
        return recording, meta.get("source") if hasattr(meta, "get") else None
    from maglevid.io import read_recording

    return read_recording(recording, mapping=mapping), str(recording)


def _open_store(history: Any) -> Any:
    """A history store from a store, a path or URL, or ``None``."""
    if isinstance(history, (str, os.PathLike)):
        from maglevid.diagnose.history import open_history

        return open_history(history)
    return history


def _amplifier_limit(limit: Any) -> float | tuple[float, ...] | None:
    """``max_excitation_std`` checked at the boundary (one or two positive volts)."""
    if limit is None:
        return None
    from maglevid.identify.planning import amplifier_limits

    a1, a2 = amplifier_limits(limit)
    return a1 if np.ndim(limit) == 0 else (a1, a2)


def _start(
    data: ClosedLoopData,
    source: str | None,
    method: str | None,
    *,
    machine: str | None,
    history: Any,
    recorded_at: Any,
    **run_args: Any,
) -> tuple[DiagnosisRun, DiagnosisStages]:
    """The diagnosis in progress, and the stages its plant kind runs for its method."""
    meta = data.metadata if hasattr(data.metadata, "get") else {}
    store = _open_store(history)
    from maglevid.diagnose.default_method import choose_diagnosis_method

    machine = machine or meta.get("machine")
    chosen, why, note = choose_diagnosis_method(data, history=store, machine=machine)
    if method is not None and method != chosen:
        why, note = "chosen by the user", None
    method = method or chosen
    kind = kind_of(data)[0]
    common = {
        "plant_kind": kind.name,
        "machine": machine,
        "recording": source,
        "recording_hash": recording_hash(data),
        "dt": data.dt,
        "created_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "method": method,
        "method_reason": why,
    }
    run = DiagnosisRun(
        data=data,
        method=method,
        common=common,
        notes=[note] if note else [],
        store=store,
        machine=common["machine"],
        when=recorded_at or meta.get("recorded_at") or datetime.now(timezone.utc),
        **run_args,
    )
    return run, kind.stages(method)


def _quality(run: DiagnosisRun, stages: DiagnosisStages) -> Diagnosis | None:
    """Stage 1: the kind resolves the baseline (a bad one is the caller's error, raised
    before anything else: a record that also fails its checks must not hide it), then
    the kind's data-quality checks; a failed blocking one ends the diagnosis."""
    stages.baseline(run)
    run.quality = stages.quality(run)
    failed = [q for q in run.quality if not q.passed and q.blocking]
    return cannot_diagnose(run, [q.message for q in failed]) if failed else None


def _identify(run: DiagnosisRun, stages: DiagnosisStages) -> Diagnosis | None:
    """Stage 2: the method identifies the plant."""
    from maglevid.identify.registry import get_method

    try:
        run.result = get_method(run.method)(run.data, **run.identify_options)
    except MaglevidError as exc:
        return cannot_diagnose(run, [str(exc)], prefix="identification failed: ")
    run.notes.extend(run.result.notes)
    if (getattr(run.result, "extras", None) or {}).get("converged") is False:
        # not an optimum: its intervals promise nothing, and a verdict read off them
        # named every parameter changed on a healthy bearing (a user's .mat whose IV
        # start was far off; docs/diagnosis.md)
        it = run.result.extras.get("iterations")  # (a fit that says it did not converge)
        why = (
            f"the {run.method} fit did not converge"
            + (f" ({it} iterations)" if it is not None else "")
            + ": its estimates are not an optimum and their intervals mean nothing; try "
            "method 'pbsid' (closed-loop subspace, needs no controller), a longer record "
            "or more excitation"
        )
        return cannot_diagnose(run, [why], prefix="identification failed: ")
    return None


def _compare(run: DiagnosisRun, stages: DiagnosisStages) -> Diagnosis | None:
    """Stage 3: the kind's parameters against the baseline (or a diagnosis that ends here)."""
    return stages.compare(run)


def _isolate(run: DiagnosisRun, stages: DiagnosisStages) -> Diagnosis:
    """Stage 4: the kind's fault hypotheses and the verdict."""
    return stages.isolate(run)


def _with_drifts(
    store: Any,
    diag: Diagnosis,
    tolerances: float | Mapping[str, float],
    alpha: float,
    parameters: tuple[str, ...],
    when: Any = None,
) -> Diagnosis:
    """Stage 5, after storing: the machine's history up to this recording (``when``)
    tested for drift and steps."""
    drifts = _drifts(store, diag, tolerances, alpha, parameters, when)
    if not drifts:
        return diag
    words = "; ".join(_drift_words(d) for d in drifts)
    extra: dict[str, Any] = {
        "drifts": tuple(drifts),
        "reasons": (*diag.reasons, f"over the history: {words}"),
    }
    if diag.verdict_code in ("no_change", "within_tolerance", "inconclusive"):
        trend = "drifting" if any(d["kind"] == "drift" for d in drifts) else "a step"
        extra["verdict"] = f"No fault yet, but {trend}: {words}"
        if diag.verdict_code != "no_change":
            # Keep the isolated cause: the trend may show first in a parameter the
            # cause moves through the operating point (x0 for a heating coil). An
            # interval across the tolerance (inconclusive) must not hide the trend's
            # alarm: the demo's heating coil, R1 +9.6 % ± 0.7 % against 10 %, was
            # "Inconclusive" instead of "drifting" (its advice stays in the text).
            extra["verdict"] += f". {diag.verdict}"
        extra["verdict_code"] = "drift"
    return replace(diag, **extra)


def diagnose(
    recording: ClosedLoopData | str | os.PathLike[str],
    *,
    baseline: str | AMBParameters | Mapping[str, float] = "nominal",
    machine: str | None = None,
    method: str | None = None,
    tolerances: float | Mapping[str, float] | None = None,
    history: Any = None,
    recorded_at: datetime | str | None = None,
    method_options: Mapping[str, Any] | None = None,
    mapping: Any = None,
    alpha: float = 0.01,
    level: float = 0.95,
    drift: bool = True,
    max_excitation_std: float | Sequence[float] | None = None,
) -> Diagnosis:
    """Diagnose one recording of a bearing against a baseline.

    The recording's plant kind (:func:`maglevid.plants.kind_of`) decides what each
    stage does; the stages are the same for every kind (the module's list).

    Parameters
    ----------
    recording : ClosedLoopData or path
        The recording (any format :func:`maglevid.io.read_recording` reads).
    baseline : "nominal", "history", AMBParameters or mapping
        ``"nominal"``: the design parameters stored in the recording's loop
        (``loop["nominal"]``); ``"history"``: the machine's latest identification
        in ``history`` (falls back to the design for the first diagnosis); or
        explicit parameters. A levitator compares with its published physics
        (``metadata["plant"]``) unless ``"history"`` finds an earlier diagnosis.
    machine : str, optional
        Machine name (needed with a history store; default: the recording's
        ``metadata["machine"]``).
    method : str, optional
        Identification method; default chosen by :func:`choose_method`: ``"ml"``
        for a two-coil bearing (unless the machine's history in ``history``
        continues with ``"physical"``, said in a note), the plant kind's otherwise.
    tolerances : float or mapping, optional
        Relative engineering tolerance per parameter (default 5 %).
    history : HistoryStore or str, optional
        Store (or its path/URL) to read the baseline and trends from and to
        record this diagnosis in.
    recorded_at : datetime or ISO string, optional
        When the recording was taken (default: ``metadata["recorded_at"]``, else now).
    method_options : mapping, optional
        Options passed to the identification method.
    mapping : optional
        Column mapping for reading a user's own log.
    alpha : float
        Significance level of the isolation and drift tests.
    level : float
        Confidence level of the intervals.
    drift : bool
        Test the machine's stored history for drift after recording (default).
        A fleet run tests drift once per machine at the end instead.
    max_excitation_std : float or (float, float), optional
        The amplifiers' limit [V rms], one for both inputs or one per input, that
        the plan of an inconclusive verdict keeps to (default: the planner's,
        :data:`maglevid.identify.planning.DEFAULT_MAX_EXCITATION_STD`).

    Returns
    -------
    Diagnosis
    """
    data, source = _read(recording, mapping)
    tol: float | Mapping[str, float] = DEFAULT_TOLERANCE if tolerances is None else tolerances
    run, stages = _start(
        data, source, method, machine=machine, history=history, recorded_at=recorded_at,
        baseline=baseline, tolerances=tol, level=level, alpha=alpha,
        method_options=method_options, max_excitation_std=_amplifier_limit(max_excitation_std),
    )  # fmt: skip
    diag = _quality(run, stages) or _identify(run, stages) or _compare(run, stages)
    verdict_reached = diag is None
    if diag is None:
        diag = _isolate(run, stages)
    diag = _record(run.store, diag, data, run.when, method_options, run.notes)
    if verdict_reached and run.store is not None and drift and stages.drift_parameters:
        diag = _with_drifts(run.store, diag, tol, alpha, stages.drift_parameters, run.when)
    return diag


def _record(
    store: Any,
    diag: Diagnosis,
    data: ClosedLoopData,
    when: Any,
    method_options: Mapping[str, Any] | None,
    notes: list[str],
) -> Diagnosis:
    """Store ``diag``; the returned Diagnosis says when it was already stored (idempotent)."""
    if store is None:
        return diag
    if diag.machine is None:
        raise DataError(
            "storing a diagnosis needs a machine name (`machine=` or metadata['machine'])"
        )
    from maglevid.diagnose.history import hash_options

    estimates: dict[str, Any] = {}
    base = diag.baseline.get("parameters", {}) if diag.baseline else {}
    if diag.identification is not None:
        cis = diag.identification.confidence_intervals()
        units = parameter_units(diag.plant_kind, diag.identification)
        for k, (v, se) in diag.estimates().items():
            if not np.isfinite(v):
                continue
            b = base.get(k)
            estimates[k] = (
                v,
                se if np.isfinite(se) else None,
                cis[k][0] if np.isfinite(cis[k][0]) else None,
                cis[k][1] if np.isfinite(cis[k][1]) else None,
                units.get(k),
                None if b is None else float(b[0]),
            )
    summary = diag.to_dict()
    summary.pop("identification", None)
    options = dict(method_options or {})
    stored = store.record_diagnosis(
        diag.machine,
        recording_hash=diag.recording_hash,
        recorded_at=when,
        method=diag.method,
        verdict=diag.verdict,
        verdict_code=diag.verdict_code,
        estimates=estimates,
        summary=to_json_nulls(json.loads(json.dumps(summary, default=str))),
        options=options,
        options_hash=hash_options(options),
        recording_path=diag.recording,
        dt=data.dt,
        n_samples=data.n_samples,
    )
    logger.info("stored diagnosis of %s (%s)", diag.machine, diag.verdict_code)
    if stored.created:
        return diag
    note = (
        f"already stored: this recording was diagnosed with {diag.method} and these options "
        f"before (diagnosis {stored.id} in the store); nothing was written"
    )
    return replace(diag, notes=(*diag.notes, note))


#: Fewest diagnoses in a machine's history before a drift test is made.
MIN_DRIFT_POINTS = 4


def _iso_day(seconds: float) -> str | None:
    """An ISO timestamp (UTC) from seconds since 1970; ``None`` beyond the calendar."""
    try:
        return datetime.fromtimestamp(float(seconds), tz=timezone.utc).isoformat(
            timespec="seconds"
        )
    except (OverflowError, ValueError, OSError):  # a near-flat trend: far beyond 9999
        return None


def _drift_words(d: Mapping[str, Any]) -> str:
    """One history finding in words: a dated step, or a drift and where it heads."""
    if d.get("kind") == "step":
        return (
            f"{d['parameter']} stepped {d['step_percent']:+.3g} % between "
            f"{(d['step_after'] or '?')[:10]} and {(d['step_before'] or '?')[:10]} "
            f"(change-point test p = {d['p_value']:.2g})"
        )
    head = f"{d['parameter']} {d['slope_percent_per_day']:+.2g} %/day (p = {d['p_value']:.2g}"
    if d.get("already_beyond"):
        return head + f", the trend is already beyond ±{d['tolerance_percent']:.0f} %)"
    if d.get("projected_crossing"):
        return (
            head + f", projected to leave ±{d['tolerance_percent']:.0f} % "
            f"on {d['projected_crossing'][:10]})"
        )
    return head + ")"


def _drifts(
    store: Any,
    diag: Diagnosis,
    tolerances: float | Mapping[str, float],
    alpha: float,
    parameters: tuple[str, ...] = DIAGNOSED_PARAMETERS,
    when: Any = None,
) -> list[dict[str, Any]]:
    """Trend test on each diagnosed parameter of the machine's stored history, up to and
    including the recording diagnosed (``when``; a trend, like a baseline, never comes
    from the future: a second `make demo` into the same folder alarmed on day 0 from the
    first run's later records, found from outside, twentieth session).

    ``parameters``: the plant kind's drift parameters (default the two-coil
    AMB's 13). ``alpha`` is the family-wise level over the parameters: each of the
    ``len(parameters)`` tests runs at ``alpha / len(...)`` (Bonferroni),
    so a healthy machine raises a false drift alarm with probability <= alpha
    per diagnosis rather than ~13 alpha; the step test adds at most alpha / 10.
    Each diagnosis re-tests the growing history; the slope's scale is floored at the
    stated standard errors (``scale_floor``), which keeps a healthy machine's false
    drift alarms over 12 looks within alpha (docs/history.md, repeated looks).
    """
    from maglevid.diagnose.drift import STEP_SHARE, detect_drift, detect_step
    from maglevid.diagnose.history import _as_utc

    alpha_each = alpha / len(parameters)
    until = None if when is None else _as_utc("recorded_at", when).timestamp()
    model_error = {c.name: c.model_error for c in diag.changes}
    out = []
    base = diag.baseline.get("parameters", {}) if diag.baseline else {}
    for k in parameters:
        try:
            tr = store.trend(diag.machine, k, method=diag.method)
        except MaglevidError:
            continue
        ok = np.isfinite(tr.value) & np.isfinite(tr.std_error) & (tr.std_error > 0)
        if until is not None:
            ok &= tr.time <= until
        if ok.sum() < MIN_DRIFT_POINTS or np.ptp(tr.time[ok]) <= 0:
            continue
        b = float(base[k][0]) if k in base else float(tr.value[ok][0])
        t = tolerances.get(k, DEFAULT_TOLERANCE) if isinstance(tolerances, Mapping) else tolerances
        res = detect_drift(
            tr.time[ok] / 86400.0,
            tr.value[ok],
            tr.std_error[ok],
            alpha=alpha_each,
            tolerance=float(t) * abs(b),
            baseline=b,
            scale_floor=True,  # repeated looks: see detect_drift and docs/history.md
        )
        # A step (change-point test): the line's t-test rarely sees one (its residuals are
        # the step), so it is a detector too, at a tenth of the level: the false-alarm
        # rate per diagnosis stays <= 1.1 alpha, and a real step has p ~ 1e-9.
        step = detect_step(
            tr.time[ok] / 86400.0, tr.value[ok], tr.std_error[ok], alpha=alpha_each / STEP_SHARE
        )
        # Significant twice over, as a comparison: a trend whose change over the
        # observed span stays within this recording's model error of the parameter is
        # not evidence of a physical change (different excursions, not wear).
        days = tr.time[ok] / 86400.0
        relevant = abs(res.slope) * float(np.ptp(days)) > model_error.get(k, 0.0)
        if not ((res.drifting and relevant) or step.is_step):
            continue
        entry = {
            "parameter": k,
            "slope_percent_per_day": 100.0 * res.slope / b if b else float("nan"),
            "p_value": res.p_value,
            "n_points": int(ok.sum()),
            "projected_crossing": None,
            "tolerance_percent": 100.0 * float(t),
            "method": res.method,
            "kind": "drift",
        }
        if step.is_step:
            times = np.sort(tr.time[ok])
            entry.update(
                kind="step",
                p_value=step.p_value,
                step_percent=100.0 * step.size / b if b else float("nan"),
                step_after=_iso_day(times[step.index - 1]),
                step_before=_iso_day(times[step.index]),
            )
            out.append(entry)
            continue
        crossing = res.projected_crossing_time
        if crossing is not None and np.isfinite(crossing):
            if crossing * 86400.0 <= float(np.max(tr.time[ok])):
                entry["already_beyond"] = True  # never project a crossing already past
            else:
                entry["projected_crossing"] = _iso_day(crossing * 86400.0)
        out.append(entry)
    return out
