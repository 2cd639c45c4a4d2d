"""The Monte Carlo runner of the reproductions: order, worker count, timing."""

from __future__ import annotations

import argparse
import math
import os
import sys

import pytest

from maglevid.experiments._parallel import one_blas_thread, run_parallel, start_method


def _args(workers: int | None) -> argparse.Namespace:
    return argparse.Namespace(workers=workers, quiet=True, json=True)


@pytest.mark.parametrize("workers", [1, 2])
def test_results_keep_the_order_of_the_specs(workers: int) -> None:
    specs = [float(k) for k in range(7, 0, -1)]
    results, timing = run_parallel(math.sqrt, specs, _args(workers))
    assert results == [math.sqrt(s) for s in specs]
    assert timing["workers"] == workers
    assert timing["tasks"] == len(specs)
    assert timing["wall_s"] > 0 and timing["cpu_s"] >= 0
    assert timing["cores_obtained"] == pytest.approx(timing["cpu_s"] / timing["wall_s"])


def test_never_more_workers_than_tasks() -> None:
    _, timing = run_parallel(math.sqrt, [4.0], _args(8))
    assert timing["workers"] == 1


def test_one_blas_thread_respects_the_users_setting(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    with one_blas_thread():
        assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
        assert os.environ["OMP_NUM_THREADS"] == "1"
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
    assert "OMP_NUM_THREADS" not in os.environ


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        ({"OPENBLAS_NUM_THREADS": "1"}, "fork"),
        ({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}, "fork"),
        ({}, "spawn"),  # BLAS threads unknown: a forked worker would inherit them
        ({"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "4"}, "spawn"),
    ],
)
def test_workers_are_forked_only_with_one_blas_thread(
    monkeypatch: pytest.MonkeyPatch, env: dict[str, str], expected: str
) -> None:
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(k, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    monkeypatch.setattr(sys, "platform", "linux")
    # Only the environment is under test: a thread left by an earlier test (a Dask
    # client's offload thread) rightly forbids fork, and is not this test's subject.
    import threading

    monkeypatch.setattr(threading, "active_count", lambda: 1)
    assert start_method() == expected


@pytest.mark.parametrize("blas", ["1", None])
def test_forked_and_spawned_workers_give_the_same_results(
    monkeypatch: pytest.MonkeyPatch, blas: str | None
) -> None:
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(k, raising=False)
    if blas is not None:
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", blas)
    specs = [float(k) for k in range(5)]
    results, timing = run_parallel(math.sqrt, specs, _args(2))
    assert results == [math.sqrt(s) for s in specs]
    assert timing["start_method"] == start_method()
