"""``maglevid fleet`` on the session's Dask cluster (--scheduler), reports, a poison recording."""

from __future__ import annotations

import functools
import json
import re
from pathlib import Path
from typing import Any

import pytest
from _fleet_helpers import (
    N_SHORT,
    Where,
    always_kill,
    day,
    fake_fault,
    write_corrupt,
    write_sim,
)

from maglevid.cli.main import main
from maglevid.fleet import run_fleet

pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def small_fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("small") / "recordings"
    for m, machine in enumerate(("fan-1", "pump-2")):
        for k in range(2):
            write_sim(root / machine / f"r{k}.npz", seed=10 * m + k, recorded_at=day(k))
    write_sim(root / "fan-1" / "short.npz", seed=99, n_samples=N_SHORT, recorded_at=day(2))
    write_corrupt(root / "pump-2" / "broken.npz", "garbage")
    return root


def test_cli_json_text_summary_page_and_exit_code(
    small_fleet: Path, where: Where, dask_client: Any, tmp_path: Path, capsys: Any
) -> None:
    address = dask_client.scheduler.address
    page = tmp_path / "out" / "fleet.html"
    page.parent.mkdir()
    common = [str(small_fleet), *where.cli_args(), "--scheduler", address]
    rc = main(["fleet", *common, "--json", "--summary", str(page)])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert out["format"] == "maglevid-fleet-summary"
    assert out["counts"] == {"diagnosed": 5, "unreadable": 1}
    assert out["run"]["local_cluster"] is False and out["run"]["scheduler"] == address
    assert {m["name"] for m in out["machines"]} == {"fan-1", "pump-2"}
    assert out["summary_page"] == str(page)
    html = page.read_text(encoding="utf-8")
    data = re.search(r'<script type="application/json" id="fleet-data">(.*?)</script>', html, re.S)
    assert json.loads(data.group(1))["counts"] == out["counts"]
    assert "broken.npz" in html and "FileFormatError" in html

    # Again, as text: the table, the problems, nothing new in the store.
    n_before = where.n_diagnoses()
    rc = main(["fleet", *common, "-q"])
    text = capsys.readouterr().out
    assert rc == 0
    assert text.startswith("fleet: 6 recordings of 2 machines: 5 skipped, 1 unreadable")
    assert re.search(r"^machine\s+recs\s+state\s+latest verdict$", text, re.M)
    assert "could not be diagnosed" in text and "broken.npz" in text and "short.npz" in text
    assert where.n_diagnoses() == n_before

    # A fault stored for a later recording makes the machine "changed": exit 3 on request.
    with where.open() as st:
        st.record_diagnosis(
            "pump-2",
            recording_hash="later",
            recorded_at=day(30),
            method="physical",
            verdict="Fault: amplifier 1 gain kw1 -40 %",
            verdict_code="fault",
            estimates={},
        )
    rc = main(["fleet", *common, "-q", "--fail-on-change"])
    text = capsys.readouterr().out
    assert rc == 3
    assert "changed (1):\n  pump-2: Fault: amplifier 1 gain kw1 -40 %" in text


def test_cli_errors_are_one_line(tmp_path: Path, capsys: Any) -> None:
    rc = main(["fleet", str(tmp_path / "nothing-here"), "--store", str(tmp_path / "s.sqlite")])
    err = capsys.readouterr().err
    assert rc == 1
    assert err.startswith("maglevid fleet: error: ") and "no such folder" in err
    assert len(err.strip().splitlines()) == 1


def test_report_for_the_latest_recording_of_a_faulty_machine(
    small_fleet: Path, dask_client: Any, tmp_path: Path
) -> None:
    # Engine logic, not storage: SQLite only (a report costs seconds of plotting).
    reports = tmp_path / "reports"
    summary = run_fleet(
        small_fleet,
        store=tmp_path / "fleet.sqlite",
        scheduler=dask_client,
        reports=reports,
        diagnose_fn=functools.partial(fake_fault, faulty_machines=("fan-1",)),
    )
    assert [p.name for p in reports.iterdir()] == ["fan-1.html"]  # pump-2 is not faulty
    with_report = {Path(o.recording).name: o.report for o in summary.outcomes if o.report}
    # The latest by recording time (day 2), though the files' order says otherwise.
    assert with_report == {"short.npz": str(reports / "fan-1.html")}
    assert summary.machine("fan-1").report == str(reports / "fan-1.html")
    assert summary.machine("pump-2").report is None
    html = (reports / "fan-1.html").read_text(encoding="utf-8")
    assert 'data-verdict-code="fault"' in html and "fan-1" in html


@pytest.mark.slow
def test_a_recording_that_kills_every_worker_is_lost_alone(
    small_fleet: Path, dask_client: Any, tmp_path: Path
) -> None:
    # The batch holding the poison recording dies (twice: allowed-failures = 1 in the
    # session cluster), is split into single recordings, and only the poison one is lost.
    # Engine logic, not storage: SQLite only (each worker death costs a restart).
    victim = str(small_fleet / "fan-1" / "r1.npz")
    where = Where(str(tmp_path / "fleet.sqlite"), None)
    summary = run_fleet(
        small_fleet,
        store=where.location,
        schema=where.schema,
        scheduler=dask_client,
        batch_size=8,
        diagnose_fn=functools.partial(always_kill, victim=victim),
    )
    status = {o.recording: o.status for o in summary.outcomes}
    assert status.pop(victim) == "lost"
    assert set(status.values()) == {"diagnosed", "unreadable"}
    lost = next(o for o in summary.outcomes if o.status == "lost")
    assert "KilledWorker" in lost.error
    assert where.n_diagnoses() == 5  # all but the lost one; it is retried by the next run
