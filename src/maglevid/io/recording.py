"""Read and write closed-loop recordings: :func:`read_recording`, :func:`write_recording`.

Formats (chosen by the extension, or ``format=``):

=============  =============================================  =========  =========
format         file(s)                                        read       write
=============  =============================================  =========  =========
``csv``        ``rec.csv`` + JSON side-car ``rec.json``       yes        yes
``npz``        ``rec.npz`` (arrays + JSON string)             yes        yes
``mat``        ``rec.mat`` MATLAB v5 (v7.3/HDF5 read too)     yes        yes
``mat73``      ``rec.mat`` MATLAB v7.3 (HDF5, needs h5py)     yes        yes
``parquet``    ``rec.parquet`` (needs pyarrow)                yes, chunks  yes
``text``       a user's ``.txt``/``.dat``/``.tsv`` log        mapping    no
=============  =============================================  =========  =========

Any format can also be read through a column mapping
(:mod:`maglevid.io.mapping`): a user's own log, or a preset such as
``"uaq-levitador"``. The layout of every format is in
``docs/recording-format.md``.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import MIN_SAMPLES, ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io import _native
from maglevid.io._files import (
    READ_FORMATS,
    WRITE_FORMATS,
    check_input_file,
    check_input_units,
    format_from_path,
    sidecar_path,
    write_files,
)
from maglevid.io.mapping import ColumnMapping, load_mapping

__all__ = [
    "READ_FORMATS",
    "WRITE_FORMATS",
    "iter_recording_chunks",
    "read_recording",
    "summarize_recording",
    "write_recording",
]

log = logging.getLogger(__name__)


def _choose(path: Path, fmt: str, m: ColumnMapping) -> ColumnMapping:
    """Pick the alternative of an ``any_of`` mapping whose column count fits the file."""
    if fmt not in ("csv", "text"):
        raise FileFormatError(
            f"mapping {m.origin} chooses between alternatives by the number of text "
            f"columns; it does not apply to a {fmt} file",
            path=str(path),
        )
    from maglevid.io._text import TextTable, check_text_file, resolve_text_options

    seen = []
    for alt in m.alternatives:
        opts = resolve_text_options(alt.text, path, csv_default=fmt == "csv")
        check_text_file(path, opts.encoding)  # a binary file is named as such, not skipped
        try:
            n = TextTable(path, opts).n_columns
        except FileFormatError:
            continue
        seen.append(n)
        if n == alt.n_columns:
            log.info("%s: using %s (%d columns)", path, alt.origin, n)
            return alt
    want = ", ".join(f"{a.n_columns} ({a.origin})" for a in m.alternatives)
    raise FileFormatError(
        f"matches no alternative of mapping {m.origin}: it has "
        f"{sorted(set(seen)) or 'no readable'} column(s); expected {want}",
        path=str(path),
    )


def _prepare(
    path: str | os.PathLike[str], format: str | None, mapping: Any
) -> tuple[Path, str, ColumnMapping | None]:
    p = Path(path)
    m = None if mapping is None else load_mapping(mapping)
    if format is None and m is not None and m.format is not None:
        format = m.format
    fmt = format_from_path(p, format, writing=False)
    check_input_file(p)
    if m is not None and m.alternatives:
        m = _choose(p, fmt, m)
    return p, fmt, m


def read_recording(
    path: str | os.PathLike[str], *, format: str | None = None, mapping: Any = None
) -> ClosedLoopData:
    """Read a recording from a file.

    Parameters
    ----------
    path : str or path-like
        The recording: ``.csv`` (with its ``.json`` side-car), ``.npz``,
        ``.mat`` (v5 or v7.3), ``.parquet``; or a user's own log with ``mapping``.
    format : {"csv", "text", "npz", "mat", "parquet"}, optional
        Overrides the format named by the extension.
    mapping : dict, str or path-like, optional
        A column mapping (:func:`maglevid.io.load_mapping`): a dict, a
        ``.json``/``.toml`` file or a preset name (``"uaq-levitador"``,
        ``"maggy-ntnu"``). A mapping that places signals reads the file's
        columns/variables as it says; one with only options (``layout``,
        ``expect_units``, ``dt``...) refines how a maglevid file is read.

    Returns
    -------
    ClosedLoopData
        ``metadata["source"]`` is the absolute path read (so that
        :func:`write_recording` never writes over it), ``metadata["source_format"]``
        the format; extra channels (e.g. a reference) are in
        ``metadata["extra_signals"]``.

    Raises
    ------
    FileFormatError
        One clear error naming the file, the column and the problem: missing
        channel, non-uniform time, NaN/inf, too few samples, unit mismatch,
        input not held within a control period, unknown format, malformed
        metadata or side-car.
    FileNotFoundError
        No such file.

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> d = ClosedLoopData(y=np.arange(8.0), u=np.ones(4), dt=0.01, p=2)
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> path = write_recording(d, folder / "rec.csv")
    >>> back = read_recording(path)
    >>> bool(np.array_equal(back.y, d.y)), back.p
    (True, 2)
    """
    p, fmt, m = _prepare(path, format, mapping)
    if fmt == "csv":
        from maglevid.io._text import read_native_csv, read_text

        data = (
            read_text(p, m, csv_default=True)
            if m is not None and m.has_signals
            else read_native_csv(p, m)
        )
    elif fmt == "text":
        from maglevid.io._text import check_text_file, read_text

        if m is None or not m.has_signals:
            check_text_file(p)
            raise FileFormatError(
                "a text log is read through a column mapping: a .json/.toml mapping file or "
                "a preset name (--mapping on the command line; mapping=, also a dict, in "
                "Python; see docs/recording-format.md)",
                path=str(p),
            )
        data = read_text(p, m, csv_default=False)
    elif fmt == "npz":
        from maglevid.io._variables import read_npz

        data = read_npz(p, m)
    elif fmt == "mat":
        from maglevid.io._variables import read_mat

        data = read_mat(p, m)
    else:
        from maglevid.io._parquet import read_parquet

        data = read_parquet(p, m)
    log.info("read %s: %r", p, data)
    return data


def write_recording(
    data: ClosedLoopData,
    path: str | os.PathLike[str],
    *,
    format: str | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a recording to a file, atomically, never over its own source.

    Parameters
    ----------
    data : ClosedLoopData
    path : str or path-like
        Target file. For CSV the side-car ``<stem>.json`` is written beside it.
    format : {"csv", "npz", "mat", "mat73", "parquet"}, optional
        Overrides the extension (``.mat`` writes v5; ``"mat73"`` writes v7.3/HDF5).
    overwrite : bool
        Replace an existing file. Without it an existing target is an error.
        Even with it, the file the data was read from (``metadata["source"]``,
        and a CSV source's side-car) is never written over.

    Returns
    -------
    pathlib.Path
        The path written (for CSV, the ``.csv``; its side-car is beside it).

    Raises
    ------
    FileFormatError
        Target exists (without ``overwrite``), is the data's source, or the
        format is unknown.
    DataError
        Metadata that is not JSON-safe; input channels with inconsistent units.

    Notes
    -----
    Each file is written to a temporary file in the target's folder and moved
    into place with an atomic rename, so a reader never sees half a file and
    an error leaves any existing target untouched.
    """
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    target = Path(path)
    fmt = format_from_path(target, format, writing=True)
    check_input_units(data)
    try:
        json.dumps(_native.describe(data), allow_nan=True)
    except (TypeError, ValueError) as exc:
        raise DataError(f"the recording's loop/metadata is not JSON-safe: {exc}") from None
    if fmt == "csv":
        from maglevid.io._text import write_csv

        side = sidecar_path(target)
        if side == target:
            raise FileFormatError(
                "a CSV recording needs a name whose side-car (.json) differs from it; use .csv",
                path=str(target),
            )
        writers = [
            (target, lambda tmp: write_csv(data, target, tmp, sidecar=False)),
            (side, lambda tmp: write_csv(data, target, tmp, sidecar=True)),
        ]
    elif fmt == "npz":
        from maglevid.io._variables import write_npz

        writers = [(target, lambda tmp: write_npz(data, tmp))]
    elif fmt == "mat":
        from maglevid.io._variables import write_mat

        writers = [(target, lambda tmp: write_mat(data, tmp))]
    elif fmt == "mat73":
        from maglevid.io._variables import write_mat73

        writers = [(target, lambda tmp: write_mat73(data, tmp))]
    else:
        from maglevid.io._parquet import write_parquet

        writers = [(target, lambda tmp: write_parquet(data, tmp))]
    write_files(writers, overwrite=overwrite, metadata=data.metadata)
    return target


def _segment(data: ClosedLoopData, start: int, stop: int, n_total: int) -> ClosedLoopData:
    """Control periods ``start:stop``, with extra channels sliced too."""
    p = data.p
    meta = dict(data.metadata)
    extras = meta.get("extra_signals")
    if extras:
        sliced = {}
        for name, e in extras.items():
            values = np.asarray(e["values"])
            lo, hi = (start * p, stop * p) if e.get("rate") == "output" else (start, stop)
            sliced[name] = {**dict(e), "values": values[lo:hi]}
        meta["extra_signals"] = sliced
    meta["chunk"] = {"start": start, "stop": stop, "n_total": n_total}
    sig = {
        s: (None if getattr(data, s) is None else getattr(data, s)[start:stop])
        for s in ("u", "r", "u_f")
    }
    return ClosedLoopData(
        y=data.y[start * p : stop * p],
        dt=data.dt,
        p=p,
        names=data.names,
        units=data.units,
        t0=data.t0 + start * data.dt,
        loop=data.loop,
        metadata=meta,
        **sig,
    )


def iter_recording_chunks(
    path: str | os.PathLike[str],
    chunk_size: int,
    *,
    format: str | None = None,
    mapping: Any = None,
) -> Iterator[ClosedLoopData]:
    """Yield a recording as consecutive segments of ``chunk_size`` control periods.

    Parquet files are streamed (one record batch at a time, only the columns
    used); other formats are read whole and then cut. Each segment keeps its
    time origin (``t0``) and says where it lies in ``metadata["chunk"]``
    (``start``, ``stop``, ``n_total`` in control periods). The last segment
    takes the remainder; a remainder shorter than two control periods (too
    short to be a recording) joins the segment before it.

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> d = ClosedLoopData(y=np.arange(9.0), u=np.ones(9), dt=0.1)
    >>> path = write_recording(d, pathlib.Path(tempfile.mkdtemp()) / "rec.npz")
    >>> [c.n_samples for c in iter_recording_chunks(path, 4)]  # 4 + 4 + 1: the 1 joins
    [4, 5]
    """
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)):
        raise DataError(f"`chunk_size` must be an integer >= {MIN_SAMPLES}; got {chunk_size!r}")
    if chunk_size < MIN_SAMPLES:
        raise DataError(f"`chunk_size` must be an integer >= {MIN_SAMPLES}; got {chunk_size}")
    p, fmt, m = _prepare(path, format, mapping)
    if fmt == "parquet":
        from maglevid.io._parquet import iter_parquet_chunks

        yield from iter_parquet_chunks(p, int(chunk_size), m)
        return
    data = read_recording(p, format=fmt, mapping=m)
    n = data.n_samples
    bounds = [*range(0, n, int(chunk_size)), n]
    if len(bounds) > 2 and bounds[-1] - bounds[-2] < MIN_SAMPLES:
        del bounds[-2]
    for start, stop in itertools.pairwise(bounds):
        yield _segment(data, start, stop, n)


def summarize_recording(data: ClosedLoopData) -> dict[str, Any]:
    """A short JSON-safe description: sizes, timing, channels with units and statistics.

    Examples
    --------
    >>> d = ClosedLoopData(y=[[0.0], [2.0], [4.0]], dt=0.5, units={"y": ["m"]})
    >>> s = summarize_recording(d)
    >>> s["n_samples"], s["duration_s"], s["signals"]["y"][0]["mean"]
    (3, 1.5, 2.0)
    """
    signals: dict[str, list[dict[str, Any]]] = {}
    for sig in data.signals():
        arr = data.y if sig == "y" else getattr(data, sig)
        signals[sig] = [
            {
                "name": name,
                "unit": unit,
                "min": float(col.min()),
                "max": float(col.max()),
                "mean": float(col.mean()),
                "std": float(col.std()),
            }
            for name, unit, col in zip(data.channel_names(sig), data.channel_units(sig), arr.T)
        ]
    extras = {}
    for name, unit, rate, values in _native.extra_signals(data):
        extras[name] = {
            "unit": unit,
            "rate": rate,
            "min": float(values.min()),
            "max": float(values.max()),
            "mean": float(values.mean()),
        }
    meta_keys = sorted(k for k in data.metadata if k != "extra_signals")
    return {
        "n_samples": data.n_samples,
        "n_output_samples": int(data.y.shape[0]),
        "dt": data.dt,
        "p": data.p,
        "dt_output": data.dt_output,
        "sample_rate_hz": 1.0 / data.dt,
        "t0": data.t0,
        "duration_s": data.n_samples * data.dt,
        "ny": data.ny,
        "nu": data.nu,
        "signals": signals,
        "extra_signals": extras,
        "loop_keys": sorted(data.loop),
        "metadata_keys": meta_keys,
        "source": data.metadata.get("source"),
    }
