"""Helpers of the fleet tests: simulated fleets, store backends, a worker that dies once.

The functions a Dask worker runs (``kill_once``) live here, not in a test
module: spawned worker processes import them by module name (this folder is on
the ``sys.path`` they inherit from pytest).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import signal
import uuid
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest

from maglevid.io import write_recording
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

NOMINAL = AMBParameters.nominal()
T0 = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)

#: Samples of a "short" recording: the fewest the quality checks accept
#: (``diagnose.checks.MIN_SAMPLES``), so a diagnosis costs ~0.1 s.
N_SAMPLES = 2000

#: A recording that fails the record-length check (bad data, readable file).
N_SHORT = 600

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


@dataclasses.dataclass(frozen=True)
class Where:
    """A fresh store: its location and schema (PostgreSQL) for run_fleet / the CLI."""

    location: str
    schema: str | None

    def open(self) -> Any:
        from maglevid.diagnose.history import open_history

        return open_history(self.location, schema=self.schema)

    def cli_args(self) -> list[str]:
        return ["--store", self.location] + (["--schema", self.schema] if self.schema else [])

    def n_diagnoses(self) -> int:
        with self.open() as st:
            return sum(m.n_diagnoses for m in st.machines())


def store_where(kind: str, tmp_path: Path) -> Iterator[Where]:
    """A fresh SQLite file or PostgreSQL schema; the schema is dropped afterwards."""
    if kind == "sqlite":
        yield Where(str(tmp_path / "fleet.sqlite"), None)
        return
    import psycopg

    schema = f"fleet_{uuid.uuid4().hex[:16]}"
    yield Where(PG_URL, schema)
    with psycopg.connect(PG_URL, autocommit=True) as conn:
        conn.execute(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')


def write_sim(
    path: Path,
    *,
    fault: dict[str, float] | None = None,
    seed: int,
    n_samples: int = N_SAMPLES,
    recorded_at: datetime | None = None,
) -> Path:
    """One simulated AMB recording (fault factors on the nominal bearing) written to ``path``."""
    data = simulate_amb_loop(
        NOMINAL.with_fault(**(fault or {})),
        nominal=NOMINAL,
        n_samples=n_samples,
        rng=seed,
        plant_model="linear",
    )
    if recorded_at is not None:
        meta = dict(data.metadata)
        meta["recorded_at"] = recorded_at.isoformat()
        data = dataclasses.replace(data, metadata=meta)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_recording(data, path)


def write_corrupt(path: Path, kind: str) -> Path:
    """A recording file that cannot be read: ``"garbage"`` bytes or ``"truncated"`` npz."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind == "garbage":
        path.write_bytes(b"this is not a recording\n" * 10)
    elif kind == "text":
        path.write_text("t,x\n0,1\n1,oops\n")
    else:
        raise ValueError(kind)
    return path


def kill_once(recording: Any, *, victim: str, marker: str, **kwargs: Any) -> Any:
    """The pipeline's diagnose, except that the first time it meets ``victim`` it kills its worker.

    The marker file is written (with this worker's pid) before the SIGKILL, so
    the rerun on the restarted worker diagnoses normally and the test can tell
    that the kill happened.
    """
    from maglevid.diagnose.pipeline import diagnose

    source = str(recording.metadata.get("source", ""))
    if source.endswith(victim) and not os.path.exists(marker):
        with open(marker, "w") as f:
            f.write(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return diagnose(recording, **kwargs)


def logged_diagnose(recording: Any, *, log: str, **kwargs: Any) -> Any:
    """The pipeline's diagnose, appending "machine file start end" (epoch s) to ``log``."""
    import time

    from maglevid.diagnose.pipeline import diagnose

    t0 = time.time()
    out = diagnose(recording, **kwargs)
    name = Path(str(recording.metadata["source"])).name
    with open(log, "a") as f:
        f.write(f"{kwargs['machine']} {name} {t0} {time.time()}\n")
    return out


def day(n: float) -> datetime:
    return T0 + timedelta(days=n)


def always_kill(recording: Any, *, victim: str, **kwargs: Any) -> Any:
    """The pipeline's diagnose, except that ``victim`` kills its worker every time."""
    from maglevid.diagnose.pipeline import diagnose

    if str(recording.metadata.get("source", "")).endswith(victim):
        os.kill(os.getpid(), signal.SIGKILL)
    return diagnose(recording, **kwargs)


@functools.lru_cache(maxsize=1)
def _example_fault() -> Any:
    from diagnosis_examples import faulty_diagnosis

    return faulty_diagnosis()


def fake_fault(
    recording: Any,
    *,
    machine: str,
    history: Any = None,
    recorded_at: Any = None,
    faulty_machines: tuple[str, ...] = (),
    **kwargs: Any,
) -> Any:
    """A test double of the pipeline: the report tests' R1 fault, or no change.

    Recordings of ``faulty_machines`` get the fault of ``diagnosis_examples``,
    the others "no change". It stores the diagnosis like the pipeline (so the
    summary sees it) but identifies nothing: the report-writing path is what is
    tested with it.
    """
    from maglevid.diagnose.diagnosis import Diagnosis
    from maglevid.diagnose.pipeline import recording_hash

    common = {
        "machine": machine,
        "recording": str(recording.metadata["source"]),
        "recording_hash": recording_hash(recording),
        "method": "fake",
    }
    if machine in faulty_machines:
        d = dataclasses.replace(_example_fault(), **common)
    else:
        d = Diagnosis(verdict="No significant change", verdict_code="no_change", **common)
    if history is not None:
        history.record_diagnosis(
            machine,
            recording_hash=d.recording_hash,
            recorded_at=recorded_at,
            method=d.method,
            verdict=d.verdict,
            verdict_code=d.verdict_code,
            estimates=d.estimates(),
            recording_path=d.recording,
        )
    return d
