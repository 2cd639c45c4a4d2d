"""maglevid.parallel: tasks on the cores, in order, never workers of workers."""

from __future__ import annotations

import functools
import math

from maglevid.parallel import available_cores, map_in_processes


def test_results_keep_the_order_and_one_worker_runs_here() -> None:
    specs = [float(k) for k in range(9, 0, -1)]
    for workers in (1, 2, 3):
        results, n, how = map_in_processes(math.sqrt, specs, workers)
        assert results == [math.sqrt(s) for s in specs]
        assert n == workers and (how == "serial") == (workers == 1)
    assert map_in_processes(math.sqrt, [4.0], 8)[1:] == (1, "serial")  # no more than tasks
    assert 1 <= available_cores()


def test_a_worker_runs_its_own_tasks_in_order() -> None:
    # a pool inside a pool's worker would oversubscribe the cores the outer one shares
    # out (a fleet's Dask workers identifying levitators), and daemonic workers may not
    # start processes at all
    inner = functools.partial(map_in_processes, math.sqrt, [4.0, 9.0])
    outs, n, _ = map_in_processes(inner, [2, 2], 2)
    assert n == 2
    assert outs == [([2.0, 3.0], 1, "serial")] * 2


def test_the_watch_sees_every_result() -> None:
    seen: list[float] = []

    def watch(stream):
        for r in stream:
            seen.append(r)
            yield r

    results, _, _ = map_in_processes(math.sqrt, [1.0, 4.0, 9.0], 2, watch=watch)
    assert seen == results == [1.0, 2.0, 3.0]


def test_library_code_runs_in_order_where_workers_would_be_spawned(monkeypatch) -> None:
    # A spawned worker imports the caller's main module again: a plain script without a
    # main guard that called fit_levitator died with a broken pool (this session's first
    # cut, on Linux with a second thread alive). spawn=False: fork or nothing.
    import maglevid.parallel as par

    monkeypatch.setattr(par, "start_method", lambda: "spawn")
    assert par.map_in_processes(math.sqrt, [4.0, 9.0], 2, spawn=False) == ([2.0, 3.0], 1, "serial")


def test_a_command_runs_on_one_blas_thread_unless_the_environment_chose(monkeypatch):
    """Small matrices on a second BLAS thread made `maglevid identify` of a suspension
    2.5x slower (parallel.one_blas_thread_here); a number in the environment wins."""
    from threadpoolctl import threadpool_info

    from maglevid.parallel import one_blas_thread_here

    def blas_threads():
        return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}

    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(k, raising=False)
    before = blas_threads()
    with one_blas_thread_here():
        assert blas_threads() == {1}
    assert blas_threads() == before
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    with one_blas_thread_here():
        assert blas_threads() == before  # the user's choice is left alone
