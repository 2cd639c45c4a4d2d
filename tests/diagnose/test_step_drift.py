"""History: a step is dated by a change-point test, a drift projected only forward."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from maglevid.diagnose.diagnosis import Diagnosis
from maglevid.diagnose.drift import detect_step
from maglevid.diagnose.history import open_history
from maglevid.diagnose.pipeline import _drifts
from maglevid.exceptions import DataError

T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)


def test_step_is_found_and_placed():
    # Eight points, level 1.0 then 0.8 (a -20 % step) with 0.2 % noise: the split is
    # at index 4 and two levels fit far better than a line.
    rng = np.random.default_rng(1)
    t = np.arange(8.0)
    y = np.r_[np.full(4, 1.0), np.full(4, 0.8)] + 0.002 * rng.standard_normal(8)
    r = detect_step(t, y, np.full(8, 0.002))
    assert r.is_step and r.index == 4
    assert r.size == pytest.approx(-0.2, abs=0.01)
    assert r.chi2_step < r.chi2_line


def test_linear_drift_is_not_a_step():
    rng = np.random.default_rng(2)
    t = np.arange(10.0)
    y = 1 + 0.01 * t + 0.002 * rng.standard_normal(10)
    assert not detect_step(t, y, np.full(10, 0.002)).is_step


def test_no_change_gives_no_step_at_about_alpha():
    # Under a constant level the Bonferroni bound keeps false steps below alpha.
    rng = np.random.default_rng(3)
    hits = sum(
        detect_step(np.arange(8.0), rng.standard_normal(8), np.ones(8), alpha=0.05).is_step
        for _ in range(400)
    )
    assert hits / 400 <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / 400)


def test_false_alarm_rate_of_twenty_point_histories():
    # (From the former diagnose/step.py tests: one step test now serves `history`,
    # `diagnose` and the fleet.) Bonferroni over the n - 1 splits is conservative: at
    # most 1 % of 400 steady 20-point series are flagged; Binomial(400, 0.01) exceeds
    # 10 with probability < 0.3 %.
    rng = np.random.default_rng(7)
    t = np.arange(20.0)
    flagged = sum(
        detect_step(t, 2.0 + 0.01 * rng.standard_normal(20), np.full(20, 0.01)).p_value < 0.01
        for _ in range(400)
    )
    assert flagged <= 10


def test_step_placed_in_a_long_history():
    # kw1 -20 % at point 12 of 20 with 0.5 % noise: split at 12, size within 4 of its
    # standard errors sqrt(se^2 (1/12 + 1/8)).
    rng = np.random.default_rng(1)
    t = np.arange(20.0)
    y = np.where(t < 12, 1.0, 0.8) + 0.005 * rng.standard_normal(20)
    r = detect_step(t, y, np.full(20, 0.005))
    assert r.is_step and r.index == 12
    assert abs(r.size + 0.2) < 4 * 0.005 * np.sqrt(1 / 12 + 1 / 8)


def test_step_without_standard_errors_uses_the_scatter():
    # No standard errors (a method without covariance): equal weights, the scale from
    # the residuals; a 1 -> 3 step over 0.1 scatter is found at point 4.
    r = detect_step(np.arange(8.0), [1.0, 1.1, 0.9, 1.0, 3.0, 3.1, 2.9, 3.0])
    assert r.is_step and r.index == 4


def test_step_needs_three_points():
    with pytest.raises(DataError, match="at least 3"):
        detect_step([0.0, 1.0], [1.0, 2.0])


def _store_history(tmp_path, values):
    store = open_history(tmp_path / "h.sqlite")
    for i, v in enumerate(values):
        store.record_diagnosis(
            "B1", recording_hash=f"h{i}", recorded_at=T0 + timedelta(days=7 * i),
            method="physical", verdict="x", verdict_code="no_change",
            estimates={"kw1": (v, 0.002, None, None, None, 1.0)},
        )  # fmt: skip
    return store


def _diag():
    return Diagnosis(
        verdict="x", verdict_code="no_change", machine="B1", method="physical",
        baseline={"parameters": {"kw1": [1.0, 0.0]}},
    )  # fmt: skip


def test_history_step_is_dated_not_projected(tmp_path):
    # kw1 -20 % from one weekly recording to the next: a dated step, no crossing date.
    store = _store_history(tmp_path, [1.0, 1.001, 0.999, 0.8, 0.801, 0.799])
    (d,) = _drifts(store, _diag(), 0.1, 0.01)
    assert d["kind"] == "step" and d["projected_crossing"] is None
    assert d["step_after"].startswith("2026-01-15") and d["step_before"].startswith("2026-01-22")
    assert d["step_percent"] == pytest.approx(-20, abs=0.5)
    store.close()


def test_drift_already_past_its_limit_is_not_projected(tmp_path):
    # A steady -2 %/week drift that left ±5 % weeks ago: no crossing date in the past.
    store = _store_history(tmp_path, [1.0 - 0.02 * i for i in range(8)])
    (d,) = _drifts(store, _diag(), 0.05, 0.01)
    assert d["kind"] == "drift" and d["projected_crossing"] is None and d["already_beyond"]
    store.close()


def test_a_trend_never_comes_from_the_future(tmp_path):
    """The trend of a diagnosis stops at its own recording: a second `make demo` into the
    same folder (the first run's later weeks already stored) alarmed on day 0."""
    store = _store_history(tmp_path, [1.0 - 0.02 * i for i in range(8)])
    assert _drifts(store, _diag(), 0.05, 0.01, when=T0 + timedelta(days=14)) == []
    (d,) = _drifts(store, _diag(), 0.05, 0.01, when=(T0 + timedelta(days=49)).isoformat())
    assert d["kind"] == "drift"
    store.close()
