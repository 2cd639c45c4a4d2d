"""Independent tasks on the machine's cores: one process per core, one BLAS thread each.

The tasks this package runs in parallel are many small matrix problems (Monte Carlo
records of the reproductions, the levitator's candidate grey boxes), where a
multi-threaded BLAS in every worker only makes the workers fight over the same cores
(docs/performance.md, "Threads").

How workers start: when this process already runs one BLAS thread (the
``OPENBLAS_NUM_THREADS``/``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` it started with say 1)
and no other Python thread, on Linux, workers are *forked*: they inherit the loaded
modules and start at once. Otherwise they are *spawned* fresh with one BLAS thread set
in their environment (a forked worker would inherit the parent's BLAS threads), which
costs each worker its imports (~1-2 s; measured in BENCHMARKS.md, section 5).

Library code that any script may call asks for fork or nothing (``spawn=False``): it runs
in order where workers would have to be spawned. A process that is itself a worker (of
this module, of a fleet's Dask cluster, of a user's pool) runs its tasks in order:
workers of workers would oversubscribe the cores the outer pool already shares out, and
daemonic workers may not start processes.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

__all__ = [
    "available_cores",
    "map_in_processes",
    "one_blas_thread",
    "one_blas_thread_here",
    "start_method",
]

_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def available_cores() -> int:
    """Cores this process may use (the affinity mask, else ``os.cpu_count()``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


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


@contextlib.contextmanager
def one_blas_thread_here() -> Iterator[None]:
    """One BLAS thread in this process while inside, unless the environment chose a number
    (``OPENBLAS_NUM_THREADS`` and the like). maglevid's matrices are small: a second BLAS
    thread on them costs more than it gives (docs/performance.md, "Threads"); measured on
    the 2-core machine, `maglevid identify` of an inter-sampled suspension 9.8 s -> 3.9 s,
    `maglevid diagnose` of a bearing record 2.8 s -> 1.9 s. The numpy already loaded keeps
    its thread pool, limited through threadpoolctl (without it, nothing changes)."""
    if any(os.environ.get(k) for k in _BLAS_THREAD_VARIABLES):
        yield
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a core dependency; an old install lacks it
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def start_method() -> str:
    """``"fork"`` where it is safe and faster (see the module notes), else ``"spawn"``."""
    values = [os.environ.get(k) for k in _BLAS_THREAD_VARIABLES]
    one_thread = "1" in values and all(v in (None, "1") for v in values)
    if sys.platform.startswith("linux") and one_thread and threading.active_count() == 1:
        return "fork"
    return "spawn"


def map_in_processes(
    task: Callable[[Any], Any],
    specs: Sequence[Any],
    workers: int | None = None,
    *,
    watch: Callable[[Iterable[Any]], Iterable[Any]] | None = None,
    spawn: bool = True,
) -> tuple[list[Any], int, str]:
    """``[task(s) for s in specs]``, on up to ``workers`` processes (default: every
    available core), in the order of ``specs`` whatever the number of workers.

    ``task`` must be a module-level function (it is pickled). In order, in this process,
    when one worker would do (``workers`` 1, one spec, one core) or this process is itself
    a worker (see the module notes). ``watch`` wraps the stream of results as they come
    (a progress bar).

    ``spawn=False`` for library code that any script may call: a spawned worker imports
    the caller's main module again, and a script without an ``if __name__ ==
    "__main__":`` guard then dies with a broken pool (found when the levitator's
    candidates first ran on workers: a plain script on Linux with a second thread). Such
    callers run in order unless workers can be forked (:func:`start_method`). The
    command line's entry point has the guard: its reproductions may spawn.

    Returns
    -------
    results : list
    workers : int
        The processes used (1: in order, here).
    how : {"serial", "fork", "spawn"}
    """
    n = available_cores() if workers is None else max(1, int(workers))
    n = min(n, max(1, len(specs)))
    watch = watch or (lambda results: results)
    method = start_method()
    if n == 1 or multiprocessing.parent_process() is not None or (method == "spawn" and not spawn):
        return list(watch(task(s) for s in specs)), 1, "serial"
    with one_blas_thread():
        ctx = multiprocessing.get_context(method)
        with ProcessPoolExecutor(max_workers=n, mp_context=ctx) as pool:
            return list(watch(pool.map(task, specs))), n, method
