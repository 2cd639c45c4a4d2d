"""Trends from the history store, through `maglevid history --json`, into the report."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.diagnose.diagnosis import Diagnosis
from maglevid.diagnose.history import open_history
from maglevid.exceptions import DataError
from maglevid.plotting.diagnosis import drift_crossing, drift_line, plot_trends
from maglevid.report import render_report, trends_from_history

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)


@pytest.fixture
def history(tmp_path, rng, capsys):
    """R1 drifts by +2 mOhm/day over 12 weekly recordings; Ls1 is steady; a second
    method has one R1 point that must not be mixed in."""
    path = tmp_path / "h.sqlite"
    with open_history(path) as s:
        for i in range(12):
            s.record_diagnosis(
                "pump-7", recording_hash=f"p{i}", recorded_at=T0 + timedelta(days=7 * i),
                method="deadbeat", verdict="ok", verdict_code="no_change",
                estimates={
                    "R1": (2.0 + 0.014 * i + 0.002 * rng.standard_normal(), 0.002, None,
                           None, "ohm", 2.0),
                    "Ls1": (0.03 + 1e-4 * rng.standard_normal(), 1e-4, None, None, "H", 0.03),
                },
            )  # fmt: skip
        s.record_diagnosis(
            "pump-7", recording_hash="q", recorded_at=T0, method="subspace", verdict="ok",
            verdict_code="no_change", estimates={"R1": (9.0, None)},
        )  # fmt: skip
    code = main(["--json", "history", "pump-7", "--store", str(path), "--tolerance", "R1=0.2"])
    assert code == 0
    return json.loads(capsys.readouterr().out)


def test_history_output_becomes_report_trends(history):
    trends = trends_from_history(history)
    assert list(trends) == list(history["parameters"])
    r1 = trends["R1"]
    assert r1["method"] == "deadbeat" and len(r1["value"]) == 12  # the subspace point left out
    assert r1["baseline"] == 2.0 and r1["tolerance"] == pytest.approx(0.1)
    assert r1["drift"]["drifting"] is True
    # The drift line in report units: 2 mOhm/day = 0.014/7 per day, in seconds.
    slope, t_ref, v_ref = drift_line(r1["drift"])
    assert slope * 86400 == pytest.approx(0.002, rel=0.1)
    # The band 2.0 +- 0.2 is left around day 100 after T0.
    cross = datetime.fromtimestamp(drift_crossing(r1["drift"]), tz=timezone.utc)
    assert abs((cross - T0).days - 100) < 10
    # The plotted line goes through (t_ref, value_at_ref).
    fig = plot_trends({"R1": r1})
    (line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "fitted trend"]
    t = (line.get_xdata().astype("datetime64[us]").astype(np.int64) / 1e6).astype(float)
    np.testing.assert_allclose(np.interp(t_ref, t, line.get_ydata()), v_ref, rtol=1e-9)


def test_method_choice_and_errors(history):
    only = trends_from_history(history, method="subspace")
    assert list(only) == ["R1"] and only["R1"]["value"] == [9.0]
    assert np.isnan(only["R1"]["std_error"][0])
    assert only["R1"]["drift"] == {}  # the history skipped the test: one point
    with pytest.raises(DataError, match="not in the history"):
        trends_from_history(history, parameters=["R9"])
    with pytest.raises(DataError, match="maglevid history"):
        trends_from_history({"machines": []})


def test_report_shows_the_history(history):
    html = render_report(
        Diagnosis(verdict="x", verdict_code="no_change"),
        trends=trends_from_history(history, parameters=["R1"]),
    )
    assert "<img" in html and "could not be drawn" not in html
    assert "drifting" in html and "leaves the tolerance band around 2026-0" in html


def test_a_step_travels_from_the_history_to_the_report(tmp_path):
    # The history judged a step (amplifier 1 loses 20 % between two recordings):
    # the report draws the two means and says "step at ...", not a drift line.
    from maglevid.diagnose.trend_summary import history_summary

    t0 = datetime(2026, 1, 5, tzinfo=timezone.utc)
    rng = np.random.default_rng(5)
    with open_history(tmp_path / "h.sqlite") as store:
        for i in range(10):
            kw1 = (1.0 if i < 6 else 0.8) + 0.004 * rng.standard_normal()
            store.record_diagnosis(
                "amp", recording_hash=f"h{i}", recorded_at=t0 + timedelta(days=7 * i),
                method="physical", verdict="-", verdict_code="no_change",
                estimates={"kw1": (kw1, 0.004, None, None, "V·V⁻¹", 1.0)},
            )  # fmt: skip
        trends = trends_from_history(history_summary(store, "amp"))
    step = trends["kw1"]["step"]
    assert step["index"] == 6 and step["at"] == (t0 + timedelta(days=42)).isoformat()
    fig = plot_trends(trends)
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert any(t.startswith("step at 2026-02-16") for t in texts)
    # Two horizontal segments at the two means, no fitted line.
    segments = [ln for ln in fig.axes[0].lines if len(ln.get_ydata()) == 2]
    levels = sorted(float(y[0]) for y in (ln.get_ydata() for ln in segments) if y[0] == y[1])
    assert levels == pytest.approx([step["after"], step["before"]])
