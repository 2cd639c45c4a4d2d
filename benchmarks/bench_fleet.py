"""Fleet runs on Dask: throughput, engine overhead against a plain loop, memory, store writes.

Generates N short simulated AMB recordings (2000-4000 samples; 70 % healthy,
20 % faulty: kw1 -40 % or R1 +30 %; 10 % that cannot be read), 5 per machine,
and measures, for each N:

* ``loop``: the same per-recording work (read, content hash, diagnose, store
  write; :func:`maglevid.fleet.worker.diagnose_batch`) in this process, one
  recording after the other: the work itself;
* ``engine``: :func:`maglevid.fleet.run_fleet` on a local cluster of 1 and 2
  worker processes (batched as by default, and one recording per task), wall
  time from the call to the summary, split into cluster start + diagnosis,
  and the summary (drift tests); overhead = engine (1 worker) / loop - 1;
* ``rerun``: the same command again (everything skipped; nothing added);
* the peak resident memory of each worker process (``ru_maxrss``);
* the store: seconds per diagnosis write, and the aggregate write rate of 1, 2
  and 4 processes writing at once (SQLite; PostgreSQL too when
  ``MAGLEVID_TEST_POSTGRES_URL`` is set).

Run from the repository root::

    PYTHONPATH=src python -m benchmarks.bench_fleet                 # N = 100 and 1000
    PYTHONPATH=src python -m benchmarks.bench_fleet --n 100 --data /tmp/fleet-data

Prints Markdown table rows with the load average before and after each row
(the machine may be shared: compare ratios taken in one run).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import os
import platform
import shutil
import sys
import tempfile
import time
from collections import Counter
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np

import maglevid
from maglevid.diagnose.history import HistoryStore, open_history
from maglevid.fleet import collect_jobs, run_fleet
from maglevid.fleet.worker import BatchContext, diagnose_batch
from maglevid.io import write_recording
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)


def _load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def make_fleet(root: Path, n: int, *, seed: int = 20261122) -> dict[str, str]:
    """``n`` recordings in ``root/<machine>/rec<k>.npz`` (5 per machine); returns path -> kind."""
    rng = np.random.default_rng(seed)
    nominal = AMBParameters.nominal()
    kinds: dict[str, str] = {}
    for i in range(n):
        machine, k = f"m{i // 5:04d}", i % 5
        path = root / machine / f"rec{k}.npz"
        path.parent.mkdir(parents=True, exist_ok=True)
        u = rng.uniform()
        if u < 0.1:
            kinds[str(path)] = "corrupt"
            if i % 2:
                path.write_bytes(b"not a recording\n" * 64)
            else:  # a truncated copy of a good one
                good = simulate_amb_loop(
                    nominal, n_samples=2000, rng=int(rng.integers(2**62)), plant_model="linear"
                )
                write_recording(good, path)
                data = path.read_bytes()
                path.write_bytes(data[: len(data) // 2])
            continue
        fault = {} if u < 0.8 else ({"kw1": 0.6} if u < 0.9 else {"R1": 1.3})
        data = simulate_amb_loop(
            nominal.with_fault(**fault),
            nominal=nominal,
            n_samples=int(rng.integers(2000, 4001)),
            rng=int(rng.integers(2**62)),
            plant_model="linear",
        )
        meta = dict(data.metadata)
        meta["recorded_at"] = (T0 + timedelta(days=k)).isoformat()
        write_recording(dataclasses.replace(data, metadata=meta), path)
        kinds[str(path)] = "faulty" if fault else "healthy"
    (root / "kinds.json").write_text(json.dumps(kinds))
    return kinds


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def run_loop(root: Path, store: str) -> dict[str, Any]:
    """The work itself: every recording through the worker's code, in this process."""
    jobs = collect_jobs(root)
    write_time = [0.0]
    original = HistoryStore.record_diagnosis

    def timed(self: Any, *args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            write_time[0] += time.perf_counter() - t

    HistoryStore.record_diagnosis = timed  # type: ignore[method-assign]
    try:
        with open_history(store):
            pass
        t = time.perf_counter()
        outcomes = diagnose_batch(jobs, BatchContext(store=store))[1]
        wall = time.perf_counter() - t
    finally:
        HistoryStore.record_diagnosis = original  # type: ignore[method-assign]
    return {
        "wall": wall,
        "n": len(outcomes),
        "write_s": write_time[0],
        "n_written": sum(o.status in ("diagnosed", "unreadable") for o in outcomes),
        "rss_mb": _peak_rss_mb(),
    }


def run_engine(
    root: Path, store: str, workers: int, batch_size: int | None, rss: bool = True
) -> dict[str, Any]:
    """``run_fleet`` on a fresh local cluster; worker peak memory read before it closes."""
    from distributed import Client, LocalCluster

    t = time.perf_counter()
    with (
        LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address="127.0.0.1:0",
        ) as cluster,
        Client(cluster) as client,
    ):
        t_up = time.perf_counter()
        summary = run_fleet(root, store=store, scheduler=client, batch_size=batch_size)
        t_run = time.perf_counter()
        peaks = list(client.run(_peak_rss_mb).values()) if rss else []
    return {
        "wall": t_run - t,
        "start": t_up - t,
        "diagnosis": summary.run["seconds_diagnosis"],
        "summary": summary.run["seconds_summary"],
        "n": len(summary.outcomes),
        "tasks": summary.run["n_tasks"],
        "batch": summary.run["batch_size"],
        "counts": summary.counts,
        "rss_mb": peaks,
        "work": sum(o.seconds for o in summary.outcomes),
        "outcomes": summary.outcomes,
    }


def _writer(location: str, schema: str | None, proc: int, n: int, barrier: Any, q: Any) -> None:
    estimates = {f"p{k}": (1.0 + k, 0.01, 0.98, 1.02, "u", 1.0) for k in range(27)}
    summary = {"text": "x" * 14_000}  # a pipeline summary is ~15 kB of JSON
    with open_history(location, schema=schema) as st:
        barrier.wait()
        t = time.perf_counter()
        for i in range(n):
            st.record_diagnosis(
                f"w{proc}",
                recording_hash=f"{proc}-{i}",
                recorded_at=T0 + timedelta(minutes=i),
                method="physical",
                verdict="No significant change",
                verdict_code="no_change",
                estimates=estimates,
                summary=summary,
            )
        q.put(time.perf_counter() - t)


def store_writes(location: str, schema: str | None, procs: int, n: int) -> float:
    """Aggregate diagnoses written per second by ``procs`` processes at once."""
    ctx = multiprocessing.get_context("spawn")
    barrier, q = ctx.Barrier(procs), ctx.Queue()
    with open_history(location, schema=schema):
        pass
    ps = [
        ctx.Process(target=_writer, args=(location, schema, p, n, barrier, q))
        for p in range(procs)
    ]
    for p in ps:
        p.start()
    times = [q.get(timeout=600) for _ in ps]
    for p in ps:
        p.join()
    return procs * n / max(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="*", default=[100, 1000], help="fleet sizes")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--data", type=Path, default=None, help="keep the recordings here")
    parser.add_argument("--writes", type=int, default=200, help="diagnoses per writer process")
    parser.add_argument("--skip-writes", action="store_true")
    args = parser.parse_args(argv)

    import dask
    import distributed

    print(
        f"<!-- maglevid {maglevid.__version__}, dask {dask.__version__}, distributed "
        f"{distributed.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
        f"{os.cpu_count()} CPUs, {platform.machine()}, load average {_load()} -->"
    )
    base = args.data or Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    print("| N | run | workers | batch | tasks | wall s | rec/s | overhead vs loop | "
          "overhead vs own work | start s | summary s | peak RSS MB/worker | "
          "load before -> after |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.n:
        root = base / f"n{n}"
        if not root.is_dir():
            t = time.perf_counter()
            make_fleet(root, n)
            print(f"<!-- generated {n} recordings in {time.perf_counter() - t:.1f} s -->")
        stores = base / f"stores-{n}"
        shutil.rmtree(stores, ignore_errors=True)
        stores.mkdir()
        before = _load()
        loop = run_loop(root, str(stores / "loop.sqlite"))
        print(
            f"| {n} | plain loop | 1 (this process) | - | - | {loop['wall']:.1f} | "
            f"{n / loop['wall']:.2f} | - | - | - | - | {loop['rss_mb']:.0f} | "
            f"{before} -> {_load()} |"
        )
        print(
            f"<!-- store writes in the loop: {loop['n_written']} diagnoses, "
            f"{1e3 * loop['write_s'] / max(1, loop['n_written']):.1f} ms each, "
            f"{100 * loop['write_s'] / loop['wall']:.1f} % of the work -->"
        )
        sys.stdout.flush()
        for workers in args.workers:
            for batch in (None, 1) if workers == 1 else (None,):
                before = _load()
                store = str(stores / f"engine-{workers}-{batch}.sqlite")
                r = run_engine(root, store, workers, batch)
                over = f"{100 * (r['wall'] / loop['wall'] - 1):+.1f} %" if workers == 1 else "-"
                # The same run's own work (seconds inside the tasks) spread over the workers:
                # robust to a load that changes between the loop and the engine runs.
                own = f"{100 * (r['wall'] / (r['work'] / workers) - 1):+.1f} %"
                print(
                    f"| {n} | engine | {workers} | {r['batch']} | {r['tasks']} | "
                    f"{r['wall']:.1f} | {n / r['wall']:.2f} | {over} | {own} | {r['start']:.1f} | "
                    f"{r['summary']:.1f} | {' / '.join(f'{m:.0f}' for m in r['rss_mb'])} | "
                    f"{before} -> {_load()} |"
                )
                sys.stdout.flush()
        kinds = json.loads((root / "kinds.json").read_text())
        verdicts = Counter((kinds[o.recording], o.verdict_code) for o in r["outcomes"])
        print(
            "<!-- verdicts by kind (last engine run): "
            + ", ".join(f"{k} -> {v}: {c}" for (k, v), c in sorted(verdicts.items()))
            + " -->"
        )
        before = _load()
        r = run_engine(root, store, args.workers[-1], None, rss=False)
        assert r["counts"].get("diagnosed", 0) == 0, r["counts"]  # nothing new the second time
        print(
            f"| {n} | rerun (all skipped) | {args.workers[-1]} | {r['batch']} | {r['tasks']} | "
            f"{r['wall']:.1f} | {n / r['wall']:.2f} | - | - | {r['start']:.1f} | "
            f"{r['summary']:.1f} | - | {before} -> {_load()} |"
        )
        sys.stdout.flush()
    if not args.skip_writes:
        print()
        print("| store | writer processes | diagnoses/s (all together) | load before -> after |")
        print("|---|---|---|---|")
        targets = [("SQLite (WAL, synchronous=FULL)", None)]
        if os.environ.get("MAGLEVID_TEST_POSTGRES_URL"):
            targets.append(("PostgreSQL", os.environ["MAGLEVID_TEST_POSTGRES_URL"]))
        for label, url in targets:
            for procs in (1, 2, 4):
                before = _load()
                if url is None:
                    loc, schema = str(base / f"writes-{procs}.sqlite"), None
                    for suffix in ("", "-wal", "-shm"):
                        Path(loc + suffix).unlink(missing_ok=True)
                else:
                    loc, schema = url, f"bench_writes_{os.getpid()}_{procs}"
                rate = store_writes(loc, schema, procs, args.writes)
                if url is not None:
                    import psycopg

                    with psycopg.connect(url, autocommit=True) as conn:
                        conn.execute(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')
                print(f"| {label} | {procs} | {rate:.0f} | {before} -> {_load()} |")
                sys.stdout.flush()
    if args.data is None:
        shutil.rmtree(base, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
