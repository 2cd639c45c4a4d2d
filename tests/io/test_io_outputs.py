"""Writers never replace what they did not create; readers never block (issue 17).

The rule of every maglevid output (:func:`maglevid.io.write_output`): never
over an input or its side-car (even with ``overwrite``), never over an
existing file without ``overwrite``, atomically (a failed write leaves the
target as it was and no temporary file). Every reader refuses a special file
(FIFO, device) before opening it.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io import (
    check_input_file,
    check_output,
    iter_recording_chunks,
    load_mapping,
    read_recording,
    write_output,
    write_recording,
)


def _data() -> ClosedLoopData:
    return ClosedLoopData(y=np.arange(8.0), u=np.ones(8), dt=0.01)


def test_output_never_over_an_input_or_its_sidecar(tmp_path: Path):
    rec = write_recording(_data(), tmp_path / "rec.csv")
    side = tmp_path / "rec.json"
    before = {p: p.read_bytes() for p in (rec, side)}
    for target in (rec, side):
        with pytest.raises(FileFormatError, match="is an input"):
            write_output(target, "<html>", overwrite=True, inputs=[rec])
    assert {p: p.read_bytes() for p in (rec, side)} == before


def test_output_refuses_an_existing_file_without_overwrite(tmp_path: Path):
    out = write_output(tmp_path / "a.html", "first")
    with pytest.raises(FileFormatError, match="exists; refusing to overwrite"):
        write_output(out, "second")
    assert out.read_text() == "first"
    write_output(out, "third", overwrite=True)
    assert out.read_text() == "third"


def test_output_refuses_folders_special_files_and_missing_folders(tmp_path: Path):
    with pytest.raises(FileFormatError, match="is a folder"):
        check_output(tmp_path, overwrite=True)
    fifo = tmp_path / "pipe.html"
    os.mkfifo(fifo)
    with pytest.raises(FileFormatError, match="special file"):
        check_output(fifo, overwrite=True)
    with pytest.raises(FileFormatError, match="does not exist"):
        check_output(tmp_path / "no" / "a.html")


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EFBIG])
def test_disk_full_is_one_clear_error_and_nothing_half_written(tmp_path, monkeypatch, code):
    # Simulated: the write fails part-way with the errno a full disk (or a
    # file-size limit) gives; the first bytes already reached the temporary file.
    target = write_output(tmp_path / "rep.html", "old content")

    def full(tmp: Path) -> None:
        tmp.write_bytes(b"half a rep")
        raise OSError(code, os.strerror(code))

    with pytest.raises(FileFormatError, match="nothing was written") as info:
        write_output(target, full, overwrite=True)
    assert ("no space left" if code == errno.ENOSPC else "file too large") in str(info.value)
    assert target.read_text() == "old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep.html"]  # no temporary left


def test_disk_full_while_writing_a_recording(tmp_path, monkeypatch):
    real = np.savez_compressed

    def full(file, *args, **kwargs):
        real(file, *args, **kwargs)
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(np, "savez_compressed", full)
    monkeypatch.setattr(np, "savez", full)
    with pytest.raises(FileFormatError, match="file too large"):
        write_recording(_data(), tmp_path / "rec.npz")
    assert list(tmp_path.iterdir()) == []


def test_readers_refuse_a_fifo_up_front(no_hang, tmp_path: Path):
    # Opening a FIFO for reading blocks until a writer appears: had any reader
    # opened it, this test would hang instead of failing.
    for name in ("rec.npz", "rec.csv", "rec.parquet", "rec.mat"):
        fifo = tmp_path / name
        os.mkfifo(fifo)
        with pytest.raises(FileFormatError, match="FIFO"):
            read_recording(fifo)
        with pytest.raises(FileFormatError, match="FIFO"):
            next(iter_recording_chunks(fifo, 100))
    mapping = tmp_path / "map.json"
    os.mkfifo(mapping)
    with pytest.raises(DataError):
        load_mapping(mapping)


def test_a_csv_whose_sidecar_is_a_fifo_is_refused(no_hang, tmp_path: Path):
    rec = write_recording(_data(), tmp_path / "rec.csv")
    (tmp_path / "rec.json").unlink()
    os.mkfifo(tmp_path / "rec.json")
    with pytest.raises(FileFormatError, match="side-car"):
        read_recording(rec)


def test_devices_are_refused():
    with pytest.raises(FileFormatError, match="device"):
        check_input_file("/dev/zero")
    with pytest.raises(FileFormatError, match="device"):
        read_recording("/dev/null", format="npz")
