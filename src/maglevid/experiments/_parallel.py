"""Monte Carlo runs of the reproductions on all cores, with the cores they obtained.

The processes, their start (fork or spawn) and their one BLAS thread are
:mod:`maglevid.parallel`'s; this adds the reproductions' progress and timing.
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from maglevid.parallel import map_in_processes, one_blas_thread, start_method

__all__ = ["Progress", "no_progress", "one_blas_thread", "run_parallel", "start_method"]

#: Progress reporting passed in by the caller: ``progress(iterable, *, desc, total=None)``
#: returns an iterable over the same items (the CLI passes a tqdm bar).
Progress = Callable[..., Iterable[Any]]


def no_progress(
    iterable: Iterable[Any], *, desc: str = "", total: int | None = None
) -> Iterable[Any]:
    """The default :data:`Progress`: the items, unreported."""
    return iterable


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

    t0, c0 = time.perf_counter(), _cpu_seconds()
    results, workers, method = map_in_processes(
        task,
        specs,
        getattr(args, "workers", None) or os.cpu_count() or 1,
        watch=lambda stream: progress(stream, desc=desc, total=len(specs)),
    )
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
