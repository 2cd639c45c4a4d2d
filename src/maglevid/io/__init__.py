"""Recordings in and out of files: CSV (+ JSON side-car), NPZ, MATLAB .mat, Parquet.

:func:`read_recording` and :func:`write_recording` move a
:class:`~maglevid.data.ClosedLoopData` to and from files;
:func:`iter_recording_chunks` streams a long one; a column mapping
(:func:`load_mapping`, :func:`available_presets`) imports a user's own log.
The file layouts are documented in ``docs/recording-format.md``.
"""

from maglevid.io.mapping import ColumnMapping, available_presets, load_mapping
from maglevid.io.recording import (
    READ_FORMATS,
    WRITE_FORMATS,
    iter_recording_chunks,
    read_recording,
    summarize_recording,
    write_recording,
)

__all__ = [
    "READ_FORMATS",
    "WRITE_FORMATS",
    "ColumnMapping",
    "available_presets",
    "iter_recording_chunks",
    "load_mapping",
    "read_recording",
    "summarize_recording",
    "write_recording",
]
