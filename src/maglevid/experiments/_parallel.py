"""Monte Carlo runs of the reproductions on all cores, with the cores they obtained.

One process per core, one BLAS thread per process: the runs are many small
matrix problems, where a multi-threaded BLAS in every worker only makes the
workers fight over the same cores (docs/performance.md, "Threads").

How workers start: when this process already runs one BLAS thread (the
``OPENBLAS_NUM_THREADS``/``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` it started
with say 1) and no other Python thread, on Linux, workers are *forked*: they
inherit the loaded modules and start at once. Otherwise they are *spawned*
fresh with one BLAS thread set in their environment (a forked worker would
inherit the parent's BLAS threads), which costs each worker its imports
(~1-2 s; measured in BENCHMARKS.md, section 5).
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import resource
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

#: Progress reporting passed in by the caller: ``progress(iterable, *, desc, total=None)``
#: returns an iterable over the same items (the CLI passes a tqdm bar).
Progress = Callable[..., Iterable[Any]]


def no_progress(
    iterable: Iterable[Any], *, desc: str = "", total: int | None = None
) -> Iterable[Any]:
    """The default :data:`Progress`: the items, unreported."""
    return iterable


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


def start_method() -> str:
    """``"fork"`` where it is safe and faster (see the module notes), else ``"spawn"``."""
    values = [os.environ.get(k) for k in _BLAS_THREAD_VARIABLES]
    one_thread = "1" in values and all(v in (None, "1") for v in values)
    if sys.platform.startswith("linux") and one_thread and threading.active_count() == 1:
        return "fork"
    return "spawn"


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
    progress: Progress | None = None,
) -> tuple[list[Any], dict[str, Any]]:
    """``[task(s) for s in specs]`` on ``args.workers`` processes (default: all cores).

    ``task`` must be a module-level function (it is pickled). Results keep the
    order of ``specs``, so they do not depend on the number of workers.
    ``progress`` (a :data:`Progress`, default none) reports the tasks done.

    Returns
    -------
    results : list
    timing : dict
        ``workers``, ``start_method`` (``serial``, ``fork`` or ``spawn``), ``wall_s``
        (this phase only), ``cpu_s`` (this process and its
        workers) and ``cores_obtained = cpu_s / wall_s``: how many cores the phase
        actually had, which tells a busy machine apart from poor scaling.
    """
    progress = progress or no_progress

    workers = max(1, int(getattr(args, "workers", None) or os.cpu_count() or 1))
    workers = min(workers, max(1, len(specs)))
    t0, c0 = time.perf_counter(), _cpu_seconds()
    method = "serial"
    if workers == 1:
        results = [task(s) for s in progress(specs, desc=desc, total=len(specs))]
    else:
        method = start_method()
        with one_blas_thread():
            ctx = multiprocessing.get_context(method)
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                results = list(progress(pool.map(task, specs), desc=desc, total=len(specs)))
    wall = time.perf_counter() - t0
    cpu = _cpu_seconds() - c0
    timing = {
        "workers": workers,
        "start_method": method,
        "tasks": len(specs),
        "wall_s": wall,
        "cpu_s": cpu,
        "cores_obtained": cpu / wall if wall > 0 else float("nan"),
    }
    return results, timing
