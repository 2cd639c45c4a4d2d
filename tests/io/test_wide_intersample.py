"""The wide inter-sampled layout through a mapping: one row per control period, y_0..y_{p-1}."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import FileFormatError
from maglevid.io import read_recording
from maglevid.simulate.suspension import simulate_suspension


@pytest.fixture(scope="module")
def record():
    return simulate_suspension(p=3, duration=1.0, rng=3)


def _write_wide(path, rec):
    n, p = rec.n_samples, rec.p
    Y = np.asarray(rec.y).reshape(n, p)  # row m: y(mT), y(mT + T/3), y(mT + 2T/3)
    t = np.arange(n) * rec.dt
    table = np.column_stack([t, Y, rec.u[:, 0], rec.u_f[:, 0]])
    header = "t,y_0,y_1,y_2,u,u_f"
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.17g")


MAPPING = {
    "time": {"column": "t"},
    "y": [{"intersamples": ["y_0", "y_1", "y_2"], "name": "gap", "unit": "m"}],
    "u": [{"column": "u", "unit": "V"}],
    "u_f": [{"column": "u_f", "unit": "V"}],
}


def test_wide_file_reads_as_the_interleaved_record(tmp_path, record):
    path = tmp_path / "wide.csv"
    _write_wide(path, record)
    got = read_recording(path, mapping=MAPPING)
    assert got.p == 3 and got.n_samples == record.n_samples
    assert got.dt == pytest.approx(record.dt, rel=1e-9)
    # Exact: the file holds the numbers to 17 digits.
    np.testing.assert_array_equal(got.y, record.y)
    np.testing.assert_array_equal(got.u, record.u)
    assert got.channel_names("y") == ("gap",)


def test_p_must_agree_with_the_columns(tmp_path, record):
    path = tmp_path / "wide.csv"
    _write_wide(path, record)
    with pytest.raises(FileFormatError, match="intersamples"):
        read_recording(path, mapping={**MAPPING, "p": 2})
    bad = {**MAPPING, "y": [{"intersamples": ["y_0"], "unit": "m"}]}
    with pytest.raises(FileFormatError, match="p >= 2 columns"):
        read_recording(path, mapping=bad)
    missing = {**MAPPING, "y": [{"intersamples": ["y_0", "y_1", "y_9"], "unit": "m"}]}
    with pytest.raises(FileFormatError, match="y_9"):
        read_recording(path, mapping=missing)
