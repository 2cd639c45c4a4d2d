"""What a fleet run diagnoses: recordings, their machines and baselines.

A fleet run takes one or more *sources*:

* a **manifest** (``.csv`` with a header row naming at least ``machine`` and
  ``recording``, or ``.json``): one row per recording, with its machine, its
  baseline and optionally the method, tolerances, recording time and method
  options (see :func:`read_manifest`);
* a **folder**: every recording file below it (``.npz``, ``.mat``, ``.parquet``,
  ``.csv``; hidden files and folders, and the ``.json`` side-cars of CSV files,
  are left out);
* a **glob** (``"data/*/*.npz"``, ``**`` recurses) or a single recording file.

The machine of a recording, in order:

1. the manifest's ``machine`` column;
2. ``machine=`` given by the caller (``--machine``): every recording of the
   folders, globs and files belongs to that machine;
3. a folder ``DIR``: the first folder below it, ``DIR/<machine>/.../<recording>``
   (date sub-folders below the machine folder are fine); a recording lying
   directly in ``DIR`` belongs to the machine named like ``DIR`` itself, so
   ``maglevid fleet recordings/pump-7/`` diagnoses one machine's folder;
4. a glob or a single file: the name of the folder holding the recording.

Nothing here reads a recording: collecting 10^5 jobs costs one directory walk.
"""

from __future__ import annotations

import csv
import glob as _glob
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from types import MappingProxyType
from typing import Any

from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters

__all__ = [
    "MANIFEST_COLUMNS",
    "RECORDING_SUFFIXES",
    "FleetJob",
    "ManifestError",
    "collect_jobs",
    "parse_baseline",
    "parse_tolerances",
    "read_manifest",
]

#: File suffixes taken as recordings when a folder or glob is scanned.
RECORDING_SUFFIXES: tuple[str, ...] = (".npz", ".mat", ".parquet", ".csv")

#: Columns (CSV) or keys (JSON) a manifest row may have; the first two are required.
MANIFEST_COLUMNS: tuple[str, ...] = (
    "machine",
    "recording",
    "baseline",
    "method",
    "tolerances",
    "recorded_at",
    "method_options",
)

_GLOB_CHARS = frozenset("*?[")


class ManifestError(DataError):
    """A manifest that cannot be read: names the file, the row and the problem."""


@dataclass(frozen=True)
class FleetJob:
    """One recording to diagnose, with everything the diagnosis needs.

    Attributes
    ----------
    machine : str
        Machine name (the history store's key).
    recording : str
        Absolute path of the recording file.
    baseline : "nominal", "history", AMBParameters or mapping
        What :func:`maglevid.diagnose.pipeline.diagnose` compares with.
    method : str or None
        Identification method (``None``: chosen from the recording).
    tolerances : float, mapping or None
        Relative engineering tolerances (``None``: the pipeline's default).
    recorded_at : datetime or None
        When the recording was taken (UTC). ``None``: the recording's
        ``metadata["recorded_at"]``, else the file's modification time.
    method_options : mapping
        Options of the identification method (part of the store's key).
    source : str
        Where the job came from, for messages (``"fleet.csv:7"``, a folder).
    """

    machine: str
    recording: str
    baseline: Any = "nominal"
    method: str | None = None
    tolerances: float | Mapping[str, float] | None = None
    recorded_at: datetime | None = None
    method_options: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.machine, str) or not self.machine.strip():
            raise DataError(f"`machine` = {self.machine!r}; expected a non-empty name")
        object.__setattr__(self, "recording", os.fspath(self.recording))
        object.__setattr__(self, "baseline", parse_baseline(self.baseline))
        object.__setattr__(self, "tolerances", parse_tolerances(self.tolerances))
        if self.recorded_at is not None:
            object.__setattr__(self, "recorded_at", _utc("recorded_at", self.recorded_at))
        if not isinstance(self.method_options, Mapping):
            raise DataError(
                f"`method_options` is {type(self.method_options).__name__}; expected a mapping"
            )
        object.__setattr__(self, "method_options", MappingProxyType(dict(self.method_options)))

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        # Plain pickle (Dask's first choice) cannot pickle the read-only mappings.
        base = dict(self.baseline) if isinstance(self.baseline, Mapping) else self.baseline
        tol = dict(self.tolerances) if isinstance(self.tolerances, Mapping) else self.tolerances
        return (
            FleetJob,
            (
                self.machine,
                self.recording,
                base,
                self.method,
                tol,
                self.recorded_at,
                dict(self.method_options),
                self.source,
            ),
        )

    @property
    def baseline_label(self) -> str:
        """The baseline in words: ``"nominal"``, ``"history"`` or ``"given parameters"``."""
        return self.baseline if isinstance(self.baseline, str) else "given parameters"

    def to_dict(self) -> dict[str, Any]:
        base = self.baseline
        if isinstance(base, AMBParameters):
            base = base.to_dict()
        elif isinstance(base, Mapping):
            base = dict(base)
        tol = dict(self.tolerances) if isinstance(self.tolerances, Mapping) else self.tolerances
        return {
            "machine": self.machine,
            "recording": self.recording,
            "baseline": base,
            "method": self.method,
            "tolerances": tol,
            "recorded_at": None if self.recorded_at is None else self.recorded_at.isoformat(),
            "method_options": dict(self.method_options),
            "source": self.source,
        }


# ---------------------------------------------------------------------------
# Field parsers (shared by the manifest, the CLI and FleetJob)
# ---------------------------------------------------------------------------


def _utc(name: str, v: Any) -> datetime:
    if isinstance(v, str):
        text = v.strip()
        try:
            v = datetime.fromisoformat(text[:-1] + "+00:00" if text.endswith("Z") else text)
        except ValueError:
            raise DataError(f"`{name}` = {text!r} is not an ISO 8601 time") from None
    if not isinstance(v, datetime):
        raise DataError(f"`{name}` is {type(v).__name__}; expected an ISO 8601 time")
    if v.tzinfo is None or v.utcoffset() is None:
        raise DataError(
            f"`{name}` = {v.isoformat()} has no time zone; expected e.g. "
            "2026-01-05T08:00:00+01:00 or ...Z (a naive time is not guessed)"
        )
    return v.astimezone(timezone.utc)


def parse_baseline(value: Any, *, relative_to: str | os.PathLike[str] | None = None) -> Any:
    """A baseline for the pipeline from ``"nominal"``, ``"history"``, parameters or a JSON file.

    A string other than ``"nominal"``/``"history"`` is the path (relative to
    ``relative_to`` when given) of a JSON object of parameter values, as for
    ``maglevid diagnose --baseline FILE``; a complete set of
    :class:`~maglevid.physics.amb.AMBParameters` fields becomes AMBParameters.
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return "nominal"
    if isinstance(value, AMBParameters):
        return value
    if isinstance(value, Mapping):
        values: dict[str, float] = {}
        for k, v in value.items():
            try:
                x = float(v)
            except (TypeError, ValueError):
                raise DataError(f"baseline value {k!r} = {v!r} is not a number") from None
            if not math.isfinite(x):
                raise DataError(f"baseline value {k!r} = {v!r} is not finite")
            values[str(k)] = x
        try:
            return AMBParameters(**values)
        except TypeError:  # not exactly the AMBParameters fields: a partial baseline
            return MappingProxyType(values)
    if not isinstance(value, str):
        raise DataError(
            f"`baseline` is {type(value).__name__}; expected 'nominal', 'history', "
            "AMBParameters, a mapping of parameter values or a JSON file"
        )
    text = value.strip()
    if text in ("nominal", "history"):
        return text
    path = Path(text)
    if relative_to is not None and not path.is_absolute():
        path = Path(relative_to) / path
    if not path.is_file():
        raise DataError(
            f"baseline {text!r}: expected 'nominal', 'history' or a JSON file of "
            f"parameter values; no file {str(path)!r}"
        )
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"baseline file {str(path)!r} is not valid JSON ({exc})") from None
    if isinstance(raw, Mapping) and isinstance(raw.get("parameters"), Mapping):
        raw = raw["parameters"]
    if not isinstance(raw, Mapping):
        raise DataError(f"baseline file {str(path)!r}: expected a JSON object of parameters")
    return parse_baseline(raw)


def parse_tolerances(value: Any) -> float | Mapping[str, float] | None:
    """Tolerances from a number, a mapping, or text ``"0.05"`` / ``"R1=0.1 Ls1=0.05"``.

    Relative fractions (0.05 = 5 %), each finite and > 0. Text items are
    separated by spaces, commas or semicolons; ``NAME=VALUE`` per parameter.
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    if isinstance(value, str):
        items = value.replace(";", " ").replace(",", " ").split()
        if len(items) == 1 and "=" not in items[0]:
            try:
                number = float(items[0])
            except ValueError:
                raise DataError(
                    f"tolerances {value!r}: expected one fraction (0.05) or NAME=FRACTION "
                    "items (R1=0.1 Ls1=0.05)"
                ) from None
            return parse_tolerances(_float("tolerances", number))
        out: dict[str, float] = {}
        for item in items:
            name, sep, v = item.partition("=")
            if not sep or not name:
                raise DataError(
                    f"tolerances {value!r}: expected one fraction (0.05) or NAME=FRACTION "
                    "items (R1=0.1 Ls1=0.05)"
                )
            out[name] = _float(f"tolerances[{name!r}]", v)
        return parse_tolerances(out)
    if isinstance(value, Mapping):
        out = {str(k): _float(f"tolerances[{k!r}]", v) for k, v in value.items()}
        if not out:
            return None
        return MappingProxyType(out)
    return _float("tolerances", value)


def _float(name: str, v: Any) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise DataError(f"`{name}` = {v!r}; expected a number") from None
    if not (math.isfinite(x) and x > 0):
        raise DataError(f"`{name}` = {v!r}; expected a finite fraction > 0 (0.05 = 5 %)")
    return x


# ---------------------------------------------------------------------------
# Manifests
# ---------------------------------------------------------------------------


def _is_manifest(path: Path) -> bool:
    """A JSON file, or a CSV file whose header names ``machine`` and ``recording``."""
    suffix = path.suffix.lower()
    if suffix == ".json":
        return True
    if suffix != ".csv":
        return False
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            header = next(csv.reader(f), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return False
    names = {h.strip().lower() for h in header}
    return {"machine", "recording"} <= names


def read_manifest(
    path: str | os.PathLike[str],
    *,
    baseline: Any = "nominal",
    method: str | None = None,
    tolerances: Any = None,
) -> list[FleetJob]:
    """Jobs from a manifest file (CSV or JSON).

    CSV: a header row, then one recording per row. JSON: a list of objects, or
    ``{"defaults": {...}, "recordings": [...]}`` where ``defaults`` holds
    values for the optional keys. Columns/keys (:data:`MANIFEST_COLUMNS`):

    ``machine``, ``recording`` (required)
        Machine name; recording path, relative to the manifest's folder.
    ``baseline``
        ``nominal``, ``history`` or a JSON file of parameter values (relative
        to the manifest's folder); empty: ``baseline``.
    ``method``
        Identification method; empty: ``method`` (``None``: chosen).
    ``tolerances``
        ``0.05`` or ``R1=0.1 Ls1=0.05`` (JSON: a number or an object).
    ``recorded_at``
        ISO 8601 time with its offset (``2026-01-05T08:00:00+01:00``).
    ``method_options``
        A JSON object (CSV: its text).

    Parameters
    ----------
    path : path-like
        The manifest.
    baseline, method, tolerances
        Values for rows that leave the column empty.

    Raises
    ------
    ManifestError
        Unreadable file, missing or unknown column, a row without machine or
        recording, or a malformed value; the message names the file and row.
    """
    p = Path(path)
    where = str(p)
    if not p.is_file():
        raise ManifestError(f"manifest {where!r} does not exist")
    folder = p.resolve().parent
    defaults: dict[str, Any] = {}
    rows: list[tuple[str, Mapping[str, Any]]]
    if p.suffix.lower() == ".json":
        try:
            raw = json.loads(p.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ManifestError(f"manifest {where!r} is not valid JSON ({exc})") from None
        if isinstance(raw, Mapping):
            extra = set(raw) - {"defaults", "recordings"}
            if extra or "recordings" not in raw:
                raise ManifestError(
                    f"manifest {where!r}: expected a list of recordings or an object with "
                    f"'recordings' (and optional 'defaults'); got keys {sorted(raw)}"
                )
            defaults = dict(raw.get("defaults") or {})
            bad = set(defaults) - set(MANIFEST_COLUMNS[2:])
            if bad:
                raise ManifestError(
                    f"manifest {where!r}: unknown defaults {sorted(bad)}; allowed "
                    f"{list(MANIFEST_COLUMNS[2:])}"
                )
            raw = raw["recordings"]
        if not isinstance(raw, list):
            raise ManifestError(f"manifest {where!r}: 'recordings' must be a list of objects")
        rows = []
        for i, row in enumerate(raw):
            if not isinstance(row, Mapping):
                raise ManifestError(f"{where}: recordings[{i}] is not an object")
            rows.append((f"{where}: recordings[{i}]", row))
    else:
        try:
            with open(p, newline="", encoding="utf-8-sig") as f:
                reader = csv.DictReader(f)
                header = [h.strip().lower() for h in (reader.fieldnames or [])]
                reader.fieldnames = header
                rows = [
                    (f"{where}:{reader.line_num}", {k: v for k, v in r.items() if k is not None})
                    for r in reader
                    if any((v or "").strip() for v in r.values() if isinstance(v, str))
                ]
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise ManifestError(f"manifest {where!r} cannot be read as CSV ({exc})") from None
        if not {"machine", "recording"} <= set(header):
            raise ManifestError(
                f"manifest {where!r}: the header must name 'machine' and 'recording'; got {header}"
            )
    defaults.setdefault("baseline", baseline)
    defaults.setdefault("method", method)
    defaults.setdefault("tolerances", tolerances)
    jobs = []
    for label, row in rows:
        unknown = sorted(set(row) - set(MANIFEST_COLUMNS))
        if unknown:
            raise ManifestError(
                f"{label}: unknown column(s) {unknown}; allowed {list(MANIFEST_COLUMNS)}"
            )
        jobs.append(_job_from_row(label, row, defaults, folder))
    return jobs


def _blank(v: Any) -> bool:
    return v is None or (isinstance(v, str) and not v.strip())


def _job_from_row(
    label: str, row: Mapping[str, Any], defaults: Mapping[str, Any], folder: Path
) -> FleetJob:
    def get(key: str) -> Any:
        v = row.get(key)
        return defaults.get(key) if _blank(v) else v

    machine, recording = row.get("machine"), row.get("recording")
    if _blank(machine) or _blank(recording):
        raise ManifestError(f"{label}: 'machine' and 'recording' are required")
    if not isinstance(machine, str) or not isinstance(recording, str):
        raise ManifestError(f"{label}: 'machine' and 'recording' must be text")
    rec = Path(recording.strip())
    if not rec.is_absolute():
        rec = folder / rec
    options = get("method_options")
    try:
        if isinstance(options, str):
            try:
                options = json.loads(options)
            except json.JSONDecodeError as exc:
                raise DataError(f"method_options is not a JSON object ({exc})") from None
        method = get("method")
        return FleetJob(
            machine=machine.strip(),
            recording=str(rec),
            baseline=parse_baseline(get("baseline"), relative_to=folder),
            method=None if _blank(method) else str(method).strip(),
            tolerances=get("tolerances"),
            recorded_at=get("recorded_at"),
            method_options=options or {},
            source=label,
        )
    except DataError as exc:
        raise ManifestError(f"{label}: {exc}") from None


# ---------------------------------------------------------------------------
# Folders, globs and files
# ---------------------------------------------------------------------------


def _is_recording(path: Path) -> bool:
    return path.suffix.lower() in RECORDING_SUFFIXES and not path.name.startswith(".")


def _walk(folder: Path) -> Iterable[Path]:
    for root, dirs, files in os.walk(folder, followlinks=False):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            p = Path(root) / name
            if _is_recording(p) and not _is_manifest(p):
                yield p


def collect_jobs(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    machine: str | None = None,
    baseline: Any = "nominal",
    method: str | None = None,
    tolerances: Any = None,
    method_options: Mapping[str, Any] | None = None,
) -> list[FleetJob]:
    """Every recording named by ``sources`` as a :class:`FleetJob`.

    Parameters
    ----------
    sources : path, glob or sequence of them
        Folders, globs, manifests (CSV/JSON) and single recording files; see
        the module docstring for how each is read and how machines are named.
    machine : str, optional
        Machine of every recording from folders, globs and files (manifests
        name their own).
    baseline, method, tolerances, method_options
        For recordings from folders, globs and files, and for manifest rows
        that leave the column empty.

    Returns
    -------
    list of FleetJob
        In the order of the sources; within a folder, sorted by path. A
        recording named twice for one machine appears twice (the runner
        diagnoses it once).

    Raises
    ------
    DataError
        A source that does not exist or matches nothing, a file that is neither
        a recording nor a manifest, or a malformed manifest (:class:`ManifestError`).
    """
    if isinstance(sources, (str, os.PathLike)):
        sources = [sources]
    if not sources:
        raise DataError("no sources given: expected folders, globs or manifest files")
    common = {
        "baseline": parse_baseline(baseline),
        "method": method,
        "tolerances": parse_tolerances(tolerances),
        "method_options": dict(method_options or {}),
    }
    jobs: list[FleetJob] = []
    for src in sources:
        text = os.fspath(src)
        path = Path(text)
        if path.is_dir():
            root = path.resolve()
            found = list(_walk(root))
            if not found:
                raise DataError(
                    f"folder {text!r} holds no recordings ({', '.join(RECORDING_SUFFIXES)})"
                )
            for p in found:
                rel = p.relative_to(root).parts
                name = machine or (rel[0] if len(rel) > 1 else root.name)
                jobs.append(FleetJob(name, str(p), source=f"folder {text}", **common))
        elif path.is_file():
            if _is_manifest(path):
                for job in read_manifest(
                    path, baseline=baseline, method=method, tolerances=tolerances
                ):
                    if method_options and not job.method_options:
                        job = FleetJob(**{**_fields(job), "method_options": method_options})
                    jobs.append(job)
            elif _is_recording(path):
                p = path.resolve()
                jobs.append(
                    FleetJob(machine or p.parent.name, str(p), source=f"file {text}", **common)
                )
            else:
                raise DataError(
                    f"{text!r} is neither a recording ({', '.join(RECORDING_SUFFIXES)}) nor a "
                    "manifest (.json, or .csv with 'machine' and 'recording' columns)"
                )
        elif _GLOB_CHARS & set(text):
            found = sorted(
                Path(m).resolve()
                for m in _glob.glob(text, recursive=True)
                if Path(m).is_file() and _is_recording(Path(m))
            )
            if not found:
                raise DataError(f"glob {text!r} matches no recording")
            for p in found:
                jobs.append(
                    FleetJob(machine or p.parent.name, str(p), source=f"glob {text}", **common)
                )
        else:
            raise DataError(f"{text!r}: no such folder, file or matching glob")
    return jobs


def _fields(job: FleetJob) -> dict[str, Any]:
    return {
        "machine": job.machine,
        "recording": job.recording,
        "baseline": job.baseline,
        "method": job.method,
        "tolerances": job.tolerances,
        "recorded_at": job.recorded_at,
        "method_options": job.method_options,
        "source": job.source,
    }
