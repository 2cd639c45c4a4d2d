"""Monte Carlo runs of the reproductions on all cores, with the cores they obtained.

One process per core, one BLAS thread per process: the runs are many small
matrix problems, where a multi-threaded BLAS in every worker only makes the
workers fight over the same cores (docs/performance.md, "Threads"). Workers are
spawned fresh so that the thread setting reaches their BLAS, whatever the
parent process has already loaded.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import resource
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Set one BLAS thread for the processes started inside (unless the user set it)."""
    old = {k: os.environ.get(k) for k in _BLAS_THREAD_VARIABLES}
    for k in _BLAS_THREAD_VARIABLES:
        os.environ.setdefault(k, "1")
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)  # workers, once waited for
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_parallel(
    task: Callable[[Any], Any],
    specs: Sequence[Any],
    args: argparse.Namespace,
    *,
    desc: str = "Monte Carlo",
) -> tuple[list[Any], dict[str, Any]]:
    """``[task(s) for s in specs]`` on ``args.workers`` processes (default: all cores).

    ``task`` must be a module-level function (it is pickled). Results keep the
    order of ``specs``, so they do not depend on the number of workers.

    Returns
    -------
    results : list
    timing : dict
        ``workers``, ``wall_s`` (this phase only), ``cpu_s`` (this process and its
        workers) and ``cores_obtained = cpu_s / wall_s``: how many cores the phase
        actually had, which tells a busy machine apart from poor scaling.
    """
    from maglevid.cli._progress import progress

    workers = max(1, int(getattr(args, "workers", None) or os.cpu_count() or 1))
    workers = min(workers, max(1, len(specs)))
    t0, c0 = time.perf_counter(), _cpu_seconds()
    if workers == 1:
        results = [task(s) for s in progress(specs, desc=desc, args=args)]
    else:
        with one_blas_thread():
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                results = list(
                    progress(pool.map(task, specs), desc=desc, total=len(specs), args=args)
                )
    wall = time.perf_counter() - t0
    cpu = _cpu_seconds() - c0
    timing = {
        "workers": workers,
        "tasks": len(specs),
        "wall_s": wall,
        "cpu_s": cpu,
        "cores_obtained": cpu / wall if wall > 0 else float("nan"),
    }
    return results, timing
