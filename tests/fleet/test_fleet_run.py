"""Fleet runs on a real local Dask cluster, on SQLite and PostgreSQL.

The 200-recording test is the issue's acceptance test: right verdicts, a
worker killed mid-run, and a second run that adds nothing.
"""

from __future__ import annotations

import functools
import itertools
import os
import shutil
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from _fleet_helpers import (
    N_SHORT,
    Where,
    day,
    kill_once,
    logged_diagnose,
    write_corrupt,
    write_sim,
)

from maglevid.diagnose.pipeline import diagnose
from maglevid.fleet import FleetJob, run_fleet
from maglevid.io import read_recording

pytest.importorskip("distributed")

#: Machines of the 200-recording fleet: 5 recordings each.
N_HEALTHY, N_FAULTY, N_TROUBLED = 20, 10, 10
FAULT = {"kw1": 0.6}  # amplifier 1 gain down 40 %


@pytest.fixture(scope="module")
def fleet200(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """200 recordings of 40 machines in DIR/<machine>/<recording>; what each one is.

    Healthy machines: 5 healthy recordings. Faulty: 5 recordings with kw1 -40 %.
    Troubled: 3 healthy, one too short for the quality checks (readable, bad
    data) and one that cannot be read (garbage .npz or a CSV without its side-car).
    Machines share recordings (copies): the store's key is (machine, content),
    and simulating 190 recordings would cost more than diagnosing them.
    """
    root = tmp_path_factory.mktemp("fleet200")
    proto = root / "_proto"
    sims = {
        kind: [
            write_sim(
                proto / f"{kind}{k}.npz",
                fault=FAULT if kind == "faulty" else None,
                seed=100 * n + k,
                n_samples=N_SHORT if kind == "short" else 2000,
                recorded_at=day(k),
            )
            for k in range(5)
        ]
        for n, kind in enumerate(("healthy", "faulty", "short"))
    }
    kinds: dict[str, str] = {}
    for m in range(N_HEALTHY + N_FAULTY + N_TROUBLED):
        machine = root / "fleet" / f"m{m:02d}"
        machine.mkdir(parents=True)
        for k in range(5):
            if m < N_HEALTHY:
                kind = "healthy"
            elif m < N_HEALTHY + N_FAULTY:
                kind = "faulty"
            else:
                kind = ("healthy", "healthy", "healthy", "short", "corrupt")[k]
            if kind == "corrupt":
                path = write_corrupt(
                    machine / ("rec4.npz" if m % 2 else "rec4.csv"), "garbage" if m % 2 else "text"
                )
            else:
                path = machine / f"rec{k}.npz"
                shutil.copyfile(sims[kind][k], path)
            kinds[str(path)] = kind
    assert len(kinds) == 200
    return {"root": root / "fleet", "kinds": kinds}


def _count(items: Any, total: int, seen: list[int]) -> Any:
    for item in items:
        seen.append(1)
        yield item
    seen.append(total)


@pytest.mark.slow
def test_fleet200_verdicts_killed_worker_and_rerun(
    fleet200: dict[str, Any], where: Where, dask_client: Any, tmp_path: Path
) -> None:
    kinds = fleet200["kinds"]
    victim = next(p for p, k in kinds.items() if k == "healthy" and "m03" in p)
    marker = tmp_path / "killed.pid"
    killer = functools.partial(kill_once, victim=victim, marker=str(marker))
    seen: list[int] = []

    summary = run_fleet(
        fleet200["root"],
        store=where.location,
        schema=where.schema,
        scheduler=dask_client,
        diagnose_fn=killer,
        progress=lambda items, total: _count(items, total, seen),
    )

    # The worker really died once, mid-run, and its recordings were diagnosed elsewhere.
    assert marker.exists(), "the victim's worker was never killed"
    killed_pid = int(marker.read_text())
    by_path = {o.recording: o for o in summary.outcomes}
    assert len(by_path) == 200 and len(summary.outcomes) == 200
    assert by_path[victim].status == "diagnosed"
    assert by_path[victim].worker is not None
    assert not by_path[victim].worker.endswith(f"pid {killed_pid}")
    assert sum(seen[:-1]) == 200 and seen[-1] == 200  # progress saw every recording

    # Right verdicts: the fleet says what diagnose() says for each recording alone;
    # failures are recorded with their reason and stop nothing.
    counts = Counter(o.status for o in summary.outcomes)
    assert counts == {"diagnosed": 190, "unreadable": 10}, counts
    for path, kind in kinds.items():
        o = by_path[path]
        assert o.machine == Path(path).parent.name
        if kind == "corrupt":
            assert (o.status, o.verdict_code) == ("unreadable", "cannot_diagnose")
            assert "FileFormatError" in o.error and path in o.error
        elif kind == "short":
            assert (o.status, o.verdict_code) == ("diagnosed", "cannot_diagnose")
            assert any("too short" in r for r in o.reasons), o.reasons
    sample = [*sorted(p for p, k in kinds.items() if k in ("healthy", "faulty"))[::25], victim]
    for path in sample:
        alone = diagnose(read_recording(path), machine=by_path[path].machine, recorded_at=day(0))
        o = by_path[path]
        assert (o.verdict_code, o.verdict, o.reasons) == (
            alone.verdict_code,
            alone.verdict,
            alone.reasons,
        ), path
    problems = {o.recording for o in summary.problems}
    assert problems >= {p for p, k in kinds.items() if k in ("short", "corrupt")}
    assert problems == {
        o.recording for o in summary.outcomes if o.verdict_code == "cannot_diagnose"
    }
    assert all(o.problem for o in summary.problems)
    troubled = summary.machine(f"m{N_HEALTHY + N_FAULTY:02d}")
    assert {p["recording"] for p in troubled.problems} >= {
        p for p, k in kinds.items() if k in ("short", "corrupt") and "/m30/" in p
    }

    # The store holds one diagnosis per recording, each verdict as reported.
    n_first = where.n_diagnoses()
    assert n_first == 200
    with where.open() as st:
        assert st.check() == []
        stored = {
            d.recording_path: d.verdict_code
            for m in {o.machine for o in summary.outcomes}
            for d in st.diagnoses(m)
        }
    assert stored == {o.recording: o.verdict_code for o in summary.outcomes}

    # Run again: nothing added; every readable recording is skipped before its
    # identification (diagnose_fn would kill its worker again if it were called
    # for the victim without the marker).
    marker.unlink()
    again = run_fleet(
        fleet200["root"],
        store=where.location,
        schema=where.schema,
        scheduler=dask_client,
        diagnose_fn=killer,
    )
    assert not marker.exists()
    assert Counter(o.status for o in again.outcomes) == {"skipped": 190, "unreadable": 10}
    assert where.n_diagnoses() == n_first
    first = {o.recording: (o.verdict_code, o.verdict) for o in summary.outcomes}
    assert {o.recording: (o.verdict_code, o.verdict) for o in again.outcomes} == first
    assert {m.name: m.state for m in again.machines} == {m.name: m.state for m in summary.machines}


def test_manifest_run_missing_duplicate_and_options(
    where: Where, dask_client: Any, tmp_path: Path
) -> None:
    good = write_sim(tmp_path / "data" / "good.npz", seed=1, recorded_at=day(0))
    short = write_sim(tmp_path / "data" / "short.npz", seed=2, n_samples=N_SHORT)
    bad = write_corrupt(tmp_path / "data" / "bad.npz", "garbage")
    os.utime(short, (1_767_600_000, 1_767_600_000))  # no time in it: the file's mtime is used
    manifest = tmp_path / "fleet.csv"
    manifest.write_text(
        "machine,recording,baseline,recorded_at\n"
        f"pump-1,data/good.npz,nominal,\n"
        f"pump-1,{good},,\n"  # the same file again, by absolute path
        "pump-1,data/short.npz,,\n"
        "pump-2,data/bad.npz,,2026-02-01T00:00:00Z\n"
        "pump-2,data/gone.npz,,\n"
    )
    summary = run_fleet(manifest, store=where.location, schema=where.schema, scheduler=dask_client)
    got = [(o.machine, Path(o.recording).name, o.status) for o in summary.outcomes]
    assert got == [
        ("pump-1", "good.npz", "diagnosed"),
        ("pump-1", "good.npz", "duplicate"),
        ("pump-1", "short.npz", "diagnosed"),
        ("pump-2", "bad.npz", "unreadable"),
        ("pump-2", "gone.npz", "missing"),
    ]
    short_o, bad_o, gone_o = summary.outcomes[2:]
    assert short_o.recorded_at == "2026-01-05T08:00:00+00:00"  # the file's mtime
    assert bad_o.recorded_at == "2026-02-01T00:00:00+00:00"  # the manifest's time
    assert gone_o.verdict_code is None and "FileNotFoundError" in gone_o.error
    with where.open() as st:
        recs = {
            (d.recording_path, d.method): d for m in ("pump-1", "pump-2") for d in st.diagnoses(m)
        }
        assert st.check() == []
    assert len(recs) == 3  # good, short and the unreadable file; nothing for the missing one
    unreadable = recs[(str(bad), "unreadable")]
    assert unreadable.verdict_code == "cannot_diagnose"
    assert unreadable.recording_hash.startswith("file-sha256:")
    pump2 = summary.machine("pump-2")
    assert pump2.state == "undiagnosed" and len(pump2.problems) == 2
    assert summary.to_dict()["counts"] == {
        "diagnosed": 2,
        "duplicate": 1,
        "unreadable": 1,
        "missing": 1,
    }


def test_history_chain_runs_in_recording_time_order(
    where: Where, dask_client: Any, tmp_path: Path
) -> None:
    log = tmp_path / "calls.log"
    paths = []
    for k in (3, 0, 4, 1, 2):  # written out of order: the chain follows recorded_at
        paths.append(write_sim(tmp_path / "pump" / f"r{k}.npz", seed=10 + k, recorded_at=day(k)))
    jobs = [
        FleetJob("pump", str(p), baseline="history", recorded_at=day(int(p.stem[1])))
        for p in paths
    ]
    jobs.append(FleetJob("other", str(paths[0]), baseline="nominal"))
    summary = run_fleet(
        jobs,
        store=where.location,
        schema=where.schema,
        scheduler=dask_client,
        batch_size=2,
        diagnose_fn=functools.partial(logged_diagnose, log=str(log)),
    )
    assert summary.run["n_chains"] == 1 and summary.run["n_tasks"] == 4
    calls = [line.split() for line in log.read_text().splitlines()]
    pump = [(c[1], float(c[2]), float(c[3])) for c in calls if c[0] == "pump"]
    assert [name for name, _, _ in pump] == ["r0.npz", "r1.npz", "r2.npz", "r3.npz", "r4.npz"]
    # Each recording of the chain starts after the one before it has finished (and written).
    assert all(nxt[1] >= prev[2] for prev, nxt in itertools.pairwise(pump))
    assert all(o.status == "diagnosed" for o in summary.outcomes)
