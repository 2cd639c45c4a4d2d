"""Parameter history: every diagnosis of a machine, stored in a real database.

A :class:`HistoryStore` keeps, per machine, the recordings that were diagnosed,
each diagnosis (method, options, verdict, summary) and its parameter estimates
with their uncertainties, so that a parameter can be followed over months and a
slow drift told apart from noise (:mod:`maglevid.diagnose.drift`).

Two backends, one schema and one set of migrations:

* SQLite in a file (default; no server): ``open_history("plant.sqlite")`` or
  ``open_history("sqlite:///plant.sqlite")``;
* PostgreSQL for a store shared by many users and machines:
  ``open_history("postgresql://user:password@host:5432/db")`` (psycopg 3, from
  the ``fleet`` extra).

The API takes and returns plain types (str, float, dict, NumPy arrays, frozen
dataclasses of those) so it does not depend on any result class. Recording a
diagnosis is idempotent: the same (machine, recording hash, method, options
hash) stored twice adds nothing and returns the first id. Concurrency and crash
safety are argued in ``docs/history.md`` and tested in
``tests/diagnose/test_history_robustness.py``.

Examples
--------
>>> from maglevid.diagnose.history import open_history
>>> with open_history(":memory:") as store:
...     rec = store.record_diagnosis(
...         "pump-7",
...         recording_hash="3f2a...",
...         recorded_at="2026-01-05T08:00:00+00:00",
...         method="deadbeat-arx",
...         verdict="healthy",
...         verdict_code="no_change",
...         estimates={"R1": (2.01, 0.02), "Ls1": {"value": 0.031, "unit": "H"}},
...     )
...     again = store.record_diagnosis(
...         "pump-7",
...         recording_hash="3f2a...",
...         recorded_at="2026-01-05T08:00:00+00:00",
...         method="deadbeat-arx",
...         verdict="healthy",
...         verdict_code="no_change",
...         estimates={"R1": (2.01, 0.02)},
...     )
...     (rec.created, again.created, again.id == rec.id)
...     store.latest_estimates("pump-7")["R1"].std_error
(True, False, True)
0.02
"""

from __future__ import annotations

import errno
import getpass
import hashlib
import json
import logging
import math
import os
import socket
import stat
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np

from maglevid.diagnose._migrations import SCHEMA_VERSION
from maglevid.diagnose._sql import (
    Backend,
    HistoryError,
    NotFoundError,
    SchemaVersionError,
    StoreBusyError,
    Tx,
    connect,
    migrate,
    parse_target,
)
from maglevid.exceptions import DataError
from maglevid.jsonable import to_json_checked

__all__ = [
    "DEFAULT_STORE",
    "SCHEMA_VERSION",
    "DiagnosisRecord",
    "Estimate",
    "HistoryError",
    "HistoryStore",
    "MachineInfo",
    "NotFoundError",
    "Recorded",
    "SchemaVersionError",
    "StoreBusyError",
    "Trend",
    "default_store_location",
    "hash_file",
    "hash_options",
    "open_history",
    "parse_target",
]

logger = logging.getLogger(__name__)

#: File name of the store when neither ``--store`` nor ``MAGLEVID_HISTORY`` says.
DEFAULT_STORE = "maglevid-history.sqlite"


def default_store_location() -> str:
    """``$MAGLEVID_HISTORY`` if set, else ``maglevid-history.sqlite`` in the current folder."""
    return os.environ.get("MAGLEVID_HISTORY") or DEFAULT_STORE


# ---------------------------------------------------------------------------
# Plain value types
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Estimate:
    """One parameter estimate of one diagnosis.

    Attributes
    ----------
    value : float
        The estimate, in SI units (finite).
    std_error : float or None
        Its standard error; ``None`` when the method gives none (never 0 for
        "unknown").
    ci_low, ci_high : float or None
        Confidence interval bounds, when the method gives them.
    unit : str or None
        Unit symbol, e.g. ``"ohm"``, ``"H"``.
    baseline : float or None
        The reference value the diagnosis compared against (nominal or the
        previous diagnosis).
    """

    value: float
    std_error: float | None = None
    ci_low: float | None = None
    ci_high: float | None = None
    unit: str | None = None
    baseline: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "value": self.value,
            "std_error": self.std_error,
            "ci_low": self.ci_low,
            "ci_high": self.ci_high,
            "unit": self.unit,
            "baseline": self.baseline,
        }


class Recorded(NamedTuple):
    """What :meth:`HistoryStore.record_diagnosis` did: the diagnosis id, and whether it is new."""

    id: int
    created: bool


@dataclass(frozen=True)
class MachineInfo:
    """A machine of the store and how much history it has."""

    name: str
    created_at: datetime
    metadata: Mapping[str, Any]
    n_diagnoses: int
    first_recorded_at: datetime | None
    last_recorded_at: datetime | None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "created_at": self.created_at.isoformat(),
            "metadata": dict(self.metadata),
            "n_diagnoses": self.n_diagnoses,
            "first_recorded_at": _iso(self.first_recorded_at),
            "last_recorded_at": _iso(self.last_recorded_at),
        }


@dataclass(frozen=True)
class DiagnosisRecord:
    """One stored diagnosis with its recording and estimates."""

    id: int
    machine: str
    recording_hash: str
    recording_path: str | None
    recorded_at: datetime
    dt: float | None
    n_samples: int | None
    created_at: datetime
    method: str
    options_hash: str
    options: Mapping[str, Any]
    verdict: str
    verdict_code: str
    summary: Mapping[str, Any]
    report_path: str | None
    estimates: Mapping[str, Estimate]
    software_version: str | None = None
    written_by: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "machine": self.machine,
            "recording_hash": self.recording_hash,
            "recording_path": self.recording_path,
            "recorded_at": self.recorded_at.isoformat(),
            "dt": self.dt,
            "n_samples": self.n_samples,
            "created_at": self.created_at.isoformat(),
            "method": self.method,
            "options_hash": self.options_hash,
            "options": dict(self.options),
            "verdict": self.verdict,
            "verdict_code": self.verdict_code,
            "summary": dict(self.summary),
            "report_path": self.report_path,
            "estimates": {k: e.to_dict() for k, e in self.estimates.items()},
            "software_version": self.software_version,
            "written_by": self.written_by,
        }


def _readonly(a: Any, dtype: Any) -> np.ndarray:
    out = np.array(a, dtype=dtype)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class Trend:
    """One parameter of one machine over time, oldest first.

    Attributes
    ----------
    machine, parameter : str
    unit : str or None
        The unit shared by every point that gives one (different units raise
        when the trend is read).
    time : ndarray, shape (n,)
        Recording times in seconds since 1970-01-01 UTC (``float64``).
    value, std_error, ci_low, ci_high, baseline : ndarray, shape (n,)
        ``NaN`` where the diagnosis gave none.
    method : ndarray of str, shape (n,)
    diagnosis_id : ndarray of int64, shape (n,)
    """

    machine: str
    parameter: str
    unit: str | None
    time: np.ndarray
    value: np.ndarray
    std_error: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    baseline: np.ndarray
    method: np.ndarray
    diagnosis_id: np.ndarray

    def __len__(self) -> int:
        return int(self.time.shape[0])

    @property
    def recorded_at(self) -> np.ndarray:
        """The recording times as ``datetime64[us]`` (UTC)."""
        return (self.time * 1e6).round().astype("datetime64[us]")


# ---------------------------------------------------------------------------
# Validation and conversion of inputs
# ---------------------------------------------------------------------------


def _iso(t: datetime | None) -> str | None:
    return None if t is None else t.isoformat()


def _as_utc(name: str, v: Any) -> datetime:
    """A timezone-aware UTC datetime from a datetime, ISO string, epoch seconds or datetime64."""
    if isinstance(v, np.datetime64):
        v = float(v.astype("datetime64[us]").astype(np.int64)) / 1e6  # numpy has no zone: UTC
    if isinstance(v, datetime):
        if v.tzinfo is None or v.utcoffset() is None:
            raise DataError(
                f"`{name}` is a naive datetime {v.isoformat()}; expected a timezone-aware one "
                "(e.g. datetime(..., tzinfo=timezone.utc))"
            )
        return v.astimezone(timezone.utc)
    if isinstance(v, str):
        try:
            t = datetime.fromisoformat(v.replace("Z", "+00:00") if v.endswith("Z") else v)
        except ValueError as exc:
            raise DataError(f"`{name}` = {v!r} is not an ISO 8601 time") from exc
        return _as_utc(name, t)
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        if not math.isfinite(float(v)):
            raise DataError(f"`{name}` = {v!r}; expected finite seconds since 1970-01-01 UTC")
        return datetime.fromtimestamp(float(v), tz=timezone.utc)
    raise DataError(
        f"`{name}` is {type(v).__name__}; expected an aware datetime, an ISO 8601 string "
        "with offset, or seconds since 1970-01-01 UTC"
    )


def _text(name: str, v: Any, *, optional: bool = False) -> str | None:
    if v is None and optional:
        return None
    if not isinstance(v, str) or not v.strip():
        raise DataError(f"`{name}` = {v!r}; expected a non-empty string")
    return v


def _opt_float(
    name: str, v: Any, *, nonnegative: bool = False, finite: bool = True
) -> float | None:
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError) as exc:
        raise DataError(f"`{name}` = {v!r}; expected a number or None") from exc
    if math.isnan(x):
        return None  # "unknown" is stored as NULL, never as 0
    if finite and not math.isfinite(x):
        raise DataError(f"`{name}` = {x}; expected a finite number or None")
    if nonnegative and x < 0:
        raise DataError(f"`{name}` = {x}; expected >= 0")
    return x


_ESTIMATE_FIELDS = ("value", "std_error", "ci_low", "ci_high", "unit", "baseline")


def _as_estimate(name: str, v: Any) -> Estimate:
    """An :class:`Estimate` from an Estimate, a number, a tuple or a mapping."""
    where = f"estimates[{name!r}]"
    if isinstance(v, Estimate):
        fields = v.to_dict()
    elif isinstance(v, Mapping):
        extra = set(v) - set(_ESTIMATE_FIELDS)
        if extra or "value" not in v:
            raise DataError(
                f"`{where}` has keys {sorted(v)}; expected 'value' and optionally "
                f"{list(_ESTIMATE_FIELDS[1:])}"
            )
        fields = dict(v)
    elif isinstance(v, (tuple, list)):
        if not 1 <= len(v) <= len(_ESTIMATE_FIELDS):
            raise DataError(
                f"`{where}` has {len(v)} items; expected (value, std_error, ci_low, ci_high, "
                "unit, baseline), trailing ones optional"
            )
        fields = dict(zip(_ESTIMATE_FIELDS, v))
    else:
        fields = {"value": v}
    value = _opt_float(f"{where}.value", fields.get("value"))
    if value is None:
        raise DataError(f"`{where}.value` = {fields.get('value')!r}; expected a finite number")
    lo = _opt_float(f"{where}.ci_low", fields.get("ci_low"), finite=False)
    hi = _opt_float(f"{where}.ci_high", fields.get("ci_high"), finite=False)
    if lo is not None and hi is not None and lo > hi:
        raise DataError(f"`{where}`: ci_low = {lo} > ci_high = {hi}")
    return Estimate(
        value=value,
        std_error=_opt_float(f"{where}.std_error", fields.get("std_error"), nonnegative=True),
        ci_low=lo,
        ci_high=hi,
        unit=_text(f"{where}.unit", fields.get("unit"), optional=True),
        baseline=_opt_float(f"{where}.baseline", fields.get("baseline")),
    )


def _dumps(v: Any, where: str) -> str:
    return json.dumps(to_json_checked(v, where), sort_keys=True, separators=(",", ":"))


def _loads(v: Any) -> dict[str, Any]:
    if v is None:
        return {}
    return json.loads(v) if isinstance(v, (str, bytes)) else dict(v)


def hash_options(options: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of the canonical JSON of ``options`` (sorted keys, no spaces).

    Two option dicts that are equal as JSON hash alike, whatever their key
    order, so ``options_hash`` can serve as the idempotency key.
    """
    if not isinstance(options, Mapping):
        raise DataError(f"`options` is {type(options).__name__}; expected a mapping")
    return hashlib.sha256(_dumps(options, "options").encode()).hexdigest()


def hash_file(path: str | os.PathLike[str], *, chunk_size: int = 1 << 20) -> str:
    """SHA-256 (hex) of a file's bytes: the ``recording_hash`` of a recording file.

    Raises
    ------
    OSError
        No such file, or not a regular file: a FIFO, device or socket is
        refused before it is opened (reading one would block, or never end).
    """
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise OSError(
            errno.EINVAL, "not a regular file (a FIFO, device or socket): not read", str(path)
        )
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk_size):
            h.update(block)
    return h.hexdigest()


def _writer() -> str:
    try:
        user = getpass.getuser()
    except Exception:  # no login name in some containers
        user = f"uid{os.getuid()}" if hasattr(os, "getuid") else "unknown"
    return f"{user}@{socket.gethostname()} pid {os.getpid()}"


def _software_version() -> str:
    import maglevid

    return f"maglevid {maglevid.__version__}"


# ---------------------------------------------------------------------------
# The store
# ---------------------------------------------------------------------------


class _DiagnosisRow(NamedTuple):
    """One diagnosis as :meth:`HistoryStore.record_diagnosis` stores it, checked."""

    machine: str
    recording_hash: str
    recorded_at: datetime
    method: str
    verdict: str
    verdict_code: str
    estimates: list[tuple[str, Estimate]]
    options_json: str
    options_hash: str
    summary_json: str
    meta_json: str
    dt: float | None
    n_samples: Any
    recording_path: str | None
    report_path: str | None
    provenance: tuple[str, str]


def _checked_row(machine: str, **given: Any) -> _DiagnosisRow:
    """The keywords of :meth:`HistoryStore.record_diagnosis` (all given) checked
    (DataError) and converted, before any write."""
    machine = _text("machine", machine)
    text = {k: _text(k, given[k]) for k in ("recording_hash", "method", "verdict", "verdict_code")}
    t_rec = _as_utc("recorded_at", given["recorded_at"])
    estimates = given["estimates"]
    if not isinstance(estimates, Mapping):
        raise DataError(f"`estimates` is {type(estimates).__name__}; expected a mapping")
    est = [(_text("estimates key", k), _as_estimate(k, v)) for k, v in estimates.items()]
    opts = dict(given["options"] or {})
    options_json = _dumps(opts, "options")
    options_hash = given["options_hash"]
    if options_hash is None:
        options_hash = hash_options(opts)
    options_hash = _text("options_hash", options_hash)
    summary_json = _dumps(dict(given["summary"] or {}), "summary")
    meta_json = _dumps(dict(given["machine_metadata"] or {}), "machine_metadata")
    dt_v = _opt_float("dt", given["dt"])
    if dt_v is not None and dt_v <= 0:
        raise DataError(f"`dt` = {dt_v}; expected seconds > 0")
    n_samples = given["n_samples"]
    if n_samples is not None and (
        isinstance(n_samples, bool)
        or not isinstance(n_samples, (int, np.integer))
        or n_samples < 0
    ):
        raise DataError(f"`n_samples` = {n_samples!r}; expected an int >= 0")
    paths = {k: given[k] for k in ("recording_path", "report_path")}
    return _DiagnosisRow(
        machine=machine,
        recorded_at=t_rec,
        estimates=est,
        options_json=options_json,
        options_hash=options_hash,
        summary_json=summary_json,
        meta_json=meta_json,
        dt=dt_v,
        n_samples=n_samples,
        **{k: None if v is None else os.fspath(v) for k, v in paths.items()},
        provenance=(_software_version(), _writer()),
        **text,
    )


def open_history(
    location: str | os.PathLike[str] | None = None,
    *,
    create: bool = True,
    timeout: float = 30.0,
    schema: str | None = None,
) -> HistoryStore:
    """Open (and create or migrate) the parameter history store at ``location``.

    Parameters
    ----------
    location : str or path-like, optional
        A file path or ``sqlite:///relative/path`` / ``sqlite:////absolute/path``
        (SQLite; ``":memory:"`` for a throwaway store), or
        ``postgresql://user:password@host:port/database`` (PostgreSQL through
        psycopg 3). Default: :func:`default_store_location`.
    create : bool
        Create a missing SQLite file (default). ``False`` raises
        :class:`HistoryError` instead (what a read-only command wants).
    timeout : float
        Seconds to wait for a lock (SQLite ``busy_timeout`` plus retries;
        PostgreSQL ``lock_timeout`` plus retries) before :class:`StoreBusyError`.
    schema : str, optional
        PostgreSQL schema (namespace) holding the tables; default ``maglevid``.
        Lets several independent stores share one database. SQLite: not allowed.

    Returns
    -------
    HistoryStore
        Use as a context manager, or call :meth:`HistoryStore.close`.

    Raises
    ------
    HistoryError
        The store cannot be reached or opened.
    SchemaVersionError
        The store was written by a newer maglevid (schema version above
        :data:`SCHEMA_VERSION`), or the file/schema holds something else.

    Notes
    -----
    An older store is migrated on opening, all missing migrations in one
    transaction: a failure leaves it as it was.
    """
    if location is None:
        location = default_store_location()
    if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and timeout > 0):
        raise DataError(f"`timeout` = {timeout!r}; expected seconds > 0")
    backend = connect(location, timeout=float(timeout), create=create, schema=schema)
    try:
        old, new = migrate(backend)
    except BaseException:
        backend.close()
        raise
    if old != new:
        logger.info("%s: schema migrated from version %d to %d", backend.description, old, new)
    return HistoryStore(backend)


class HistoryStore:
    """Per-machine history of diagnoses and parameter estimates (SQLite or PostgreSQL).

    Open with :func:`open_history`. One store object per process (and thread):
    it holds one database connection. All methods are transactions; writes are
    atomic and idempotent.
    """

    def __init__(self, backend: Backend):
        if not isinstance(backend, Backend):
            raise TypeError("open a HistoryStore with open_history(location)")
        self._backend = backend

    # -- life cycle -----------------------------------------------------------
    @property
    def dialect(self) -> str:
        """``"sqlite"`` or ``"postgresql"``."""
        return self._backend.dialect

    @property
    def location(self) -> str:
        """Where the store is (password redacted)."""
        return self._backend.description

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._backend.close()

    def __enter__(self) -> HistoryStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._backend.closed else "open"
        return f"<HistoryStore {self.dialect} {self.location} ({state})>"

    def _run(self, fn: Any, *, write: bool) -> Any:
        return self._backend.run(fn, write=write)

    @property
    def schema_version(self) -> int:
        """The schema version of the store (equal to :data:`SCHEMA_VERSION` once open)."""
        return int(
            self._run(lambda tx: tx.one("SELECT MAX(version) FROM schema_migrations"), write=False)
        )

    # -- writing --------------------------------------------------------------
    @staticmethod
    def _ensure_machine(tx: Tx, name: str, metadata_json: str, now: Any) -> int:
        tx.execute(
            "INSERT INTO machines (name, created_at, metadata) VALUES (?, ?, ?) "
            "ON CONFLICT (name) DO NOTHING",
            (name, now, metadata_json),
        )
        return int(tx.one("SELECT id FROM machines WHERE name = ?", (name,)))

    def add_machine(self, name: str, *, metadata: Mapping[str, Any] | None = None) -> bool:
        """Register ``name`` (with JSON ``metadata``); returns whether it was new.

        An existing machine keeps its metadata.
        """
        name = _text("name", name)
        meta = _dumps(dict(metadata or {}), "metadata")

        def work(tx: Tx) -> bool:
            before = tx.one("SELECT id FROM machines WHERE name = ?", (name,))
            self._ensure_machine(tx, name, meta, tx.ts_in(datetime.now(timezone.utc)))
            return before is None

        return bool(self._run(work, write=True))

    def record_diagnosis(
        self,
        machine: str,
        *,
        recording_hash: str,
        recorded_at: datetime | str | float,
        method: str,
        verdict: str,
        verdict_code: str,
        estimates: Mapping[str, Any],
        summary: Mapping[str, Any] | None = None,
        options: Mapping[str, Any] | None = None,
        options_hash: str | None = None,
        recording_path: str | os.PathLike[str] | None = None,
        dt: float | None = None,
        n_samples: int | None = None,
        report_path: str | os.PathLike[str] | None = None,
        machine_metadata: Mapping[str, Any] | None = None,
    ) -> Recorded:
        """Store one diagnosis of ``machine`` atomically; idempotent.

        Parameters
        ----------
        machine : str
            Machine name; created on first use (with ``machine_metadata``).
        recording_hash : str
            Content hash of the recording (e.g. :func:`hash_file`).
        recorded_at : datetime, str or float
            When the recording was taken: an aware datetime, an ISO 8601 string
            with offset, or seconds since 1970-01-01 UTC.
        method : str
            Diagnosis/identification method name.
        verdict : str
            Human verdict, e.g. ``"healthy"``.
        verdict_code : str
            Machine-readable verdict, e.g. one of
            ``maglevid.diagnose.diagnosis.VERDICT_CODES`` (``"no_change"``,
            ``"fault"``, ...); stored as given.
        estimates : mapping of str -> estimate
            Per parameter: an :class:`Estimate`, a number (value only), a tuple
            ``(value, std_error, ci_low, ci_high, unit, baseline)`` with trailing
            items optional, or a mapping with those keys.
        summary : mapping, optional
            JSON-like summary (NumPy values converted; NaN stored as null).
        options : mapping, optional
            Options of the method, stored as JSON and hashed into
            ``options_hash`` when that is not given.
        options_hash : str, optional
            The idempotency key of the options (default ``hash_options(options or {})``).
        recording_path, dt, n_samples : optional
            Where the recording was, its sample time (s) and length.
        report_path : optional
            Where the report of this diagnosis was written.
        machine_metadata : mapping, optional
            Metadata of the machine if this call creates it.

        Returns
        -------
        Recorded
            ``(id, created)``: ``created`` is False when this (machine,
            recording_hash, method, options_hash) was already stored; then
            nothing is written and ``id`` is the stored diagnosis.

        Raises
        ------
        DataError
            An argument is malformed (checked before any write).

        Notes
        -----
        The recording is identified by its content hash: when the same hash is
        stored with another ``recorded_at`` (a second ``diagnose --store``
        dated "now", or a ``fleet`` run that dated the file by its mtime), it
        is the same recording, its first stored time is kept, and a diagnosis
        with the same method and options is "already stored" (``created`` is
        False).
        """
        row = _checked_row(
            machine, recording_hash=recording_hash, recorded_at=recorded_at, method=method,
            verdict=verdict, verdict_code=verdict_code, estimates=estimates, summary=summary,
            options=options, options_hash=options_hash, recording_path=recording_path, dt=dt,
            n_samples=n_samples, report_path=report_path, machine_metadata=machine_metadata,
        )  # fmt: skip

        def work(tx: Tx) -> Recorded:
            now = tx.ts_in(datetime.now(timezone.utc))
            machine_id = self._ensure_machine(tx, row.machine, row.meta_json, now)
            rec_id = self._insert_recording(tx, machine_id, row)
            return self._insert_diagnosis(tx, machine_id, rec_id, row, now)

        out: Recorded = self._run(work, write=True)
        logger.debug(
            "%s: diagnosis %d of %s (%s) %s",
            self.location,
            out.id,
            row.machine,
            row.method,
            "stored" if out.created else "already stored",
        )
        return out

    def _insert_recording(self, tx: Tx, machine_id: int, row: _DiagnosisRow) -> int:
        """The recording's id, stored on first sight; its first ``recorded_at`` stays."""
        tx.execute(
            "INSERT INTO recordings (machine_id, content_hash, path, dt, n_samples, "
            "recorded_at) VALUES (?, ?, ?, ?, ?, ?) "
            "ON CONFLICT (machine_id, content_hash) DO NOTHING",
            (
                machine_id,
                row.recording_hash,
                row.recording_path,
                row.dt,
                row.n_samples,
                tx.ts_in(row.recorded_at),
            ),
        )
        rec_id, rec_time = tx.execute(
            "SELECT id, recorded_at FROM recordings WHERE machine_id = ? AND content_hash = ?",
            (machine_id, row.recording_hash),
        ).fetchone()
        if tx.ts_out(rec_time) != row.recorded_at:
            # The content hash is the recording's identity: the same bytes
            # stored again (a second `diagnose --store`, or after `fleet`,
            # which dates a file by its mtime where diagnose says "now") are
            # the same recording, and its first stored time stays.
            logger.info(
                "%s: recording %s of %s is stored with recorded_at %s; keeping it (got %s)",
                self.location,
                row.recording_hash,
                row.machine,
                tx.ts_out(rec_time).isoformat(),
                row.recorded_at.isoformat(),
            )
        return int(rec_id)

    @staticmethod
    def _insert_diagnosis(
        tx: Tx, machine_id: int, rec_id: int, row: _DiagnosisRow, now: Any
    ) -> Recorded:
        """The diagnosis and its estimates, unless this (recording, method, options) is stored."""
        cur = tx.execute(
            "INSERT INTO diagnoses (machine_id, recording_id, method, options_hash, "
            "options, created_at, verdict, verdict_code, summary, report_path, "
            "n_estimates, software_version, written_by) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
            "ON CONFLICT (machine_id, recording_id, method, options_hash) DO NOTHING",
            (
                machine_id,
                rec_id,
                row.method,
                row.options_hash,
                row.options_json,
                now,
                row.verdict,
                row.verdict_code,
                row.summary_json,
                row.report_path,
                len(row.estimates),
                *row.provenance,
            ),
        )
        created = cur.rowcount == 1
        diag_id = int(
            tx.one(
                "SELECT id FROM diagnoses WHERE machine_id = ? AND recording_id = ? "
                "AND method = ? AND options_hash = ?",
                (machine_id, rec_id, row.method, row.options_hash),
            )
        )
        if created:
            tx.executemany(
                "INSERT INTO estimates (diagnosis_id, parameter, value, std_error, "
                "ci_low, ci_high, unit, baseline) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (diag_id, k, e.value, e.std_error, e.ci_low, e.ci_high, e.unit, e.baseline)
                    for k, e in row.estimates
                ],
            )
        return Recorded(diag_id, created)

    # -- reading --------------------------------------------------------------
    @staticmethod
    def _machine_id(tx: Tx, machine: str) -> int:
        mid = tx.one("SELECT id FROM machines WHERE name = ?", (machine,))
        if mid is None:
            names = [r[0] for r in tx.all("SELECT name FROM machines ORDER BY name LIMIT 11")]
            known = ", ".join(names[:10]) + (", ..." if len(names) > 10 else "")
            raise NotFoundError(
                f"no machine {machine!r} in the history store; "
                + (f"known: {known}" if names else "the store is empty")
            )
        return int(mid)

    def machines(self) -> list[MachineInfo]:
        """Every machine, by name, with its number of diagnoses and time span."""

        def work(tx: Tx) -> list[MachineInfo]:
            rows = tx.all(
                "SELECT m.name, m.created_at, m.metadata, COUNT(d.id), "
                "MIN(r.recorded_at), MAX(r.recorded_at) "
                "FROM machines m LEFT JOIN diagnoses d ON d.machine_id = m.id "
                "LEFT JOIN recordings r ON r.id = d.recording_id "
                "GROUP BY m.id, m.name, m.created_at, m.metadata ORDER BY m.name"
            )
            return [
                MachineInfo(
                    name=r[0],
                    created_at=tx.ts_out(r[1]),
                    metadata=MappingProxyType(_loads(r[2])),
                    n_diagnoses=int(r[3]),
                    first_recorded_at=None if r[4] is None else tx.ts_out(r[4]),
                    last_recorded_at=None if r[5] is None else tx.ts_out(r[5]),
                )
                for r in rows
            ]

        return self._run(work, write=False)

    def parameters(self, machine: str) -> list[str]:
        """Names of the parameters ever estimated for ``machine``, sorted."""

        def work(tx: Tx) -> list[str]:
            mid = self._machine_id(tx, machine)
            return [
                r[0]
                for r in tx.all(
                    "SELECT DISTINCT e.parameter FROM estimates e "
                    "JOIN diagnoses d ON d.id = e.diagnosis_id WHERE d.machine_id = ? "
                    "ORDER BY e.parameter",
                    (mid,),
                )
            ]

        return self._run(work, write=False)

    def methods(self, machine: str) -> dict[str, int]:
        """The methods of ``machine``'s diagnoses that have estimates, with their counts.

        Ordered by each method's latest recording, the most recent last (the last
        key is the method the machine's history continues with, see
        :func:`maglevid.diagnose.pipeline.choose_method`). Empty for a machine the
        store does not know: a first diagnosis has no history to continue.
        """

        def work(tx: Tx) -> dict[str, int]:
            mid = tx.one("SELECT id FROM machines WHERE name = ?", (machine,))
            if mid is None:
                return {}
            rows = tx.all(
                "SELECT d.method, COUNT(d.id), MAX(r.recorded_at), MAX(d.id) FROM diagnoses d "
                "JOIN recordings r ON r.id = d.recording_id WHERE d.machine_id = ? "
                "AND EXISTS (SELECT 1 FROM estimates e WHERE e.diagnosis_id = d.id) "
                "GROUP BY d.method ORDER BY MAX(r.recorded_at), MAX(d.id)",
                (int(mid),),
            )
            return {str(r[0]): int(r[1]) for r in rows}

        return self._run(work, write=False)

    _DIAG_COLUMNS = (
        "d.id, r.content_hash, r.path, r.recorded_at, r.dt, r.n_samples, d.created_at, "
        "d.method, d.options_hash, d.options, d.verdict, d.verdict_code, d.summary, "
        "d.report_path, d.software_version, d.written_by"
    )

    def diagnoses(self, machine: str, *, method: str | None = None) -> list[DiagnosisRecord]:
        """Every diagnosis of ``machine`` (optionally of one ``method``), oldest first."""

        def work(tx: Tx) -> list[DiagnosisRecord]:
            mid = self._machine_id(tx, machine)
            where, params = "d.machine_id = ?", [mid]
            if method is not None:
                where, params = where + " AND d.method = ?", [*params, method]
            rows = tx.all(
                f"SELECT {self._DIAG_COLUMNS} FROM diagnoses d "
                f"JOIN recordings r ON r.id = d.recording_id WHERE {where} "
                "ORDER BY r.recorded_at, d.id",
                params,
            )
            est = self._estimates_by_diagnosis(tx, where, params)
            return [self._diagnosis(tx, machine, r, est.get(int(r[0]), {})) for r in rows]

        return self._run(work, write=False)

    def diagnosis(self, diagnosis_id: int) -> DiagnosisRecord:
        """The stored diagnosis with id ``diagnosis_id``."""

        def work(tx: Tx) -> DiagnosisRecord:
            row = tx.execute(
                f"SELECT {self._DIAG_COLUMNS}, m.name FROM diagnoses d "
                "JOIN recordings r ON r.id = d.recording_id "
                "JOIN machines m ON m.id = d.machine_id WHERE d.id = ?",
                (int(diagnosis_id),),
            ).fetchone()
            if row is None:
                raise NotFoundError(f"no diagnosis with id {diagnosis_id} in the history store")
            est = self._estimates_by_diagnosis(tx, "d.id = ?", [int(diagnosis_id)])
            return self._diagnosis(tx, row[-1], row[:-1], est.get(int(diagnosis_id), {}))

        return self._run(work, write=False)

    @staticmethod
    def _estimates_by_diagnosis(
        tx: Tx, where: str, params: Sequence[Any]
    ) -> dict[int, dict[str, Estimate]]:
        out: dict[int, dict[str, Estimate]] = {}
        for r in tx.all(
            "SELECT e.diagnosis_id, e.parameter, e.value, e.std_error, e.ci_low, e.ci_high, "
            "e.unit, e.baseline FROM estimates e JOIN diagnoses d ON d.id = e.diagnosis_id "
            f"WHERE {where} ORDER BY e.diagnosis_id, e.id",
            params,
        ):
            out.setdefault(int(r[0]), {})[r[1]] = Estimate(*r[2:])
        return out

    @staticmethod
    def _diagnosis(
        tx: Tx, machine: str, r: Sequence[Any], estimates: Mapping[str, Estimate]
    ) -> DiagnosisRecord:
        return DiagnosisRecord(
            id=int(r[0]),
            machine=machine,
            recording_hash=r[1],
            recording_path=r[2],
            recorded_at=tx.ts_out(r[3]),
            dt=r[4],
            n_samples=None if r[5] is None else int(r[5]),
            created_at=tx.ts_out(r[6]),
            method=r[7],
            options_hash=r[8],
            options=MappingProxyType(_loads(r[9])),
            verdict=r[10],
            verdict_code=r[11],
            summary=MappingProxyType(_loads(r[12])),
            report_path=r[13],
            estimates=MappingProxyType(dict(estimates)),
            software_version=r[14],
            written_by=r[15],
        )

    def latest_estimates(
        self,
        machine: str,
        *,
        method: str | None = None,
        before: datetime | str | float | None = None,
        exclude_recording: str | None = None,
    ) -> dict[str, Estimate]:
        """Estimates of the most recent diagnosis of ``machine`` that has estimates.

        The natural baseline for the next diagnosis. Diagnoses without estimates
        (e.g. "cannot diagnose") are passed over. ``before`` keeps only recordings
        taken strictly earlier (a baseline never comes from the future), and
        ``exclude_recording`` (a content hash) keeps a recording from being its own
        baseline on a re-run. Empty when nothing qualifies.
        """
        t_before = None if before is None else _as_utc("before", before)

        def work(tx: Tx) -> dict[str, Estimate]:
            mid = self._machine_id(tx, machine)
            where, params = "d.machine_id = ?", [mid]
            if method is not None:
                where, params = where + " AND d.method = ?", [*params, method]
            if t_before is not None:
                where, params = where + " AND r.recorded_at < ?", [*params, tx.ts_in(t_before)]
            if exclude_recording is not None:
                where, params = where + " AND r.content_hash <> ?", [*params, exclude_recording]
            where += " AND EXISTS (SELECT 1 FROM estimates e WHERE e.diagnosis_id = d.id)"
            last = tx.one(
                "SELECT d.id FROM diagnoses d JOIN recordings r ON r.id = d.recording_id "
                f"WHERE {where} ORDER BY r.recorded_at DESC, d.id DESC LIMIT 1",
                params,
            )
            if last is None:
                return {}
            return self._estimates_by_diagnosis(tx, "d.id = ?", [int(last)]).get(int(last), {})

        return self._run(work, write=False)

    def _estimate_rows(
        self, machine: str, parameters: Sequence[str] | None, method: str | None
    ) -> list[tuple[Any, ...]]:
        def work(tx: Tx) -> list[tuple[Any, ...]]:
            mid = self._machine_id(tx, machine)
            where, params = "d.machine_id = ?", [mid]
            if method is not None:
                where, params = where + " AND d.method = ?", [*params, method]
            if parameters is not None:
                marks = ", ".join("?" * len(parameters))
                where, params = where + f" AND e.parameter IN ({marks})", [*params, *parameters]
            rows = tx.all(
                "SELECT d.id, r.recorded_at, d.method, e.parameter, e.value, e.std_error, "
                "e.ci_low, e.ci_high, e.unit, e.baseline FROM estimates e "
                "JOIN diagnoses d ON d.id = e.diagnosis_id "
                "JOIN recordings r ON r.id = d.recording_id "
                f"WHERE {where} ORDER BY r.recorded_at, d.id, e.id",
                params,
            )
            return [(r[0], tx.ts_out(r[1]), *r[2:]) for r in rows]

        return self._run(work, write=False)

    def trend(self, machine: str, parameter: str, *, method: str | None = None) -> Trend:
        """The history of one parameter of ``machine``, oldest recording first.

        Every stored diagnosis contributes a point (several methods on one
        recording give several points at the same time; pass ``method`` to
        keep one).

        Raises
        ------
        NotFoundError
            Unknown machine, or no estimate of ``parameter`` (the message lists
            the known parameters).
        HistoryError
            The points have different units.
        """
        rows = self._estimate_rows(machine, [parameter], method)
        if not rows:
            known = self.parameters(machine)
            raise NotFoundError(
                f"machine {machine!r} has no estimate of {parameter!r}"
                + (f" by method {method!r}" if method is not None else "")
                + f"; parameters: {', '.join(known) if known else 'none'}"
            )
        units = {r[8] for r in rows if r[8] is not None}  # no unit given is no conflict
        if len(units) > 1:
            raise HistoryError(
                f"{parameter!r} of machine {machine!r} is stored in different units "
                f"{sorted(units)}; a trend needs one unit (filter by method?)"
            )

        def col(i: int) -> list[float]:
            return [np.nan if r[i] is None else r[i] for r in rows]

        return Trend(
            machine=machine,
            parameter=parameter,
            unit=units.pop() if units else None,
            time=_readonly([r[1].timestamp() for r in rows], np.float64),
            value=_readonly(col(4), np.float64),
            std_error=_readonly(col(5), np.float64),
            ci_low=_readonly(col(6), np.float64),
            ci_high=_readonly(col(7), np.float64),
            baseline=_readonly(col(9), np.float64),
            method=_readonly([r[2] for r in rows], object),
            diagnosis_id=_readonly([r[0] for r in rows], np.int64),
        )

    def estimates_table(
        self,
        machine: str,
        *,
        parameters: Sequence[str] | None = None,
        method: str | None = None,
    ) -> dict[str, np.ndarray]:
        """All estimates of ``machine`` as columns (long format), oldest first.

        Columns: ``diagnosis_id``, ``time`` (s since 1970 UTC), ``recorded_at``
        (``datetime64[us]``, UTC), ``method``, ``parameter``, ``value``,
        ``std_error``, ``ci_low``, ``ci_high``, ``baseline`` (NaN where none),
        ``unit``. Pandas-free; ``pandas.DataFrame(table)`` turns it into a frame.
        """
        if parameters is not None:
            parameters = [_text("parameters item", p) for p in parameters]
            if not parameters:
                raise DataError("`parameters` is empty; give None for all parameters")
        rows = self._estimate_rows(machine, parameters, method)
        t = np.array([r[1].timestamp() for r in rows], dtype=np.float64)

        def num(i: int) -> np.ndarray:
            return _readonly([np.nan if r[i] is None else r[i] for r in rows], np.float64)

        return {
            "diagnosis_id": _readonly([r[0] for r in rows], np.int64),
            "time": _readonly(t, np.float64),
            "recorded_at": _readonly((t * 1e6).round().astype("datetime64[us]"), "datetime64[us]"),
            "method": _readonly([r[2] for r in rows], object),
            "parameter": _readonly([r[3] for r in rows], object),
            "value": num(4),
            "std_error": num(5),
            "ci_low": num(6),
            "ci_high": num(7),
            "baseline": num(9),
            "unit": _readonly([r[8] for r in rows], object),
        }

    def to_dataframe(
        self,
        machine: str,
        *,
        parameters: Sequence[str] | None = None,
        method: str | None = None,
    ) -> Any:
        """:meth:`estimates_table` as a ``pandas.DataFrame`` (long format, oldest first).

        One row per (diagnosis, parameter) with ``recorded_at`` (UTC), ``method``,
        ``parameter``, ``value``, ``std_error``, ``ci_low``, ``ci_high``,
        ``baseline`` and ``unit``; ``df.pivot(index="recorded_at",
        columns="parameter", values="value")`` gives one column per parameter.
        """
        import pandas as pd

        table = self.estimates_table(machine, parameters=parameters, method=method)
        df = pd.DataFrame({k: v for k, v in table.items() if k != "time"})
        df["recorded_at"] = pd.to_datetime(df["recorded_at"], utc=True)
        return df

    # -- health ---------------------------------------------------------------
    def check(self) -> list[str]:
        """Consistency problems of the store; an empty list means healthy.

        SQLite: ``PRAGMA integrity_check`` and ``PRAGMA foreign_key_check``.
        Both dialects: every diagnosis has exactly the ``n_estimates`` estimate
        rows it announced (no partial diagnosis), and the schema version is
        this code's.
        """

        def work(tx: Tx) -> list[str]:
            problems: list[str] = []
            if tx.dialect == "sqlite":
                ok = [r[0] for r in tx.all("PRAGMA integrity_check")]
                if ok != ["ok"]:
                    problems += [f"integrity_check: {m}" for m in ok]
                problems += [f"foreign_key_check: {r}" for r in tx.all("PRAGMA foreign_key_check")]
            for did, want, got in tx.all(
                "SELECT d.id, d.n_estimates, COUNT(e.id) FROM diagnoses d "
                "LEFT JOIN estimates e ON e.diagnosis_id = d.id "
                "GROUP BY d.id, d.n_estimates HAVING COUNT(e.id) <> d.n_estimates"
            ):
                problems.append(f"diagnosis {did}: {got} estimate rows, {want} announced")
            version = tx.one("SELECT MAX(version) FROM schema_migrations")
            if version != SCHEMA_VERSION:
                problems.append(f"schema version {version}, expected {SCHEMA_VERSION}")
            return problems

        return self._run(work, write=False)
