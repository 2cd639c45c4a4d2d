"""Read/write speed of every recording format for a 10^6-sample recording.

Run from the repository root::

    PYTHONPATH=src python benchmarks/io_speed.py [--n 1000000] [--folder /tmp/x]

Prints seconds per write and read and the file sizes. Timings on a shared
machine are noisy; compare formats within one run, not across runs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.io import iter_recording_chunks, read_recording, write_recording


def make(n: int, rng: np.random.Generator) -> ClosedLoopData:
    return ClosedLoopData(
        y=rng.standard_normal((n, 3)),
        u=rng.standard_normal((n, 2)),
        r=rng.standard_normal((n, 2)),
        dt=1e-4,
        names={"y": ["x", "i1", "i2"]},
        units={"y": ["m", "A", "A"], "u": ["V", "V"], "r": ["V", "V"]},
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--folder", default=None)
    args = ap.parse_args()
    data = make(args.n, np.random.default_rng(0))
    folder = Path(args.folder or tempfile.mkdtemp())
    print(f"N = {args.n}, 3 outputs + 2 inputs + 2 excitations, folder {folder}")
    print(f"{'format':>8} {'write s':>9} {'read s':>9} {'chunks s':>9} {'MB':>8}")
    for name, fmt in [
        ("rec.csv", None),
        ("rec.npz", None),
        ("rec.mat", None),
        ("rec73.mat", "mat73"),
        ("rec.parquet", None),
    ]:
        path = folder / name
        t = time.perf_counter()
        write_recording(data, path, format=fmt, overwrite=True)
        tw = time.perf_counter() - t
        t = time.perf_counter()
        back = read_recording(path)
        tr = time.perf_counter() - t
        assert np.array_equal(back.y, data.y) and np.array_equal(back.u, data.u)
        t = time.perf_counter()
        n = sum(c.n_samples for c in iter_recording_chunks(path, 100_000))
        tc = time.perf_counter() - t
        assert n == data.n_samples
        size = path.stat().st_size / 1e6
        print(f"{fmt or path.suffix[1:]:>8} {tw:9.2f} {tr:9.2f} {tc:9.2f} {size:8.1f}")


if __name__ == "__main__":
    main()
