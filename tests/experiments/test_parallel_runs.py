"""The Monte Carlo runner of the reproductions: order, worker count, timing."""

from __future__ import annotations

import argparse
import math
import os

import pytest

from maglevid.experiments._parallel import one_blas_thread, run_parallel


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
