"""The history store under stress: concurrent processes, a writer killed mid-transaction,
lock timeouts, and schema migrations (old, newer, failing). SQLite always; PostgreSQL
when ``MAGLEVID_TEST_POSTGRES_URL`` is set.

Nothing here asserts a duration: waits have generous limits only so that a hung
test fails instead of blocking the suite.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
import traceback
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

import maglevid
from maglevid.diagnose import _sql
from maglevid.diagnose._migrations import MIGRATIONS, SCHEMA_VERSION, Migration
from maglevid.diagnose.history import (
    HistoryError,
    SchemaVersionError,
    StoreBusyError,
    open_history,
)

PG_URL = os.environ.get("MAGLEVID_TEST_POSTGRES_URL")
BACKENDS = [
    pytest.param("sqlite", id="sqlite"),
    pytest.param(
        "postgresql",
        id="postgresql",
        marks=[
            pytest.mark.postgres,
            pytest.mark.skipif(
                not PG_URL,
                reason="MAGLEVID_TEST_POSTGRES_URL is not set: no PostgreSQL server to test "
                "against (source .ci/postgres.sh to start one)",
            ),
        ],
    ),
]
T0 = datetime(2026, 1, 5, tzinfo=timezone.utc)


@pytest.fixture(params=BACKENDS)
def where(request, tmp_path):
    """``(location, open_history keywords)`` of a fresh, not yet created store."""
    if request.param == "sqlite":
        yield str(tmp_path / "history.sqlite"), {}
        return
    import psycopg

    schema = f"test_{uuid.uuid4().hex[:16]}"
    yield PG_URL, {"schema": schema}
    with psycopg.connect(PG_URL, autocommit=True) as conn:
        conn.execute(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')


def _estimates(base: float, n: int) -> dict[str, tuple[float, float]]:
    return {f"p{k}": (base + k / 1000.0, 0.1) for k in range(n)}


# -- (a) concurrent writers ------------------------------------------------------------

N_PROC, N_EACH, N_PARAMS = 4, 50, 8
N_SHARED = N_EACH // 5  # every process also writes the same 10 diagnoses


def _writer(location, kwargs, worker, barrier, queue):
    """Child process: N_EACH own diagnoses interleaved with N_SHARED common ones."""
    try:
        barrier.wait(timeout=60)  # all open (and create) the store at once
        own, shared = [], []
        with open_history(location, **kwargs) as store:
            for i in range(N_EACH):
                r = store.record_diagnosis(
                    f"rig-{worker % 2}",
                    recording_hash=f"w{worker}-{i}",
                    recorded_at=T0 + timedelta(hours=worker, minutes=i),
                    method="deadbeat-arx",
                    verdict="healthy",
                    verdict_code="no_change",
                    estimates=_estimates(1000.0 * worker + i, N_PARAMS),
                )
                own.append((i, r.id, r.created))
                if i % 5 == 0:
                    j = i // 5
                    r = store.record_diagnosis(
                        "shared-rig",
                        recording_hash=f"s{j}",
                        recorded_at=T0 + timedelta(days=j),
                        method="deadbeat-arx",
                        verdict="healthy",
                        verdict_code="no_change",
                        estimates=_estimates(-float(j), N_PARAMS),
                    )
                    shared.append((j, r.id, r.created))
        queue.put((worker, own, shared, None))
    except BaseException:
        queue.put((worker, None, None, traceback.format_exc()))


def test_concurrent_writer_processes_lose_nothing(where):
    location, kwargs = where
    ctx = multiprocessing.get_context("fork")
    barrier = ctx.Barrier(N_PROC)
    queue = ctx.Queue()
    procs = [
        ctx.Process(target=_writer, args=(location, kwargs, w, barrier, queue))
        for w in range(N_PROC)
    ]
    for p in procs:
        p.start()
    try:
        results = [queue.get(timeout=240) for _ in procs]
    finally:
        for p in procs:
            p.join(timeout=60)
            if p.is_alive():
                p.kill()
    errors = [r[3] for r in results if r[3]]
    assert not errors, errors[0]
    assert all(p.exitcode == 0 for p in procs)

    own_ids = [i for r in results for (_, i, created) in r[1] if created]
    assert len(own_ids) == N_PROC * N_EACH == len(set(own_ids))
    # The common diagnoses: one process created each, every process got its id.
    for j in range(N_SHARED):
        got = [(i, c) for r in results for (jj, i, c) in r[2] if jj == j]
        assert len({i for i, _ in got}) == 1
        assert sum(c for _, c in got) == 1

    with open_history(location, **kwargs) as store:
        assert store.check() == []
        assert {m.name: m.n_diagnoses for m in store.machines()} == {
            "rig-0": 2 * N_EACH,
            "rig-1": 2 * N_EACH,
            "shared-rig": N_SHARED,
        }
        for machine in ("rig-0", "rig-1"):
            for d in store.diagnoses(machine):
                worker, i = map(int, d.recording_hash[1:].split("-"))
                got = {k: (e.value, e.std_error) for k, e in d.estimates.items()}
                assert got == _estimates(1000.0 * worker + i, N_PARAMS)  # exact doubles
                assert d.recorded_at == T0 + timedelta(hours=worker, minutes=i)
        assert sorted(d.id for m in ("rig-0", "rig-1") for d in store.diagnoses(m)) == sorted(
            own_ids
        )


# -- (b) a writer killed inside its transaction -----------------------------------------

_KILLED_CHILD = textwrap.dedent(
    """
    import os, sys, time
    from datetime import datetime, timedelta, timezone
    from maglevid.diagnose import _sql
    from maglevid.diagnose.history import open_history

    location, schema, flag = sys.argv[1], sys.argv[2], sys.argv[3]
    n_committed, n_big = int(sys.argv[4]), int(sys.argv[5])
    t0 = datetime(2026, 1, 5, tzinfo=timezone.utc)
    store = open_history(location, **({"schema": schema} if schema else {}))

    def put(i, n, tag):
        return store.record_diagnosis(
            "rig", recording_hash=f"{tag}-{i}", recorded_at=t0 + timedelta(days=i),
            method="deadbeat-arx", verdict="healthy", verdict_code="no_change",
            estimates={f"p{k}": (i + k / 1e4, 0.1) for k in range(n)},
        )

    for i in range(n_committed):
        put(i, 8, "ok")
    if store.dialect == "sqlite":
        conn = store._backend.conn
        # Empty the WAL, then shrink the page cache: the open transaction's dirty
        # pages must spill into the WAL before it commits (the hard case).
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        conn.execute("PRAGMA cache_size = 10")

    original = _sql.Tx.executemany

    def half_then_stall(self, sql, rows):
        rows = list(rows)
        original(self, sql, rows[: len(rows) // 2])
        wal = location + "-wal"
        size = os.path.getsize(wal) if store.dialect == "sqlite" else -1
        with open(flag + ".tmp", "w") as f:
            f.write(str(size))
        os.replace(flag + ".tmp", flag)  # the parent sees the whole flag or none
        time.sleep(600)  # killed here, inside the transaction

    _sql.Tx.executemany = half_then_stall
    put(n_committed, n_big, "big")
    """
)


def test_writer_killed_mid_transaction_loses_nothing_committed(where, tmp_path):
    location, kwargs = where
    n_committed, n_big = 5, 5000
    script = tmp_path / "child.py"
    script.write_text(_KILLED_CHILD)
    flag = tmp_path / "mid-transaction"
    env = dict(os.environ)
    src = str(Path(maglevid.__file__).resolve().parents[1])
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    child = subprocess.Popen(
        [
            sys.executable,
            str(script),
            location,
            kwargs.get("schema", ""),
            str(flag),
            str(n_committed),
            str(n_big),
        ],
        env=env,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 120
        while not flag.exists():
            if child.poll() is not None:
                pytest.fail(f"child ended before the kill: {child.stderr.read().decode()}")
            if time.monotonic() > deadline:
                pytest.fail("child never reached the middle of its transaction")
            time.sleep(0.05)
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stderr.close()
    assert child.returncode == -signal.SIGKILL
    if location.endswith(".sqlite"):
        # Uncommitted pages of the killed transaction were on disk (in the WAL).
        assert int(flag.read_text()) > 0
        assert Path(location + "-wal").exists()

    with open_history(location, **kwargs) as store:
        assert store.check() == []  # SQLite: integrity_check and foreign keys too
        ds = store.diagnoses("rig")
        assert [d.recording_hash for d in ds] == [f"ok-{i}" for i in range(n_committed)]
        assert all(len(d.estimates) == 8 for d in ds)
        assert store.parameters("rig") == [f"p{k}" for k in range(8)]  # no p8...p4999
        # The killed write can be done again, in full.
        r = store.record_diagnosis(
            "rig",
            recording_hash=f"big-{n_committed}",
            recorded_at=T0 + timedelta(days=n_committed),
            method="deadbeat-arx",
            verdict="healthy",
            verdict_code="no_change",
            estimates={f"p{k}": (float(k), 0.1) for k in range(n_big)},
        )
        assert r.created
        assert len(store.diagnosis(r.id).estimates) == n_big
        assert store.check() == []
    if location.endswith(".sqlite"):
        with sqlite3.connect(location) as conn:
            assert conn.execute("PRAGMA integrity_check").fetchall() == [("ok",)]


# -- lock contention: wait, retry, or fail clearly ---------------------------------------


def _hold_write_lock(location, kwargs, held, release):
    """Hold the store's writer lock (SQLite) or an exclusive table lock (PostgreSQL)."""
    if not kwargs:
        conn = sqlite3.connect(location, isolation_level=None)
        conn.execute("BEGIN IMMEDIATE")
        commit = conn.execute
    else:
        import psycopg

        conn = psycopg.connect(PG_URL, autocommit=True)
        conn.execute("BEGIN")
        conn.execute(f'LOCK TABLE "{kwargs["schema"]}".machines IN ACCESS EXCLUSIVE MODE')
        commit = conn.execute
    held.set()
    release.wait(timeout=60)
    commit("COMMIT")
    conn.close()


def _one(store, i):
    return store.record_diagnosis(
        "rig",
        recording_hash=f"r{i}",
        recorded_at=T0,
        method="m",
        verdict="healthy",
        verdict_code="no_change",
        estimates={"R1": 2.0},
    )


def test_locked_store_times_out_clearly_then_recovers(where):
    location, kwargs = where
    open_history(location, **kwargs).close()  # create the schema
    held, release = threading.Event(), threading.Event()
    holder = threading.Thread(target=_hold_write_lock, args=(location, kwargs, held, release))
    holder.start()
    try:
        assert held.wait(timeout=60)
        with open_history(location, timeout=0.5, **kwargs) as store:
            with pytest.raises(StoreBusyError, match="locked"):
                _one(store, 0)
    finally:
        release.set()
        holder.join(timeout=60)
    with open_history(location, **kwargs) as store:
        assert store.machines() == []  # the timed-out write left nothing
        assert _one(store, 0).created


def test_writer_waits_for_a_lock_released_later(where):
    location, kwargs = where
    open_history(location, **kwargs).close()
    held, release = threading.Event(), threading.Event()
    holder = threading.Thread(target=_hold_write_lock, args=(location, kwargs, held, release))
    holder.start()
    try:
        assert held.wait(timeout=60)
        threading.Timer(0.3, release.set).start()
        with open_history(location, timeout=60, **kwargs) as store:
            assert _one(store, 0).created  # blocked, then went through
    finally:
        release.set()
        holder.join(timeout=60)


# -- migrations ---------------------------------------------------------------------------


def _connect(location, kwargs):
    return _sql.connect(location, timeout=10, create=True, schema=kwargs.get("schema"))


def test_old_store_is_migrated_with_its_data(where):
    location, kwargs = where
    backend = _connect(location, kwargs)
    assert _sql.migrate(backend, MIGRATIONS[:1]) == (0, 1)

    def v1_rows(tx):  # what maglevid with schema version 1 wrote
        now = tx.ts_in(T0)
        tx.execute(
            "INSERT INTO machines (name, created_at, metadata) VALUES (?, ?, ?)",
            ("old-rig", now, "{}"),
        )
        mid = tx.one("SELECT id FROM machines")
        tx.execute(
            "INSERT INTO recordings (machine_id, content_hash, recorded_at) VALUES (?, ?, ?)",
            (mid, "h0", now),
        )
        rid = tx.one("SELECT id FROM recordings")
        tx.execute(
            "INSERT INTO diagnoses (machine_id, recording_id, method, options_hash, options, "
            "created_at, verdict, verdict_code, summary, n_estimates) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (mid, rid, "deadbeat-arx", "o", "{}", now, "healthy", "no_change", "{}", 1),
        )
        did = tx.one("SELECT id FROM diagnoses")
        tx.execute(
            "INSERT INTO estimates (diagnosis_id, parameter, value, std_error) "
            "VALUES (?, ?, ?, ?)",
            (did, "R1", 2.0, 0.01),
        )

    backend.run(v1_rows, write=True)
    backend.close()

    with open_history(location, **kwargs) as store:
        assert store.schema_version == SCHEMA_VERSION == 2
        [old] = store.diagnoses("old-rig")
        assert old.estimates["R1"].value == 2.0 and old.software_version is None
        r = store.record_diagnosis(
            "old-rig",
            recording_hash="h1",
            recorded_at=T0 + timedelta(days=1),
            method="deadbeat-arx",
            verdict="healthy",
            verdict_code="no_change",
            estimates={"R1": (2.1, 0.01)},
        )
        assert store.diagnosis(r.id).software_version.startswith("maglevid")
        assert list(store.trend("old-rig", "R1").value) == [2.0, 2.1]
        assert store.check() == []
    backend = _connect(location, kwargs)
    rows = backend.run(
        lambda tx: tx.all("SELECT version FROM schema_migrations ORDER BY version"), write=False
    )
    backend.close()
    assert rows == [(1,), (2,)]


def test_newer_store_is_refused(where):
    location, kwargs = where
    open_history(location, **kwargs).close()
    backend = _connect(location, kwargs)
    backend.run(
        lambda tx: tx.execute(
            "INSERT INTO schema_migrations (version, description, applied_at) VALUES (?, ?, ?)",
            (SCHEMA_VERSION + 7, "from the future", tx.ts_in(T0)),
        ),
        write=True,
    )
    backend.close()
    with pytest.raises(SchemaVersionError, match=r"schema version 9, newer .* upgrade maglevid"):
        open_history(location, **kwargs)


def test_failed_migration_leaves_the_store_as_it_was(where):
    location, kwargs = where
    with open_history(location, **kwargs) as store:
        _one(store, 0)
    bad = Migration(
        SCHEMA_VERSION + 1,
        "half good, half broken",
        (
            "CREATE TABLE extra (x INTEGER)",
            "ALTER TABLE diagnoses ADD COLUMN extra_note TEXT",
            "ALTER TABLE no_such_table ADD COLUMN y TEXT",
        ),
    )
    backend = _connect(location, kwargs)
    with pytest.raises(HistoryError, match="no_such_table"):
        _sql.migrate(backend, (*MIGRATIONS, bad))
    tables = backend.run(backend.user_tables, write=False)
    backend.close()
    assert "extra" not in tables
    with open_history(location, **kwargs) as store:  # still version 2, still readable
        assert store.schema_version == SCHEMA_VERSION
        assert len(store.diagnoses("rig")) == 1
        assert store.check() == []


def test_migration_list_must_be_gapless(tmp_path):
    backend = _sql.connect(tmp_path / "x.sqlite", timeout=5, create=True, schema=None)
    try:
        with pytest.raises(ValueError, match="without gaps"):
            _sql.migrate(backend, (MIGRATIONS[1],))
    finally:
        backend.close()
