"""Recordings in and out of files: CSV (+ JSON side-car), NPZ, MATLAB .mat, Parquet.

:func:`read_recording` and :func:`write_recording` move a
:class:`~maglevid.data.ClosedLoopData` to and from files;
:func:`iter_recording_chunks` streams a long one; every output of maglevid
(recordings, reports, pages, figures) goes through :func:`write_output` /
:func:`check_output` (never over an input or its side-car, never over an
existing file without ``overwrite``, atomically) and every input through
:func:`check_input_file` (regular files only: a FIFO or device is refused); a column mapping
(:func:`load_mapping`, :func:`available_presets`) imports a user's own log.
The file layouts are documented in ``docs/recording-format.md``.
"""

from maglevid.io._files import check_input_file, check_output, write_output
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
    "check_input_file",
    "check_output",
    "iter_recording_chunks",
    "load_mapping",
    "read_recording",
    "summarize_recording",
    "write_output",
    "write_recording",
]
