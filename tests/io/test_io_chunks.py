"""Reading in chunks: the segments put together are the recording, exactly."""

from __future__ import annotations

import numpy as np
import pytest
from _io_helpers import assert_same_recording, full_recording, user_columns, write_user_file

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io import iter_recording_chunks, read_recording, write_recording

WRITERS = [("rec.parquet", None), ("rec.csv", None), ("rec.npz", None), ("rec.mat", None)]


def join(chunks: list[ClosedLoopData]) -> dict[str, np.ndarray]:
    out = {"y": np.vstack([c.y for c in chunks])}
    for sig in ("u", "r", "u_f"):
        out[sig] = np.vstack([getattr(c, sig) for c in chunks])
    for name in chunks[0].metadata["extra_signals"]:
        out[name] = np.concatenate([c.metadata["extra_signals"][name]["values"] for c in chunks])
    return out


@pytest.mark.parametrize("name,fmt", WRITERS, ids=[w[0] for w in WRITERS])
def test_chunks_put_together_are_the_recording(tmp_path, rng, name, fmt):
    data = full_recording(rng, p=3, n=47)
    path = write_recording(data, tmp_path / name, format=fmt)
    chunks = list(iter_recording_chunks(path, 10))
    # 47 = 10+10+10+10+7: the remainder of 7 >= 2 periods is a chunk of its own.
    assert [c.n_samples for c in chunks] == [10, 10, 10, 10, 7]
    whole = join(chunks)
    assert np.array_equal(whole["y"], data.y) and np.array_equal(whole["u_f"], data.u_f)
    ext = data.metadata["extra_signals"]
    assert np.array_equal(whole["ref"], ext["ref"]["values"])
    assert np.array_equal(whole["temp"], ext["temp"]["values"])
    for k, c in enumerate(chunks):
        assert c.t0 == pytest.approx(data.t0 + 10 * k * data.dt, rel=1e-15)
        assert c.metadata["chunk"] == {
            "start": 10 * k,
            "stop": min(10 * k + 10, 47),
            "n_total": 47,
        }
        assert c.names == data.names and c.units == data.units and c.p == 3
        assert c.loop["controller"]["name"] == "state feedback"


def test_a_short_remainder_joins_the_last_chunk(tmp_path, rng):
    data = ClosedLoopData(y=rng.standard_normal(21), u=rng.standard_normal(21), dt=0.1)
    for name in ("r.parquet", "r.npz"):
        path = write_recording(data, tmp_path / name)
        assert [c.n_samples for c in iter_recording_chunks(path, 10)] == [10, 11]
        assert [c.n_samples for c in iter_recording_chunks(path, 100)] == [21]


def test_parquet_streaming_reads_batches_across_row_groups(tmp_path, rng):
    # Row groups of 7 rows, chunks of 5 periods x p=2 = 10 rows: batches must be joined.
    cols = user_columns(30, p=2)
    path, _ = write_user_file(tmp_path, "parquet", cols)
    m = {"time": "t", "p": 2, "y": ["gap"], "u": ["v"], "extra": ["w"]}
    whole = read_recording(path, mapping=m)
    chunks = list(iter_recording_chunks(path, 5, mapping=m))
    assert [c.n_samples for c in chunks] == [5] * 6
    assert np.array_equal(np.vstack([c.y for c in chunks]), whole.y)
    assert np.array_equal(np.vstack([c.u for c in chunks]), whole.u)
    assert [c.t0 for c in chunks] == pytest.approx([whole.t0 + 5 * k * whole.dt for k in range(6)])
    assert all(c.dt == whole.dt for c in chunks)


def test_parquet_streaming_checks_the_time_across_chunk_joins(tmp_path):
    cols = user_columns(20)
    cols["t"] = cols["t"].copy()
    cols["t"][10:] += 0.005  # the gap is exactly at the join of chunks [0, 10) and [10, 20)
    path, _ = write_user_file(tmp_path, "parquet", cols)
    # With dt and t0 known no pass over the whole time column is needed: the join is
    # checked when the second chunk arrives, after the first was yielded.
    m = {"time": "t", "dt": 0.01, "t0": 0.0, "y": ["gap"]}
    chunks = iter_recording_chunks(path, 10, mapping=m)
    assert next(chunks).n_samples == 10
    with pytest.raises(FileFormatError, match=r"non-uniform time.*row 9 to row 10"):
        next(chunks)
    # Without t0 the whole time column is checked first.
    m = {"time": "t", "dt": 0.01, "y": ["gap"]}
    with pytest.raises(FileFormatError, match=r"non-uniform time.*row 9 to row 10"):
        next(iter_recording_chunks(path, 10, mapping=m))


def test_parquet_streaming_of_a_truncated_or_bad_file(tmp_path, rng):
    import pyarrow.parquet as pq

    data = full_recording(rng, p=1, n=20)
    path = write_recording(data, tmp_path / "rec.parquet")
    table = pq.read_table(path)
    pq.write_table(table.slice(0, 15), tmp_path / "cut.parquet")
    with pytest.raises(FileFormatError, match="has 15 control period"):
        list(iter_recording_chunks(tmp_path / "cut.parquet", 4))
    pq.write_table(table.slice(0, 1), tmp_path / "one.parquet")
    with pytest.raises(FileFormatError, match="too few samples"):
        list(iter_recording_chunks(tmp_path / "one.parquet", 4))


def test_chunk_size_is_checked(tmp_path, rng):
    path = write_recording(full_recording(rng, p=1, n=5), tmp_path / "rec.npz")
    for bad in (1, 0, 2.5, True):
        with pytest.raises(DataError, match="chunk_size"):
            list(iter_recording_chunks(path, bad))


def test_one_chunk_equals_the_whole_recording(tmp_path, rng):
    data = full_recording(rng, p=2, n=9)
    path = write_recording(data, tmp_path / "rec.parquet")
    (only,) = iter_recording_chunks(path, 9)
    assert_same_recording(
        only.replace(metadata={**only.metadata, "chunk": None}),
        data.replace(metadata={**data.metadata, "chunk": None}),
    )
