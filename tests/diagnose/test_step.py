"""Step test of a parameter's history (issue 18's `history`: trend or step)."""

from __future__ import annotations

import numpy as np

from maglevid.diagnose.step import detect_step, step_fits_better


def test_false_alarm_rate_at_most_alpha():
    # Bonferroni over the n - 3 splits makes the test conservative: at most 1 %
    # of 400 steady series of 20 points are flagged; Binomial(400, 0.01) exceeds
    # 10 with probability < 0.3 %.
    rng = np.random.default_rng(7)
    flagged = 0
    for _ in range(400):
        y = 2.0 + 0.01 * rng.standard_normal(20)
        flagged += int(detect_step(y, np.full(20, 0.01), alpha=0.01).significant)
    assert flagged <= 10


def test_a_step_is_found_where_it_is_and_beats_a_line():
    rng = np.random.default_rng(1)
    t = np.arange(20.0)
    y = np.where(t < 12, 1.0, 0.8) + 0.005 * rng.standard_normal(20)  # kw1 -20 % at point 12
    se = np.full(20, 0.005)
    s = detect_step(y, se)
    assert s.significant and s.index == 12
    assert abs(s.size + 0.2) < 4 * 0.005 * np.sqrt(1 / 12 + 1 / 8)
    assert step_fits_better(t, y, se, s)


def test_a_ramp_is_a_trend_not_a_step():
    rng = np.random.default_rng(2)
    t = np.arange(20.0)
    y = 2.0 + 0.01 * t + 0.005 * rng.standard_normal(20)
    se = np.full(20, 0.005)
    s = detect_step(y, se)
    assert not step_fits_better(t, y, se, s)


def test_too_short_and_unknown_errors():
    assert detect_step([1.0, 2.0, 3.0, 4.0]) is None
    s = detect_step([1.0, 1.1, 0.9, 1.0, 3.0, 3.1, 2.9, 3.0], [np.nan] * 8)
    assert s.index == 4 and s.significant
