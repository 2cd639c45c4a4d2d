"""The fleet summary: latest state per machine, drift tests over the history, problems.

No cluster: outcomes are built by hand and the store is filled directly.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from _fleet_helpers import Where, day

from maglevid.fleet import RecordingOutcome, machine_drifts
from maglevid.fleet.summary import summarize_fleet


def _record(st: Any, machine: str, k: int, code: str, estimates: dict, verdict: str = "") -> None:
    st.record_diagnosis(
        machine,
        recording_hash=f"{machine}-{k}",
        recorded_at=day(k),
        method="physical",
        verdict=verdict or code,
        verdict_code=code,
        estimates=estimates,
        recording_path=f"/data/{machine}/r{k}.npz",
        summary={
            "reasons": [f"reason {k}"],
            "changes": [
                {"name": "kw1", "change_percent": -40.0, "status": "changed", "significant": True}
            ]
            if code == "fault"
            else [],
            "isolation": {
                "explained": True,
                "best": {"parameters": ["kw1"], "description": "amplifier 1 gain kw1 -40 %"},
            }
            if code == "fault"
            else {},
        },
    )


def test_drift_found_in_the_stored_history(where: Where) -> None:
    rng = np.random.default_rng(5)
    with where.open() as st:
        for k in range(10):
            r1 = 17.5 * (1 + 0.01 * k) * (1 + 0.002 * rng.standard_normal())  # +1 %/day
            r2 = 17.5 * (1 + 0.002 * rng.standard_normal())
            est = {
                "R1": (r1, 0.002 * 17.5, None, None, "ohm", 17.5),
                "R2": (r2, 0.002 * 17.5, None, None, "ohm", 17.5),
                "v1": (7.7e5, 1e3),  # not a diagnosed parameter: not tested
            }
            _record(st, "drifty", k, "no_change", est)
        for k in range(3):  # too few points for a test
            _record(st, "young", k, "no_change", {"R1": (17.5 + k, 0.01)})
        tests = {d["parameter"]: d for d in machine_drifts(st, "drifty", alpha=0.01)}
        assert set(tests) == {"R1", "R2"}
        r1, r2 = tests["R1"], tests["R2"]
        assert r1["drifting"] and not r2["drifting"]
        assert r1["alpha"] == pytest.approx(0.005)  # Bonferroni over the machine's 2 tests
        assert r1["slope_percent_per_day"] == pytest.approx(1.0, rel=0.1)
        assert r1["n"] == 10 and r1["method"] == "physical"
        # +-5 % of 17.5 is crossed about 5 days after the first recording, before the last
        # (day 9): a crossing already past is never projected (issue 12), it is stated.
        assert r1["kind"] == "drift" and r1["projected_crossing"] is None
        assert any("already beyond the tolerance" in n for n in r1["notes"])
        assert machine_drifts(st, "young") == []
        assert machine_drifts(st, "nobody") == []


class _TableStore:
    """Only ``estimates_table``, what machine_drifts reads: a Monte Carlo without a database."""

    def __init__(self, tables: dict[str, dict[str, np.ndarray]]):
        self.tables = tables

    def estimates_table(self, machine: str, *, parameters: Any = None) -> dict[str, np.ndarray]:
        return self.tables[machine]


def test_bonferroni_keeps_the_false_alarms_per_machine_at_alpha() -> None:
    # 1000 drift-free machines, 5 parameters, 8 recordings each, heteroscedastic errors.
    # P(any false alarm per machine) = 1 - (1 - alpha/5)^5 = 0.0490 at alpha = 0.05: about
    # 49 machines (s.d. 6.8); without the split it would be 1 - 0.95^5 = 22.6 % (226).
    rng = np.random.default_rng(20261122)
    names = ("R1", "R2", "L1", "L2", "kw1")
    tables = {}
    for m in range(1000):
        t = np.sort(rng.uniform(0, 60, 8)) * 86400.0 + 1.7e9
        cols: dict[str, list] = {
            k: [] for k in ("time", "method", "parameter", "value", "std_error", "baseline")
        }
        for name in names:
            se = rng.uniform(0.5, 2.0, t.size)
            cols["time"] += list(t)
            cols["method"] += ["physical"] * t.size
            cols["parameter"] += [name] * t.size
            cols["value"] += list(10.0 + se * rng.standard_normal(t.size))
            cols["std_error"] += list(se)
            cols["baseline"] += [10.0] * t.size
        tables[f"m{m}"] = {
            k: np.asarray(v, dtype=object if k in ("method", "parameter") else float)
            for k, v in cols.items()
        }
    store = _TableStore(tables)
    alarms = sum(
        any(d["drifting"] for d in machine_drifts(store, m, alpha=0.05, parameters=names))
        for m in tables
    )
    assert 49 - 3 * 6.8 <= alarms <= 49 + 3 * 6.8, alarms


def _outcome(machine: str, k: int, status: str, code: str | None, **kw: Any) -> RecordingOutcome:
    return RecordingOutcome(
        machine=machine,
        recording=f"/data/{machine}/r{k}.npz",
        status=status,
        verdict_code=code,
        verdict=kw.pop("verdict", code or ""),
        recorded_at=None if code is None else day(k).isoformat(),
        **kw,
    )


def test_latest_state_problems_and_json(where: Where) -> None:
    with where.open() as st:
        _record(st, "pump", 9, "fault", {"kw1": (0.6, 0.01)}, "Fault: amplifier 1 gain")
        earlier = {"pump": st.diagnoses("pump")}
        outcomes = [
            # An older recording diagnosed today does not hide last week's fault.
            _outcome("pump", 2, "diagnosed", "no_change"),
            _outcome("pump", 3, "unreadable", "cannot_diagnose", error="FileFormatError: junk"),
            _outcome("fan", 1, "diagnosed", "no_change"),
            _outcome("fan", 2, "diagnosed", "cannot_diagnose", verdict="Cannot diagnose: short"),
            _outcome("fan", 3, "error", None, error="RuntimeError: bug"),
            _outcome("gone", 1, "missing", None, error="FileNotFoundError: gone"),
        ]
        summary = summarize_fleet(outcomes, st, earlier=earlier, run={"n_workers": 2})
    pump, fan, gone = (summary.machine(n) for n in ("pump", "fan", "gone"))
    assert pump.state == "changed" and pump.latest["recorded_at"] == day(9).isoformat()
    assert pump.latest["cause"] == "amplifier 1 gain kw1 -40 %" and not pump.latest["in_this_run"]
    assert pump.latest["changes"][0]["parameter"] == "kw1"
    assert fan.state == "ok" and fan.latest["recorded_at"] == day(1).isoformat()
    assert gone.state == "undiagnosed" and gone.latest is None
    assert [p["reason"] for p in fan.problems] == ["Cannot diagnose: short", "RuntimeError: bug"]
    assert [m.name for m in summary.changed] == ["pump"]
    assert summary.counts == {"diagnosed": 3, "unreadable": 1, "error": 1, "missing": 1}
    assert len(summary.problems) == 4
    d = summary.to_dict()
    assert d["format"] == "maglevid-fleet-summary" and d["changed"] == ["pump"]
    assert d["run"] == {"n_workers": 2}
    json.dumps(d, allow_nan=False)  # JSON-safe: no NaN, no objects
