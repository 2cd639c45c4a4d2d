"""Jobs from folders, globs, files and manifests; the task graph. No cluster, no diagnosis."""

from __future__ import annotations

import json
import os
import pickle
from datetime import datetime, timezone
from pathlib import Path

import pytest

from maglevid.exceptions import DataError
from maglevid.fleet import FleetJob, ManifestError, collect_jobs, plan_batches, read_manifest
from maglevid.fleet.jobs import parse_tolerances
from maglevid.physics.amb import AMBParameters


def _touch(path: Path, text: str = "x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def layout(tmp_path: Path) -> Path:
    root = tmp_path / "recordings"
    _touch(root / "pump-7" / "2026-01" / "a.npz")
    _touch(root / "pump-7" / "b.npz")
    _touch(root / "fly-2" / "c.parquet")
    _touch(root / "fly-2" / "d.csv", "t,x\n0,1\n")
    _touch(root / "fly-2" / "d.json", "{}")  # a CSV's side-car, not a recording
    _touch(root / "fly-2" / ".hidden.npz")
    _touch(root / ".cache" / "e.npz")
    _touch(root / "loose.mat")
    _touch(root / "notes.txt")
    return root


def test_folder_machine_is_first_folder_below_it(layout: Path) -> None:
    jobs = collect_jobs(layout)
    got = sorted((j.machine, Path(j.recording).relative_to(layout).as_posix()) for j in jobs)
    assert got == [
        ("fly-2", "fly-2/c.parquet"),
        ("fly-2", "fly-2/d.csv"),
        ("pump-7", "pump-7/2026-01/a.npz"),  # date folders below the machine folder
        ("pump-7", "pump-7/b.npz"),
        ("recordings", "loose.mat"),  # directly in DIR: the machine named like DIR
    ]
    assert all(Path(j.recording).is_absolute() for j in jobs)
    assert all(j.baseline == "nominal" and j.method is None for j in jobs)


def test_one_machines_folder_and_machine_option(layout: Path) -> None:
    jobs = collect_jobs(layout / "pump-7")
    # b.npz lies in the folder itself (machine pump-7); a.npz in its sub-folder "2026-01".
    assert {j.machine for j in jobs if j.recording.endswith("b.npz")} == {"pump-7"}
    assert {j.machine for j in collect_jobs(layout, machine="B7")} == {"B7"}


def test_glob_and_file_machine_is_parent_folder(layout: Path) -> None:
    jobs = collect_jobs(str(layout / "*" / "*.npz"))
    assert [(j.machine, Path(j.recording).name) for j in jobs] == [("pump-7", "b.npz")]
    jobs = collect_jobs(str(layout / "**" / "*.npz"))  # recursive: a.npz's folder is 2026-01
    assert sorted((j.machine, Path(j.recording).name) for j in jobs) == [
        ("2026-01", "a.npz"),
        ("pump-7", "b.npz"),
    ]
    (job,) = collect_jobs(layout / "fly-2" / "c.parquet")
    assert job.machine == "fly-2"


def test_sources_that_name_nothing_are_errors(tmp_path: Path, layout: Path) -> None:
    with pytest.raises(DataError, match="no such folder"):
        collect_jobs(tmp_path / "nope")
    with pytest.raises(DataError, match="matches no recording"):
        collect_jobs(str(tmp_path / "*.npz"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="holds no recordings"):
        collect_jobs(tmp_path / "empty")
    with pytest.raises(DataError, match="neither a recording"):
        collect_jobs(layout / "notes.txt")
    with pytest.raises(DataError, match="no sources"):
        collect_jobs([])


def test_csv_manifest(tmp_path: Path) -> None:
    base = _touch(
        tmp_path / "design.json", json.dumps({"parameters": AMBParameters.nominal().to_dict()})
    )
    manifest = _touch(
        tmp_path / "fleet.csv",
        "machine,recording,baseline,method,tolerances,recorded_at,method_options\n"
        "pump-7,data/a.npz,,,,2026-01-05T09:00:00+01:00,\n"
        "pump-7,/abs/b.npz,history,physical,R1=0.1 Ls1=0.02,2026-01-06T08:00:00Z,"
        '"{""order"": 4}"\n'
        "\n"
        f"fly-2,c.npz,{base.name},,0.08,,\n",
    )
    jobs = read_manifest(manifest, tolerances=0.05)
    assert [j.machine for j in jobs] == ["pump-7", "pump-7", "fly-2"]
    a, b, c = jobs
    assert a.recording == str(tmp_path / "data" / "a.npz")  # relative to the manifest
    assert a.baseline == "nominal" and a.method is None and a.tolerances == 0.05
    assert a.recorded_at == datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)
    assert a.source == f"{manifest}:2"
    assert b.recording == "/abs/b.npz" and b.baseline == "history" and b.method == "physical"
    assert dict(b.tolerances) == {"R1": 0.1, "Ls1": 0.02}
    assert dict(b.method_options) == {"order": 4}
    assert c.baseline == AMBParameters.nominal() and c.tolerances == 0.08
    assert c.source.endswith(":5")  # the blank line is skipped, line numbers kept
    # A folder holding a CSV manifest does not take it for a recording.
    assert collect_jobs(manifest, tolerances=0.05) == jobs


def test_json_manifest_with_defaults(tmp_path: Path) -> None:
    manifest = _touch(
        tmp_path / "fleet.json",
        json.dumps(
            {
                "defaults": {"baseline": "history", "tolerances": {"R1": 0.1}},
                "recordings": [
                    {"machine": "m1", "recording": "r1.npz"},
                    {
                        "machine": "m2",
                        "recording": "r2.npz",
                        "baseline": "nominal",
                        "method_options": {"order": 2},
                    },
                ],
            }
        ),
    )
    m1, m2 = read_manifest(manifest)
    assert m1.baseline == "history" and dict(m1.tolerances) == {"R1": 0.1}
    assert m2.baseline == "nominal" and dict(m2.method_options) == {"order": 2}
    assert m1.source == f"{manifest}: recordings[0]"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("machine,file\npump,a.npz\n", "must name 'machine' and 'recording'"),
        ("machine,recording,colour\npump,a.npz,red\n", r"unknown column\(s\) \['colour'\]"),
        ("machine,recording\n,a.npz\n", r"fleet.csv:2: 'machine' and 'recording' are required"),
        ("machine,recording,recorded_at\np,a.npz,2026-01-05T08:00:00\n", "no time zone"),
        ("machine,recording,tolerances\np,a.npz,R1=-1\n", "finite fraction > 0"),
        ("machine,recording,tolerances\np,a.npz,R1\n", "NAME=FRACTION"),
        ("machine,recording,baseline\np,a.npz,lastweek.json\n", "no file"),
        ("machine,recording,method_options\np,a.npz,{oops\n", "not a JSON object"),
    ],
)
def test_manifest_errors_name_file_and_row(tmp_path: Path, text: str, match: str) -> None:
    manifest = _touch(tmp_path / "fleet.csv", text)
    with pytest.raises(ManifestError, match=match):
        read_manifest(manifest)


def test_json_manifest_errors(tmp_path: Path) -> None:
    bad = _touch(tmp_path / "a.json", "{not json")
    with pytest.raises(ManifestError, match="not valid JSON"):
        read_manifest(bad)
    bad = _touch(tmp_path / "b.json", json.dumps({"rows": []}))
    with pytest.raises(ManifestError, match="'recordings'"):
        read_manifest(bad)
    bad = _touch(tmp_path / "c.json", json.dumps({"recordings": [], "defaults": {"colour": 1}}))
    with pytest.raises(ManifestError, match="unknown defaults"):
        read_manifest(bad)
    bad = _touch(tmp_path / "d.json", json.dumps([["m", "r"]]))
    with pytest.raises(ManifestError, match=r"recordings\[0\] is not an object"):
        read_manifest(bad)


def test_tolerances_parsing() -> None:
    assert parse_tolerances(None) is None and parse_tolerances("  ") is None
    assert parse_tolerances("0.05") == 0.05
    assert dict(parse_tolerances("R1=0.1; Ls1=0.02,kw1=0.03")) == {
        "R1": 0.1,
        "Ls1": 0.02,
        "kw1": 0.03,
    }
    for bad in ("0", "nan", "-0.1", {"R1": "x"}):
        with pytest.raises(DataError):
            parse_tolerances(bad)


def test_jobs_pickle_with_plain_pickle() -> None:
    # Dask's first serializer is pickle: read-only mappings inside must survive it.
    job = FleetJob(
        "m",
        "/r.npz",
        baseline={"R1": 17.5},
        tolerances={"R1": 0.1},
        method_options={"order": 4},
        recorded_at="2026-01-05T08:00:00Z",
    )
    back = pickle.loads(pickle.dumps(job))
    assert back == job and dict(back.baseline) == {"R1": 17.5}
    assert job.to_dict()["recorded_at"] == "2026-01-05T08:00:00+00:00"


def test_plan_batches_independent_and_history_chains(tmp_path: Path) -> None:
    def job(machine: str, name: str, baseline: str, day: int | None = None) -> FleetJob:
        when = None if day is None else datetime(2026, 1, day, tzinfo=timezone.utc)
        return FleetJob(machine, str(tmp_path / name), baseline=baseline, recorded_at=when)

    jobs = [
        job("a", "a1", "nominal"),
        job("h", "h3", "history", 3),
        job("a", "a2", "nominal"),
        job("h", "h1", "history", 1),
        job("a", "a3", "nominal"),
        job("b", "b1", "nominal"),
        job("h", "h2", "history", 2),
        job("g", "g2", "history"),  # no time given: the file's modification time
        job("g", "g1", "history"),
    ]
    for name, mtime in (("g1", 1_000_000), ("g2", 2_000_000)):
        _touch(tmp_path / name)
        os.utime(tmp_path / name, (mtime, mtime))
    independent, chains = plan_batches(jobs, batch_size=2)
    assert [b.jobs for b in independent] == [(0, 2), (4,), (5,)]  # one machine per batch
    assert all(b.chain is None for b in independent)
    assert [b.jobs for b in chains["h"]] == [(3, 6), (1,)]  # recording-time order
    assert [b.position for b in chains["h"]] == [0, 1]
    assert [b.jobs for b in chains["g"]] == [(8, 7)]
    with pytest.raises(DataError, match="batch_size"):
        plan_batches(jobs, batch_size=0)
