"""Data-quality checks: each failure has a recording that triggers it, a clean one passes all."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.diagnose.checks import (
    check_channels_move,
    check_excitation,
    check_feedback_consistency,
    check_length,
    check_levitation,
    check_output_clipping,
    check_saturation,
    check_units,
    run_checks,
)
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

NOMINAL = AMBParameters.nominal()


@pytest.fixture(scope="module")
def clean():
    return simulate_amb_loop(
        NOMINAL, dt=1e-4, n_samples=4000, nominal=NOMINAL, rng=3, plant_model="linear"
    )


def test_clean_recording_passes_every_check(clean):
    checks = run_checks(clean)
    assert all(c.passed for c in checks), [c.message for c in checks if not c.passed]
    fb = next(c for c in checks if c.name == "feedback consistency")
    assert fb.value < 1e-9  # the simulator's feedback replays to round-off


def test_too_short(clean):
    c = check_length(clean.segment(0, 500))
    assert not c.passed and "too short" in c.message and c.value == 500


def test_too_little_excitation():
    rec = simulate_amb_loop(NOMINAL, dt=1e-4, n_samples=3000, nominal=NOMINAL, excitation_std=1e-4,
                            rng=4, plant_model="linear")  # fmt: skip
    c = check_excitation(rec)
    assert not c.passed and "too little excitation" in c.message
    assert not check_excitation(rec.replace(r=None, u=rec.u)).passed


def test_saturation(clean):
    u = np.array(clean.u)
    lim = np.quantile(u[:, 0], 0.97)
    u[:, 0] = np.minimum(u[:, 0], lim)  # 3 % of samples clipped at one value
    c = check_saturation(clean.replace(u=u))
    assert not c.passed and "saturates" in c.message
    assert c.value == pytest.approx(0.03, abs=0.005)
    # With stated limits, the same test counts samples at or beyond them.
    assert not check_saturation(clean, limits=[(-0.1, 0.1), (-0.1, 0.1)]).passed


def test_lost_levitation(clean):
    y = np.array(clean.y)
    y[2000:, 0] = 0.8 * NOMINAL.x0  # rotor on the retainer bearing
    c = check_levitation(clean.replace(y=y))
    assert not c.passed and "levitation was lost" in c.message
    y[:, 0] = 1e-6
    assert "does not move" in check_levitation(clean.replace(y=y)).message


def test_feedback_inconsistent_with_stated_controller(clean):
    loop = clean.replace().loop
    import copy

    from maglevid.jsonable import thaw

    bad = copy.deepcopy(thaw(loop))
    bad["controller"]["F"] = (1.1 * np.asarray(bad["controller"]["F"])).tolist()
    c = check_feedback_consistency(clean.replace(loop=bad))
    assert not c.passed and "inconsistent with the stated controller" in c.message
    # Swapped output channels are caught the same way.
    swapped = clean.replace(y=np.asarray(clean.y)[:, [0, 2, 1]])
    assert not check_feedback_consistency(swapped).passed


def test_a_dead_channel_is_named(clean):
    # An all-zero coil current (a dead sensor) was reported only as "logged feedback
    # differs from the stated controller by 47 %", and a constant levitator current as
    # "Singular matrix" (found from outside, issue 16, thirteenth session).
    y = np.array(clean.y, copy=True)
    y[:, 1] = 0.0
    q = check_channels_move(clean.replace(y=y))
    assert not q.passed and q.blocking
    assert q.message.startswith("constant channel(s): i1 = 0 throughout")
    assert check_channels_move(clean).passed


def test_a_displacement_beyond_the_gap_names_the_units(clean):
    # A displacement logged in mm (x 1000) was called a touch-down (found from outside,
    # issue 16, thirteenth session): beyond about one air gap the backup bearing stops
    # any rotor, so the units (or the stated gap) are what is wrong.
    y = np.array(clean.y, copy=True)
    y[:, 0] *= 1000.0
    q = check_levitation(clean.replace(y=y))
    assert not q.passed and "probably not in metres (mm?)" in q.message
    assert "touch-down" not in q.message


def test_coil_currents_in_ma_read_as_a_are_refused(clean):
    # Currents logged in mA under a label of A passed every check and identified R1 =
    # 1.7e-5 ohm +- 0.4 % (found from outside, issue 16, fourteenth session): a coil
    # current i0 + di stays within about [0, 2 i0], so ten bias currents is no bearing.
    y = np.array(clean.y, copy=True)
    y[:, 1:] *= 1000.0
    q = check_units(clean.replace(y=y))
    assert not q.passed and "probably logged in mA" in q.message and "'i1'" in q.message
    assert check_units(clean).passed


def test_absolute_coil_currents_are_refused_with_the_offset_to_subtract(clean):
    # Coil currents logged as i0 + di passed every check and read "Fault: bias current i0
    # -100 %" (found from outside, seventeenth session): a fault moves the currents' mean
    # by milliamperes, so a mean of half a bias current or more is not a deviation.
    i0 = clean.loop["operating_point"]["i0"]
    y = np.array(clean.y, copy=True)
    y[:, 1:] += i0
    q = check_units(clean.replace(y=y))
    assert not q.passed and "'i1' and 'i2'" in q.message
    assert "absolute current" in q.message and f'"offset": {-i0:.6g}' in q.message
    y = np.array(clean.y, copy=True)
    y[:, 2] -= 0.6 * i0  # one channel, not i0: an offset, not the absolute current
    q = check_units(clean.replace(y=y))
    assert not q.passed and "'i2'" in q.message and "'i1'" not in q.message
    assert "absolute" not in q.message and "offset, or i0 is wrong" in q.message
    y = np.array(clean.y, copy=True)
    y[:, 1:] += 0.4 * i0  # within the limit
    assert check_units(clean.replace(y=y)).passed
    y = np.array(clean.y, copy=True)
    y[:, 1:] = (y[:, 1:] + 0.01) * 1000.0  # mA: the swing's message alone
    q = check_units(clean.replace(y=y))
    assert "probably logged in mA" in q.message and "offset" not in q.message


def test_an_absolute_gap_is_named_not_called_a_touch_down(clean):
    # x logged as the gap x0 + x read "levitation was lost (touch-down)" (found from
    # outside, seventeenth session).
    x0 = clean.loop["operating_point"]["x0"]
    y = np.array(clean.y, copy=True)
    y[:, 0] += x0
    q = check_levitation(clean.replace(y=y))
    assert not q.passed and "absolute gap x0 + x" in q.message and "touch-down" not in q.message
    y = np.array(clean.y, copy=True)
    y[:100, 0] = 0.9 * x0  # a real touch-down stays one
    assert "touch-down" in check_levitation(clean.replace(y=y)).message


def test_a_clipped_output_sensor_is_refused(clean):
    # x clipped at its 30th and 70th percentiles passed every check of a user's .mat and
    # identified R1 = 3.07 ohm (17.5 true; found from outside, seventeenth session).
    y = np.array(clean.y, copy=True)
    lo, hi = np.percentile(y[:, 0], [30, 70])
    y[:, 0] = np.clip(y[:, 0], lo, hi)
    q = check_output_clipping(clean.replace(y=y))
    assert not q.passed and "'x' (30 % of its samples)" in q.message and "clipped" in q.message
    assert q.value == pytest.approx(0.3, abs=0.01)
    gate = {c.name: c for c in run_checks(clean.replace(y=y))}
    assert not gate["output clipping"].passed
    assert check_output_clipping(clean).passed
    # A coarse ADC (steps of one standard deviation: 8 levels) thins out at its extremes:
    # not a clip. A fine one (steps of 0.05 std) clipped at +1.5 std is: ~7 % of the
    # samples on the top level against ~0.5 % on the next.
    y = np.array(clean.y, copy=True)
    step = np.std(y[:, 1])
    y[:, 1] = np.round(y[:, 1] / step) * step
    assert check_output_clipping(clean.replace(y=y)).passed
    y = np.array(clean.y, copy=True)
    y[:, 1] = np.minimum(np.round(y[:, 1] / (0.05 * step)) * 0.05 * step, 1.5 * step)
    q = check_output_clipping(clean.replace(y=y))
    assert not q.passed and "'i1'" in q.message


def test_outputs_in_another_order_are_named_not_only_the_units(clean):
    # y saved as [i1, i2, x]: the refusal blamed the units ("mm?") only (found from
    # outside, issue 16, fourteenth session); the displacement-sized third channel is
    # now named as the likely first one.
    y = np.asarray(clean.y)[:, [1, 2, 0]]
    q = check_levitation(clean.replace(y=y))
    assert not q.passed and "another order" in q.message and "'x'" not in q.message
    y_mm = np.array(clean.y, copy=True)
    y_mm[:, 0] *= 1000.0  # the units indeed: no order hint
    assert "another order" not in check_levitation(clean.replace(y=y_mm)).message
