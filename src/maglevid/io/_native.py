"""maglevid's own description of a recording, shared by every native format.

The description is :meth:`ClosedLoopData.to_dict` (format, version, dt, p, t0,
n_samples, signal names and units, loop, metadata) with the extra channels
(``metadata["extra_signals"]``) moved out of ``metadata`` into a list that says
where each one is stored: their values are columns or variables of the file,
not JSON. Every native reader turns the description into a
:class:`~maglevid.io.mapping.ColumnMapping`, so native files pass the same
checks as users' logs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import SIGNALS, ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io.mapping import ChannelSpec, ColumnMapping, TimeSpec

FORMAT_NAME = "maglevid-recording"
FORMAT_VERSION = 1

#: Time-column tolerances for maglevid's own files: the column is written as
#: ``t0 + k*dt/p`` in full precision, so only rounding of that sum remains.
NATIVE_TIME_TOLERANCE = 1e-6
NATIVE_RATE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Description:
    dt: float
    p: int
    t0: float
    n_samples: int | None
    signals: dict[str, tuple[tuple[str, ...], tuple[str, ...]]]  # signal -> (names, units)
    loop: dict[str, Any]
    metadata: dict[str, Any]
    extras: tuple[dict[str, Any], ...]  # {"name", "unit", "rate", "key"}

    def width(self, signal: str) -> int:
        return len(self.signals[signal][0])


# -------------------------------------------------------------- describe
def _variable_name(name: str, taken: set[str]) -> str:
    base = "extra_" + (re.sub(r"\W", "_", name, flags=re.ASCII) or "x")
    base = base[:60]
    key, k = base, 2
    while key in taken:
        key, k = f"{base}_{k}", k + 1
    taken.add(key)
    return key


def extra_signals(data: ClosedLoopData) -> list[tuple[str, str, str, np.ndarray]]:
    """``(name, unit, rate, values)`` of each extra channel kept in ``metadata``."""
    raw = data.metadata.get("extra_signals")
    if not raw:
        return []
    out = []
    n, L = data.n_samples, data.y.shape[0]
    for name, entry in raw.items():
        if not isinstance(entry, Mapping) or "values" not in entry:
            raise DataError(
                f"metadata['extra_signals'][{name!r}] must be a mapping with 'values' "
                "(and 'unit', 'rate')"
            )
        values = np.asarray(entry["values"], dtype=float).reshape(-1)
        rate = entry.get("rate") or ("output" if values.size == L else "control")
        if values.size != (L if rate == "output" else n):
            raise DataError(
                f"metadata['extra_signals'][{name!r}] has {values.size} values; a {rate}-rate "
                f"channel of this recording needs {L if rate == 'output' else n}"
            )
        out.append((str(name), str(entry.get("unit", "")), rate, values))
    return out


def describe(data: ClosedLoopData) -> dict[str, Any]:
    """The JSON-safe description written beside or inside a native file."""
    desc = data.to_dict()
    meta = dict(desc["metadata"])
    meta.pop("extra_signals", None)
    desc["metadata"] = meta
    taken = set(SIGNALS) | {"dt", "p", "t0", "metadata"}
    desc["extra_signals"] = [
        {"name": name, "unit": unit, "rate": rate, "key": _variable_name(name, taken)}
        for name, unit, rate, _ in extra_signals(data)
    ]
    return desc


def _unique_labels(labels: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for label in labels:
        k = seen.get(label, 0) + 1
        seen[label] = k
        out.append(label if k == 1 else f"{label}#{k}")
    return out


def column_labels(desc: Description) -> tuple[list[str], list[str]]:
    """Header labels and units of a row-per-output-sample file (CSV, Parquet)."""
    labels, units = ["t"], ["s"]
    for sig in SIGNALS:
        if sig in desc.signals:
            names, sig_units = desc.signals[sig]
            labels += [f"{sig}:{n}" for n in names]
            units += list(sig_units)
    for e in desc.extras:
        labels.append(f"extra:{e['name']}")
        units.append(e["unit"])
    return _unique_labels(labels), units


def row_columns(data: ClosedLoopData) -> tuple[list[str], list[str], list[np.ndarray]]:
    """Labels, units and output-rate columns (inputs held over each period) of ``data``."""
    p = data.p
    columns = [data.time_output]
    for sig in data.signals():
        arr = data.y if sig == "y" else np.repeat(getattr(data, sig), p, axis=0)
        columns += list(arr.T)
    for _, _, rate, values in extra_signals(data):
        columns.append(values if rate == "output" else np.repeat(values, p))
    desc = parse_description(describe(data), path=None)
    labels, units = column_labels(desc)
    return labels, units, columns


# ------------------------------------------------------------------ parse
def parse_description(raw: Any, *, path: str | None) -> Description:
    """Check a stored description; a malformed one is a :class:`FileFormatError`."""

    def bad(message: str) -> FileFormatError:
        return FileFormatError(f"malformed maglevid metadata: {message}", path=path)

    if not isinstance(raw, Mapping):
        raise bad("expected a JSON object")
    if "format" not in raw:  # "'format' is None" read as a bad value (seventeenth session)
        raise bad(
            f"no 'format' key (it has: {', '.join(map(str, list(raw)[:8])) or 'nothing'}): "
            "not a maglevid description; a file of your own is read through a column "
            "mapping (--mapping FILE.json, mapping= in Python)"
        )
    if raw.get("format") != FORMAT_NAME:
        raise bad(f"'format' is {raw.get('format')!r}; expected {FORMAT_NAME!r}")
    version = raw.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise bad(f"'version' is {version!r}; expected a positive integer")
    if version > FORMAT_VERSION:
        raise bad(
            f"'version' {version} is newer than this maglevid reads ({FORMAT_VERSION}); "
            "upgrade maglevid"
        )

    def number(key: str, default: float | None = None, positive: bool = False) -> float:
        if key not in raw and default is None:
            raise bad(f"no {key!r} is stated" + (" (the sample time in s)" if key == "dt" else ""))
        v = raw.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise bad(f"{key!r} is {v!r}; expected a finite number")
        if positive and v <= 0:
            raise bad(f"{key!r} is {v!r}; expected a positive number")
        return float(v)

    dt = number("dt", positive=True)
    p = raw.get("p", 1)
    if isinstance(p, bool) or not isinstance(p, int) or p < 1:
        raise bad(f"'p' is {p!r}; expected an integer >= 1")
    t0 = number("t0", 0.0)
    n_samples = raw.get("n_samples")
    if n_samples is not None and (
        isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 1
    ):
        raise bad(f"'n_samples' is {n_samples!r}; expected a positive integer")
    sigs = raw.get("signals")
    if not isinstance(sigs, Mapping) or "y" not in sigs:
        raise bad("'signals' must be an object with at least 'y'")
    signals: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {}
    width = None
    for sig, entry in sigs.items():
        if sig not in SIGNALS:
            raise bad(f"'signals' has unknown signal {sig!r}; expected some of {SIGNALS}")
        if not isinstance(entry, Mapping):
            raise bad(f"'signals.{sig}' must be an object with 'names' and 'units'")
        names = entry.get("names")
        units = entry.get("units", [""] * len(names) if isinstance(names, list) else None)
        ok = (
            isinstance(names, list)
            and isinstance(units, list)
            and all(isinstance(s, str) for s in [*names, *units])
        )
        if not ok or not names:
            raise bad(f"'signals.{sig}' needs 'names' and 'units', non-empty lists of strings")
        if len(names) != len(units):
            raise bad(f"'signals.{sig}' has {len(names)} names but {len(units)} units")
        if sig != "y":
            if width is not None and len(names) != width:
                raise bad(f"'signals.{sig}' has {len(names)} channels; the other inputs {width}")
            width = len(names)
        signals[sig] = (tuple(names), tuple(units))
    loop = raw.get("loop", {})
    meta = raw.get("metadata", {})
    if not isinstance(loop, Mapping) or not isinstance(meta, Mapping):
        raise bad("'loop' and 'metadata' must be objects")
    extras_raw = raw.get("extra_signals", [])
    if not isinstance(extras_raw, list):
        raise bad("'extra_signals' must be a list")
    extras = []
    for i, e in enumerate(extras_raw):
        if not (
            isinstance(e, Mapping)
            and isinstance(e.get("name"), str)
            and e.get("rate") in ("output", "control")
        ):
            raise bad(f"'extra_signals[{i}]' needs 'name' and 'rate' ('output' or 'control')")
        extras.append(
            {
                "name": e["name"],
                "unit": str(e.get("unit", "")),
                "rate": e["rate"],
                "key": str(e.get("key", "")),
            }
        )
    return Description(
        dt=dt,
        p=p,
        t0=t0,
        n_samples=n_samples,
        signals=signals,
        loop=dict(loop),
        metadata=dict(meta),
        extras=tuple(extras),
    )


# ---------------------------------------------------------------- mappings
def _base(desc: Description, origin: str, **kw: Any) -> ColumnMapping:
    return ColumnMapping(
        origin=origin,
        dt=desc.dt,
        p=desc.p,
        t0=desc.t0,
        n_samples=desc.n_samples,
        loop=desc.loop,
        metadata=desc.metadata,
        **kw,
    )


def row_mapping(desc: Description, *, origin: str) -> ColumnMapping:
    """Mapping of a row-per-output-sample file: columns by position (t first)."""
    col = 1
    signals = {}
    for sig in SIGNALS:
        if sig in desc.signals:
            names, units = desc.signals[sig]
            signals[sig] = tuple(
                ChannelSpec(column=col + j, name=n, unit=u)
                for j, (n, u) in enumerate(zip(names, units))
            )
            col += len(names)
    extra = tuple(
        ChannelSpec(column=col + j, name=e["name"], unit=e["unit"], rate=e["rate"])
        for j, e in enumerate(desc.extras)
    )
    time = TimeSpec(
        column=0, tolerance=NATIVE_TIME_TOLERANCE, rate_tolerance=NATIVE_RATE_TOLERANCE
    )
    return _base(desc, origin, time=time, signals=signals, extra=extra)


def variable_mapping(desc: Description, *, origin: str, present: set[str]) -> ColumnMapping:
    """Mapping of an NPZ/MAT file: variables ``y``, ``u``, ``r``, ``u_f``, ``extra_*``."""
    signals = {}
    for sig in SIGNALS:
        if sig in desc.signals:
            names, units = desc.signals[sig]
            signals[sig] = tuple(
                ChannelSpec(column=sig, index=j, name=n, unit=u)
                for j, (n, u) in enumerate(zip(names, units))
            )
    extra = []
    for e in desc.extras:
        if e["key"] not in present:
            raise FileFormatError(f"extra signal {e['name']!r} lacks its variable {e['key']!r}")
        extra.append(ChannelSpec(column=e["key"], name=e["name"], unit=e["unit"], rate=e["rate"]))
    return _base(desc, origin, signals=signals, extra=tuple(extra))


def source_metadata(stored: Mapping[str, Any], path: Path, fmt: str) -> dict[str, Any]:
    """Where this recording was read from (a conversion keeps the earlier source)."""
    src = str(Path(path).resolve())
    out: dict[str, Any] = {"source": src, "source_format": fmt}
    old = stored.get("source")
    if isinstance(old, str) and old and old != src:
        out["converted_from"] = old
    return out
