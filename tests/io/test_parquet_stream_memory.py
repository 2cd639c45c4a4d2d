"""Streaming a Parquet recording holds one chunk at a time, not the file read so far."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.data import ClosedLoopData
from maglevid.io import iter_recording_chunks, write_recording

pa = pytest.importorskip("pyarrow")


def test_parquet_chunks_do_not_accumulate_arrow_memory(tmp_path, rng):
    # 1 500 000 rows x 5 columns in chunks of 300 000 (more than a row group of 2^18).
    # With pyarrow's pre-buffering the column chunks read so far stayed allocated until
    # the reader closed (+72 MB per 10^6-row chunk of a 10-column file; this file: +23 MB
    # after the 2nd chunk); the Arrow memory in use must not grow with the chunks read
    # (allow one row group's worth between the 2nd chunk and the last).
    n = 1_500_000
    data = ClosedLoopData(y=rng.standard_normal((n, 2)), u=rng.standard_normal((n, 2)), dt=1e-4)
    path = write_recording(data, tmp_path / "rec.parquet")
    row_group_bytes = 2**18 * 5 * 8
    seen = []
    total = 0
    for chunk in iter_recording_chunks(path, 300_000):
        total += chunk.n_samples
        seen.append(pa.total_allocated_bytes())
    assert total == n
    assert max(seen[1:]) <= seen[1] + row_group_bytes, [s / row_group_bytes for s in seen]
    np.testing.assert_array_equal(chunk.y, data.y[-300_000:])
