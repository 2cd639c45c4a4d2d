"""The history store's API, one suite run against SQLite and (when a server is given) PostgreSQL.

PostgreSQL runs when ``MAGLEVID_TEST_POSTGRES_URL`` names a database the tests
may create schemas in (``.ci/postgres.sh`` starts a throwaway one); each test
gets its own schema, dropped afterwards. Otherwise those cases skip with the
reason.
"""

from __future__ import annotations

import json
import os
import uuid
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from maglevid.diagnose import _sql
from maglevid.diagnose.history import (
    SCHEMA_VERSION,
    DiagnosisRecord,
    Estimate,
    HistoryError,
    NotFoundError,
    SchemaVersionError,
    default_store_location,
    hash_file,
    hash_options,
    open_history,
)
from maglevid.exceptions import DataError

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

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)


class Where:
    """How to open the store under test: a location and the keywords it needs."""

    def __init__(self, location, **kwargs):
        self.location = location
        self.kwargs = kwargs

    def open(self, **kw):
        return open_history(self.location, **self.kwargs, **kw)


def drop_pg_schema(schema: str) -> None:
    import psycopg

    with psycopg.connect(PG_URL, autocommit=True) as conn:
        conn.execute(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')


@pytest.fixture(params=BACKENDS)
def where(request, tmp_path):
    if request.param == "sqlite":
        yield Where(tmp_path / "history.sqlite")
        return
    schema = f"test_{uuid.uuid4().hex[:16]}"
    yield Where(PG_URL, schema=schema)
    drop_pg_schema(schema)


@pytest.fixture
def store(where):
    with where.open() as s:
        yield s


def record(store, i=0, *, machine="pump-7", method="deadbeat-arx", **kw):
    """A diagnosis of recording ``i`` (one day apart) with two parameters."""
    args = {
        "recording_hash": f"sha-{i}",
        "recorded_at": T0 + timedelta(days=i),
        "method": method,
        "verdict": "healthy",
        "verdict_code": "no_change",
        "estimates": {
            "R1": Estimate(2.0 + 0.01 * i, 0.02, 1.96 + 0.01 * i, 2.04 + 0.01 * i, "ohm", 2.0),
            "Ls1": (0.031, 0.0004, None, None, "H"),
        },
    }
    args.update(kw)
    return store.record_diagnosis(machine, **args)


# -- round trip -----------------------------------------------------------------------


def test_round_trip_of_every_field(store):
    summary = {
        "max_deviation": np.float64(3.5),
        "flags": np.array([1, 2]),
        "nan": float("nan"),
        "pole": np.complex128(0.9 + 0.1j),
        "limit": -np.inf,
    }
    rec = store.record_diagnosis(
        "pump-7",
        recording_hash="abc",
        recorded_at="2026-01-05T09:00:00+01:00",
        method="deadbeat-arx",
        verdict="degraded",
        verdict_code="fault",
        estimates={
            "R1": {"value": 2.5, "std_error": 0.1, "unit": "ohm", "baseline": 2.0},
            "ki1": 17.0,
            "Ls1": (0.031, float("nan")),
        },
        summary=summary,
        options={"order": 4, "rho": 1e-3},
        recording_path="rec/2026-01-05.npz",
        dt=2e-4,
        n_samples=5000,
        report_path="out/report.html",
        machine_metadata={"site": "hall 3"},
    )
    assert rec.created and rec.id > 0
    d = store.diagnosis(rec.id)
    assert isinstance(d, DiagnosisRecord)
    assert d.machine == "pump-7" and d.recording_hash == "abc"
    assert d.recorded_at == T0  # 09:00+01:00 is 08:00 UTC, returned aware in UTC
    assert d.recorded_at.tzinfo is not None
    assert (d.method, d.verdict, d.verdict_code) == ("deadbeat-arx", "degraded", "fault")
    assert dict(d.options) == {"order": 4, "rho": 1e-3}
    assert d.options_hash == hash_options({"rho": 1e-3, "order": 4})
    assert dict(d.summary) == {
        "max_deviation": 3.5,
        "flags": [1, 2],
        "nan": None,
        "pole": {"re": 0.9, "im": 0.1},
        "limit": "-inf",
    }
    assert (d.recording_path, d.dt, d.n_samples) == ("rec/2026-01-05.npz", 2e-4, 5000)
    assert d.report_path == "out/report.html"
    assert list(d.estimates) == ["R1", "ki1", "Ls1"]  # the caller's order
    assert d.estimates["R1"] == Estimate(2.5, 0.1, None, None, "ohm", 2.0)
    assert d.estimates["ki1"] == Estimate(17.0)
    assert d.estimates["Ls1"].std_error is None  # NaN means unknown: stored as NULL
    assert d.software_version.startswith("maglevid ")
    assert "pid" in d.written_by
    assert abs(d.created_at - datetime.now(timezone.utc)) < timedelta(minutes=5)
    [m] = store.machines()
    assert m.name == "pump-7" and dict(m.metadata) == {"site": "hall 3"}
    assert m.n_diagnoses == 1 and m.first_recorded_at == m.last_recorded_at == T0
    json.dumps(d.to_dict(), allow_nan=False)
    assert store.diagnoses("pump-7")[0].to_dict() == d.to_dict()
    assert store.check() == []
    assert store.schema_version == SCHEMA_VERSION


def test_persists_across_reopening(where):
    with where.open() as s:
        rec = record(s, 3)
    with where.open(create=False) as s:
        assert s.diagnosis(rec.id).estimates["R1"].value == pytest.approx(2.03, rel=1e-15)
        assert s.check() == []


# -- idempotency ----------------------------------------------------------------------


def test_same_diagnosis_twice_adds_nothing(store):
    first = record(store, 1, options={"order": 4, "rho": 0.1})
    table_before = store.estimates_table("pump-7")
    again = record(store, 1, options={"rho": 0.1, "order": 4}, verdict="changed")  # key order
    assert again == (first.id, False)
    assert len(store.diagnoses("pump-7")) == 1
    assert store.diagnosis(first.id).verdict == "healthy"  # the stored one is kept
    after = store.estimates_table("pump-7")
    for k in table_before:
        np.testing.assert_array_equal(after[k], table_before[k])


def test_other_method_or_options_is_a_new_diagnosis_of_the_same_recording(store):
    a = record(store, 1)
    b = record(store, 1, method="subspace")
    c = record(store, 1, options={"order": 6})
    d = record(store, 1, options_hash="caller-hash")
    assert len({a.id, b.id, c.id, d.id}) == 4 and all(r.created for r in (a, b, c, d))
    ds = store.diagnoses("pump-7")
    assert len(ds) == 4
    assert {x.recording_hash for x in ds} == {"sha-1"}  # one recording, four diagnoses
    assert [x.id for x in store.diagnoses("pump-7", method="subspace")] == [b.id]


def test_same_recording_at_another_time_is_the_same_recording(store):
    # Issue 17: the content hash is the recording's identity. The same bytes stored
    # again with another time (a second `diagnose --store` dated "now", or after
    # `fleet` dated the file by its mtime) must not fail: the first time is kept and
    # the same diagnosis is "already stored" (this was a HistoryError before).
    a = record(store, 1)
    again = record(store, 1, recorded_at=T0 + timedelta(days=5))
    assert (again.id, again.created) == (a.id, False)
    other = record(store, 1, method="subspace", recorded_at=T0 + timedelta(days=5))
    assert other.created
    ds = store.diagnoses("pump-7")
    assert len(ds) == 2
    assert {d.recorded_at for d in ds} == {ds[0].recorded_at}  # one recording, one time


# -- atomicity of a failing write -----------------------------------------------------


def test_failure_inside_the_transaction_leaves_nothing(store, monkeypatch):
    record(store, 0)

    def boom(self, sql, rows):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(_sql.Tx, "executemany", boom)
    with pytest.raises(RuntimeError, match="disk on fire"):
        record(store, 1, machine="new-machine")
    monkeypatch.undo()
    # Machine, recording and diagnosis rows of the failed call were rolled back.
    assert [m.name for m in store.machines()] == ["pump-7"]
    assert len(store.diagnoses("pump-7")) == 1
    assert store.check() == []
    assert record(store, 1, machine="new-machine").created


# -- reading --------------------------------------------------------------------------


def test_trend_is_ordered_by_recording_time_not_insertion(store):
    for i in (4, 0, 2, 1, 3):
        record(store, i)
    tr = store.trend("pump-7", "R1")
    assert len(tr) == 5 and tr.unit == "ohm"
    expected_t = np.array([(T0 + timedelta(days=i)).timestamp() for i in range(5)])
    np.testing.assert_array_equal(tr.time, expected_t)
    np.testing.assert_allclose(tr.value, 2.0 + 0.01 * np.arange(5), rtol=1e-15)
    np.testing.assert_array_equal(tr.std_error, np.full(5, 0.02))
    np.testing.assert_allclose(tr.ci_low, 1.96 + 0.01 * np.arange(5), rtol=1e-15)
    np.testing.assert_array_equal(tr.baseline, np.full(5, 2.0))
    assert tr.recorded_at[0] == np.datetime64("2026-01-05T08:00:00")
    assert not tr.value.flags.writeable
    ls = store.trend("pump-7", "Ls1")
    assert np.isnan(ls.ci_low).all() and np.isnan(ls.baseline).all()


def test_trend_method_filter_and_errors(store):
    record(store, 0)
    record(store, 0, method="subspace")
    record(store, 1)
    assert list(store.trend("pump-7", "R1").method) == ["deadbeat-arx", "subspace", "deadbeat-arx"]
    assert len(store.trend("pump-7", "R1", method="subspace")) == 1
    with pytest.raises(NotFoundError, match="parameters: Ls1, R1"):
        store.trend("pump-7", "kw1")
    with pytest.raises(NotFoundError, match="known: pump-7"):
        store.trend("pump-8", "R1")
    with pytest.raises(LookupError):  # NotFoundError is a LookupError too
        store.diagnoses("nobody")


def test_trend_refuses_mixed_units(store):
    record(store, 0)
    record(store, 1, estimates={"R1": (2100.0, 20.0, None, None, "mohm")})
    with pytest.raises(HistoryError, match="different units"):
        store.trend("pump-7", "R1")
    record(store, 2, estimates={"Ls1": (0.03, 0.001)})  # no unit: compatible with "H"
    assert store.trend("pump-7", "Ls1").unit == "H"


def test_latest_estimates_is_the_latest_recording(store):
    assert store.add_machine("empty-rig", metadata={"bearing": "radial"})
    assert not store.add_machine("empty-rig")
    assert store.latest_estimates("empty-rig") == {}
    record(store, 5)
    record(store, 2)  # inserted later, recorded earlier
    record(store, 3, method="subspace")
    latest = store.latest_estimates("pump-7")
    assert latest["R1"].value == pytest.approx(2.05, rel=1e-15)
    assert list(latest) == ["R1", "Ls1"]
    assert store.latest_estimates("pump-7", method="subspace")["R1"].value == pytest.approx(
        2.03, rel=1e-15
    )


def test_machines_and_parameters(store):
    record(store, 0, machine="b-rig")
    record(store, 2, machine="a-rig")
    record(store, 7, machine="a-rig")
    ms = store.machines()
    assert [m.name for m in ms] == ["a-rig", "b-rig"]
    assert ms[0].n_diagnoses == 2
    assert ms[0].first_recorded_at == T0 + timedelta(days=2)
    assert ms[0].last_recorded_at == T0 + timedelta(days=7)
    assert store.parameters("a-rig") == ["Ls1", "R1"]


def test_methods_of_a_machine_latest_last_on_both_backends(store):
    # diagnose's default-method rule reads the machine's latest method from here
    # (issue 13): counts per method, ordered by each method's latest recording; a
    # diagnosis without estimates does not count; an unknown machine has none.
    record(store, 0, method="physical")
    record(store, 1, method="physical")
    record(store, 2, method="ml")
    record(store, 3, method="physical")
    store.record_diagnosis(
        "pump-7", recording_hash="sha-9", recorded_at=T0 + timedelta(days=9), method="okid",
        verdict="cannot diagnose", verdict_code="cannot_diagnose", estimates={},
    )  # fmt: skip
    assert store.methods("pump-7") == {"ml": 1, "physical": 3}
    assert list(store.methods("pump-7"))[-1] == "physical"
    assert store.methods("no-such-machine") == {}


def test_estimates_table_is_a_pandas_free_long_table(store):
    for i in range(3):
        record(store, i)
    tab = store.estimates_table("pump-7")
    assert set(tab) == {
        "diagnosis_id",
        "time",
        "recorded_at",
        "method",
        "parameter",
        "value",
        "std_error",
        "ci_low",
        "ci_high",
        "baseline",
        "unit",
    }
    assert all(len(v) == 6 for v in tab.values())
    assert list(tab["parameter"]) == ["R1", "Ls1"] * 3
    assert list(tab["unit"]) == ["ohm", "H"] * 3
    only = store.estimates_table("pump-7", parameters=["Ls1"])
    np.testing.assert_array_equal(only["value"], np.full(3, 0.031))
    pd = pytest.importorskip("pandas")
    frame = pd.DataFrame(tab)
    assert frame.pivot(index="recorded_at", columns="parameter", values="value").shape == (3, 2)


# -- validation happens before anything is written ------------------------------------


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"recorded_at": datetime(2026, 1, 5)}, "naive"),
        ({"recorded_at": "yesterday"}, "ISO 8601"),
        ({"recorded_at": [1]}, "recorded_at"),
        ({"estimates": [("R1", 2.0)]}, "mapping"),
        ({"estimates": {"R1": (float("nan"), 0.1)}}, "finite"),
        ({"estimates": {"R1": (2.0, -0.1)}}, ">= 0"),
        ({"estimates": {"R1": (2.0, 0.1, 2.1, 1.9)}}, "ci_low"),
        ({"estimates": {"R1": {"value": 2.0, "sigma": 0.1}}}, "keys"),
        ({"estimates": {"R1": (1, 2, 3, 4, 5, 6, 7)}}, "7 items"),
        ({"summary": {"x": object()}}, "JSON-like"),
        ({"verdict_code": 0}, "verdict_code"),
        ({"verdict": ""}, "non-empty"),
        ({"dt": -1.0}, "dt"),
        ({"n_samples": 1.5}, "n_samples"),
    ],
)
def test_bad_arguments_raise_before_writing(store, kw, match):
    with pytest.raises(DataError, match=match):
        record(store, 0, **kw)
    assert store.machines() == []


def test_closed_store_and_other_process(store, where):
    s = where.open()
    s.close()
    s.close()  # idempotent
    with pytest.raises(HistoryError, match="closed"):
        s.machines()
    assert "closed" in repr(s)
    store._backend.pid = -1  # as if this object had been inherited by a forked child
    try:
        with pytest.raises(HistoryError, match="open the store in each process"):
            store.machines()
    finally:
        store._backend.pid = os.getpid()


# -- locations ------------------------------------------------------------------------


def test_sqlite_locations(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with open_history("sqlite:///rel.sqlite") as s:
        record(s)
        assert s.dialect == "sqlite"
    assert (tmp_path / "rel.sqlite").is_file()
    with open_history(f"sqlite:///{tmp_path}/abs.sqlite") as s:  # sqlite:////abs/path
        assert s.location == f"{tmp_path}/abs.sqlite"
    with open_history(tmp_path / "pathlike.sqlite") as s:
        assert s.machines() == []
    with open_history(":memory:") as s:
        record(s)
        assert len(s.diagnoses("pump-7")) == 1
    monkeypatch.setenv("MAGLEVID_HISTORY", str(tmp_path / "env.sqlite"))
    assert default_store_location() == str(tmp_path / "env.sqlite")
    with open_history() as s:
        assert s.location == str(tmp_path / "env.sqlite")
    monkeypatch.delenv("MAGLEVID_HISTORY")
    assert default_store_location() == "maglevid-history.sqlite"


def test_bad_locations(tmp_path):
    with pytest.raises(HistoryError, match="no history store"):
        open_history(tmp_path / "missing.sqlite", create=False)
    assert not (tmp_path / "missing.sqlite").exists()
    with pytest.raises(HistoryError, match="folder"):
        open_history(tmp_path)
    with pytest.raises(HistoryError, match="unknown scheme"):
        open_history("mysql://u:secret@h/db")
    with pytest.raises(HistoryError, match="PostgreSQL stores only"):
        open_history(tmp_path / "x.sqlite", schema="s")
    with pytest.raises(DataError, match="timeout"):
        open_history(tmp_path / "x.sqlite", timeout=0)
    junk = tmp_path / "recording.npz"
    junk.write_bytes(b"PK\x03\x04 this is not a database" * 100)
    with pytest.raises(SchemaVersionError, match="not a maglevid history store"):
        open_history(junk)
    other = tmp_path / "other.sqlite"
    import sqlite3

    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE machines (serial TEXT)")
    with pytest.raises(SchemaVersionError, match="not a maglevid history store"):
        open_history(other)
    foreign = tmp_path / "foreign.sqlite"
    with sqlite3.connect(foreign) as conn:
        conn.execute("PRAGMA application_id = 123")
    with pytest.raises(SchemaVersionError, match="another application"):
        open_history(foreign)
    with open_history(tmp_path / "ours.sqlite"):
        pass
    with sqlite3.connect(tmp_path / "ours.sqlite") as conn:  # "MLVH": ours, recognisable
        assert conn.execute("PRAGMA application_id").fetchone() == (_sql.APPLICATION_ID,)


def test_unreachable_postgres_names_the_url_without_password():
    pytest.importorskip("psycopg")
    # Port 1 on localhost: refused at once, no server needed.
    with pytest.raises(HistoryError, match="cannot connect") as info:
        open_history("postgresql://alice:s3cret@127.0.0.1:1/db", timeout=2)
    assert "s3cret" not in str(info.value)
    assert "alice:***@127.0.0.1:1" in str(info.value)
    with pytest.raises(HistoryError, match="identifier"):
        open_history("postgresql://alice@127.0.0.1:1/db", schema="drop table;")


def test_redact_url():
    assert _sql.redact_url("postgresql://u:p@h:5/d") == "postgresql://u:***@h:5/d"
    assert _sql.redact_url("postgresql://u@h/d") == "postgresql://u@h/d"


def test_hash_helpers(tmp_path):
    f = tmp_path / "rec.bin"
    f.write_bytes(b"abc")
    # SHA-256 of "abc" (FIPS 180-2, appendix B.1).
    assert hash_file(f) == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    assert hash_options({"a": 1, "b": [1.0, 2]}) == hash_options({"b": [1.0, 2], "a": 1})
    assert hash_options({"a": 1}) != hash_options({"a": 2})
    assert hash_options({"x": np.float64(0.5)}) == hash_options({"x": 0.5})
    assert len(hash_options({})) == 64
