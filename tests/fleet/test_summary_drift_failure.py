"""A drift test that fails is reported, not dropped (issue 17: fleet/summary.py
used to ``pass`` on the error, and the report showed no drift test at all)."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from maglevid.diagnose.history import open_history
from maglevid.exceptions import DataError
from maglevid.fleet import trends as fleet_trends
from maglevid.report.html import render_report


def test_failed_drift_test_is_reported(tmp_path, monkeypatch, caplog):
    t0 = datetime(2026, 1, 5, tzinfo=timezone.utc)
    with open_history(tmp_path / "s.sqlite") as st:
        for k in range(6):
            st.record_diagnosis(
                "M", recording_hash=f"h{k}", recorded_at=t0 + timedelta(days=k),
                method="physical", verdict="ok", verdict_code="no_change",
                estimates={"R1": (17.5 + 0.01 * k, 0.05)},
            )  # fmt: skip

        def broken(*args, **kwargs):
            raise DataError("the weights are singular")

        import maglevid.diagnose.drift as drift

        monkeypatch.setattr(drift, "detect_drift", broken)
        trends = fleet_trends.report_trends(st, "M", method="physical")
    entry = trends["R1"]
    assert entry["drift"]["verdict"] == "drift test failed: the weights are singular"
    assert "drift test of R1 failed" in caplog.text
    from maglevid.diagnose.diagnosis import Diagnosis

    page = render_report(Diagnosis(verdict="ok", verdict_code="no_change"), trends=trends)
    assert "drift test failed: the weights are singular" in page
    assert pytest.approx(entry["value"][-1]) == 17.55
