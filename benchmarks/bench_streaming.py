"""Records larger than memory: a long bearing record written to Parquet, identified streamed.

Run from the repository root (the file goes to /tmp, never into the repository)::

    python -m benchmarks.bench_streaming --n 1e7                 # about 2 minutes
    python -m benchmarks.bench_streaming --n 1e8 --methods physical
    python -m benchmarks.bench_streaming --n 1e6 --compare       # streamed vs in memory

The record is the closed-loop bearing of ``bench_amb_speed`` (R1 and kw1 +20 %,
paper-like noise), simulated chunk by chunk with the loop state carried from
one chunk to the next (:func:`maglevid.simulate.loop.closed_loop_system` run by
:func:`maglevid.simulate.kernel.simulate_lti`), and written with pyarrow's
``ParquetWriter`` in maglevid's Parquet layout, so memory stays bounded while
writing too. Each identification runs in its own process and reports its wall
time and the process's peak resident memory (``getrusage`` ``ru_maxrss``:
interpreter, libraries and data together).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_amb_mc import PAPER_LIKE_NOISE
from benchmarks.bench_amb_speed import FAULT, bearing_case

#: Control periods simulated and written per chunk.
WRITE_CHUNK = 1_000_000
#: Control periods per chunk when identifying.
READ_CHUNK = 1_000_000
#: Where the records go (never the repository).
DEFAULT_FOLDER = Path("/tmp/maglevid-bench")


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far [MiB] (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def write_parquet_chunked(path: Path, n: int, *, chunk: int = WRITE_CHUNK, seed: int = 11) -> dict:
    """Simulate ``n`` control periods of the bearing loop and write them to ``path`` in chunks."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from maglevid.control import IntegralStateFeedback, Observer
    from maglevid.data import ClosedLoopData
    from maglevid.io import _native
    from maglevid.io._parquet import METADATA_KEY, ROW_GROUP_ROWS
    from maglevid.physics.amb import AMBParameters, amb_state_space
    from maglevid.simulate.kernel import simulate_lti
    from maglevid.simulate.loop import closed_loop_system

    t_start = time.perf_counter()
    template, _ = bearing_case(100, seed=seed)  # the loop, names, units and metadata
    loop = template.loop
    plant = AMBParameters.nominal().with_fault(**FAULT)
    dt = template.dt
    observer = Observer.from_dict(loop["observer"])
    controller = IntegralStateFeedback.from_dict(loop["controller"])
    sys_ = closed_loop_system(amb_state_space(plant, dt), observer, controller)
    rng = np.random.default_rng(seed)
    noise = np.asarray(PAPER_LIKE_NOISE)
    z = None
    writer = None
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".parquet.part")
    try:
        for a in range(0, n, chunk):
            c = min(chunk, n - a)
            r = rng.standard_normal((c, 2))
            v = rng.standard_normal((c, 3)) * noise
            if z is None:  # from rest, as simulate_linear_loop: e'(0) = E v(0)
                z = np.zeros(sys_.nx)
                z[-controller.ne :] = controller.E @ v[0]
            out, z = simulate_lti(sys_, np.hstack([r, v]), x0=z)
            y, u_f = out[:, :3], out[:, 3:]
            d = ClosedLoopData(
                y=y,
                u=u_f + r,
                r=r,
                u_f=u_f,
                dt=dt,
                t0=a * dt,
                names=template.names,
                units=template.units,
                loop=loop,
                metadata=template.metadata,
            )
            labels, units, columns = _native.row_columns(d)
            if writer is None:
                desc = _native.describe(d)
                desc["n_samples"] = int(n)
                desc["t0"] = 0.0
                desc["file"] = {
                    "format": "parquet",
                    "columns": labels,
                    "column_units": units,
                    "rows": int(n),
                    "time_column": "t",
                    "layout": "one row per output sample (N*p rows); inputs held over each "
                    "control period (p equal rows)",
                }
                fields = [
                    pa.field(lab, pa.float64(), nullable=False, metadata={"unit": un})
                    for lab, un in zip(labels, units)
                ]
                schema = pa.schema(fields, metadata={METADATA_KEY: json.dumps(desc).encode()})
                writer = pq.ParquetWriter(tmp, schema, use_dictionary=False)
            table = pa.Table.from_arrays(
                [pa.array(np.asarray(col)) for col in columns], schema=schema
            )
            writer.write_table(table, row_group_size=ROW_GROUP_ROWS)
    finally:
        if writer is not None:
            writer.close()
    tmp.replace(path)
    return {
        "n": n,
        "path": str(path),
        "bytes": path.stat().st_size,
        "write_s": time.perf_counter() - t_start,
        "peak_rss_mib": peak_rss_mib(),
    }


def _summary(res: Any, truth: dict[str, Any]) -> dict[str, Any]:
    from benchmarks.bench_amb_speed import unstable_pole

    params = {k: float(v) for k, v in res.parameters.items()}
    out = {"parameters": params, **unstable_pole(res.model.poles(), truth)}
    if "v1" in params:
        v = np.array([params[f"v{i}"] for i in range(1, 10)])
        out["v_error_max"] = float(np.max(np.abs(v / truth["v"] - 1)))
    return out


def fit_file(
    path: Path, method: str, *, stream: bool, chunk: int = READ_CHUNK, **options: Any
) -> dict:
    """Identify the record in ``path``: streamed (chunks) or read whole. Time and peak memory."""
    from maglevid.identify.registry import get_method
    from maglevid.identify.streaming import identify_streamed
    from maglevid.io import iter_recording_chunks, read_recording

    _, truth = bearing_case(100)
    rss0 = peak_rss_mib()
    t0 = time.perf_counter()
    if stream:
        res = identify_streamed(lambda: iter_recording_chunks(path, chunk), method, **options)
    else:
        data = read_recording(path)
        res = get_method(method)(data, **options)
    wall = time.perf_counter() - t0
    return {
        "method": method,
        "stream": stream,
        "chunk": chunk if stream else None,
        "n_samples": res.n_samples,
        "time_s": wall,
        "peak_rss_mib": peak_rss_mib(),
        "rss_before_mib": rss0,
        **_summary(res, truth),
    }


#: What the streaming demonstration identifies: ``method -> options``.
STREAM_METHODS: dict[str, dict[str, Any]] = {
    "physical": {},
    "moesp": {"order": 4, "horizon": 40},
}


def _in_subprocess(call: str, timeout: float) -> dict:
    """Run ``call`` (Python source returning a dict) in a fresh interpreter: clean peak memory."""
    code = (
        "import json, sys\n"
        "from pathlib import Path\n"
        "from benchmarks.bench_streaming import *\n"
        f"print('@@' + json.dumps({call}))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=os.environ,
    )
    lines = [x for x in r.stdout.splitlines() if x.startswith("@@")]
    if r.returncode != 0 or not lines:
        raise RuntimeError(r.stderr.strip()[-800:])
    return json.loads(lines[-1][2:])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=float, default=1e7, help="control periods")
    ap.add_argument(
        "--methods", nargs="+", default=list(STREAM_METHODS), choices=list(STREAM_METHODS)
    )
    ap.add_argument("--folder", default=str(DEFAULT_FOLDER))
    ap.add_argument("--compare", action="store_true", help="also identify the file in memory")
    ap.add_argument("--keep", action="store_true", help="keep the Parquet file")
    ap.add_argument("--timeout", type=float, default=3600.0)
    args = ap.parse_args(argv)
    n = int(args.n)
    path = Path(args.folder) / f"bearing-{n}.parquet"
    w = _in_subprocess(f"write_parquet_chunked(Path({str(path)!r}), {n})", args.timeout)
    print(
        f"wrote {path}: {w['bytes'] / 2**20:.0f} MiB in {w['write_s']:.1f} s "
        f"(peak RSS {w['peak_rss_mib']:.0f} MiB)"
    )
    try:
        for method in args.methods:
            modes = [True, False] if args.compare else [True]
            for stream in modes:
                opts = ", ".join(f"{k}={v!r}" for k, v in STREAM_METHODS[method].items())
                call = f"fit_file(Path({str(path)!r}), {method!r}, stream={stream}, {opts})"
                r = _in_subprocess(call, args.timeout)
                mode = "streamed" if stream else "in memory"
                print(
                    f"{method:<9} {mode:<10} {r['time_s']:8.1f} s  "
                    f"peak RSS {r['peak_rss_mib']:7.0f} MiB  unstable pole error "
                    f"{r['pole_error']:.2e}  max v error {r.get('v_error_max', float('nan')):.2e}"
                )
    finally:
        if not args.keep:
            path.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
