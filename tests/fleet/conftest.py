"""Fixtures of the fleet tests: one local Dask cluster for the session, store backends."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from _fleet_helpers import BACKENDS, Where, store_where


@pytest.fixture(scope="session")
def dask_client() -> Iterator[Any]:
    """A local cluster of 2 single-threaded worker processes, shared by the session.

    Starting one costs seconds (processes, imports): the tests share it and pass
    it to ``run_fleet(scheduler=client)`` or its address to the CLI. A task may
    see one worker death and is then rerun (``allowed-failures`` = 1, default 3):
    enough for the kill test, and a recording that kills its worker every time
    is given up after two deaths instead of four.
    """
    pytest.importorskip("distributed")
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        cluster = LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.CRITICAL,
        )
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


@pytest.fixture(params=BACKENDS)
def where(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Where]:
    """A fresh history store on each backend (SQLite file; PostgreSQL schema when available)."""
    yield from store_where(request.param, tmp_path)
