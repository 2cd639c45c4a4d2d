"""MATLAB habits (issue 18): Ts for dt, Y/U in capitals, v7.3 files opened by another reader."""

from __future__ import annotations

import json

import mat73  # independent v7.3 reader from PyPI (dev extra; docs/dependencies.md)
import numpy as np
import pytest
import scipy.io as sio

from maglevid.exceptions import FileFormatError
from maglevid.io import read_recording, write_recording
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop


@pytest.fixture(scope="module")
def rec():
    nominal = AMBParameters.nominal()
    return simulate_amb_loop(nominal, nominal=nominal, dt=1e-4, n_samples=1000, rng=4)


def test_ts_and_capital_names_are_read(tmp_path, rec):
    path = tmp_path / "own.mat"
    sio.savemat(path, {"Y": rec.y, "U": rec.u, "Ts": rec.dt})  # as MATLAB's iddata names them
    got = read_recording(path)
    assert got.dt == rec.dt
    np.testing.assert_array_equal(got.y, rec.y)
    np.testing.assert_array_equal(got.u, rec.u)


def test_two_names_for_one_variable_are_an_error(tmp_path, rec):
    path = tmp_path / "both.mat"
    sio.savemat(path, {"y": rec.y, "Ts": rec.dt, "dt": rec.dt})
    with pytest.raises(FileFormatError, match=r"both '(Ts|dt)' and '(Ts|dt)'"):
        read_recording(path)
    sio.savemat(path, {"y": rec.y, "Y": rec.y, "dt": rec.dt})
    with pytest.raises(FileFormatError, match="both"):
        read_recording(path)


def test_v73_written_by_maglevid_is_read_by_mat73(tmp_path, rec):
    path = write_recording(rec, tmp_path / "rec73.mat", format="mat73")
    with open(path, "rb") as fh:
        header = fh.read(128)
    assert header.startswith(b"MATLAB 7.3 MAT-file") and header[126:128] == b"IM"
    got = mat73.loadmat(str(path))
    # Every array bit for bit, in MATLAB's (time x channels) orientation.
    for sig in ("y", "u", "r", "u_f"):
        np.testing.assert_array_equal(got[sig], getattr(rec, sig))
    assert float(got["dt"]) == rec.dt and int(got["p"]) == 1
    meta = json.loads(got["metadata"])
    assert meta["format"] == "maglevid-recording" and meta["signals"]["y"]["names"] == [
        "x",
        "i1",
        "i2",
    ]
