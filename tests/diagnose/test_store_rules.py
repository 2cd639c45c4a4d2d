"""The history store's rules (issue 17), each case failing on main e62a9f8.

* A store maglevid refuses (another application's SQLite file, foreign tables,
  a newer schema) is opened read-only and left byte-identical: no switch to
  WAL, no header change, no -wal/-shm files. Checked by hashing the file
  before and after, for the library, ``history`` and ``diagnose --store``.
* Storing the same diagnosis twice is idempotent, whatever ``recorded_at``
  the second call says: "already stored", no failure.
"""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

import pytest

from maglevid.cli.main import main
from maglevid.diagnose._sql import SchemaVersionError
from maglevid.diagnose.history import open_history
from maglevid.io import write_recording
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import simulate_amb_loop


def _foreign_tables(path: Path) -> None:
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE invoices (id INTEGER PRIMARY KEY, amount REAL)")
        conn.execute("INSERT INTO invoices (amount) VALUES (12.5)")
    conn.close()


def _other_application(path: Path) -> None:
    with sqlite3.connect(path) as conn:
        conn.execute("PRAGMA application_id = 1234")
        conn.execute("CREATE TABLE t (x)")
    conn.close()


def _newer_schema(path: Path) -> None:
    open_history(path).close()  # a maglevid store at today's version ...
    with sqlite3.connect(path) as conn:  # ... that a later maglevid moved to version 9
        conn.execute("PRAGMA journal_mode = DELETE")
        conn.execute(
            "INSERT INTO schema_migrations (version, description, applied_at) "
            "VALUES (9, 'from the future', '2030-01-01T00:00:00+00:00')"
        )
    conn.close()


def _not_sqlite(path: Path) -> None:
    path.write_bytes(b"machine,R1\nM,17.5\n" * 20)


REFUSED = {
    "foreign-tables": _foreign_tables,
    "other-application": _other_application,
    "newer-schema": _newer_schema,
    "not-sqlite": _not_sqlite,
}


def _snapshot(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("kind", sorted(REFUSED))
def test_refused_store_is_left_byte_identical(tmp_path, kind):
    store = tmp_path / "store.sqlite"
    REFUSED[kind](store)
    before = _snapshot(tmp_path)
    assert list(before) == ["store.sqlite"]
    with pytest.raises(SchemaVersionError, match="left unchanged"):
        open_history(store)
    with pytest.raises(SchemaVersionError):
        open_history(store, create=False)
    assert _snapshot(tmp_path) == before  # same bytes, and no -wal / -shm beside it


def test_a_fifo_store_is_refused_without_blocking(no_hang, tmp_path):
    import os

    from maglevid.diagnose._sql import HistoryError

    os.mkfifo(tmp_path / "s.sqlite")
    with pytest.raises(HistoryError, match="special file"):
        open_history(tmp_path / "s.sqlite")


@pytest.mark.parametrize("kind", sorted(REFUSED))
def test_history_command_leaves_a_refused_store_byte_identical(tmp_path, capsys, kind):
    store = tmp_path / "store.sqlite"
    REFUSED[kind](store)
    before = _snapshot(tmp_path)
    assert main(["history", "--store", str(store), "--list"]) == 1
    assert main(["history", "M", "--store", str(store)]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("error:") == 2
    assert _snapshot(tmp_path) == before


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rec")
    data = simulate_amb_loop(AMBParameters.nominal(), n_samples=2000, rng=5)
    return write_recording(data, folder / "rec.npz")


def test_diagnose_into_a_refused_store_leaves_it_byte_identical(tmp_path, capsys, recording):
    store = tmp_path / "store.sqlite"
    _foreign_tables(store)
    before = _snapshot(tmp_path)
    argv = ["-q", "diagnose", str(recording), "--store", str(store), "--machine", "M"]
    assert main(argv) == 1
    assert "not a maglevid history store" in capsys.readouterr().err
    assert _snapshot(tmp_path) == before


def test_storing_the_same_diagnosis_twice_is_idempotent(tmp_path, capsys, recording):
    store = tmp_path / "s.sqlite"
    argv = ["-q", "diagnose", str(recording), "--store", str(store), "--machine", "M"]
    assert main(argv) == 0
    assert "already stored" not in capsys.readouterr().out
    # The second run dates the recording "now" again (it has no recorded_at):
    # a different time for the same content, which failed on main.
    assert main(argv) == 0
    assert "already stored" in capsys.readouterr().out
    with open_history(store) as h:
        assert len(h.diagnoses("M")) == 1


def test_diagnose_after_fleet_stored_it_is_idempotent(tmp_path, capsys, recording):
    pytest.importorskip("distributed")
    import shutil

    folder = tmp_path / "fleet" / "M"
    folder.mkdir(parents=True)
    rec = Path(shutil.copy(recording, folder / "rec.npz"))
    store = tmp_path / "s.sqlite"
    glob = str(tmp_path / "fleet" / "*" / "*.npz")
    assert main(["-q", "fleet", glob, "--store", str(store), "--workers", "1"]) == 0
    capsys.readouterr()
    # fleet dated the file by its mtime, diagnose dates it "now": same content.
    assert main(["-q", "diagnose", str(rec), "--store", str(store), "--machine", "M"]) == 0
    assert "already stored" in capsys.readouterr().out
    with open_history(store) as h:
        assert len(h.diagnoses("M")) == 1


def test_an_overflow_in_the_fault_isolation_is_a_note(tmp_path, recording, monkeypatch):
    # Issue 17: pure noise gave an OverflowError traceback from diagnose/isolate.py
    # (math.exp of a runaway log-factor). The gate now refuses pure noise; any
    # overflow left in the isolation is a note at the pipeline's boundary.
    import maglevid.diagnose.pipeline as pipeline
    import maglevid.plants.amb

    def overflow(*args, **kwargs):
        raise OverflowError("math range error")

    # The isolation stage of a two-coil AMB lives in its plant-kind module (issue 19).
    monkeypatch.setattr(maglevid.plants.amb, "isolate_fault", overflow)
    diag = pipeline.diagnose(recording)
    assert any("fault isolation not possible: math range error" in n for n in diag.notes)


def test_fleet_never_blocks_on_a_fifo(no_hang, tmp_path):
    # Issue 17: a FIFO among a fleet's recordings hung the run (the reader, then
    # the hash of the unreadable file, opened it). Now it is one outcome, with
    # the reason, and the run goes on.
    import os

    from maglevid.fleet.jobs import collect_jobs
    from maglevid.fleet.worker import BatchContext, diagnose_batch

    folder = tmp_path / "M"
    folder.mkdir()
    os.mkfifo(folder / "x.npz")
    jobs = collect_jobs([str(tmp_path)])
    ctx = BatchContext(store=str(tmp_path / "s.sqlite"), schema=None, run_id="r")
    _, outcomes = diagnose_batch(jobs, ctx)
    assert len(outcomes) == 1 and "FIFO" in outcomes[0].error
