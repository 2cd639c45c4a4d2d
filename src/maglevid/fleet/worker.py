"""What runs on a Dask worker: diagnose a batch of recordings, never raise for one of them.

Each recording is read once; its content hash (the history store's key,
:func:`maglevid.diagnose.pipeline.recording_hash`) and method decide whether the
store already holds its diagnosis (then the identification is skipped); else
the pipeline diagnoses it and, given the store, records it itself. Whatever
happens to one recording becomes a :class:`RecordingOutcome`; the batch goes on.

Who writes what to the store (see ``docs/fleet.md``):

* the pipeline writes each diagnosis it makes (quality failures included),
  from the worker, idempotently on (machine, content hash, method, options);
* a file that cannot be read gets a ``cannot_diagnose`` diagnosis of method
  :data:`UNREADABLE_METHOD` keyed by the SHA-256 of its bytes (there is no
  content to hash), so the store's history shows it too;
* an exception of the pipeline (a bug, a wrong baseline, a store failure) is
  *not* stored: it is reported in the fleet summary and retried by the next run.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import threading
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from maglevid.exceptions import MaglevidError
from maglevid.fleet.jobs import FleetJob

__all__ = [
    "OUTCOME_STATUSES",
    "REPORT_VERDICTS",
    "UNREADABLE_METHOD",
    "BatchContext",
    "RecordingOutcome",
    "diagnose_batch",
    "drop_kept",
    "report_file_name",
    "write_kept_report",
]

logger = logging.getLogger(__name__)

#: Method name of the store's diagnoses of files that could not be read.
UNREADABLE_METHOD = "unreadable"

#: What happened to one recording in a fleet run.
OUTCOME_STATUSES: dict[str, str] = {
    "diagnosed": "diagnosed in this run (and recorded by the pipeline)",
    "skipped": "already in the store (same machine, content, method and options)",
    "unreadable": "the file cannot be read as a recording (recorded as cannot_diagnose)",
    "missing": "the file does not exist (not recorded)",
    "error": "the diagnosis raised an exception (not recorded; the next run retries it)",
    "lost": "the worker running it died repeatedly (not recorded; the next run retries it)",
    "duplicate": "the same file is named twice for this machine (diagnosed once)",
}

#: Verdicts whose machine gets a report with ``reports=``.
REPORT_VERDICTS: tuple[str, ...] = ("fault", "unexplained_change")


@dataclass(frozen=True)
class RecordingOutcome:
    """What a fleet run did with one recording: plain data, cheap to send back.

    Attributes
    ----------
    machine, recording : str
        The job's machine and recording path.
    status : str
        One of :data:`OUTCOME_STATUSES`.
    verdict_code : str or None
        The diagnosis' code (``"cannot_diagnose"`` for unreadable files);
        ``None`` when there is no diagnosis (missing, error, lost, duplicate).
    verdict : str
        The verdict in words, or what went wrong.
    reasons : tuple of str
        The numbers behind the verdict.
    method, recording_hash, recorded_at : str or None
        The store's key of the diagnosis (``recorded_at`` in ISO 8601, UTC).
    changes : tuple of dict
        The significant parameter changes: ``{"parameter", "change_percent",
        "ci_percent", "status"}``.
    cause : str or None
        The isolated physical cause, when the isolation found one.
    drifts : tuple of dict
        Drifting parameters the pipeline found in the machine's history.
    error : str or None
        ``"ExceptionType: message"`` for unreadable, missing, error and lost.
    report : str or None
        Path of the HTML report written for this recording.
    seconds : float
        Worker time spent on the recording.
    worker : str or None
        ``"host pid N"`` of the process that produced the outcome.
    source : str
        Where the job came from (manifest row, folder, glob).
    """

    machine: str
    recording: str
    status: str
    verdict_code: str | None = None
    verdict: str = ""
    reasons: tuple[str, ...] = ()
    method: str | None = None
    recording_hash: str | None = None
    recorded_at: str | None = None
    changes: tuple[Mapping[str, Any], ...] = ()
    cause: str | None = None
    drifts: tuple[Mapping[str, Any], ...] = ()
    error: str | None = None
    report: str | None = None
    seconds: float = 0.0
    worker: str | None = None
    source: str = ""

    def __post_init__(self) -> None:
        if self.status not in OUTCOME_STATUSES:
            raise ValueError(f"status {self.status!r} not in {list(OUTCOME_STATUSES)}")
        for name in ("reasons", "changes", "drifts"):
            object.__setattr__(self, name, tuple(getattr(self, name)))

    @property
    def diagnosed(self) -> bool:
        """Whether a diagnosis of this recording exists (made now or found in the store)."""
        return self.verdict_code is not None

    @property
    def problem(self) -> str | None:
        """Why the recording could not be diagnosed (``None`` if it was)."""
        if self.status in ("missing", "error", "lost", "unreadable"):
            return self.error or self.verdict
        if self.verdict_code == "cannot_diagnose":
            return self.verdict
        return None

    def to_dict(self) -> dict[str, Any]:
        return {
            "machine": self.machine,
            "recording": self.recording,
            "status": self.status,
            "verdict_code": self.verdict_code,
            "verdict": self.verdict,
            "reasons": list(self.reasons),
            "method": self.method,
            "recording_hash": self.recording_hash,
            "recorded_at": self.recorded_at,
            "changes": [dict(c) for c in self.changes],
            "cause": self.cause,
            "drifts": [dict(d) for d in self.drifts],
            "error": self.error,
            "report": self.report,
            "seconds": self.seconds,
            "worker": self.worker,
            "source": self.source,
        }


@dataclass(frozen=True)
class BatchContext:
    """Everything a batch needs besides its jobs (sent once per batch, small).

    ``known`` maps a machine to the (content hash, method, options hash) keys
    the store held when the run started. With ``reports_dir`` the worker keeps
    the latest faulty :class:`~maglevid.diagnose.diagnosis.Diagnosis` of each
    machine it diagnosed (under ``run_id``) for :func:`write_kept_report`.
    """

    store: str
    schema: str | None = None
    known: Mapping[str, frozenset[tuple[str, str, str]]] = field(default_factory=dict)
    reports_dir: str | None = None
    diagnose_fn: Callable[..., Any] | None = None
    run_id: str = ""


# -- one store connection per worker process and thread ------------------------------------

_STORES: dict[tuple[str, str | None, int, int], Any] = {}
_STORES_LOCK = threading.Lock()


def _store(location: str, schema: str | None) -> Any:
    """The worker's connection to the store (opened once per process and thread)."""
    from maglevid.diagnose.history import open_history

    key = (location, schema, os.getpid(), threading.get_ident())
    with _STORES_LOCK:
        store = _STORES.get(key)
    if store is None:
        store = open_history(location, schema=schema)
        with _STORES_LOCK:
            _STORES[key] = store
    return store


def _drop_store(location: str, schema: str | None) -> None:
    key = (location, schema, os.getpid(), threading.get_ident())
    with _STORES_LOCK:
        store = _STORES.pop(key, None)
    if store is not None:
        try:
            store.close()
        except Exception:  # a broken connection: nothing to save
            logger.debug("closing a broken store connection failed", exc_info=True)


def _worker_name() -> str:
    return f"{socket.gethostname()} pid {os.getpid()}"


def _error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _recorded_at(job: FleetJob, data: Any) -> datetime:
    """Manifest time, else the recording's ``metadata["recorded_at"]``, else the file's mtime.

    The pipeline would take "now" for a recording without a time; the fleet
    never does, because the same content stored at two times is refused by the
    store (and a second run would then fail instead of adding nothing).
    """
    if job.recorded_at is not None:
        return job.recorded_at
    meta = getattr(data, "metadata", None)
    stamp = meta.get("recorded_at") if hasattr(meta, "get") else None
    if stamp:
        from maglevid.fleet.jobs import _utc

        return _utc("metadata['recorded_at']", stamp)
    return datetime.fromtimestamp(os.stat(job.recording).st_mtime, tz=timezone.utc)


def report_file_name(machine: str) -> str:
    """A file name for a machine's report: safe characters, unique per machine name."""
    import hashlib

    safe = "".join(c if (c.isalnum() or c in "-_.") else "_" for c in machine).strip("._")
    if safe != machine or not safe:
        safe = f"{safe or 'machine'}-{hashlib.sha256(machine.encode()).hexdigest()[:8]}"
    return f"{safe}.html"


def _finite(x: float) -> float | None:
    """JSON-safe: a float, or ``None`` for NaN/inf (the summary is JSON)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _changes(diag: Any) -> list[dict[str, Any]]:
    out = []
    for c in getattr(diag, "changes", ()):
        if not c.significant:
            continue
        b = c.baseline if c.baseline else float("nan")
        out.append(
            {
                "parameter": c.name,
                "change_percent": _finite(c.change_percent),
                "ci_percent": [
                    _finite(100.0 * c.change_ci[0] / b),
                    _finite(100.0 * c.change_ci[1] / b),
                ],
                "status": c.status,
            }
        )
    return out


def _cause(diag: Any) -> str | None:
    iso = getattr(diag, "isolation", None)
    if iso is None or not iso.explained or not iso.best.parameters:
        return None
    return str(iso.best.describe())


def _from_diagnosis(
    job: FleetJob, diag: Any, *, recorded_at: datetime, seconds: float
) -> RecordingOutcome:
    return RecordingOutcome(
        machine=job.machine,
        recording=job.recording,
        status="diagnosed",
        verdict_code=diag.verdict_code,
        verdict=diag.verdict,
        reasons=tuple(diag.reasons),
        method=diag.method or None,
        recording_hash=diag.recording_hash,
        recorded_at=recorded_at.isoformat(),
        changes=tuple(_changes(diag)),
        cause=_cause(diag),
        drifts=tuple(dict(d) for d in getattr(diag, "drifts", ())),
        seconds=seconds,
        worker=_worker_name(),
        source=job.source,
    )


def _record_unreadable(
    job: FleetJob, exc: BaseException, ctx: BatchContext, t0: float
) -> RecordingOutcome:
    from maglevid.diagnose.history import hash_file

    message = _error_text(exc)
    try:
        fhash = "file-sha256:" + hash_file(job.recording)
        when = job.recorded_at or datetime.fromtimestamp(
            os.stat(job.recording).st_mtime, tz=timezone.utc
        )
    except OSError as os_exc:  # vanished or unreadable bytes: nothing to key it by
        return RecordingOutcome(
            machine=job.machine,
            recording=job.recording,
            status="missing",
            verdict=f"the file cannot be opened: {os_exc}",
            error=_error_text(os_exc),
            seconds=time.perf_counter() - t0,
            worker=_worker_name(),
            source=job.source,
        )
    verdict = f"Cannot diagnose: the file cannot be read ({message})"
    try:
        _store(ctx.store, ctx.schema).record_diagnosis(
            job.machine,
            recording_hash=fhash,
            recorded_at=when,
            method=UNREADABLE_METHOD,
            verdict=verdict,
            verdict_code="cannot_diagnose",
            estimates={},
            summary={"error": message},
            recording_path=job.recording,
        )
    except Exception as store_exc:
        _drop_store(ctx.store, ctx.schema)
        message += f"; recording it in the store failed too ({_error_text(store_exc)})"
    return RecordingOutcome(
        machine=job.machine,
        recording=job.recording,
        status="unreadable",
        verdict_code="cannot_diagnose",
        verdict=verdict,
        reasons=(message,),
        method=UNREADABLE_METHOD,
        recording_hash=fhash,
        recorded_at=when.isoformat(),
        error=message,
        seconds=time.perf_counter() - t0,
        worker=_worker_name(),
        source=job.source,
    )


# -- reports: the faulty diagnoses a worker keeps until the client asks for a report -------

_KEPT: dict[tuple[str, str], tuple[datetime, str, Any]] = {}
_KEPT_LOCK = threading.Lock()


def _keep(ctx: BatchContext, job: FleetJob, when: datetime, diag: Any) -> None:
    """Keep ``diag`` if it is the machine's latest faulty diagnosis on this worker so far."""
    key = (ctx.run_id, job.machine)
    with _KEPT_LOCK:
        old = _KEPT.get(key)
        if old is None or (when, job.recording) >= old[:2]:
            _KEPT[key] = (when, job.recording, diag)


def write_kept_report(
    run_id: str, machine: str, recording: str, reports_dir: str, store: str, schema: str | None
) -> str | None:
    """Write the report of the diagnosis this worker kept for ``machine`` (a Dask task).

    Runs on the worker that diagnosed ``recording``: the Diagnosis (models,
    identification, isolation) never travels to the client. Returns the path,
    or ``None`` when this worker no longer holds that diagnosis (it restarted,
    or kept a later one). The report includes the machine's parameter trends.
    """
    from maglevid.fleet.trends import report_trends
    from maglevid.report import write_report

    with _KEPT_LOCK:
        kept = _KEPT.get((run_id, machine))
    if kept is None or kept[1] != recording:
        return None
    diag = kept[2]
    path = Path(reports_dir) / report_file_name(machine)
    trends = report_trends(_store(store, schema), machine, method=diag.method)
    # A report maglevid wrote earlier for this machine is replaced; any other file is not.
    from maglevid.report.html import is_maglevid_page

    return str(
        write_report(
            diag, path, trends=trends or None, overwrite=is_maglevid_page(path), inputs=[recording]
        )
    )


def drop_kept(run_id: str) -> int:
    """Forget the diagnoses kept for run ``run_id`` (run on every worker at the end)."""
    with _KEPT_LOCK:
        keys = [k for k in _KEPT if k[0] == run_id]
        for k in keys:
            del _KEPT[k]
    return len(keys)


def _diagnose_one(job: FleetJob, ctx: BatchContext) -> RecordingOutcome:
    from maglevid.diagnose.history import hash_options
    from maglevid.diagnose.pipeline import choose_method, recording_hash
    from maglevid.io import read_recording

    t0 = time.perf_counter()
    base = {
        "machine": job.machine,
        "recording": job.recording,
        "worker": _worker_name(),
        "source": job.source,
    }
    try:
        data = read_recording(job.recording)
    except FileNotFoundError as exc:
        return RecordingOutcome(
            status="missing",
            verdict="the file does not exist",
            error=_error_text(exc),
            seconds=time.perf_counter() - t0,
            **base,
        )
    except (MaglevidError, OSError, ValueError, KeyError, EOFError) as exc:
        # A corrupt or foreign file: the readers raise FileFormatError, but a
        # truncated zip or HDF5 file can surface as the library's own error.
        return _record_unreadable(job, exc, ctx, t0)
    try:
        rhash = recording_hash(data)
        store = _store(ctx.store, ctx.schema)
        # The diagnosis default, or the method this machine's stored history continues with.
        method = job.method or choose_method(data, history=store, machine=job.machine)[0]
        key = (rhash, method, hash_options(dict(job.method_options)))
        when = _recorded_at(job, data)
        if key in ctx.known.get(job.machine, ()):
            return RecordingOutcome(
                status="skipped",
                method=method,
                recording_hash=rhash,
                recorded_at=when.isoformat(),
                seconds=time.perf_counter() - t0,
                **base,
            )
        fn = ctx.diagnose_fn
        if fn is None:
            from maglevid.diagnose.pipeline import diagnose as fn
        diag = fn(
            data,
            baseline=job.baseline,
            machine=job.machine,
            method=job.method,
            tolerances=job.tolerances,
            history=store,
            recorded_at=when,
            method_options=dict(job.method_options) or None,
            # The recordings of a machine are diagnosed in parallel, so a per-recording
            # drift test would see whichever part of the history other workers had
            # written: the fleet tests drift once per machine after the run instead
            # (maglevid.fleet.summary.machine_drifts).
            drift=False,
        )
    except Exception as exc:
        # Not stored: a bug, a wrong baseline or a store failure is not a
        # property of the recording, and the next run should try again.
        _drop_store(ctx.store, ctx.schema)
        logger.warning("diagnosis of %s failed: %s", job.recording, _error_text(exc))
        return RecordingOutcome(
            status="error",
            verdict=f"the diagnosis failed: {_error_text(exc)}",
            error=_error_text(exc),
            reasons=tuple(traceback.format_exception_only(type(exc), exc)),
            seconds=time.perf_counter() - t0,
            **base,
        )
    if ctx.reports_dir and diag.verdict_code in REPORT_VERDICTS:
        _keep(ctx, job, when, diag)
    return _from_diagnosis(job, diag, recorded_at=when, seconds=time.perf_counter() - t0)


def diagnose_batch(
    jobs: Sequence[FleetJob], ctx: BatchContext
) -> tuple[str | None, list[RecordingOutcome]]:
    """Diagnose ``jobs`` one after the other: ``(worker address, one outcome per job)``.

    The Dask task of a fleet run. It raises only if the worker itself is
    broken: every recording's failure is an outcome. The address tells the
    client where a kept faulty diagnosis is (``None`` outside a Dask worker).
    """
    try:
        from distributed import get_worker

        address: str | None = get_worker().address
    except (ImportError, ValueError):  # called directly, not as a Dask task
        address = None
    return address, [_diagnose_one(job, ctx) for job in jobs]
