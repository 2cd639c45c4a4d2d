"""The runner's own cluster (the default: no set-up) and its checks before scheduling."""

from __future__ import annotations

import json
import multiprocessing
import socket
from pathlib import Path
from typing import Any

import pytest
from _fleet_helpers import N_SHORT, day, write_corrupt, write_sim

from maglevid.cli.main import main
from maglevid.exceptions import DataError
from maglevid.fleet.runner import (
    _auto_batch_size,
    _check_store_reachable,
    _shared_location,
    default_n_workers,
)

pytest.importorskip("distributed")


class _Client:
    def __init__(self, hosts: list[str]):
        self.hosts = hosts

    def run(self, fn: Any) -> dict[str, str]:
        return {f"tcp://w{i}:1": h for i, h in enumerate(self.hosts)}


def test_sqlite_store_with_workers_on_other_hosts_is_refused(tmp_path: Path) -> None:
    here = socket.gethostname()
    store = str(tmp_path / "s.sqlite")
    _check_store_reachable(store, _Client([here, here]), local=False)  # same host: fine
    _check_store_reachable(store, _Client(["elsewhere"]), local=True)  # own local cluster
    _check_store_reachable("postgresql://u@db/x", _Client(["elsewhere"]), local=False)
    with pytest.raises(DataError, match=r"SQLite file .* workers run on elsewhere.*PostgreSQL"):
        _check_store_reachable(store, _Client([here, "elsewhere"]), local=False)


def test_store_location_as_the_workers_need_it(tmp_path: Path, monkeypatch: Any) -> None:
    monkeypatch.chdir(tmp_path)
    assert _shared_location("plant.sqlite") == str(tmp_path / "plant.sqlite")
    assert _shared_location("sqlite:///sub/plant.sqlite") == str(tmp_path / "sub" / "plant.sqlite")
    assert _shared_location("postgresql://u@db/x") == "postgresql://u@db/x"
    for private in (":memory:", "sqlite://"):
        with pytest.raises(DataError, match="private to each process"):
            _shared_location(private)


def test_auto_batch_size() -> None:
    # 8 tasks per worker at least (the last tasks keep every worker busy), at most 8 per task.
    assert _auto_batch_size(10, 2) == 1
    assert _auto_batch_size(200, 2) == 8
    assert _auto_batch_size(200, 16) == 1
    assert _auto_batch_size(10_000, 16) == 8
    assert default_n_workers() >= 1


def test_default_local_cluster_is_started_and_closed(tmp_path: Path, capsys: Any) -> None:
    write_sim(tmp_path / "rec" / "pump" / "a.npz", seed=1, n_samples=N_SHORT, recorded_at=day(0))
    write_corrupt(tmp_path / "rec" / "pump" / "b.npz", "garbage")
    before = set(multiprocessing.active_children())
    rc = main(
        ["fleet", str(tmp_path / "rec"), "--store", str(tmp_path / "s.sqlite"),
         "--workers", "1", "--json"]
    )  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert out["run"]["local_cluster"] is True and out["run"]["n_workers"] == 1
    assert out["counts"] == {"diagnosed": 1, "unreadable": 1}
    assert set(multiprocessing.active_children()) <= before  # no worker process left behind
