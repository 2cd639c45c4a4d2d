"""diagnose's default method (issue 13: ml for a two-coil bearing) and existing histories.

Histories are per method: a machine whose history was recorded with the former
default `physical` continues with it (a note says so) until a diagnosis with
--method ml starts its ml series. docs/history.md, "Default method and existing
histories".
"""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from maglevid.diagnose.history import open_history
from maglevid.diagnose.pipeline import choose_method, diagnose
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

NOMINAL = AMBParameters.nominal()
T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)


@pytest.fixture(scope="module")
def rec():
    # Linear plant at the demo's sensor noise (5 nm, 10 uA), 1 s: enough for a verdict.
    return simulate_amb_loop(
        NOMINAL,
        dt=1e-4,
        n_samples=10_000,
        nominal=NOMINAL,
        noise_std=(5e-9, 1e-5, 1e-5),
        rng=3,
        plant_model="linear",
    )


def _store(tmp_path, methods):
    """A store whose machine B1 has one diagnosis per entry of ``methods``, weekly."""
    store = open_history(tmp_path / "h.sqlite")
    for i, m in enumerate(methods):
        store.record_diagnosis(
            "B1", recording_hash=f"h{i}", recorded_at=T0 + timedelta(days=7 * i),
            method=m, verdict="x", verdict_code="no_change",
            estimates={"R1": (17.5, 0.1)},
        )  # fmt: skip
    return store


def test_a_bearing_is_diagnosed_with_ml_by_default(rec):
    method, reason = choose_method(rec)
    assert method == "ml" and "maximum likelihood" in reason
    # Without a history (or a machine unknown to it) nothing continues.
    assert choose_method(rec, history=None, machine="B1")[0] == "ml"


def test_methods_of_a_machine_latest_last(tmp_path):
    store = _store(tmp_path, ["physical", "physical", "ml", "physical"])
    assert store.methods("B1") == {"ml": 1, "physical": 3}  # physical used last
    assert store.methods("no-such-machine") == {}
    store.close()


def test_a_physical_history_continues_with_physical_and_says_so(tmp_path, rec):
    store = _store(tmp_path, ["physical"] * 3)
    assert choose_method(rec, history=store, machine="B1")[0] == "physical"
    assert choose_method(rec, history=store, machine="B2")[0] == "ml"  # a new machine
    d = diagnose(rec, machine="B1", history=store, recorded_at=T0 + timedelta(days=30))
    assert d.method == "physical" and d.method_reason.startswith("continues")
    (note,) = [n for n in d.notes if "continues machine 'B1'" in n]
    assert "3 diagnoses with physical" in note and "--method ml" in note
    assert "note: method physical: continues" in d.summary()
    # The stored physical series grows, nothing else is touched.
    assert store.methods("B1") == {"physical": 4}
    store.close()


def test_method_ml_once_switches_the_machine_over(tmp_path, rec):
    store = _store(tmp_path, ["physical"] * 3)
    d = diagnose(
        rec, machine="B1", method="ml", history=store, recorded_at=T0 + timedelta(days=30)
    )
    assert d.method == "ml" and d.method_reason == "chosen by the user"
    assert not any("continues" in n for n in d.notes)
    assert list(store.methods("B1")) == ["physical", "ml"]
    # Later diagnoses without --method continue the ml series; the physical points stay.
    assert choose_method(rec, history=store, machine="B1")[0] == "ml"
    assert len(store.trend("B1", "R1", method="physical")) == 3
    assert np.all(store.trend("B1", "R1", method="ml").method == "ml")
    store.close()


def test_other_plant_kinds_keep_their_default():
    from maglevid.data import ClosedLoopData

    lev = ClosedLoopData(y=np.zeros((50, 2)), u=np.zeros((50, 1)), dt=0.01)
    assert choose_method(lev)[0] == "levitator"
