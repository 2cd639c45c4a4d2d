"""The one place where file columns become a :class:`ClosedLoopData`.

Every reader (native or through a user's mapping) presents the file as a
:class:`Table` of named columns or variables and hands it, with a
:class:`~maglevid.io.mapping.ColumnMapping`, to :func:`assemble`. All checks
that produce :class:`FileFormatError` live here, so every format reports
missing channels, non-uniform time, NaN/inf, too few samples, unit mismatches
and non-held inputs the same way, naming the file, the column and the row.

Layout of row-per-output-sample files (text, CSV, Parquet) with ``p > 1``
-------------------------------------------------------------------------
There are ``N*p`` rows, one per output sample; row ``k = m*p + j`` is the
output sample ``y(m T + j T/p)`` (Sun et al., Fig. 2). The inputs are held by
the zero-order hold over each control period, so an input column repeats
its value ``p`` times: ``u[m] = column[m*p] = ... = column[m*p + p - 1]``.
The reader takes ``column[::p]`` after checking the repetition exactly (a
column that changes inside a period was not sampled at the control rate, and
taking every ``p``-th value would silently alias it).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import MIN_SAMPLES, SIGNALS, ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io.mapping import ChannelSpec, ColumnMapping

log = logging.getLogger(__name__)

Key = str | int


class Table:
    """A file seen as columns (text, Parquet) or variables (NPZ, MAT).

    Subclasses fill ``names`` (``None`` when columns have no names, e.g. a
    header-less text file: then they are addressed by 0-based index) and
    implement :meth:`load`.
    """

    kind = "table"

    def __init__(self, path: Path, names: Sequence[str] | None, n_columns: int):
        self.path = path
        self.names = None if names is None else tuple(names)
        self.n_columns = n_columns
        #: Bare names (header "gap [mm]" -> "gap") to full names.
        self.aliases: dict[str, str] = {}
        #: Units stated by the file: key -> unit, or key -> list of units (2-D variables).
        self.units: dict[Key, Any] = {}
        #: Information about the file for ``metadata`` (header comments, ...).
        self.metadata: dict[str, Any] = {}
        #: Index of this table's first row in the whole file (chunked reading).
        self.row_offset = 0

    # -- to be implemented -------------------------------------------------
    def load(self, keys: Sequence[Key]) -> dict[Key, np.ndarray]:  # pragma: no cover
        raise NotImplementedError

    def where(self, row: int) -> str:
        """Human description of a 0-based data row, for messages."""
        return f"row {row + self.row_offset}"

    # -- shared -------------------------------------------------------------
    def label(self, key: Key, index: int | None = None) -> str:
        """How a column is named in messages."""
        base = key if isinstance(key, str) else f"#{key}"
        return base if index is None else f"{base}[{index}]"

    def default_name(self, key: Key) -> str | None:
        """A channel name taken from the file (header name without its unit), if any."""
        if not isinstance(key, str):
            return None
        for bare, full in self.aliases.items():
            if full == key:
                return bare
        return key

    def error(self, message: str, column: str | None = None) -> FileFormatError:
        return FileFormatError(message, path=str(self.path), column=column)

    def resolve(self, ref: Key) -> Key:
        """The key of a column reference (name or 0-based index)."""
        if isinstance(ref, int):
            if ref >= self.n_columns:
                raise self.error(
                    f"column index {ref} is out of range: the file has {self.n_columns} "
                    "column(s), indexed from 0",
                    column=str(ref),
                )
            return self.names[ref] if self.names is not None else ref
        if self.names is None:
            raise self.error(
                "the file has no column names (no header): refer to columns by 0-based index "
                'or name them with "columns" in the mapping',
                column=ref,
            )
        if ref in self.names:
            return ref
        if ref in self.aliases:
            return self.aliases[ref]
        shown = ", ".join(repr(n) for n in self.names[:30])
        more = f" (+{len(self.names) - 30} more)" if len(self.names) > 30 else ""
        raise self.error(f"missing: the file has {shown}{more}", column=ref)

    def stated_unit(self, key: Key, index: int | None) -> str | None:
        unit = self.units.get(key)
        if isinstance(unit, (list, tuple)):
            if index is None or index >= len(unit):
                return None
            unit = unit[index]
        return unit or None


class ArrayTable(Table):
    """A table over arrays already in memory (NPZ, MAT, Parquet chunks)."""

    def __init__(
        self,
        path: Path,
        arrays: Mapping[str, Any],
        *,
        kind: str,
        order: Sequence[str] | None = None,
        matlab: bool = False,
    ):
        names = list(order) if order is not None else list(arrays)
        super().__init__(path, names, len(names))
        self.kind = kind
        self._arrays = arrays
        self._matlab = matlab

    def load(self, keys: Sequence[Key]) -> dict[Key, np.ndarray]:
        out = {}
        for key in keys:
            value = self._arrays[key]  # type: ignore[index]
            if callable(value):
                value = value()
            out[key] = value
        return out

    def where(self, row: int) -> str:
        k = row + self.row_offset
        return f"sample {k} (MATLAB index {k + 1})" if self._matlab else f"row {k}"


# ---------------------------------------------------------------- layout
def _transposed(table: Table, key: Key, shape: tuple[int, ...], layout: str) -> bool:
    """Whether a stored 2-D variable of ``shape`` is channels x samples (see :func:`orient`)."""
    name = table.label(key)
    if len(shape) > 2:
        raise table.error(
            f"has {len(shape)} dimensions {shape}; expected a vector or a matrix", column=name
        )
    if len(shape) < 2:
        return False
    rows, cols = shape
    if rows == 0 or cols == 0:
        raise table.error(
            f"is an empty variable ({rows}x{cols}: 0 samples); a recording needs at least "
            f"{MIN_SAMPLES} samples",
            column=name,
        )
    if layout == "channels_first":
        return True
    if layout == "time_first":
        return False
    if rows == 1:
        return True  # a MATLAB row vector: one channel
    if rows < cols:
        raise table.error(
            f"has shape {tuple(shape)} ({rows} rows x {cols} columns). maglevid wants time "
            "along the rows (samples x channels); this looks like channels x samples, as "
            "MATLAB users often store signals. It is not transposed silently: store the "
            f"transpose ({key}.' in MATLAB), or read it with a mapping "
            '{"layout": "channels_first"} (mapping= in Python, --mapping FILE.json on the '
            f'command line), or "time_first" if it really holds {rows} samples of {cols} '
            "channels",
            column=name,
        )
    return False


def orient(table: Table, key: Key, value: Any, layout: str) -> np.ndarray:
    """A stored variable as a time-first 2-D float array, or a clear error.

    A 1-D array and a MATLAB row vector ``(1, N)`` are one channel. A 2-D
    array with fewer rows than columns looks like channels x samples (how many
    MATLAB users store signals); it is *not* transposed silently: the mapping
    must say ``"layout": "channels_first"`` (or ``"time_first"`` if it really
    is a short record with many channels).
    """
    name = table.label(key)
    a = np.asarray(value)
    if a.dtype.kind == "c":
        raise table.error(
            f"holds complex numbers ({a.dtype}); a recording's signals must be real. Store "
            "the real part (real(x) in MATLAB, x.real in numpy) or whichever real quantity "
            "was measured",
            column=name,
        )
    if a.dtype.kind not in "biuf":
        raise table.error(
            f"holds {a.dtype} data, not numbers (a MATLAB cell/struct/char variable?)",
            column=name,
        )
    a = a.astype(float, copy=False)
    if a.ndim == 0:
        raise table.error("is a scalar, not a signal", column=name)
    if a.ndim == 1:
        return a[:, None]
    return a.T if _transposed(table, key, a.shape, layout) else a


def oriented_width(table: Table, key: Key, shape: tuple[int, ...], layout: str) -> int:
    """Number of channels a variable of ``shape`` has once oriented (no data loaded)."""
    if len(shape) == 0:
        raise table.error("is a scalar, not a signal", column=table.label(key))
    if len(shape) == 1:
        return 1
    return shape[0] if _transposed(table, key, tuple(shape), layout) else shape[1]


# ---------------------------------------------------------------- checks
def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def check_finite_column(table: Table, values: np.ndarray, column: str) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        k = _first_bad(bad)
        kind = "NaN" if np.isnan(values[k]) else "inf"
        raise table.error(
            f"{int(bad.sum())} non-finite value(s) ({kind} first at {table.where(k)}); "
            "remove or interpolate them first",
            column=column,
        )


def check_time(
    table: Table,
    t: np.ndarray,
    column: str,
    *,
    step: float | None,
    tolerance: float,
    rate_tolerance: float,
    t_before: float | None = None,
) -> float:
    """Check a time column is uniform; return its output sample interval.

    ``step`` is the expected interval ``dt/p`` (``None``: estimated as the
    mean step). Each step must be within ``tolerance * step`` of it, and the
    mean step within ``rate_tolerance * step``. ``t_before`` is the time of the
    row before this table (chunked reading), so chunk joins are checked too.
    """
    check_finite_column(table, t, column)
    offset = 0
    if t_before is not None:
        t = np.concatenate(([t_before], t))
        offset = -1
    if t.size < 2:
        return float(step) if step is not None else math.nan
    mean = (t[-1] - t[0]) / (t.size - 1)
    ref = mean if step is None else step
    steps = np.diff(t)
    if not ref > 0 or np.any(steps <= 0):
        k = _first_bad(steps <= 0) if np.any(steps <= 0) else 0
        raise table.error(
            f"time does not increase: from {table.where(k + offset)} to "
            f"{table.where(k + 1 + offset)} it goes {float(t[k])!r} -> {float(t[k + 1])!r}",
            column=column,
        )
    # Time stamps far from zero (an epoch t0) carry rounding of a few ulps of |t|
    # in every value, whatever the tolerance: allow it on top.
    slack = 4 * np.finfo(float).eps * max(abs(float(t[0])), abs(float(t[-1])))
    bad = np.abs(steps - ref) > tolerance * ref + slack
    if bad.any() and step is not None and abs(mean - step) > rate_tolerance * step:
        # every step alike but not dt: a unit or a dt, not a gap (a time column in ms
        # against a dt in s was "non-uniform time ... 19999 bad steps": found from
        # outside, issue 16, thirteenth session)
        if np.all(np.abs(steps - mean) <= tolerance * mean + slack):
            ratio = mean / step
            unit = (
                " (the time column in ms?)" if abs(ratio / 1000 - 1) < 0.01
                else " (the time column in us?)" if abs(ratio * 1000 - 1) < 0.01
                else ""
            )  # fmt: skip
            raise table.error(
                f"the time steps are uniform at {mean:.9g} s, {ratio:.6g} times the expected "
                f"dt/p = {step:.9g} s{unit}: is the time column in seconds, and the dt "
                "right?",
                column=column,
            )
    if bad.any():
        k = _first_bad(bad)
        raise table.error(
            f"non-uniform time: the step from {table.where(k + offset)} to "
            f"{table.where(k + 1 + offset)} is {steps[k]:.9g} s; expected {ref:.9g} s within "
            f"{tolerance:.3g} (relative) ({int(bad.sum())} bad step(s)); a gap or dropped "
            'samples? If the time stamps are only coarsely printed, raise "time.tolerance" '
            "in the mapping",
            column=column,
        )
    rate_slack = slack / (t.size - 1)
    if (
        step is not None
        and t_before is None
        and abs(mean - step) > rate_tolerance * step + rate_slack
    ):
        raise table.error(
            f"the mean time step is {mean:.9g} s but dt/p = {step:.9g} s (relative difference "
            f"{abs(mean - step) / step:.3g} > {rate_tolerance:.3g}): is the mapping's dt right?",
            column=column,
        )
    return float(ref)


def check_held(table: Table, values: np.ndarray, p: int, column: str) -> np.ndarray:
    """Inputs logged at the output rate must repeat over each control period; return ``[::p]``."""
    if p == 1:
        return values
    blocks = values.reshape(-1, p)
    bad = blocks != blocks[:, :1]
    if bad.any():
        k = _first_bad(bad.ravel())
        m = k // p
        raise table.error(
            f"an input must be held over each control period (p={p} rows per period), but "
            f"{table.where(k)} ({float(values[k])!r}) differs from {table.where(m * p)} "
            f"({float(values[m * p])!r}), the first row of its period",
            column=column,
        )
    return values[::p]


# ---------------------------------------------------------------- assemble
def _channel_name(table: Table, spec: ChannelSpec, key: Key, signal: str, i: int) -> str:
    if spec.name is not None:
        return spec.name
    base = table.default_name(key)
    if base is not None:
        return base if spec.index is None else f"{base}{spec.index + 1}"
    return f"{signal}{i + 1}"


def _check_unit(table: Table, spec: ChannelSpec, key: Key, column: str) -> None:
    stated = table.stated_unit(key, spec.index)
    expected = spec.expected_file_unit
    if stated is not None and expected is not None and stated != expected:
        raise table.error(
            f"unit mismatch: the file says {stated!r}, the mapping expects {expected!r} "
            '(give "file_unit" and "scale" to convert)',
            column=column,
        )


def _check_time_unit(table: Table, mapping: ColumnMapping, time_key: Key | None) -> None:
    """The time column's stated unit (a ``time [ms]`` header) against the mapping's: a
    header in ms under a mapping in s read a 10 kHz log as 10 Hz and identified R1 =
    1.8e-8 ohm with one warning (found from outside, seventeenth session), where a
    channel's unit was checked already."""
    if time_key is None or mapping.time is None:
        return
    stated = table.stated_unit(time_key, None)
    if stated is None or stated == mapping.time.unit:
        return
    from maglevid.io.mapping import TIME_UNITS

    scale = mapping.time.scale  # seconds per file unit
    if stated in TIME_UNITS and abs(TIME_UNITS[stated] - scale) > 1e-9 * scale:
        raise table.error(
            f"unit mismatch: the file says {stated!r}, the mapping reads the time in "
            f'{mapping.time.unit!r} (give the mapping\'s time "unit": "{stated}")',
            column=table.label(time_key),
        )


def assemble(
    table: Table,
    mapping: ColumnMapping,
    *,
    t_before: float | None = None,
    dt_known: float | None = None,
    t0_known: float | None = None,
    extra_metadata: Mapping[str, Any] | None = None,
) -> ClosedLoopData:
    """Apply ``mapping`` to ``table`` and return the checked recording.

    ``t_before``/``dt_known``/``t0_known`` are for chunked reading (the time
    of the previous row, the recording's dt, and this chunk's start time);
    ``extra_metadata`` is added to the recording's metadata (its source).
    """
    if mapping.n_columns is not None and table.n_columns != mapping.n_columns:
        raise table.error(
            f"has {table.n_columns} column(s); the mapping ({mapping.origin}) expects "
            f"{mapping.n_columns}"
        )
    p = mapping.p or 1
    # Resolve every reference first: a missing channel is reported before any loading.
    plan, wide, time_key, raw = _resolve(table, mapping)
    _check_time_unit(table, mapping, time_key)
    column_of = _ColumnReader(table, raw, mapping.layout)
    ch = _read_channels(table, plan, wide, column_of, mapping.origin)  # outputs fix L = N*p
    n = _check_length(table, mapping, ch, p, t_before)
    dt, t0 = _time_axis(
        table, mapping, time_key, column_of, ch.length, n, p, t_before, dt_known, t0_known
    )
    arrays = _signal_arrays(table, mapping, ch, n, p)
    extras = _extra_channels(table, plan, column_of, ch.length, n, p)
    _check_units(table, mapping, arrays, ch)

    metadata = dict(mapping.metadata)
    metadata.update(table.metadata)
    metadata.update(extra_metadata or {})
    if extras:
        metadata["extra_signals"] = extras
    try:
        return ClosedLoopData(
            y=arrays["y"],
            dt=dt,
            u=arrays.get("u"),
            r=arrays.get("r"),
            u_f=arrays.get("u_f"),
            p=p,
            names={s: ch.names[s] for s in arrays},
            units={s: ch.units[s] for s in arrays},
            t0=0.0 if t0 is None else t0,
            loop=mapping.loop,
            metadata=metadata,
        )
    except DataError as exc:
        raise table.error(str(exc)) from None


_Plan = list[tuple[str, int, ChannelSpec, Key]]


def _resolve(
    table: Table, mapping: ColumnMapping
) -> tuple[_Plan, dict[ChannelSpec, list[Key]], Key | None, Mapping[Key, Any]]:
    """Every channel's column (signal, index, spec, key), the wide layout's, time; loaded."""
    plan: _Plan = []
    for sig in SIGNALS:
        for i, spec in enumerate(mapping.signals.get(sig, ())):
            plan.append((sig, i, spec, table.resolve(spec.column)))
    for i, spec in enumerate(mapping.extra):
        plan.append(("extra", i, spec, table.resolve(spec.column)))
    wide = {
        spec: [table.resolve(c) for c in spec.intersamples]
        for sig, _, spec, _ in plan
        if spec.intersamples
    }
    time_key = None if mapping.time is None else table.resolve(mapping.time.column)
    keys = [k for *_, k in plan] + [k for ks in wide.values() for k in ks]
    keys = list(dict.fromkeys(keys + ([] if time_key is None else [time_key])))
    return plan, wide, time_key, table.load(keys)


class _ColumnReader:
    """``(spec, key) -> (values, label)``: one column, oriented once per key."""

    def __init__(self, table: Table, raw: Mapping[Key, Any], layout: str) -> None:
        self.table, self.raw, self.layout = table, raw, layout
        self.oriented: dict[Key, np.ndarray] = {}

    def __call__(self, spec: ChannelSpec, key: Key) -> tuple[np.ndarray, str]:
        table = self.table
        if key not in self.oriented:
            self.oriented[key] = orient(table, key, self.raw[key], self.layout)
        arr = self.oriented[key]
        width = arr.shape[1]
        if spec.index is None and width > 1:
            raise table.error(
                f'has {width} columns; say which with "index" (0-based) in the mapping',
                column=table.label(key),
            )
        idx = spec.index or 0
        if idx >= width:
            raise table.error(
                f"has {width} column(s); index {idx} is out of range (0-based)",
                column=table.label(key),
            )
        return arr[:, idx], table.label(key, spec.index if width > 1 else None)


@dataclass
class _Channels:
    """The signals' columns as read (unscaled), with names, units and labels."""

    columns: dict[str, list[np.ndarray]]
    names: dict[str, list[str]]
    units: dict[str, list[str]]
    labels: dict[str, list[str]]
    length: int  # output samples L = N*p


def _read_channels(
    table: Table,
    plan: _Plan,
    wide: Mapping[ChannelSpec, list[Key]],
    column_of: _ColumnReader,
    origin: str,
) -> _Channels:
    """Read ``y``, ``u``, ``r``, ``u_f``; every output channel must have the same length."""
    columns: dict[str, list[np.ndarray]] = {s: [] for s in SIGNALS}
    names: dict[str, list[str]] = {s: [] for s in SIGNALS}
    units: dict[str, list[str]] = {s: [] for s in SIGNALS}
    labels: dict[str, list[str]] = {s: [] for s in SIGNALS}
    length: int | None = None
    for sig, i, spec, key in plan:
        if sig == "extra":
            continue
        if spec in wide:
            values, label = _interleaved(table, spec, wide[spec], column_of)
        else:
            values, label = column_of(spec, key)
            _check_unit(table, spec, key, label)
        if sig == "y":
            if length is None:
                length = values.size
            elif values.size != length:
                raise table.error(
                    f"has {values.size} samples; the first output channel has {length}",
                    column=label,
                )
        columns[sig].append(values)
        labels[sig].append(label)
        names[sig].append(_channel_name(table, spec, key, sig, i))
        units[sig].append(spec.unit)
    if length is None:
        raise table.error(f"the mapping ({origin}) places no output channel 'y'")
    return _Channels(columns, names, units, labels, length)


def _check_length(
    table: Table, mapping: ColumnMapping, ch: _Channels, p: int, t_before: float | None
) -> int:
    """The number of control periods ``N``: enough, whole, and as the metadata says."""
    length = ch.length
    min_rows = MIN_SAMPLES * p if t_before is None else p
    if length < min_rows:
        raise table.error(
            f"too few samples: {length} output sample(s); at least {MIN_SAMPLES * p} "
            f"(= {MIN_SAMPLES} control periods x p={p}) are needed",
            column=ch.labels["y"][0],
        )
    if length % p:
        raise table.error(
            f"{length} output samples are not a whole number of control periods of p={p} "
            "samples (an incomplete last period?)",
            column=ch.labels["y"][0],
        )
    n = length // p
    if mapping.n_samples is not None and t_before is None and n != mapping.n_samples:
        raise table.error(
            f"has {n} control period(s) ({length} rows); the metadata says "
            f"{mapping.n_samples}: the file is truncated or was edited",
            column=ch.labels["y"][0],
        )
    return n


def _time_axis(
    table: Table,
    mapping: ColumnMapping,
    time_key: Key | None,
    column_of: _ColumnReader,
    length: int,
    n: int,
    p: int,
    t_before: float | None,
    dt_known: float | None,
    t0_known: float | None,
) -> tuple[float, float | None]:
    """``dt`` and ``t0`` from the mapping, the chunk's context, or the checked time column."""
    dt = mapping.dt if mapping.dt is not None else dt_known
    t0 = mapping.t0 if t0_known is None else t0_known
    if time_key is not None and mapping.time is not None:
        spec_t = ChannelSpec(column=mapping.time.column)
        t_raw, t_label = column_of(spec_t, time_key)
        if t_raw.size not in (length, n):
            raise table.error(
                f"has {t_raw.size} rows; expected {length} (one per output sample)",
                column=t_label,
            )
        t = t_raw * mapping.time.scale
        rows_per_step = 1 if t_raw.size == length else p
        step = check_time(
            table,
            t,
            t_label,
            step=None if dt is None else dt / p * rows_per_step,
            tolerance=mapping.time.tolerance,
            rate_tolerance=mapping.time.rate_tolerance,
            t_before=t_before,
        )
        if dt is None:
            dt = step * p / rows_per_step
        if t0 is None:
            t0 = float(t[0])
    if dt is None:
        raise table.error(
            f"no time column and no sample time: the mapping ({mapping.origin}) must give "
            '"time" (a time column) or "dt" (control period, s) / "sample_rate" (Hz)'
        )
    return dt, t0


def _signal_arrays(
    table: Table, mapping: ColumnMapping, ch: _Channels, n: int, p: int
) -> dict[str, np.ndarray]:
    """Finite values; inputs held over each period or at the control rate; scaled."""
    arrays: dict[str, np.ndarray] = {}
    for sig in SIGNALS:
        if not ch.columns[sig]:
            continue
        cols = []
        for spec, values, label in zip(mapping.signals[sig], ch.columns[sig], ch.labels[sig]):
            check_finite_column(table, values, label)
            if sig != "y":
                if values.size == ch.length:
                    values = check_held(table, values, p, label)
                elif values.size != n:
                    raise table.error(
                        f"has {values.size} samples; expected {n} (one per control period) "
                        f"or {ch.length} (one per output sample, held over each period)",
                        column=label,
                    )
            cols.append(values * spec.scale + spec.offset if _scaled(spec) else values)
        arrays[sig] = np.column_stack(cols)
    return arrays


def _extra_channels(
    table: Table, plan: _Plan, column_of: _ColumnReader, length: int, n: int, p: int
) -> dict[str, dict[str, Any]]:
    """Extra channels (kept in ``metadata["extra_signals"]``), at the output or control rate."""
    extras: dict[str, dict[str, Any]] = {}
    for sig, i, spec, key in plan:
        if sig != "extra":
            continue
        values, label = column_of(spec, key)
        _check_unit(table, spec, key, label)
        check_finite_column(table, values, label)
        rate = spec.rate or ("output" if values.size == length else "control")
        if rate == "control" and values.size == length:
            values = check_held(table, values, p, label)
        want = length if rate == "output" else n
        if values.size != want:
            raise table.error(
                f"has {values.size} samples; a {rate}-rate channel needs {want}", column=label
            )
        if _scaled(spec):
            values = values * spec.scale + spec.offset
        name = spec.name if spec.name is not None else _channel_name(table, spec, key, "x", i)
        extras[name] = {"unit": spec.unit, "rate": rate, "values": values}
    return extras


def _check_units(
    table: Table, mapping: ColumnMapping, arrays: Mapping[str, np.ndarray], ch: _Channels
) -> None:
    """``u = u_f + r`` needs one unit per input channel; then the mapping's expectations."""
    units, labels = ch.units, ch.labels
    present = [s for s in ("u", "r", "u_f") if s in arrays]
    for j in range(arrays[present[0]].shape[1] if present else 0):
        seen = {s: units[s][j] for s in present if j < len(units[s]) and units[s][j]}
        if len(set(seen.values())) > 1:
            sig = next(iter(seen))
            raise table.error(
                f"inconsistent units for input channel {j}: {seen}; u = u_f + r needs one unit",
                column=labels[sig][j],
            )
    for sig, expected in mapping.expect_units.items():
        if sig not in arrays:
            raise table.error(f"the mapping expects signal {sig!r}, which the file lacks")
        got = units[sig]
        if len(expected) != len(got):
            raise table.error(
                f"the mapping expects {len(expected)} {sig!r} channel(s) with units "
                f"{list(expected)}; the file has {len(got)}"
            )
        for j, (g, e) in enumerate(zip(got, expected)):
            if g != e:
                raise table.error(
                    f"unit mismatch: {g!r} in the file, the mapping expects {e!r}",
                    column=labels[sig][j],
                )


def _interleaved(
    table: Table, spec: ChannelSpec, keys: Sequence[Key], column_of: Any
) -> tuple[np.ndarray, str]:
    """One output of the wide layout: ``p`` columns of one row per period, sample by sample.

    Row ``m`` of column ``j`` is ``y(mT + jT/p)``, so the interleaved series is
    ``[row 0 of columns 0..p-1, row 1 of columns 0..p-1, ...]`` (Sun et al., Fig. 2).
    """
    cols, labels = [], []
    for key in keys:
        one = ChannelSpec(column=key, index=spec.index, unit=spec.unit, file_unit=spec.file_unit)
        values, label = column_of(one, key)
        _check_unit(table, spec, key, label)
        if cols and values.size != cols[0].size:
            raise table.error(
                f"has {values.size} rows; inter-sample column {labels[0]!r} has {cols[0].size}",
                column=label,
            )
        cols.append(values)
        labels.append(label)
    return np.column_stack(cols).ravel(), "+".join(labels)


def _scaled(spec: ChannelSpec) -> bool:
    return spec.scale != 1.0 or spec.offset != 0.0
