"""Parquet (pyarrow): one row per output sample, description in the schema metadata.

Columns are those of the CSV format (``t``, ``y:<name>``, ..., inputs held
over each control period, ``extra:<name>``), each float64 with its unit in
the field metadata (``unit``); the JSON description is the schema's key-value
metadata under ``maglevid``. Row groups hold :data:`ROW_GROUP_ROWS` rows, so
:func:`iter_parquet_chunks` streams a long recording with bounded memory.
"""

from __future__ import annotations

import itertools
import json
import logging
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import MIN_SAMPLES, ClosedLoopData
from maglevid.exceptions import FileFormatError
from maglevid.io import _native
from maglevid.io._engine import ArrayTable, Table, assemble, check_time
from maglevid.io._files import not_readable
from maglevid.io.mapping import ColumnMapping

log = logging.getLogger(__name__)

#: Rows per Parquet row group written (a multiple of every p up to 64 that divides 2**18).
ROW_GROUP_ROWS = 2**18
METADATA_KEY = b"maglevid"


def _pyarrow(path: Path) -> tuple[Any, Any]:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ModuleNotFoundError:  # pragma: no cover - optional extra
        raise FileFormatError(
            "Parquet needs pyarrow (pip install 'maglevid[parquet]')", path=str(path)
        ) from None
    return pa, pq


def _open(path: Path, *, pre_buffer: bool = True) -> Any:
    pa, pq = _pyarrow(path)
    try:
        return pq.ParquetFile(path, pre_buffer=pre_buffer)
    except (pa.ArrowInvalid, pa.ArrowIOError, OSError) as exc:
        raise not_readable(path, "Parquet file", "parquet", exc) from None


def _column_to_numpy(path: Path, name: str, column: Any) -> np.ndarray:
    """A Parquet column as float64; timestamps become seconds, nulls are an error."""
    pa, _ = _pyarrow(path)
    import pyarrow.compute as pc

    if column.null_count:
        first = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
        raise FileFormatError(
            f"{column.null_count} missing value(s) (null), first at row {first}",
            path=str(path),
            column=name,
        )
    typ = column.type
    if pa.types.is_timestamp(typ) or pa.types.is_duration(typ):
        ns = pc.cast(
            column, pa.timestamp("ns") if pa.types.is_timestamp(typ) else pa.duration("ns")
        )
        return ns.cast(pa.int64()).to_numpy().astype(float) * 1e-9
    if not (pa.types.is_floating(typ) or pa.types.is_integer(typ) or pa.types.is_boolean(typ)):
        raise FileFormatError(f"holds {typ} values, not numbers", path=str(path), column=name)
    return column.to_numpy().astype(float, copy=False)


class _ParquetTable(ArrayTable):
    kind = "parquet"


def _table(path: Path, pf: Any, *, columns: dict[str, Any] | None = None) -> Table:
    """The file (or, with ``columns``, one chunk of it) as a table of named columns."""
    schema = pf.schema_arrow
    names = list(schema.names)

    def loader(name: str) -> Callable[[], np.ndarray]:
        def load() -> np.ndarray:
            col = columns[name] if columns is not None else pf.read(columns=[name]).column(0)
            return _column_to_numpy(path, name, col)

        return load

    table = _ParquetTable(path, {n: loader(n) for n in names}, kind="parquet", order=names)
    for field in schema:
        meta = field.metadata or {}
        if b"unit" in meta:
            table.units[field.name] = meta[b"unit"].decode("utf-8")
    return table


def _description(path: Path, pf: Any) -> _native.Description | None:
    meta = pf.schema_arrow.metadata or {}
    if METADATA_KEY not in meta:
        return None
    try:
        raw = json.loads(meta[METADATA_KEY].decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(
            f"malformed maglevid metadata in the Parquet schema: {exc}", path=str(path)
        ) from None
    desc = _native.parse_description(raw, path=str(path))
    expected, _ = _native.column_labels(desc)
    names = list(pf.schema_arrow.names)
    if names != expected:
        for i, (got, want) in enumerate(zip(names, expected)):
            if got != want:
                raise FileFormatError(
                    f"column {i} is {got!r}, but the metadata describes {want!r}",
                    path=str(path),
                    column=got,
                )
        raise FileFormatError(
            f"has {len(names)} columns; the metadata describes {len(expected)}: {expected}",
            path=str(path),
        )
    return desc


def _mapping(path: Path, pf: Any, mapping: ColumnMapping | None) -> tuple[ColumnMapping, dict]:
    if mapping is not None and mapping.has_signals:
        return mapping, _native.source_metadata({}, path, "parquet") | {"mapping": mapping.origin}
    desc = _description(path, pf)
    if desc is None:
        raise FileFormatError(
            "not a maglevid recording (no 'maglevid' key in the schema metadata); to import "
            f"its columns {pf.schema_arrow.names[:20]}, read it through a column mapping "
            "(--mapping FILE.json or a preset name on the command line, mapping= in Python; "
            "see docs/recording-format.md)",
            path=str(path),
        )
    native = _native.row_mapping(desc, origin="parquet schema metadata")
    if mapping is not None:
        native = native.with_options(mapping)
    return native, _native.source_metadata(desc.metadata, path, "parquet")


def read_parquet(path: Path, mapping: ColumnMapping | None) -> ClosedLoopData:
    pf = _open(path)
    m, md = _mapping(path, pf, mapping)
    return assemble(_table(path, pf), m, extra_metadata=md)


def iter_parquet_chunks(
    path: Path, chunk_size: int, mapping: ColumnMapping | None
) -> Iterator[ClosedLoopData]:
    """Stream a Parquet recording as consecutive segments of ``chunk_size`` control periods.

    Only the columns the mapping uses are read, one record batch at a time;
    the time column is checked across chunk joins. The last chunk takes the
    remainder; a remainder shorter than two control periods joins the chunk
    before it.
    """
    pa, _ = _pyarrow(path)
    # Without pre-buffering: with it, pyarrow keeps every column chunk it has read
    # until the reader is closed (measured: +72 MB per 10^6-row batch of a
    # 10-column file, 8 GB for 10^8 rows), which defeats streaming.
    pf = _open(path, pre_buffer=False)
    m, md = _mapping(path, pf, mapping)
    p = m.p or 1
    rows = pf.metadata.num_rows
    if rows < MIN_SAMPLES * p or rows % p:
        # Let the full reader produce the precise error.
        yield read_parquet(path, mapping)
        return
    n = rows // p
    if m.n_samples is not None and m.n_samples != n:
        raise FileFormatError(
            f"has {n} control period(s) ({rows} rows); the metadata says {m.n_samples}: the "
            "file is truncated or was edited",
            path=str(path),
        )
    table_all = _table(path, pf)
    dt = m.dt
    t0 = m.t0
    if m.time is not None and (dt is None or t0 is None):
        # dt and t0 of the whole record, from its time column (one column read).
        key = table_all.resolve(m.time.column)
        t = table_all.load([key])[key] * m.time.scale
        step = check_time(
            table_all,
            t,
            table_all.label(key),
            step=None if dt is None else dt / p,
            tolerance=m.time.tolerance,
            rate_tolerance=m.time.rate_tolerance,
        )
        dt = step * p if dt is None else dt
        t0 = float(t[0]) if t0 is None else t0
    if dt is None:
        raise FileFormatError(
            'no time column and no sample time: the mapping must give "time" or "dt"',
            path=str(path),
        )
    t0 = 0.0 if t0 is None else t0
    bounds = [*list(range(0, n, chunk_size)), n]
    if len(bounds) > 2 and bounds[-1] - bounds[-2] < MIN_SAMPLES:
        del bounds[-2]
    m_chunk = replace(m, n_samples=None)
    used = _used_columns(table_all, m)
    batches = pf.iter_batches(batch_size=min(max(chunk_size * p, 1024), 2**20), columns=used)
    pending: list[Any] = []
    pending_rows = 0
    t_before: float | None = None
    time_key = None if m.time is None else table_all.resolve(m.time.column)
    for start, stop in itertools.pairwise(bounds):
        need = (stop - start) * p
        while pending_rows < need:
            batch = next(batches)
            pending.append(batch)
            pending_rows += batch.num_rows
        merged = pa.Table.from_batches(pending)
        chunk, rest = merged.slice(0, need), merged.slice(need)
        pending = rest.to_batches() if rest.num_rows else []
        pending_rows = rest.num_rows
        cols = {name: chunk.column(name).combine_chunks() for name in used}
        table = _table(path, pf, columns=cols)
        table.row_offset = start * p
        data = assemble(
            table,
            m_chunk,
            t_before=t_before,
            dt_known=dt,
            t0_known=t0 + start * dt,
            extra_metadata=md | {"chunk": {"start": start, "stop": stop, "n_total": n}},
        )
        if time_key is not None and m.time is not None:
            t_last = _column_to_numpy(path, str(time_key), cols[time_key])[-1]
            t_before = float(t_last) * m.time.scale
        yield data


def _used_columns(table: Table, m: ColumnMapping) -> list[str]:
    refs = [c.column for sig in m.signals.values() for c in sig] + [c.column for c in m.extra]
    if m.time is not None:
        refs.append(m.time.column)
    return list(dict.fromkeys(str(table.resolve(r)) for r in refs))


def write_parquet(data: ClosedLoopData, tmp: Path) -> None:
    pa, pq = _pyarrow(tmp)
    labels, units, columns = _native.row_columns(data)
    desc = _native.describe(data)
    desc["file"] = {
        "format": "parquet",
        "columns": labels,
        "column_units": units,
        "rows": int(data.y.shape[0]),
        "time_column": "t",
        "layout": "one row per output sample (N*p rows); inputs held over each control "
        "period (p equal rows)",
    }
    fields = [
        pa.field(label, pa.float64(), nullable=False, metadata={"unit": unit} if unit else None)
        for label, unit in zip(labels, units)
    ]
    schema = pa.schema(fields, metadata={METADATA_KEY: json.dumps(desc).encode("utf-8")})
    table = pa.Table.from_arrays(
        [pa.array(np.asarray(c, dtype=float)) for c in columns], schema=schema
    )
    # No dictionary encoding: measured floats rarely repeat, and trying it costs 6x the time.
    pq.write_table(table, tmp, row_group_size=ROW_GROUP_ROWS, use_dictionary=False)
