"""Diagnosis figures: they plot what they say (data read back from the artists)."""

from __future__ import annotations

import io

import matplotlib.colors as mcolors
import numpy as np
import pytest
from matplotlib.figure import Figure
from PIL import Image

from diagnosis_examples import DT, NOMINAL, example_controller, example_trends, faulty_diagnosis
from maglevid.exceptions import DataError
from maglevid.lti import StateSpace, discretize
from maglevid.physics.amb import amb_state_space, open_loop_poles
from maglevid.plotting.diagnosis import (
    COLORS,
    figure_to_png,
    figure_to_svg,
    impulse_horizon,
    plot_frequency_responses,
    plot_impulse_responses,
    plot_parameter_changes,
    plot_pole_maps,
    plot_trends,
)
from maglevid.report.loop import close_loop, controller_state_space


@pytest.fixture(scope="module")
def diagnosis():
    return faulty_diagnosis()


@pytest.fixture(scope="module")
def loops(diagnosis):
    base = amb_state_space(NOMINAL, dt=DT)
    K = controller_state_space(example_controller(), plant=base)
    return close_loop(base, K), close_loop(discretize(diagnosis.identified_model, DT), K)


def _line_with(ax, color):
    want = mcolors.to_rgba(color)
    return [ln for ln in ax.get_lines() if mcolors.to_rgba(ln.get_color()) == want]


def test_png_and_svg_are_what_they_claim():
    fig = Figure(figsize=(2, 1))
    fig.add_subplot().plot([0, 1], [0, 1])
    png = figure_to_png(fig, dpi=50)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert Image.open(io.BytesIO(png)).size == (100, 50)
    svg = figure_to_svg(fig)
    assert svg.lstrip().startswith("<?xml") and "<svg" in svg
    # Deterministic output (no time stamp): the same figure gives the same bytes.
    assert figure_to_png(fig, dpi=50) == png


def test_forest_plot_rows_points_and_highlight(diagnosis):
    changes = diagnosis.changes
    fig = plot_parameter_changes(changes)
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert labels == [c.name for c in changes]
    # Significant rows are red and bold; the others are not.
    for tick, c in zip(ax.get_yticklabels(), changes):
        assert (mcolors.to_hex(tick.get_color()) == COLORS["changed"]) == c.significant
    # Each estimate is drawn as a single marker at (change_percent, row).
    dots = [ln for ln in ax.get_lines() if ln.get_marker() == "o" and len(ln.get_xdata()) == 1]
    xs = sorted(float(ln.get_xdata()[0]) for ln in dots)
    assert xs == pytest.approx(sorted(c.change_percent for c in changes), rel=1e-12)
    # The x range holds every interval and the tolerance band.
    lo, hi = ax.get_xlim()
    assert lo < -5.0 and hi > max(100 * c.change_ci[1] / c.baseline for c in changes)


def test_forest_plot_rejects_nothing_to_plot():
    with pytest.raises(DataError, match="empty"):
        plot_parameter_changes([])


def test_pole_maps_show_the_true_poles(diagnosis, loops):
    fig = plot_pole_maps(
        diagnosis.baseline_model, diagnosis.identified_model, dt=DT, closed_loop=loops
    )
    assert len(fig.axes) == 4
    s_ax, z_ax = fig.axes[0], fig.axes[1]
    (base_s,) = [ln for ln in s_ax.get_lines() if ln.get_label() == "baseline plant"]
    pts = np.sort_complex(base_s.get_xdata() + 1j * base_s.get_ydata())
    np.testing.assert_allclose(pts, np.sort_complex(open_loop_poles(NOMINAL)), rtol=1e-12)
    (base_z,) = [ln for ln in z_ax.get_lines() if ln.get_label() == "baseline plant"]
    zpts = np.sort_complex(base_z.get_xdata() + 1j * base_z.get_ydata())
    np.testing.assert_allclose(
        zpts, np.sort_complex(np.exp(open_loop_poles(NOMINAL) * DT)), rtol=1e-12
    )
    # The z-plane detail shows the unstable pole outside the unit circle.
    x0, x1 = z_ax.get_xlim()
    assert x0 < 1.0 < np.exp(455.04 * DT) < x1


def test_pole_maps_without_dt_draw_the_s_plane_only(diagnosis):
    fig = plot_pole_maps(diagnosis.baseline_model, diagnosis.identified_model)
    assert len(fig.axes) == 1


def test_impulse_horizon_is_analytic():
    unstable = amb_state_space(NOMINAL)
    assert impulse_horizon(unstable) == pytest.approx(4.0 / 455.0412690, rel=1e-8)
    stable = StateSpace([[-20.0]], [[1.0]], [[1.0]])
    assert impulse_horizon(stable) == pytest.approx(6.0 / 20.0, rel=1e-12)


def test_impulse_plot_is_the_markov_sequence(diagnosis, loops):
    base = diagnosis.baseline_model
    fig = plot_impulse_responses(base, diagnosis.identified_model, dt=DT, closed_loop=loops)
    assert len(fig.axes) == 4
    ax = fig.axes[1]  # open loop, input u2
    (line,) = [ln for ln in ax.get_lines() if ln.get_label() == "baseline"]
    y = line.get_ydata()
    markov = discretize(base, DT).markov(len(y) + 1)[1:, 0, 1]  # C A^(k-1) B, eq. (9)
    np.testing.assert_allclose(y, 1e6 * markov, rtol=1e-12)
    t = line.get_xdata()
    assert t[1] - t[0] == pytest.approx(DT * 1e3)  # plotted in ms
    # Short horizon for the unstable loop: it ends where e^(455 t) ~ e^4.
    assert t[-1] == pytest.approx(1e3 * 4.0 / 455.04, abs=DT * 1e3)
    # The closed loop has decayed inside its window.
    (cl,) = [ln for ln in fig.axes[2].get_lines() if ln.get_label() == "baseline"]
    yc = np.abs(cl.get_ydata())
    assert yc[-1] < 0.02 * yc.max()


def test_bode_magnitude_matches_the_static_gain():
    # First-order lag k/(s + a): |H| at w << a is 20 log10(k/a).
    sys = StateSpace([[-50.0]], [[100.0]], [[1.0]], input_names=("u",), output_names=("y",))
    fig = plot_frequency_responses(sys, sys, channels=[(0, 0)], omega=np.logspace(-2, 4, 200))
    mag = fig.axes[0].get_lines()[0].get_ydata()
    assert mag[0] == pytest.approx(20 * np.log10(2.0), abs=1e-6)
    ph = fig.axes[1].get_lines()[0].get_ydata()
    assert ph[-1] == pytest.approx(-90.0, abs=0.5)


def test_bode_default_channels_for_the_bearing(diagnosis):
    fig = plot_frequency_responses(diagnosis.baseline_model, diagnosis.identified_model, dt=DT)
    titles = [ax.get_title() for ax in fig.axes[:4]]
    assert titles == ["x / u1", "x / u2", "i1 / u1", "i2 / u2"]
    # The frequency axis ends at Nyquist.
    f = fig.axes[0].get_lines()[0].get_xdata()
    assert f[-1] == pytest.approx(0.5 / DT, rel=1e-12)


def test_trends_plot_dates_band_and_drift_line():
    trends = example_trends()
    fig = plot_trends(trends, baselines={"R1": 17.5, "R2": 17.5}, tolerances={"R1": 0.05})
    ax = fig.axes[0]
    # The verdict is a text right above each panel (issue 18: no longer the right
    # title, which a long left title ran into).
    assert any("drifting" in t.get_text() for t in ax.texts)
    assert any("no significant drift" in t.get_text() for t in fig.axes[1].texts)
    (trend,) = [ln for ln in ax.get_lines() if ln.get_label() == "fitted trend"]
    assert mcolors.to_hex(trend.get_color()) == COLORS["changed"]
    (base,) = [ln for ln in ax.get_lines() if ln.get_label() == "baseline"]
    assert base.get_ydata()[0] == 17.5
    # Dates: a date axis around early 2026.
    lo, hi = ax.get_xlim()
    import matplotlib.dates as mdates

    assert mdates.num2date(lo).year == 2026 or mdates.num2date(hi).year == 2026


def test_trends_numeric_time_and_bad_input():
    fig = plot_trends({"R1": {"time": [0.0, 1.0, 2.0], "value": [1, 2, 3], "time_unit": "h"}})
    assert fig.axes[0].get_xlabel() == "h"
    with pytest.raises(DataError, match="3 times but 2 values"):
        plot_trends({"R1": {"time": [0, 1, 2], "value": [1, 2]}})
    with pytest.raises(DataError, match="ISO 8601"):
        plot_trends({"R1": {"time": ["2026-01-01", "yesterday"], "value": [1, 2]}})
    with pytest.raises(DataError, match="'value'"):
        plot_trends({"R1": {"time": [0, 1]}})
    with pytest.raises(DataError, match="empty"):
        plot_trends({})


def test_trend_titles_do_not_overlap_their_drift_verdicts():
    # Issue 18: in the report's trend grid a long panel title ran into the
    # "no significant drift, p = ..." line beside it.
    from maglevid.plotting.diagnosis import plot_trends

    trends = example_trends()
    labels = {k: f"{k} [N·A⁻¹] · coil 1 force/current factor, a long description" for k in trends}
    fig = plot_trends(trends, labels=labels)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        left = ax._left_title
        right = next(t for t in ax.texts if "drift" in t.get_text())
        a, b = left.get_window_extent(renderer), right.get_window_extent(renderer)
        assert not a.overlaps(b), (left.get_text(), right.get_text())


def test_closed_loop_z_plane_is_zoomed_on_the_slow_poles():
    # The simulator's loop has a deadbeat observer (poles at z = 0) beside slow
    # poles near z = 1: on the whole unit circle both were blobs.
    from maglevid.control.feedback import close_loop, controller_state_space
    from maglevid.plotting.diagnosis import plot_pole_maps
    from maglevid.simulate import simulate_amb_loop

    loop = simulate_amb_loop(NOMINAL, nominal=NOMINAL, dt=1e-4, n_samples=200, rng=1).loop
    base = discretize(amb_state_space(NOMINAL), 1e-4)
    ident = discretize(amb_state_space(NOMINAL.with_fault(R1=1.2)), 1e-4)
    K = controller_state_space(dict(loop), plant=base)
    fig = plot_pole_maps(base, ident, closed_loop=(close_loop(base, K), close_loop(ident, K)))
    ax = fig.axes[3]
    lo, hi = ax.get_xlim()
    assert hi - lo < 0.5  # a window near z = 1, not the whole circle (width 2.24)
    assert "not shown" in ax.get_title()
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert any("expected" in t and "magnetic bearing" in t for t in texts)
