"""Discrete PID-type controllers, loop margins and the retuned controllers of Sun et al."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.control.pid import (
    PAPER_PID,
    RETUNED_LEAD_LAG,
    RETUNED_PID,
    DiscreteController,
    closed_loop_poles,
    closed_loop_polynomial,
    loop_margins,
    noise_gain,
    tune_controller,
)
from maglevid.exceptions import DataError, DesignError
from maglevid.physics.suspension import (
    PRINTED_T_MODEL_28,
    SuspensionParameters,
    suspension_t_model,
)

A_NOM, B_NOM = suspension_t_model(SuspensionParameters.nominal())
A_PRINTED = np.r_[1.0, PRINTED_T_MODEL_28["a"]]
B_PRINTED = np.r_[0.0, PRINTED_T_MODEL_28["b"]]


def test_printed_pid_does_not_stabilise_the_printed_plant():
    # Section 5's controller with (28) as printed, and with our nominal model:
    # C A + D B has a root outside the unit circle in both cases.
    for a, b in ((A_PRINTED, B_PRINTED), (A_NOM, B_NOM)):
        r = np.max(np.abs(closed_loop_poles(PAPER_PID, a, b)))
        assert r > 1.1, r
    assert not loop_margins(PAPER_PID, A_NOM, B_NOM).stable
    assert noise_gain(PAPER_PID, A_NOM, B_NOM) == np.inf


def test_printed_pid_gains_have_an_integral_of_the_wrong_sign():
    Kp, Ki, Kd = PAPER_PID.gains
    assert Kp < 0 and Kd < 0 and Ki > 0  # documented in docs/sun.md


@pytest.mark.parametrize("ctl", [RETUNED_PID, RETUNED_LEAD_LAG])
def test_retuned_controllers_keep_the_printed_orders(ctl):
    # n_d = 2, n_c = 1: identifiability condition (2) (n_c > 2 or n_d > 2 for a
    # third-order plant with tau_T = 1) fails, as in the paper.
    assert ctl.orders == (2, 1)
    n_a = n_b = 3
    tau = 1
    n_d, n_c = ctl.orders
    assert not (n_c > n_b - tau or n_d > n_a - tau)


@pytest.mark.parametrize("a,b", [(A_NOM, B_NOM), (A_PRINTED, B_PRINTED)])
def test_retuned_controllers_stabilise_nominal_and_printed_plant(a, b):
    for ctl in (RETUNED_PID, RETUNED_LEAD_LAG):
        assert np.max(np.abs(closed_loop_poles(ctl, a, b))) < 1.0


def test_retuned_lead_lag_has_sensible_margins():
    m = loop_margins(RETUNED_LEAD_LAG, A_NOM, B_NOM)
    assert m.stable
    assert m.peak_sensitivity < 2.3  # modulus margin > 0.43
    assert m.phase_margin_deg > 25
    assert m.gain_margin_upper > 4.0  # +12 dB
    assert m.gain_margin_lower < 0.7  # -3 dB (the unstable plant needs a minimum gain)
    np.testing.assert_allclose(noise_gain(RETUNED_LEAD_LAG, A_NOM, B_NOM), 3e5, rtol=1e-3)


def test_best_pid_has_poor_margins_documented():
    # No PID does better on this plant (global search in tune_controller; docs/sun.md).
    m = loop_margins(RETUNED_PID, A_NOM, B_NOM)
    assert m.stable
    assert 18 < m.peak_sensitivity < 20
    assert 0.9 < m.gain_margin_lower < 1.0 < m.gain_margin_upper < 1.3


def test_pid_velocity_form_round_trip():
    c = DiscreteController.pid(Kp=-2.0, Ki=-0.5, Kd=-3.0, dt=0.01)
    np.testing.assert_allclose(c.gains, (-2.0, -0.5, -3.0), rtol=1e-12)
    assert DiscreteController.from_dict(c.to_dict()).num.tolist() == c.num.tolist()
    assert c.to_dict()["type"] == "pid"
    # frequency response: D/C at z = -1
    np.testing.assert_allclose(
        c.frequency_response(np.pi / c.dt)[0], np.polyval(c.num[::-1], -1) / 2, rtol=1e-12
    )


def test_closed_loop_polynomial_is_CA_plus_DB():
    c = DiscreteController([2.0, 1.0], [1.0, -0.5], 1.0)
    g = closed_loop_polynomial(c, [1.0, -1.5], [0.0, 1.0])
    # (1 - 0.5 z)(1 - 1.5 z) + (2 + z) z  with z = z^-1
    np.testing.assert_allclose(g, [1.0, 0.0, 1.75], rtol=1e-12)


def test_margins_of_a_known_loop():
    # L = k z^-1/(1 - z^-1) (integrator): stable for 0 < k < 2; at k = 1 the
    # closed loop is deadbeat; phase margin 60 deg at w = pi/3.
    c = DiscreteController([1.0], [1.0, -1.0], 1.0)
    m = loop_margins(c, [1.0], [0.0, 1.0])
    assert m.stable
    np.testing.assert_allclose(m.gain_margin_upper, 2.0, rtol=1e-9)
    np.testing.assert_allclose(m.phase_margin_deg, 60.0, rtol=1e-6)
    np.testing.assert_allclose(m.crossover_rad_s, np.pi / 3, rtol=1e-6)
    # noise gain: u = -D A/(C A + D B) w = -w (deadbeat), so ||.||_2 = 1
    np.testing.assert_allclose(noise_gain(c, [1.0], [0.0, 1.0]), 1.0, rtol=1e-12)
    # with gain 1/2: u = -0.5/(1 - 0.5 z^-1) w, ||.||_2 = 0.5/sqrt(1 - 0.25)
    half = DiscreteController([0.5], [1.0, -1.0], 1.0)
    np.testing.assert_allclose(
        noise_gain(half, [1.0], [0.0, 1.0]), 0.5 / np.sqrt(0.75), rtol=1e-10
    )


@pytest.mark.slow
def test_tune_controller_stabilises_a_simple_unstable_plant():
    # First-order unstable plant b/(1 - 1.2 z^-1): the tuner must find a stable
    # lead-lag with a modest peak sensitivity within the noise budget.
    a, b = [1.0, -1.2], [0.0, 1.0]
    ctl = tune_controller(a, b, 1.0, kind="lead-lag", max_noise_gain=5.0, maxiter=40)
    m = loop_margins(ctl, a, b)
    assert m.stable and m.peak_sensitivity < 2.5
    assert noise_gain(ctl, a, b) <= 5.0 * 1.01


def test_controller_validation():
    with pytest.raises(DataError, match="den\\[0\\]"):
        DiscreteController([1.0], [2.0, 1.0], 1.0)
    with pytest.raises(DataError, match="kind"):
        DiscreteController([1.0], [1.0], 1.0, "fuzzy")
    with pytest.raises(DataError, match="dt"):
        DiscreteController([1.0], [1.0], -1.0)
    with pytest.raises(DesignError, match="PID"):
        _ = RETUNED_LEAD_LAG.gains


def test_no_single_digit_misprint_makes_the_printed_pid_stabilise():
    # Could one wrong digit explain the unstable printed controller? Change each of
    # its 12 printed digits to every other value: none stabilises eq. (28).
    printed = ["0.5973", "1.1897", "0.5833"]
    signs = np.array([1.0, -1.0, 1.0])
    for k, text in enumerate(printed):
        for pos, ch in enumerate(text):
            if ch == ".":
                continue
            for d in "0123456789":
                if d == ch:
                    continue
                v = [float(t) for t in printed]
                v[k] = float(text[:pos] + d + text[pos + 1 :])
                ctl = DiscreteController(-1e5 * signs * np.array(v), [1.0, -1.0], 2.4e-3)
                assert np.max(np.abs(closed_loop_poles(ctl, A_NOM, B_NOM))) > 1.0, (k, pos, d)
