"""Round trips through every format are exact, and writing never destroys a file.

Tolerance: none. Binary formats store float64; CSV prints the shortest text
that reads back to the same double, so every comparison is ``array_equal``
(and the sign of zero is compared too).
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import numpy as np
import pytest
from _io_helpers import RECORDINGS, assert_same_recording, full_recording

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io import read_recording, write_recording

#: (file name, format= argument) of every writer.
WRITERS = [
    ("rec.csv", None),
    ("rec.npz", None),
    ("rec.mat", None),
    ("rec73.mat", "mat73"),
    ("rec.parquet", None),
]


@pytest.mark.parametrize("name,fmt", WRITERS, ids=[w[0] for w in WRITERS])
@pytest.mark.parametrize("case", sorted(RECORDINGS))
def test_round_trip_is_exact(tmp_path, rng, name, fmt, case):
    data = RECORDINGS[case](rng)
    path = write_recording(data, tmp_path / name, format=fmt)
    assert path == tmp_path / name
    back = read_recording(path)
    assert_same_recording(back, data)
    assert back.metadata["source"] == str(path.resolve())


def test_csv_round_trip_without_pyarrow_is_exact(tmp_path, rng, monkeypatch):
    # The pure-Python printer (repr) and numpy.loadtxt, used when pyarrow is absent.
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.csv", None)
    for case in ("full_p3", "tricky_values"):
        data = RECORDINGS[case](rng)
        path = write_recording(data, tmp_path / f"{case}.csv")
        assert_same_recording(read_recording(path), data)


def test_csv_printers_agree(tmp_path, rng, monkeypatch):
    data = RECORDINGS["tricky_values"](rng)
    a = write_recording(data, tmp_path / "arrow.csv")
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    b = write_recording(data, tmp_path / "repr.csv")
    rows_a = [np.array(line.split(","), dtype=float) for line in a.read_text().splitlines()[1:]]
    rows_b = [np.array(line.split(","), dtype=float) for line in b.read_text().splitlines()[1:]]
    assert np.array_equal(np.array(rows_a), np.array(rows_b))


def test_csv_layout_holds_inputs_over_each_period(tmp_path):
    data = ClosedLoopData(
        y=np.arange(6.0), u=[10.0, 20.0, 30.0], dt=0.5, p=2, units={"y": ["m"], "u": ["V"]}
    )
    path = write_recording(data, tmp_path / "rec.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == "t,y:y1,u:u1"
    assert lines[1:] == ["0,0,10", "0.25,1,10", "0.5,2,20", "0.75,3,20", "1,4,30", "1.25,5,30"]
    side = (tmp_path / "rec.json").read_text()
    assert '"p": 2' in side and '"column_units": ["s", "m", "V"]' in side


def test_multirate_extra_channels_keep_their_rate(tmp_path, rng):
    data = full_recording(rng, p=3, n=10)
    for name, fmt in WRITERS:
        back = read_recording(write_recording(data, tmp_path / name, format=fmt))
        extras = back.metadata["extra_signals"]
        assert extras["ref"]["rate"] == "control" and extras["ref"]["values"].shape == (10,)
        assert extras["temp"]["rate"] == "output" and extras["temp"]["values"].shape == (30,)
        assert extras["temp"]["unit"] == "degC"


def test_conversion_chain_keeps_provenance(tmp_path, rng):
    data = full_recording(rng)
    a = write_recording(data, tmp_path / "a.npz")
    b = write_recording(read_recording(a), tmp_path / "b.parquet")
    back = read_recording(b)
    assert back.metadata["source"] == str(b.resolve())
    assert back.metadata["converted_from"] == str(a.resolve())
    assert back.metadata["source_format"] == "parquet"
    assert_same_recording(back, data)


def test_mat_v5_file_is_what_matlab_users_expect(tmp_path, rng):
    import scipy.io as sio

    data = full_recording(rng, p=2, n=8)
    path = write_recording(data, tmp_path / "rec.mat")
    m = sio.loadmat(path)
    assert m["y"].shape == (16, 2) and m["u"].shape == (8, 2)
    assert m["dt"].item() == data.dt and m["p"].item() == 2.0
    assert m["extra_ref"].shape == (8, 1)
    assert '"maglevid-recording"' in str(m["metadata"][0])


def test_mat73_header_and_layout(tmp_path, rng):
    import h5py

    data = full_recording(rng, p=1, n=5)
    path = write_recording(data, tmp_path / "rec.mat", format="mat73")
    head = path.read_bytes()[:128]
    assert head.startswith(b"MATLAB 7.3 MAT-file") and head[124:128] == b"\x00\x02IM"
    with h5py.File(path, "r") as fh:
        assert fh["y"].shape == (2, 5)  # transposed: MATLAB is column-major
        assert fh["y"].attrs["MATLAB_class"] == b"double"
        assert fh["metadata"].attrs["MATLAB_class"] == b"char"


# ------------------------------------------------------------------ safety
def test_refuses_an_existing_file_unless_overwrite(tmp_path, rng):
    data = RECORDINGS["y_only"](rng)
    for name, fmt in WRITERS:
        target = tmp_path / name
        target.write_bytes(b"precious")
        with pytest.raises(FileFormatError, match="exists; refusing to overwrite") as err:
            write_recording(data, target, format=fmt)
        assert err.value.path == str(target)
        assert target.read_bytes() == b"precious"
        write_recording(data, target, format=fmt, overwrite=True)
        assert_same_recording(read_recording(target), data)


def test_csv_refuses_an_existing_sidecar(tmp_path, rng):
    (tmp_path / "rec.json").write_text("{}")
    with pytest.raises(FileFormatError, match=r"rec\.json: exists"):
        write_recording(RECORDINGS["y_only"](rng), tmp_path / "rec.csv")
    assert not (tmp_path / "rec.csv").exists()  # checks come before any writing


@pytest.mark.parametrize("name,fmt", WRITERS, ids=[w[0] for w in WRITERS])
def test_never_writes_over_its_source_even_with_overwrite(tmp_path, rng, name, fmt):
    path = write_recording(RECORDINGS["full_p1"](rng), tmp_path / name, format=fmt)
    before = path.read_bytes()
    data = read_recording(path)
    with pytest.raises(FileFormatError, match="the file this recording was read from"):
        write_recording(data, path, format=fmt, overwrite=True)
    assert path.read_bytes() == before


def test_never_writes_over_a_csv_sources_sidecar(tmp_path, rng):
    write_recording(RECORDINGS["full_p1"](rng), tmp_path / "rec.csv")
    data = read_recording(tmp_path / "rec.csv")
    side = (tmp_path / "rec.json").read_bytes()
    # rec.npz is new, but writing CSV "rec.csv" elsewhere is fine; the side-car is protected:
    with pytest.raises(FileFormatError, match="read from"):
        write_recording(data, tmp_path / "rec.csv", overwrite=True)
    assert (tmp_path / "rec.json").read_bytes() == side


def test_source_is_protected_through_a_symlink(tmp_path, rng):
    path = write_recording(RECORDINGS["y_only"](rng), tmp_path / "rec.npz")
    link = tmp_path / "link.npz"
    link.symlink_to(path)
    data = read_recording(path)
    with pytest.raises(FileFormatError, match="read from"):
        write_recording(data, link, overwrite=True)


def test_failed_write_leaves_the_target_and_no_temporary_file(tmp_path, rng, monkeypatch):
    from maglevid.io import _variables

    target = tmp_path / "rec.npz"
    target.write_bytes(b"old")

    def broken(data, tmp):
        tmp.write_bytes(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(_variables, "write_npz", broken)
    # Since issue 17 a failed write is one FileFormatError naming the file and saying
    # nothing was written (it was a bare OSError, a traceback at the command line).
    with pytest.raises(FileFormatError, match=r"disk full.*nothing was written"):
        write_recording(RECORDINGS["y_only"](rng), target, overwrite=True)
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]


def test_written_files_are_not_private(tmp_path, rng):
    old = os.umask(0o022)
    try:
        path = write_recording(RECORDINGS["y_only"](rng), tmp_path / "rec.csv")
    finally:
        os.umask(old)
    for p in (path, tmp_path / "rec.json"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o644


def test_write_errors(tmp_path, rng):
    data = RECORDINGS["y_only"](rng)
    with pytest.raises(FileFormatError, match="does not exist"):
        write_recording(data, tmp_path / "missing" / "rec.npz")
    with pytest.raises(FileFormatError, match="cannot tell the format"):
        write_recording(data, tmp_path / "rec.xyz")
    with pytest.raises(FileFormatError, match="read through a mapping only"):
        write_recording(data, tmp_path / "rec.txt")
    with pytest.raises(FileFormatError, match="unknown format"):
        write_recording(data, tmp_path / "rec.npz", format="hdf9")
    with pytest.raises(DataError, match="must be a ClosedLoopData"):
        write_recording({"y": [1, 2]}, tmp_path / "rec.npz")  # type: ignore[arg-type]
    bad_units = ClosedLoopData(
        y=np.zeros(4), u=np.zeros(4), r=np.zeros(4), dt=1.0, units={"u": ["V"], "r": ["A"]}
    )
    with pytest.raises(DataError, match="inconsistent units"):
        write_recording(bad_units, tmp_path / "rec.npz")
    not_json = data.replace(metadata={"when": object()})
    with pytest.raises(DataError, match="not JSON-safe"):
        write_recording(not_json, tmp_path / "rec.npz")
    assert list(tmp_path.iterdir()) == []


def test_path_argument_types(tmp_path, rng):
    data = RECORDINGS["y_only"](rng)
    path = write_recording(data, str(tmp_path / "rec.npz"))
    assert isinstance(path, Path)
    assert_same_recording(read_recording(str(path)), data)
